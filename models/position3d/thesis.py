"""The thesis's 3-D position from three sonars (e10, thesis ch. 7.2, eq. 7.6).

A linear Kalman filter on the position [x, y, z] (m) with ``F = I`` and ``Q = q_var I`` per
step (sigma_p = 5 cm: the target is taken as still, up to that), and one row per sonar
reading: each sonar lies on one axis, so a reading r gives that axis's coordinate
``offset + sign * (r + target_radius)`` (the sonar's coordinate on its axis and the sign of
its direction), with ``R = r_var`` (sigma_s = 10 cm, the size of the board on its support).
A step is one sonar reading: predict (P += Q), then update the reading's axis. No gating, no
beam check: an off-axis target is read at its slant range and taken for an axial one.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from hera.estimation import KalmanFilter, Observations
from hera.models.position3d.sonars import parse_sonars
from hera.store import Sample

COLUMNS = ("x [m]", "y [m]", "z [m]", "std x [m]", "std y [m]", "std z [m]")


class ThesisPosition:
    """e10 (see module docstring). Settings: ``sonars`` (required, axis-aligned, see
    :mod:`.sonars`), ``q_var`` (0.0025 m^2 per step), ``r_var`` (0.01 m^2),
    ``target_radius`` (0.05 m), ``x0`` (the first guess, m; default: the first readings)."""

    inputs = ("sonar",)
    columns = COLUMNS

    def __init__(
        self,
        sonars: Any = None,
        q_var: float = 0.0025,
        r_var: float = 0.01,
        target_radius: float = 0.05,
        x0: list[float] | None = None,
    ) -> None:
        if not (q_var > 0 and r_var > 0):
            raise ValueError(f"q_var and r_var must be > 0, got {q_var!r}, {r_var!r}")
        self.sonars = parse_sonars(sonars)
        self.axes = {n: s.axis() for n, s in self.sonars.items()}
        self.target_radius = float(target_radius)
        self.r_var = float(r_var)
        x = np.zeros(3) if x0 is None else np.array(x0, dtype=np.float64).reshape(3)
        # without a first guess, an axis is unknown (1 m^2) until its sonar reads
        self.kf = KalmanFilter(x, np.eye(3), np.eye(3), np.eye(3) * float(q_var))
        self.seen: set[int] = set() if x0 is None else {0, 1, 2}
        self.t: float | None = None
        self.other = 0

    @classmethod
    def check(cls, settings: dict[str, Any]) -> None:
        """Raise ValueError naming a bad setting (the model is cheap to build: build it)."""
        cls(**settings)

    def process(self, sample: Sample) -> bool:
        """One step per reading: predict, then fuse its axis."""
        if sample.name != "sonar" or not sample.values:
            return False
        axis = self.axes.get(sample.node)
        if axis is None:
            self.other += 1
            return False
        i, sign = axis
        coord = float(self.sonars[sample.node].position[i]) + sign * (
            float(sample.values[0]) + self.target_radius
        )
        kf = self.kf
        if i not in self.seen:  # first reading of this axis: start it there
            x = kf.x.copy()
            x[i] = coord
            kf.reset(x, kf.P)
            self.seen.add(i)
        kf.predict(1.0)
        H = np.zeros((1, 3))
        H[0, i] = 1.0
        kf.update(Observations().add(f"sonar@{sample.node}", [coord], H=H, R=self.r_var))
        self.t = sample.t if self.t is None else max(self.t, sample.t)
        return True

    def estimate(self) -> tuple[float, list[float]] | None:
        if self.t is None:
            return None
        x, P = self.kf.x, self.kf.P
        return self.t, [*(float(v) for v in x), *(math.sqrt(float(P[i, i])) for i in range(3))]

    def counters(self) -> dict[str, int]:
        """Readings of sonars the model was not told of (``other``)."""
        return {"other": self.other}
