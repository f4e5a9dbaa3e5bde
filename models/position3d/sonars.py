"""Where the sonars of a 3-D position model are, and what one of their readings says.

A model is told its sonars in its settings: ``sonars = {<node>: {position = [x, y, z],
direction = [x, y, z]}}`` (m, world frame; the direction is normalised), the node being the
one whose ``sonar`` samples come from that sonar. A MaxSonar reports the distance to the
nearest surface of the target inside its beam, a cone of ``half_angle_deg``; the target is
taken as a sphere of ``target_radius`` (a GRiSP board on its support, thesis ch. 7.2), so a
reading r means the target's centre lies at ``r + target_radius`` from the sonar.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Sonar:
    """One sonar: ``node``, ``position`` (m) and unit ``direction`` (world frame)."""

    node: str
    position: np.ndarray
    direction: np.ndarray

    def in_beam(self, p: np.ndarray, cos_limit: float) -> bool:
        """Whether the point ``p`` lies within the cone whose half-angle has cosine
        ``cos_limit`` around this sonar's direction."""
        d = p - self.position
        n = float(np.sqrt(d @ d))
        return n > 0.0 and float(d @ self.direction) >= cos_limit * n

    def axis(self, tol_deg: float = 1.0) -> tuple[int, float]:
        """(index of the world axis it points along, +1 or -1) for a sonar aligned with an
        axis within ``tol_deg``; ValueError naming the sonar otherwise."""
        i = int(np.argmax(np.abs(self.direction)))
        if abs(float(self.direction[i])) < math.cos(math.radians(tol_deg)):
            raise ValueError(
                f"sonar {self.node!r} points along {self.direction.tolist()}, not along an axis: "
                "the thesis's linear model needs axis-aligned sonars"
            )
        return i, math.copysign(1.0, float(self.direction[i]))


def parse_sonars(table: Any) -> dict[str, Sonar]:
    """The ``sonars`` setting as ``{node: Sonar}``; ValueError naming the sonar and key that
    is wrong."""
    if not isinstance(table, Mapping) or not table:
        raise ValueError(
            "sonars must be a table of <node> = {position = [x, y, z], direction = [x, y, z]}"
        )
    out = {}
    for node, pose in table.items():
        if not isinstance(pose, Mapping):
            raise ValueError(f"sonars.{node} must be a table with position and direction")
        unknown = set(pose) - {"position", "direction"}
        if unknown:
            raise ValueError(f"sonars.{node}: unknown keys {sorted(unknown)}")
        vecs = []
        for key in ("position", "direction"):
            try:
                v = np.array([float(x) for x in pose[key]], dtype=np.float64)
            except KeyError:
                raise ValueError(f"sonars.{node} needs {key} = [x, y, z]") from None
            except (TypeError, ValueError):
                raise ValueError(f"sonars.{node}.{key} must be 3 numbers: {pose[key]!r}") from None
            if v.shape != (3,) or not np.isfinite(v).all():
                raise ValueError(f"sonars.{node}.{key} must be 3 finite numbers: {pose[key]!r}")
            vecs.append(v)
        n = float(np.linalg.norm(vecs[1]))
        if not n > 0:
            raise ValueError(f"sonars.{node}.direction must not be zero")
        out[str(node)] = Sonar(str(node), vecs[0], vecs[1] / n)
    return out


def beam_points(
    readings: Mapping[str, float], sonars: Mapping[str, Sonar], target_radius: float
) -> np.ndarray | None:
    """The position whose distance along each sonar's axis matches its reading,
    ``d_i . (p - s_i) = r_i + target_radius`` (exact for a target on the axes), by least
    squares; None unless the readings' directions span the three axes."""
    A = np.array([sonars[n].direction for n in readings])
    b = np.array([r + target_radius + float(sonars[n].direction @ sonars[n].position)
                  for n, r in readings.items()])  # fmt: skip
    if len(A) < 3 or np.linalg.matrix_rank(A, tol=1e-3) < 3:
        return None
    p, *_ = np.linalg.lstsq(A, b, rcond=None)
    return p
