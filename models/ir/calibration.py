"""What the models know of the Sharp IR sensors: the lab-1 fits V = a d^b + c (seed 000).

Distances in cm, voltages in V. The fits pass through the seed's endpoints with the seed's
exponents (its Jacobians: -29.088 d^-1.873 for the long sensor, -8.594 d^-1.7114 for the
medium one; the short one takes the ideal -1), rounded as a calibration sheet would give
them; the variances are the seed's residual standard deviations squared (0.026, 0.015,
0.089 V). Outside ``[d_min, d_max]`` a fit is not trusted: below it the real curve folds
back (the output falls again), far beyond it the slope is lost in the noise.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any


@dataclass(frozen=True)
class PowerLaw:
    """One sensor's fit: V = a d^b + c on [d_min, d_max] cm, noise variance ``var`` V^2."""

    part: str
    alias: str
    a: float
    b: float
    c: float
    d_min: float
    d_max: float
    var: float

    def volts(self, d: float) -> float:
        """Predicted output (V) at ``d`` cm (d clamped to >= 1 cm, as the seed's firmware)."""
        return self.a * max(d, 1.0) ** self.b + self.c

    def slope(self, d: float) -> float:
        """dV/dd (V/cm) at ``d`` cm: a b d^(b - 1) (the seed's Jacobian)."""
        return self.a * self.b * max(d, 1.0) ** (self.b - 1.0)

    def distance(self, v: float) -> float:
        """The distance (cm) whose predicted output is ``v`` (the fit inverted):
        ``inf`` at or below the asymptote c, where the fit has no distance."""
        if v <= self.c:
            return math.inf
        return ((v - self.c) / self.a) ** (1.0 / self.b)

    def sigma_d(self, d: float) -> float:
        """Distance noise (cm) of one reading at ``d`` cm: sqrt(var) / |dV/dd|."""
        return math.sqrt(self.var) / abs(self.slope(d))


FITS = {
    f.part: f
    for f in (
        PowerLaw("GP2Y0A41SK0F", "short", 9.231, -1.0, 0.0323, 4.0, 30.0, 0.026**2),
        PowerLaw("GP2Y0A21YK0F", "medium", 12.33, -0.7114, -0.4057, 10.0, 80.0, 0.015**2),
        PowerLaw("GP2Y0A02YK0F", "long", 34.68, -0.873, -0.0369, 20.0, 150.0, 0.089**2),
    )
}


def fit(name: str, override: Any = None) -> PowerLaw:
    """The fit of a variant (part number or short/medium/long), optionally overridden by
    ``[a, b, c]`` from a calibration; ValueError naming what is wrong."""
    law = next((f for f in FITS.values() if name in (f.part, f.alias)), None)
    if law is None:
        known = ", ".join(f"{f.part} ({f.alias})" for f in FITS.values())
        raise ValueError(f"unknown Sharp IR variant {name!r}; known: {known}")
    if override is None:
        return law
    if (
        not isinstance(override, Sequence)
        or len(override) != 3
        or not all(isinstance(x, (int, float)) and math.isfinite(x) for x in override)
    ):
        raise ValueError(f"a fit must be [a, b, c] (three numbers), got {override!r}")
    a, b, c = (float(x) for x in override)
    if a <= 0 or b >= 0:
        raise ValueError(f"a fit needs a > 0 and b < 0 (V falls with distance), got {override!r}")
    return replace(law, a=a, b=b, c=c)


def sensor_fits(
    sensors: Mapping[str, str], fits: Mapping[str, Any] | None, r: Mapping[str, float] | None
) -> dict[str, PowerLaw]:
    """Publication name -> fit, from ``sensors`` (name -> variant), optional ``fits`` (name
    -> [a, b, c]) and ``r`` (name -> variance V^2); ValueError naming a bad entry."""
    if not isinstance(sensors, Mapping) or not sensors:
        raise ValueError(f"sensors must be a table of name = variant, got {sensors!r}")
    fits, r = dict(fits or {}), dict(r or {})
    for what, table in (("fits", fits), ("r", r)):
        unknown = sorted(set(table) - set(sensors))
        if unknown:
            raise ValueError(f"{what} names {unknown}, which are not sensors ({sorted(sensors)})")
    out = {}
    for name, part in sensors.items():
        law = fit(str(part), fits.get(name))
        if name in r:
            var = r[name]
            if isinstance(var, bool) or not isinstance(var, (int, float)) or not var > 0:
                raise ValueError(f"r[{name!r}] must be a variance > 0 (V^2), got {var!r}")
            law = replace(law, var=float(var))
        out[name] = law
    return out
