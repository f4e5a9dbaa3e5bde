"""Reference frames of an AHRS: where "up" and magnetic north are, and the attitude the
accelerometer and magnetometer alone give (thesis eqs. 7.1-7.2, the TRIAD construction).

Quaternions are scalar first and rotate body -> reference (``hera.estimation.orientation``).
The reference frame is fixed by two unit vectors in it:

- ``up``: the direction an accelerometer at rest reads (specific force, the opposite of
  gravity) when the body is at the identity attitude; ``[0, 0, 1]`` in a z-up world;
- ``north``: the horizontal direction of the magnetic field (perpendicular to ``up``).

In Hera's simulated world (z up) magnetic north lies at ``mag_north_deg`` from the x axis
(90 deg: +y); :func:`world_reference` builds the pair from that angle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from hera.estimation import matrix_to_quat


def unit(v: Any, what: str = "vector") -> np.ndarray:
    """``v / |v|`` as a float64 3-vector; ValueError naming ``what`` if it is zero or not
    finite."""
    a = np.asarray(v, dtype=np.float64).reshape(3)
    n = float(np.linalg.norm(a))
    if not (n > 0.0 and math.isfinite(n)):
        raise ValueError(f"{what} must be a finite non-zero 3-vector, got {v!r}")
    return a / n


@dataclass(frozen=True)
class Reference:
    """The reference frame of an attitude: ``up`` and ``north`` unit vectors (see module
    docstring); ``north`` is made perpendicular to ``up``."""

    up: np.ndarray
    north: np.ndarray

    @classmethod
    def of(cls, up: Any, north: Any) -> Reference:
        """From any two non-parallel vectors: ``north`` keeps only its part across ``up``
        (a full field vector, dip included, may be given)."""
        u = unit(up, "up")
        n = np.asarray(north, dtype=np.float64).reshape(3)
        return cls(u, unit(n - float(n @ u) * u, "north (across up)"))


def world_reference(north_deg: float = 90.0) -> Reference:
    """Hera's z-up world with magnetic north at ``north_deg`` from +x (the world key
    ``mag_north_deg``)."""
    a = math.radians(north_deg)
    return Reference(np.array((0.0, 0.0, 1.0)), np.array((math.cos(a), math.sin(a), 0.0)))


def triad(acc: Any, mag: Any, ref: Reference) -> np.ndarray | None:
    """The body -> reference rotation matrix that the accelerometer and magnetometer alone
    give (thesis eq. 7.1, written for any reference frame): the body's up ``a`` and magnetic
    east ``m x a`` matched with ``up`` and ``north x up``. None when the two vectors are
    (nearly) parallel or zero."""
    a = np.asarray(acc, dtype=np.float64)
    m = np.asarray(mag, dtype=np.float64)
    na = float(np.linalg.norm(a))
    c = np.cross(m, a)
    nc = float(np.linalg.norm(c))
    if not (na > 0.0 and nc > 1e-9 * na * (float(np.linalg.norm(m)) + 1e-300)):
        return None
    b1 = a / na
    b2 = c / nc
    b3 = np.cross(b1, b2)
    r1 = ref.up
    r2 = np.cross(ref.north, ref.up)
    r3 = np.cross(r1, r2)
    return np.column_stack((r1, r2, r3)) @ np.column_stack((b1, b2, b3)).T


def triad_quat(acc: Any, mag: Any, ref: Reference) -> np.ndarray | None:
    """:func:`triad` as a unit quaternion (thesis eq. 7.2, with the robust branch choice of
    :func:`hera.estimation.matrix_to_quat`), or None."""
    R = triad(acc, mag, ref)
    return None if R is None else matrix_to_quat(R)
