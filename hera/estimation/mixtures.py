"""Gaussian mixtures: the moments of a weighted sum of Gaussians, and how far two are apart.

Multiple-model estimators (an IMM's modes, a static multiple-model start) keep one Gaussian
per hypothesis and report, or merge, them as one: :func:`mixture` gives the mean and
covariance of sum_j w_j N(x_j, P_j) (moment matching: the single Gaussian closest to the
mixture in Kullback-Leibler divergence; Bar-Shalom, Li & Kirubarajan 2001, eq. 11.6.6-7).
:func:`bhattacharyya` says when two hypotheses have become one (0 for equal Gaussians).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["bhattacharyya", "mixture"]


def mixture(
    xs: Sequence[np.ndarray], Ps: Sequence[np.ndarray], w: Sequence[float] | np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(mean, covariance) of the Gaussian mixture sum_j w_j N(xs_j, Ps_j); the weights are
    taken as given (they should sum to 1); the covariance is returned exactly symmetric."""
    x = sum(wj * xj for wj, xj in zip(w, xs, strict=True))
    P = sum(wj * (Pj + np.outer(xj - x, xj - x)) for wj, xj, Pj in zip(w, xs, Ps, strict=True))
    return x, 0.5 * (P + P.T)


def bhattacharyya(x1: np.ndarray, P1: np.ndarray, x2: np.ndarray, P2: np.ndarray) -> float:
    """The Bhattacharyya distance of N(x1, P1) and N(x2, P2): (1/8) d' P^-1 d + (1/2)
    ln(det P / sqrt(det P1 det P2)), d = x1 - x2, P = (P1 + P2) / 2. It is >= 0, and 0 only
    for equal Gaussians; the covariances must be positive definite."""
    P = 0.5 * (P1 + P2)
    d = np.asarray(x1, dtype=float) - np.asarray(x2, dtype=float)
    _, ld = np.linalg.slogdet(P)
    _, l1 = np.linalg.slogdet(P1)
    _, l2 = np.linalg.slogdet(P2)
    return float(0.125 * d @ np.linalg.solve(P, d) + 0.5 * (ld - 0.5 * (l1 + l2)))
