"""Bilateration: a 2-D position from two sonar ranges (thesis ch. 3.3).

Each sonar sample is ``[range m, sonar x, sonar y]``. When two different sonars have a
reading at most ``max_age`` s old (measurement times; the original used 1 s), the two
circles are intersected; of the two solutions the one on the ``keep`` side of the line
through the sonars is kept (the original rejected the lower one: ``keep = "upper"``).
``target_radius`` (m) is added to each range, since a sonar sees the target's surface.

Improvement over the original: with ``beams`` ({sonar node: [x, y] pointing direction}) a
solution outside either sonar's beam (a cone of ``half_angle_deg``) is rejected (counted in
``outside``): a sonar cannot have seen a target there, so one of the two readings was of
something else (the far side of the track, a reading from before the target entered the
beam). Without beams every solution is kept, as in the original.
"""

from __future__ import annotations

import math

from hera.models.train.beams import in_cone, unit_directions
from hera.store import Sample


def intersect(
    p1: tuple[float, float], r1: float, p2: tuple[float, float], r2: float
) -> tuple[tuple[float, float], tuple[float, float]] | None:
    """Both intersections of circles (p1, r1) and (p2, r2), or None if they do not meet
    (the two solutions coincide when the circles touch)."""
    dx, dy = p2[0] - p1[0], p2[1] - p1[1]
    d = math.hypot(dx, dy)
    if d == 0 or d > r1 + r2 or d < abs(r1 - r2):
        return None
    a = (r1 * r1 - r2 * r2 + d * d) / (2 * d)  # distance from p1 to the chord's midpoint
    h = math.sqrt(max(0.0, r1 * r1 - a * a))
    mx, my = p1[0] + a * dx / d, p1[1] + a * dy / d
    return (mx - h * dy / d, my + h * dx / d), (mx + h * dy / d, my - h * dx / d)


class Bilateration:
    """Fusion model ``bilateration``: output ``[x m, y m, span s]``, span: how long before the
    fix's time the older of its two readings was taken (a moving target was seen at two
    places: the fix describes it about span / 2 earlier)."""

    inputs = ("sonar",)
    columns = ("x [m]", "y [m]", "span [s]")

    def __init__(
        self,
        max_age: float = 1.0,
        keep: str = "upper",
        target_radius: float = 0.0,
        beams: dict[str, list[float]] | None = None,
        half_angle_deg: float = 20.0,
    ):
        if keep not in ("upper", "lower"):
            raise ValueError(f"keep must be 'upper' or 'lower', got {keep!r}")
        if not max_age > 0:
            raise ValueError(f"max_age must be > 0 s, got {max_age!r}")
        self.max_age = float(max_age)
        self.keep = keep
        self.target_radius = float(target_radius)
        self.beams = unit_directions(beams)
        self.beam_cos = math.cos(math.radians(half_angle_deg))
        self._latest: dict[str, Sample] = {}
        self._estimate: tuple[float, list[float]] | None = None
        self.misses = 0
        self.outside = 0

    def in_beam(self, sonar: Sample, x: float, y: float) -> bool:
        """Whether (x, y) lies in the beam of the sonar that took ``sonar`` (True if its
        direction is unknown)."""
        d = self.beams.get(sonar.node)
        if d is None:
            return True
        return in_cone(d, x - sonar.values[1], y - sonar.values[2], self.beam_cos)

    def process(self, sample: Sample) -> bool:
        """Remember the sonar's reading and solve with the freshest other sonar's."""
        if sample.name != "sonar" or len(sample.values) < 3:
            return False
        self._latest[sample.node] = sample
        others = [
            s
            for node, s in self._latest.items()
            if node != sample.node and 0 <= sample.t - s.t <= self.max_age
        ]
        if not others:
            return False
        other = max(others, key=lambda s: s.t)
        a, b = sample.values, other.values
        sol = intersect(
            (a[1], a[2]), a[0] + self.target_radius, (b[1], b[2]), b[0] + self.target_radius
        )
        if sol is None:
            self.misses += 1
            return False
        pick = max if self.keep == "upper" else min
        x, y = pick(sol, key=lambda p: p[1])
        if not (self.in_beam(sample, x, y) and self.in_beam(other, x, y)):
            self.outside += 1
            return False
        self._estimate = (sample.t, [x, y, sample.t - other.t])
        return True

    def counters(self) -> dict[str, int]:
        """Pairs whose circles did not meet (``misses``), solutions outside a beam
        (``outside``)."""
        return {"misses": self.misses, "outside": self.outside}

    def estimate(self) -> tuple[float, list[float]] | None:
        return self._estimate
