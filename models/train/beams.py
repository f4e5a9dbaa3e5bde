"""Sonar beams in the plane: pointing directions and the cone test (MaxSonar: about 20
degrees half-angle). Shared by the train tracker and bilateration."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence


def unit_directions(beams: Mapping[str, Sequence[float]] | None) -> dict[str, tuple[float, float]]:
    """{sonar node: unit [x, y]} from {sonar node: [x, y] pointing direction}; ValueError
    naming the node for a zero direction."""
    out = {}
    for node, d in (beams or {}).items():
        norm = math.hypot(float(d[0]), float(d[1]))
        if not norm > 0:
            raise ValueError(f"beam direction of {node!r} must be a non-zero [x, y]")
        out[node] = (float(d[0]) / norm, float(d[1]) / norm)
    return out


def in_cone(direction: tuple[float, float], dx: float, dy: float, cos_half: float) -> bool:
    """Whether the vector (dx, dy) from the sonar lies within the cone around the unit
    ``direction`` whose half-angle has cosine ``cos_half`` (a zero vector does not)."""
    norm = math.hypot(dx, dy)
    return norm > 0 and (dx * direction[0] + dy * direction[1]) / norm >= cos_half
