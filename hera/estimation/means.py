"""Weighted means and residuals for vectors holding angles or quaternions.

The UKF averages sigma points and differences them from the mean; the EKF's numerical
Jacobians difference f or h at two points. With an angle near +-pi or a quaternion (q and
-q are the same rotation) plain arithmetic is wrong: the mean of pi - 0.1 and -pi + 0.1 is
0, not pi. These helpers give the functions the filters take:

* ``mean(X, W) -> (k,)``: weighted mean of the N rows of X (N, k) with weights W (N,)
  (``UnscentedKalmanFilter(x_mean=...)``, ``Observations.add(mean=...)``);
* ``residual(a, b) -> a - b``: the difference of two vectors, or of each row of a (N, k)
  and one vector b (``residual_x=...`` of the UKF and EKF, ``Observations.add(residual=...)``).

:func:`circular_mean` averages angles about the first point of the set (in the UKF the
central sigma point, the state itself): ref + sum_i w_i wrap(a_i - ref), which is exactly
the arithmetic mean when no point is wrapped (right for a cloud less than pi wide around
the first point), and unlike atan2(sum w sin, sum w cos) loses no digits to the large
negative central weight of small-alpha sigma points (it multiplies a zero difference).
:func:`quaternion_mean` aligns every quaternion to the first one's hemisphere, averages and
normalises (the chordal L2 mean, accurate to second order in the spread).
:func:`make_mean` and :func:`make_residual` build both for vectors that mix plain
coordinates, angles and quaternions. All of them accept batches (they are marked
``vectorized``, so the UKF calls them once on all sigma points).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

import numpy as np

from .orientation import wrap_angle

__all__ = [
    "circular_mean",
    "make_mean",
    "make_residual",
    "quaternion_mean",
]

MeanFn = Callable[[np.ndarray, np.ndarray], np.ndarray]
ResidualFn = Callable[[np.ndarray, np.ndarray], np.ndarray]


def _vectorized(fn: Any) -> Any:
    fn.vectorized = True
    return fn


def circular_mean(angles: Any, weights: Any) -> np.ndarray:
    """Weighted mean of angles in radians, wrapped to (-pi, pi]: ``angles`` (N,) or (N, k)
    (each column averaged), ``weights`` (N,), summing to a non-zero value (1 for sigma
    points). Computed about the first row as ref + sum w_i wrap(a_i - ref) / sum w.
    Returns a float array of shape () or (k,)."""
    a = np.asarray(angles, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    ref = a[0]
    total = float(w.sum())
    if total == 0.0:
        raise ValueError("circular_mean: the weights sum to 0")
    d = wrap_angle(a - ref)
    # products then a sum, not a BLAS dot: a dot may fuse multiply and add (FMA) or not,
    # machine by machine, and symmetric sigma points with huge weights then cancel exactly
    # on one machine and to 1e-14 on another
    s = np.sum(w.reshape((-1,) + (1,) * (d.ndim - 1)) * d, axis=0)
    return wrap_angle(ref + s / total)


def _align(q: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """q flipped to ref's hemisphere (q . ref >= 0), row by row; q and ref are (4,) or
    (N, 4) and broadcast."""
    dots = np.sum(q * ref, axis=-1, keepdims=True)
    return np.where(dots < 0.0, -q, q)


def quaternion_mean(quats: Any, weights: Any) -> np.ndarray:
    """Weighted mean of unit quaternions (N, 4), scalar first: each aligned to the
    hemisphere of the first (q and -q are one rotation), weighted sum, normalised.
    ValueError when the sum vanishes (no meaningful mean)."""
    q = np.asarray(quats, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    ref = q[0]
    m = w @ _align(q, ref)
    norm = float(np.sqrt(m @ m))
    if not norm > 1e-12 * float(np.abs(w).sum()):
        raise ValueError("quaternion_mean: the weighted quaternions cancel out")
    return m / norm


def _indices(angles: Iterable[int], quaternions: Iterable[int]) -> tuple[list[int], list[int]]:
    ang = [int(i) for i in angles]
    quat = [int(i) for i in quaternions]
    used = ang + [i + d for i in quat for d in range(4)]
    if len(set(used)) != len(used) or any(i < 0 for i in used):
        raise ValueError(f"angles {ang} and quaternions {quat} (4 columns each) overlap")
    return ang, quat


def make_mean(*, angles: Iterable[int] = (), quaternions: Iterable[int] = ()) -> MeanFn:
    """``mean(X, W)``: the weighted mean of the rows of X (N, k), arithmetic except for the
    columns listed in ``angles`` (circular mean) and the four columns from each start index
    in ``quaternions`` (quaternion mean). E.g. a state [px, py, theta]:
    ``make_mean(angles=[2])``; a state [q1..q4, bx, by, bz]: ``make_mean(quaternions=[0])``."""
    ang, quat = _indices(angles, quaternions)

    def mean(X: np.ndarray, W: np.ndarray) -> np.ndarray:
        X = np.asarray(X, dtype=np.float64)
        W = np.asarray(W, dtype=np.float64)
        out = W @ X
        if ang:
            out[ang] = circular_mean(X[:, ang], W)
        for i in quat:
            out[i : i + 4] = quaternion_mean(X[:, i : i + 4], W)
        return out

    return _vectorized(mean)


def make_residual(*, angles: Iterable[int] = (), quaternions: Iterable[int] = ()) -> ResidualFn:
    """``residual(a, b)``: a - b, with the ``angles`` columns wrapped to (-pi, pi] and each
    quaternion (four columns from each start index in ``quaternions``) of a flipped to b's
    hemisphere before subtracting. a may be (N, k) rows and b one (k,) vector."""
    ang, quat = _indices(angles, quaternions)

    def residual(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        a = np.asarray(a, dtype=np.float64)
        b = np.asarray(b, dtype=np.float64)
        d = a - b
        if ang:
            d[..., ang] = wrap_angle(d[..., ang])
        for i in quat:
            bq = b[..., i : i + 4]
            d[..., i : i + 4] = _align(a[..., i : i + 4], bq) - bq
        return d

    return _vectorized(residual)
