"""Error model of the simulated LSM6DSL (sources: README "2-D tilt", board table).

Per output sample at ODR f (bandwidth f / 2, so white noise of density D has the standard
deviation D sqrt(f / 2)):

- accelerometer (g): ``a = (1 + s_a) a_ideal + b_a + n_a + v_a``, a_ideal the specific force
  at the sample time, v_a the vehicle's vibration while its motors run;
- gyroscope (deg/s): ``w = (1 + s_g) w_avg + b_g + walk(t) + ramp(t) + n_g + v_g`` where
  w_avg is the mean rate over the sample's 1 / f interval (the chip's decimation filter),
  walk a random walk of the bias and ramp a linear bias drift (a warming chip):
  ``gyro_ramp_dps_s`` deg/s per second from ``ramp_start_s`` (s since the epoch) for
  ``ramp_s`` seconds, then held;
- both clipped to the full scale and rounded to the LSB.

Biases and scale errors left unset are drawn per board from the board seed.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

from hera.schema import Setting, Table, list_of, number

_NN = number(0)
_V3 = list_of(number(), "[x, y, z]")

IMU_MODEL = Table(
    "lsm6dsl model",
    [
        Setting("acc_density", _NN, 80e-6, "g/sqrt(Hz), accelerometer noise density"),
        Setting("acc_bias", _V3, None, "g, fixed zero-g offset (default: drawn)"),
        Setting("acc_bias_sigma", _NN, 0.002, "g, spread of the zero-g offset left after trim"),
        Setting("acc_scale_sigma", _NN, 0.005, "relative sensitivity error spread"),
        Setting("gyro_density", _NN, 0.004, "deg/s/sqrt(Hz), gyroscope rate noise density"),
        Setting("gyro_bias", _V3, None, "deg/s, fixed zero-rate level (default: drawn)"),
        Setting("gyro_bias_sigma", _NN, 1.0, "deg/s, spread of the zero-rate level"),
        Setting("gyro_drift", _NN, 0.003, "deg/s per sqrt(s), random walk of the bias"),
        Setting("gyro_ramp_dps_s", number(), 0.0, "deg/s per s, linear bias drift"),
        Setting("ramp_start_s", _NN, 0.0, "s after the epoch the drift starts"),
        Setting("ramp_s", _NN, 60.0, "s the drift lasts (then the bias stays)"),
        Setting("gyro_scale_sigma", _NN, 0.005, "relative sensitivity error spread"),
        Setting("acc_fs_g", number(above=0), 4.0, "g, accelerometer full scale"),
        Setting("gyro_fs_dps", number(above=0), 500.0, "deg/s, gyroscope full scale"),
    ],
)
"""The declared error-model settings (the measure arg ``model = {...}``)."""


@dataclass(frozen=True)
class ImuModel:
    """Parameters of the LSM6DSL error model (the keys of :data:`IMU_MODEL`)."""

    acc_density: float = 80e-6
    acc_bias: tuple[float, float, float] | None = None
    acc_bias_sigma: float = 0.002
    acc_scale_sigma: float = 0.005
    gyro_density: float = 0.004
    gyro_bias: tuple[float, float, float] | None = None
    gyro_bias_sigma: float = 1.0
    gyro_drift: float = 0.003
    gyro_ramp_dps_s: float = 0.0
    ramp_start_s: float = 0.0
    ramp_s: float = 60.0
    gyro_scale_sigma: float = 0.005
    acc_fs_g: float = 4.0
    gyro_fs_dps: float = 500.0

    @classmethod
    def from_args(cls, table: Mapping[str, Any] | None) -> ImuModel:
        """Build from the measure arg ``model`` (checked against :data:`IMU_MODEL`)."""
        parsed = IMU_MODEL.parse(table or {}, "lsm6dsl model")
        for key in ("acc_bias", "gyro_bias"):
            v = parsed[key]
            if v is not None and len(v) != 3:
                raise ValueError(f"lsm6dsl model: {key} must be [x, y, z], got {list(v)!r}")
        return cls(**{f.name: parsed[f.name] for f in fields(cls)})

    def ramp(self, tau: float) -> float:
        """The linear bias drift (deg/s) at ``tau`` s after the epoch."""
        if not self.gyro_ramp_dps_s or tau <= self.ramp_start_s:
            return 0.0
        return self.gyro_ramp_dps_s * min(tau - self.ramp_start_s, self.ramp_s)

    @staticmethod
    def lsb(full_scale: float) -> float:
        """The LSB of a 16-bit output at ``full_scale``."""
        return full_scale / 32768.0
