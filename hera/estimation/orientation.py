"""Orientation helpers for AHRS models.

Quaternions are scalar first, q = [q1, q2, q3, q4] = [w, x, y, z] as in the thesis, and
represent the rotation body -> reference. Angles are in radians.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = [
    "align_sign",
    "angle_residual",
    "matrix_to_quat",
    "nearest_branch",
    "quat_conjugate",
    "quat_multiply",
    "quat_normalize",
    "quat_omega",
    "quat_to_matrix",
    "wrap_angle",
]

_TWO_PI = 2.0 * math.pi


def quat_multiply(p: Any, q: Any) -> np.ndarray:
    """Hamilton product p * q (rotation q followed by p): quat_to_matrix(p * q) equals
    quat_to_matrix(p) @ quat_to_matrix(q)."""
    p1, p2, p3, p4 = (float(v) for v in p)
    q1, q2, q3, q4 = (float(v) for v in q)
    return np.array(
        (
            p1 * q1 - p2 * q2 - p3 * q3 - p4 * q4,
            p1 * q2 + p2 * q1 + p3 * q4 - p4 * q3,
            p1 * q3 - p2 * q4 + p3 * q1 + p4 * q2,
            p1 * q4 + p2 * q3 - p3 * q2 + p4 * q1,
        )
    )


def quat_conjugate(q: Any) -> np.ndarray:
    """Conjugate [q1, -q2, -q3, -q4] (the inverse rotation for a unit quaternion)."""
    q = np.asarray(q, dtype=np.float64)
    return np.array((q[0], -q[1], -q[2], -q[3]))


def quat_normalize(q: Any) -> np.ndarray:
    """q / |q|. Raises ValueError for a zero or non-finite quaternion."""
    q = np.asarray(q, dtype=np.float64).reshape(4)
    norm = math.sqrt(float(q @ q))
    if not (norm > 0.0 and math.isfinite(norm)):
        raise ValueError(f"cannot normalise quaternion {q!r}")
    return q / norm


def quat_to_matrix(q: Any) -> np.ndarray:
    """Rotation matrix of a quaternion (thesis eq. 2.14); q is normalised first."""
    q1, q2, q3, q4 = quat_normalize(q).tolist()
    return np.array(
        (
            (2 * (q1 * q1 + q2 * q2) - 1, 2 * (q2 * q3 - q1 * q4), 2 * (q2 * q4 + q1 * q3)),
            (2 * (q2 * q3 + q1 * q4), 2 * (q1 * q1 + q3 * q3) - 1, 2 * (q3 * q4 - q1 * q2)),
            (2 * (q2 * q4 - q1 * q3), 2 * (q3 * q4 + q1 * q2), 2 * (q1 * q1 + q4 * q4) - 1),
        )
    )


def matrix_to_quat(R: Any) -> np.ndarray:
    """Unit quaternion (q1 >= 0) of a rotation matrix: thesis eq. 2.15 when the trace is the
    largest pivot, otherwise the branch on the largest diagonal element, so that the square
    root is never taken of a small number (eq. 2.15 alone loses precision near 180 degrees,
    where 1 + trace -> 0)."""
    (r11, r12, r13), (r21, r22, r23), (r31, r32, r33) = np.asarray(R, dtype=np.float64).tolist()
    tr = r11 + r22 + r33
    best = max(tr, r11, r22, r33)
    if best == tr:
        q1 = 0.5 * math.sqrt(max(1.0 + tr, 0.0))
        s = 0.25 / q1
        q = (q1, (r32 - r23) * s, (r13 - r31) * s, (r21 - r12) * s)
    elif best == r11:
        q2 = 0.5 * math.sqrt(max(1.0 + r11 - r22 - r33, 0.0))
        s = 0.25 / q2
        q = ((r32 - r23) * s, q2, (r12 + r21) * s, (r13 + r31) * s)
    elif best == r22:
        q3 = 0.5 * math.sqrt(max(1.0 - r11 + r22 - r33, 0.0))
        s = 0.25 / q3
        q = ((r13 - r31) * s, (r12 + r21) * s, q3, (r23 + r32) * s)
    else:
        q4 = 0.5 * math.sqrt(max(1.0 - r11 - r22 + r33, 0.0))
        s = 0.25 / q4
        q = ((r21 - r12) * s, (r13 + r31) * s, (r23 + r32) * s, q4)
    out = quat_normalize(q)
    return -out if out[0] < 0.0 else out


def align_sign(q: Any, reference: Any) -> np.ndarray:
    """q or -q, whichever lies in the hemisphere of ``reference`` (q . reference >= 0,
    thesis eq. 7.5). Use it to flip a measured quaternion towards the prediction so the
    filter's innovation is the short way round."""
    q = np.asarray(q, dtype=np.float64)
    return -q if float(q @ np.asarray(reference, dtype=np.float64)) < 0.0 else q


def wrap_angle(a: Any) -> Any:
    """Angle(s) wrapped to (-pi, pi] (thesis eq. 6.7). Floats in, float out; arrays in,
    array out."""
    if isinstance(a, float | int):
        w = math.fmod(a + math.pi, _TWO_PI)
        if w <= 0.0:
            w += _TWO_PI
        return w - math.pi
    a = np.asarray(a, dtype=np.float64)
    w = np.mod(a + np.pi, _TWO_PI)
    w = np.where(w <= 0.0, w + _TWO_PI, w)
    return w - np.pi


def nearest_branch(angle: Any, reference: Any) -> Any:
    """angle + 2 pi k closest to ``reference`` (thesis eq. 6.7: a measured heading put on the
    branch of the predicted one, or vice versa)."""
    return reference + wrap_angle(angle - reference)


def angle_residual(z: np.ndarray, hx: np.ndarray) -> np.ndarray:
    """Residual z - h(x) wrapped to (-pi, pi]; pass as a block's ``residual``. Works on
    batches too (rows of z against one hx), so the UKF calls it once for all sigma points."""
    return wrap_angle(np.asarray(z, dtype=np.float64) - hx)


angle_residual.vectorized = True  # type: ignore[attr-defined]


def quat_omega(omega: Any) -> np.ndarray:
    """4x4 matrix Omega(w) with dq/dt = 1/2 Omega(w) q for body rates w (rad/s), so that
    F = I + dt/2 Omega(w) propagates a quaternion (the AHRS model e11)."""
    wx, wy, wz = (float(v) for v in omega)
    return np.array(
        ((0.0, -wx, -wy, -wz), (wx, 0.0, wz, -wy), (wy, -wz, 0.0, wx), (wz, wy, -wx, 0.0))
    )
