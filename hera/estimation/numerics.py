"""Numerical safeguards: exceptions, covariance checks at the boundary, Joseph form,
symmetrisation and central-difference Jacobians.

References: the Joseph form ``P = (I - K H) P (I - K H)^T + K R K^T`` keeps P symmetric
positive semi-definite under roundoff for any gain K (seed 000, "Joseph Form Covariance
Update"); P is symmetrised after every update and checked for positive definiteness.

Covariances given by a user (P0, Q, R, a new P) are checked once, where they enter, by
:func:`as_covariance`: a scalar means ``s * I``, a vector the diagonal, a matrix must be
symmetric to ``SYMMETRY_RTOL`` (relative to ``sqrt(M_ii M_jj)``, the scale of entry (i, j) of
a covariance) and positive definite by a Cholesky attempt (semi-definite for a process
noise Q, which may be singular). The stored matrix is ``(M + M^T) / 2``, exactly symmetric,
so every backend reads the same numbers.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

__all__ = [
    "SYMMETRY_RTOL",
    "CovarianceError",
    "NonFiniteInputError",
    "as_covariance",
    "assert_positive_definite",
    "joseph_update",
    "numerical_jacobian",
    "symmetrise",
]

SYMMETRY_RTOL = 1e-9  # |M_ij - M_ji| <= SYMMETRY_RTOL * sqrt(|M_ii M_jj|) counts as symmetric
_PSD_RTOL = 1e-12  # a semi-definite matrix may have eigenvalues down to -this * max eigenvalue


class NonFiniteInputError(ValueError):
    """An observation block (or a Jacobian, or the state) holds NaN or inf. The filter
    state is untouched."""

    def __init__(
        self,
        label: str,
        what: str,
        context: str = "observation block",
        *,
        problem: str = "contains NaN or inf",
    ) -> None:
        self.label = label
        self.what = what
        super().__init__(f"{context} {label!r}: {what} {problem}")


class CovarianceError(ValueError, ArithmeticError):
    """A covariance matrix (P, Q, R or an innovation covariance S) is not symmetric or not
    positive definite. A ValueError (bad input) and an ArithmeticError (as before)."""

    def __init__(self, what: str, detail: str = "", *, problem: str = "positive definite") -> None:
        self.what = what
        msg = f"{what} is not {problem}"
        super().__init__(msg + (f" ({detail})" if detail else ""))


def symmetrise(P: np.ndarray) -> np.ndarray:
    """Return (P + P^T) / 2, the nearest symmetric matrix (Frobenius norm)."""
    return 0.5 * (P + P.T)


def _fmt(v: float) -> str:
    return f"{v:.6g}"


def as_covariance(a: Any, n: int, what: str, *, semidefinite: bool = False) -> np.ndarray:
    """A checked (n, n) covariance from a scalar (``a * I``), a vector of n variances (its
    diagonal) or an (n, n) matrix, as a new C-contiguous float64 array, exactly symmetric.

    Raises ValueError (wrong shape), NonFiniteInputError (NaN or inf) or CovarianceError
    (not symmetric within ``SYMMETRY_RTOL``, or not positive definite - semi-definite when
    ``semidefinite``, as for a process noise Q - by a Cholesky attempt), each naming
    ``what``. Variances (a scalar, a vector, a diagonal matrix) are checked one by one,
    which is what a Cholesky attempt on a diagonal matrix amounts to (and 5x cheaper: a
    model that passes Q every predict pays ~4 us)."""
    try:
        m = np.array(a, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a number, a vector or a matrix, got {a!r}") from None
    if m.ndim == 2 and m.shape == (n, n) and np.count_nonzero(m) == np.count_nonzero(m.diagonal()):
        m = m.diagonal()  # a diagonal matrix: its variances, checked as a vector below
    if m.ndim <= 1:  # variances: the diagonal of a diagonal matrix, checked one by one
        v = np.full(n, float(m)) if m.ndim == 0 else m
        if v.shape[0] != n:
            raise ValueError(f"{what} has {v.shape[0]} variances, expected {n}")
        if not finite(v):
            raise NonFiniteInputError(what, "the matrix", "covariance")
        low = float(v.min()) if n else 1.0
        if low < 0.0 or (low == 0.0 and not semidefinite):
            k = int(np.argmin(v))
            kind = "semi-definite" if semidefinite else "definite"
            raise CovarianceError(
                what, f"{what}[{k}, {k}] = {_fmt(low)}", problem=f"positive {kind}"
            )
        return np.diag(v)
    if m.shape != (n, n):
        raise ValueError(f"{what} has shape {m.shape}, expected ({n}, {n})")
    if not np.isfinite(m).all():
        raise NonFiniteInputError(what, "the matrix", "covariance")
    check_covariance(m, what, semidefinite=semidefinite)
    out = m + m.T
    out *= 0.5
    return out


def check_covariance(m: np.ndarray, what: str, *, semidefinite: bool = False) -> None:
    """Raise CovarianceError unless the finite square matrix m is symmetric within
    ``SYMMETRY_RTOL`` and positive definite (semi-definite if ``semidefinite``)."""
    n = m.shape[0]
    d = np.abs(np.diagonal(m))
    asym = np.abs(m - m.T)
    bad = asym > SYMMETRY_RTOL * np.sqrt(np.outer(d, d))
    if bad.any():
        i, j = (int(v) for v in np.argwhere(bad)[0])
        raise CovarianceError(
            what,
            f"{what}[{i}, {j}] = {_fmt(m[i, j])} but {what}[{j}, {i}] = {_fmt(m[j, i])}",
            problem="symmetric",
        )
    diag = np.diagonal(m)
    k = int(np.argmin(diag)) if n else 0
    if n and (diag[k] < 0.0 or (diag[k] == 0.0 and not semidefinite)):
        kind = "semi-definite" if semidefinite else "definite"
        raise CovarianceError(
            what, f"{what}[{k}, {k}] = {_fmt(diag[k])}", problem=f"positive {kind}"
        )
    sym = 0.5 * (m + m.T)
    if semidefinite:
        scale = float(diag.max()) if n else 0.0
        if scale == 0.0:
            if np.any(sym != 0.0):
                raise CovarianceError(what, "zero diagonal", problem="positive semi-definite")
            return
        # Cholesky of M + tau I with tau at roundoff level: succeeds iff M is PSD up to it.
        sym = sym + (_PSD_RTOL * scale) * np.eye(n)
    try:
        np.linalg.cholesky(sym)
    except np.linalg.LinAlgError:
        ev = np.linalg.eigvalsh(0.5 * (m + m.T))
        kind = "semi-definite" if semidefinite else "definite"
        raise CovarianceError(
            what,
            f"Cholesky failed; smallest eigenvalue {_fmt(float(ev[0]))}",
            problem=f"positive {kind}",
        ) from None


def assert_positive_definite(P: np.ndarray, what: str = "P") -> None:
    """Raise CovarianceError unless P is square, finite, symmetric (within
    ``SYMMETRY_RTOL``) and a Cholesky factorisation exists (strictly positive definite)."""
    P = np.asarray(P, dtype=np.float64)
    if P.ndim != 2 or P.shape[0] != P.shape[1]:
        raise CovarianceError(what, f"shape {P.shape} is not square")
    if not np.isfinite(P).all():
        raise CovarianceError(what, "contains NaN or inf")
    check_covariance(P, what)


def joseph_update(P: np.ndarray, K: np.ndarray, H: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Joseph-form covariance update (I - K H) P (I - K H)^T + K R K^T, symmetrised.

    Valid for any gain K (not only the optimal one), which is what makes it robust.
    """
    A = np.eye(P.shape[0]) - K @ H
    return symmetrise(A @ P @ A.T + K @ R @ K.T)


_STEP = 6.055454452393343e-06  # eps ** (1/3)


def numerical_jacobian(
    fun: Callable[[np.ndarray], Any],
    x: Any,
    out_dim: int | None = None,
    *,
    residual: Callable[[np.ndarray, np.ndarray], Any] | None = None,
) -> np.ndarray:
    """Central-difference Jacobian d fun / d x at x, shape (len(fun(x)), len(x)).

    Column j is ``residual(fun(x + h_j e_j), fun(x - h_j e_j)) / (2 h_j)``; ``residual(a, b)``
    is the difference a - b in fun's output space (default: plain subtraction). Pass the
    block's residual (e.g. ``angle_residual``) when fun returns an angle, or the state's
    residual when fun is a process model that wraps a heading: differencing through the
    wrap is what keeps a Jacobian near +-pi right (without it a column is ~2 pi / (2 h)).

    Step per coordinate: eps^(1/3) * max(1, |x_j|), the usual balance between truncation
    (O(h^2)) and roundoff (O(eps / h)) errors of a central difference.
    """
    x = np.asarray(x, dtype=np.float64).reshape(-1)
    n = x.shape[0]
    cols = []
    xp = x.copy()
    for j in range(n):
        xj = float(x[j])
        hj = _STEP * max(1.0, abs(xj))
        xp[j] = xj + hj
        fp = np.array(fun(xp), dtype=np.float64).ravel()  # copy: fun may return xp
        xp[j] = xj - hj
        fm = np.array(fun(xp), dtype=np.float64).ravel()
        xp[j] = xj
        d = fp - fm if residual is None else np.asarray(residual(fp, fm), dtype=np.float64)
        cols.append(d.ravel() / (2.0 * hj))
    if not cols:
        return np.zeros((out_dim or 0, 0))
    return np.column_stack(cols)


def finite(a: np.ndarray) -> bool:
    """True when every value of a is finite. The sum first (NaN or inf iff a value is, or
    on overflow, which the full test then clears); on Python floats for small arrays,
    where that is 3x cheaper than numpy's reduction."""
    s = sum(a.ravel().tolist()) if a.size <= 100 else float(a.sum())
    return math.isfinite(s) or bool(np.isfinite(a).all())
