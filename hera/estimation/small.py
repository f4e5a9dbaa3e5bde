"""Closed-form helpers for tiny matrices (m <= 3), where numpy call overhead dominates.

These work on plain Python floats: the innovation covariance S of a 1-3 row update is read
once with ``tolist()`` and inverted by the adjugate formula, which is far cheaper than
``np.linalg.inv`` at these sizes. Every function here is tested against the numpy path.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["inv_small", "quad_form_small"]


def _inv1(s: list[list[float]]) -> list[list[float]] | None:
    a = s[0][0]
    if not a > 0.0 or not math.isfinite(a):
        return None
    return [[1.0 / a]]


def _inv2(s: list[list[float]]) -> list[list[float]] | None:
    (a, b), (c, d) = s
    det = a * d - b * c
    if not (a > 0.0 and det > 0.0) or not math.isfinite(det):
        return None
    inv = 1.0 / det
    off = -0.5 * (b + c) * inv  # S is symmetric up to roundoff: use the mean
    return [[d * inv, off], [off, a * inv]]


def _inv3(s: list[list[float]]) -> list[list[float]] | None:
    (a, b, c), (d, e, f), (g, h, i) = s
    c00 = e * i - f * h
    c01 = f * g - d * i
    c02 = d * h - e * g
    det = a * c00 + b * c01 + c * c02
    # Leading minors positive <=> positive definite (Sylvester's criterion).
    if not (a > 0.0 and a * e - b * d > 0.0 and det > 0.0) or not math.isfinite(det):
        return None
    inv = 1.0 / det
    c11 = a * i - c * g
    c12 = c * d - a * f
    c22 = a * e - b * d
    c10 = c * h - b * i
    c20 = b * f - c * e
    c21 = b * g - a * h
    x01 = 0.5 * (c10 + c01) * inv
    x02 = 0.5 * (c20 + c02) * inv
    x12 = 0.5 * (c21 + c12) * inv
    return [[c00 * inv, x01, x02], [x01, c11 * inv, x12], [x02, x12, c22 * inv]]


_INV = (None, _inv1, _inv2, _inv3)


def inv_small(s: list[list[float]]) -> list[list[float]] | None:
    """Inverse of a symmetric positive-definite 1x1, 2x2 or 3x3 matrix given as nested lists.

    Returns None when the matrix is not positive definite (Sylvester's criterion on the
    leading minors) or not finite, so the caller can raise a precise error. The result is
    exactly symmetric.
    """
    return _INV[len(s)](s)


def quad_form_small(y: list[float], s_inv: list[list[float]]) -> float:
    """y^T S^-1 y for a short vector y (the normalised innovation squared)."""
    total = 0.0
    for i, yi in enumerate(y):
        row = s_inv[i]
        acc = 0.0
        for j, yj in enumerate(y):
            acc += row[j] * yj
        total += yi * acc
    return total


def as_array(rows: list[list[float]]) -> np.ndarray:
    """Nested lists to a float64 array (tiny helper kept for symmetry with ``tolist``)."""
    return np.array(rows, dtype=np.float64)
