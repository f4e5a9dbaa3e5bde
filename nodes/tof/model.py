"""Error model of the simulated VL53L1 (its sources: README "ToF height", board table).

A sensor sits at ``(x, y)`` on a rigid carrier board and looks along the board's -z axis;
the carrier's pose comes from the world's scenario. For a ranging at time t:

- true distance d: along the optical axis from the sensor to the desk plane z = 0 (a tilted
  board reads more than its height: d = z / cos(tilt));
- signal rate S = ``signal_k`` * reflectance * cos(incidence) / d^2 (Mcps), ambient rate A
  from the world's light, each with a relative noise;
- distance = (1 + scale) d + offset + n, n ~ N(0, sigma(d)^2), sigma(d) = ``sigma_m`` *
  max(1, d / ``sigma_ref_m``) (the return signal falls as 1/d^2), rounded to 1 mm; rates
  rounded to 1/128 Mcps (the chip's 9.7 fixed point);
- status: out of bounds beyond ``max_range_m``, signal fail below ``min_signal_mcps``,
  sigma fail when sigma(d) exceeds ``sigma_limit_m``, min-range clipped under
  ``min_range_m``; and, at random, an invalid ranging (sigma fail, signal fail or
  wrap-around with a wrong distance, probability ``invalid_prob``) or an outlier that the
  chip calls valid (``outlier_prob``: off by ``outlier_min_m`` .. ``outlier_max_m``, as from
  a reflection off the cover glass or a second target).

``offset`` / ``scale`` left unset are drawn once per sensor from the board seed with
``offset_sigma_m`` / ``scale_sigma`` (default 0: calibrated sensors, as the seed's "sigma
about 3 mm" describes them; the tests run biased and mis-scaled ones too).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

from hera.schema import Setting, Table, number

_NN = number(0)
_PROB = number(0, 1)

TOF_MODEL = Table(
    "vl53l1 model",
    [
        Setting("sigma_m", number(above=0), 0.003, "m, range noise (seed 001: about 3 mm)"),
        Setting("sigma_ref_m", number(above=0), 0.5, "m; beyond it the noise grows with d"),
        Setting("offset", number(-0.1, 0.1), None, "m, fixed offset (default: drawn)"),
        Setting("offset_sigma_m", _NN, 0.0, "m, spread of the offset left after calibration"),
        Setting("scale", number(-0.1, 0.1), None, "relative scale error (default: drawn)"),
        Setting("scale_sigma", _NN, 0.0, "spread of the relative scale error"),
        Setting("min_range_m", _NN, 0.04, "m, closer reads clipped (status 3)"),
        Setting("max_range_m", number(above=0), 4.0, "m, farther is out of bounds (status 4)"),
        Setting("signal_k", number(above=0), 0.4, "Mcps m^2, signal at 1 m off a white target"),
        Setting("signal_noise", _NN, 0.02, "relative noise of the signal rate"),
        Setting("ambient_noise", _NN, 0.05, "relative noise of the ambient rate"),
        Setting("min_signal_mcps", _NN, 0.1, "Mcps, a weaker return is a signal fail"),
        Setting("sigma_limit_m", number(above=0), 0.015, "m, noisier is a sigma fail"),
        Setting("invalid_prob", _PROB, 0.01, "probability of an invalid ranging"),
        Setting("outlier_prob", _PROB, 0.005, "probability of a wrong range marked valid"),
        Setting("outlier_min_m", _NN, 0.02, "m, smallest outlier error"),
        Setting("outlier_max_m", _NN, 0.3, "m, largest outlier error"),
        Setting("budget_ms", number(1, 1000), 33.0, "ms, timing budget of one ranging"),
    ],
)
"""The declared error-model settings (the measure arg ``model = {...}``)."""


@dataclass(frozen=True)
class TofModel:
    """Parameters of the VL53L1 error model (see the module docstring; fields are the keys
    of :data:`TOF_MODEL`)."""

    sigma_m: float = 0.003
    sigma_ref_m: float = 0.5
    offset: float | None = None
    offset_sigma_m: float = 0.0
    scale: float | None = None
    scale_sigma: float = 0.0
    min_range_m: float = 0.04
    max_range_m: float = 4.0
    signal_k: float = 0.4
    signal_noise: float = 0.02
    ambient_noise: float = 0.05
    min_signal_mcps: float = 0.1
    sigma_limit_m: float = 0.015
    invalid_prob: float = 0.01
    outlier_prob: float = 0.005
    outlier_min_m: float = 0.02
    outlier_max_m: float = 0.3
    budget_ms: float = 33.0

    @classmethod
    def from_args(cls, table: Mapping[str, Any] | None) -> TofModel:
        """Build from the measure arg ``model`` (checked against :data:`TOF_MODEL`;
        SchemaError, a ValueError, names a bad key or value)."""
        parsed = TOF_MODEL.parse(table or {}, "vl53l1 model")
        return cls(**{f.name: parsed[f.name] for f in fields(cls)})

    def sigma(self, d: float) -> float:
        """Range noise (m) at distance ``d`` (m)."""
        return self.sigma_m * max(1.0, d / self.sigma_ref_m)
