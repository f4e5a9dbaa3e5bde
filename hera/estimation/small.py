"""Cholesky helpers for tiny matrices (m <= 3) on plain Python floats, where numpy's call
overhead dominates the arithmetic.

The innovation covariance S of a 1-3 row update is read once with ``tolist()``, factorised
S = L L^T (which is also the positive-definiteness test), and its lower-triangular factor
inverted by forward substitution. Solves with S then go through L: NIS = |L^-1 y|^2 and
K^T = L^-T (L^-1 G). Unlike the adjugate (cofactor) inverse, whose determinant and cofactors
cancel catastrophically when S is ill-conditioned, this loses no more than the conditioning
of S itself costs (Higham, "Accuracy and Stability of Numerical Algorithms", ch. 8 and 10).
Every function here is tested against extended-precision references.
"""

from __future__ import annotations

import math

__all__ = ["block_nis", "chol_small", "lower_inverse", "nis_small"]

_sqrt = math.sqrt
_INF = math.inf


def chol_small(s: list[list[float]]) -> list[list[float]] | None:
    """Lower Cholesky factor L (S = L L^T) of a small symmetric matrix given as nested
    lists; only the lower triangle of S is read. None when S is not positive definite or
    not finite."""
    m = len(s)
    if m == 1:
        a = s[0][0]
        if not 0.0 < a < _INF:
            return None
        return [[_sqrt(a)]]
    L = [[0.0] * m for _ in range(m)]
    for j in range(m):
        Lj = L[j]
        d = s[j][j]
        for p in range(j):
            d -= Lj[p] * Lj[p]
        if not 0.0 < d < _INF:
            return None
        d = _sqrt(d)
        Lj[j] = d
        for i in range(j + 1, m):
            Li = L[i]
            t = s[i][j]
            for p in range(j):
                t -= Li[p] * Lj[p]
            if not math.isfinite(t):
                return None
            Li[j] = t / d
    return L


def lower_inverse(L: list[list[float]]) -> list[list[float]]:
    """Inverse of a lower-triangular matrix with a positive diagonal (forward substitution
    on the columns of I); lower triangular itself."""
    m = len(L)
    if m == 1:
        return [[1.0 / L[0][0]]]
    inv = [[0.0] * m for _ in range(m)]
    for c in range(m):
        for i in range(c, m):
            t = 1.0 if i == c else 0.0
            Li = L[i]
            for p in range(c, i):
                t -= Li[p] * inv[p][c]
            inv[i][c] = t / Li[i]
    return inv


def nis_small(Linv: list[list[float]], y: list[float]) -> float:
    """y^T S^-1 y = |L^-1 y|^2 (the normalised innovation squared) from L^-1."""
    total = 0.0
    for i, row in enumerate(Linv):
        w = 0.0
        for p in range(i + 1):
            w += row[p] * y[p]
        total += w * w
    return total


def log_det_small(L: list[list[float]]) -> float:
    """log det S = 2 sum(log L_ii) from the Cholesky factor."""
    return 2.0 * sum(math.log(L[i][i]) for i in range(len(L)))


def block_nis(s: list[list[float]], y: list[float], dims: tuple[int, ...]) -> list[float] | None:
    """The NIS of each of several stacked blocks (sizes ``dims``, at most 3 rows in all):
    y_b^T S_bb^-1 y_b from the Cholesky factor of its diagonal sub-block S_bb of the joint
    S (lower triangle read, so ragged lower rows will do); None if one is not positive
    definite."""
    out = []
    o = 0
    for d in dims:
        if d == 1:  # |L^-1 y|^2 of a 1 x 1 S: y^2 / s
            v = s[o][o]
            if not 0.0 < v < _INF:
                return None
            out.append(y[o] * y[o] / v)
            o += 1
            continue
        L = chol_small([row[o : o + d] for row in s[o : o + d]])
        if L is None:
            return None
        out.append(nis_small(lower_inverse(L), y[o : o + d]))
        o += d
    return out
