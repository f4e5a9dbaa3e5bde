"""The voltage a Sharp IR range sensor outputs, and its noise (seed 000, lab 1).

Above its minimum range a sensor follows the power law V = a d^b + c (d in cm, V in volts),
fitted to the seed's endpoints with the seed's exponent (its Jacobians give b for the
medium and long sensors; the short one uses the ideal triangulation exponent b = -1):

=================  ======================  =======================  =====  ========
variant            range (cm)              endpoints (seed)         b      std (V)
=================  ======================  =======================  =====  ========
GP2Y0A41SK0F       4 - 30 ("short")        2.34 V at 4, 0.34 at 30  -1     0.026
GP2Y0A21YK0F       10 - 80 ("medium")      1.99 V at 10, 0.14 at 80 -0.7114 0.015
GP2Y0A02YK0F       20 - 150 ("long")       2.50 V at 20, 0.40 at 150 -0.873 0.089
=================  ======================  =======================  =====  ========

Below the minimum range the output is not monotonic (the sensor's data sheet curve): it
keeps rising to a peak at ``peak_frac`` x the minimum range, then falls linearly to
``floor_frac`` of the peak at 0 cm. A reading is then: the curve, + Gaussian noise with
the seed's residual standard deviation, + rare heavy-tail events (``tail_prob``, ``tail_scale``
x the standard deviation: the seed's QQ plots), + for the short sensor the "two-spike"
toggle (``toggle_prob`` of readings shifted by ``toggle_v``: the seed's bimodal histogram),
clamped to the ADC's 0 - 3.3 V and quantised to 12 bits.
"""

from __future__ import annotations

import random
from dataclasses import dataclass
from typing import Any

from hera.nodes.ir.tables import numbers_into

V_REF = 3.3
"""ADC full scale (V): STM32F407 ADC1, 12 bits."""
ADC_CODES = 4095


@dataclass(frozen=True)
class Variant:
    """One Sharp sensor type: its name, alias, range (cm), seed endpoints (V) and exponent."""

    part: str
    alias: str
    d_min: float
    d_max: float
    v_at_min: float
    v_at_max: float
    b: float
    noise_v: float

    @property
    def a(self) -> float:
        """Scale of the power law, so that it passes through both endpoints."""
        return (self.v_at_min - self.v_at_max) / (self.d_min**self.b - self.d_max**self.b)

    @property
    def c(self) -> float:
        """Offset of the power law (V)."""
        return self.v_at_min - self.a * self.d_min**self.b


VARIANTS = {
    v.part: v
    for v in (
        Variant("GP2Y0A41SK0F", "short", 4.0, 30.0, 2.34, 0.34, -1.0, 0.026),
        Variant("GP2Y0A21YK0F", "medium", 10.0, 80.0, 1.99, 0.14, -0.7114, 0.015),
        Variant("GP2Y0A02YK0F", "long", 20.0, 150.0, 2.50, 0.40, -0.873, 0.089),
    )
}


def variant(name: str) -> Variant:
    """The variant by part number or alias (``short``, ``medium``, ``long``); ValueError
    naming the known ones."""
    for v in VARIANTS.values():
        if name in (v.part, v.alias):
            return v
    known = ", ".join(f"{v.part} ({v.alias})" for v in VARIANTS.values())
    raise ValueError(f"unknown Sharp IR variant {name!r}; known: {known}")


@dataclass(frozen=True)
class SharpModel:
    """Error model of one simulated sensor (every field can be set by the measure arg
    ``model``); ``None`` means the variant's own value."""

    noise_v: float | None = None
    """Gaussian noise std (V); default the seed's residual std of the variant."""
    tail_prob: float = 0.01
    """Probability of a heavy-tail event (A: the seed's QQ plots show heavy tails)."""
    tail_scale: float = 5.0
    """Std of a heavy-tail event, in noise stds."""
    toggle_prob: float | None = None
    """Probability that a reading sits on the second spike (default 0.2 short, 0 others)."""
    toggle_v: float = 0.25
    """Offset of the second spike (V) (A: the seed shows two spikes, not their distance)."""
    gain: float = 1.0
    """Gain error of this unit on a d^b (1 = the seed's fit holds exactly)."""
    offset_v: float = 0.0
    """Offset error of this unit (V)."""
    peak_frac: float = 0.7
    """The curve peaks at this fraction of the minimum range (A, data sheet shape)."""
    floor_frac: float = 0.3
    """At 0 cm the output is this fraction of the peak (A, data sheet shape)."""
    no_return_cm: float = 500.0
    """Distance read when nothing is in the beam (the curve's far end: about c)."""

    @classmethod
    def from_args(cls, table: Any) -> SharpModel:
        """A model from the measure arg ``model``; ValueError naming a bad field."""
        model = numbers_into(
            cls,
            table,
            "Sharp IR model",
            ("noise_v", "tail_prob", "tail_scale", "toggle_prob", "no_return_cm"),
        )
        for k in ("tail_prob", "toggle_prob"):
            value = getattr(model, k)
            if value is not None and value > 1:
                raise ValueError(f"Sharp IR model field {k!r} must be <= 1, got {value!r}")
        if not 0 < model.peak_frac < 1 or not 0 <= model.floor_frac <= 1:
            raise ValueError("Sharp IR peak_frac must be in (0, 1) and floor_frac in [0, 1]")
        return model


def curve(v: Variant, d_cm: float, gain: float = 1.0, offset_v: float = 0.0) -> float:
    """The noise-free output (V, before clamping) at ``d_cm`` cm: the power law above
    ``peak_frac`` x the minimum range, the falling branch below (see module docstring)."""
    return _curve(v, d_cm, SharpModel(gain=gain, offset_v=offset_v))


def _curve(v: Variant, d_cm: float, m: SharpModel) -> float:
    d_peak = m.peak_frac * v.d_min
    if d_cm >= d_peak:
        return m.gain * v.a * d_cm**v.b + v.c + m.offset_v
    peak = m.gain * v.a * d_peak**v.b + v.c + m.offset_v
    floor = m.floor_frac * peak
    return floor + (peak - floor) * max(d_cm, 0.0) / d_peak


def quantise(volts: float) -> float:
    """Clamp to 0 - 3.3 V and round to the nearest of the 12-bit ADC's 4096 codes."""
    code = round(min(max(volts, 0.0), V_REF) / V_REF * ADC_CODES)
    return code * V_REF / ADC_CODES


def reading(v: Variant, m: SharpModel, d_cm: float | None, rng: random.Random) -> float:
    """One ADC reading (V) of a target at ``d_cm`` (None: nothing in the beam)."""
    d = m.no_return_cm if d_cm is None else d_cm
    sigma = v.noise_v if m.noise_v is None else m.noise_v
    noise = rng.gauss(0.0, sigma)
    if rng.random() < m.tail_prob:
        noise += rng.gauss(0.0, m.tail_scale * sigma)
    toggle = m.toggle_prob
    if toggle is None:
        toggle = 0.2 if v.alias == "short" else 0.0
    if rng.random() < toggle:
        noise += m.toggle_v
    return quantise(_curve(v, d, m) + noise)
