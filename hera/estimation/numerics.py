"""Numerical safeguards: exceptions, Joseph form, symmetrisation, positive-definiteness.

References: the Joseph form ``P = (I - K H) P (I - K H)^T + K R K^T`` keeps P symmetric
positive semi-definite under roundoff (seed 000, "Joseph Form Covariance Update"); P is
symmetrised after every update and checked for positive definiteness.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "CovarianceError",
    "NonFiniteInputError",
    "assert_positive_definite",
    "joseph_update",
    "numerical_jacobian",
    "symmetrise",
]


class NonFiniteInputError(ValueError):
    """An observation block (or a Jacobian) holds NaN or inf. The filter state is untouched."""

    def __init__(self, label: str, what: str, context: str = "observation block") -> None:
        self.label = label
        self.what = what
        super().__init__(f"{context} {label!r}: {what} contains NaN or inf")


class CovarianceError(ArithmeticError):
    """A covariance matrix (P, or an innovation covariance S) is not symmetric positive definite."""

    def __init__(self, what: str, detail: str = "") -> None:
        self.what = what
        msg = f"{what} is not positive definite"
        super().__init__(msg + (f" ({detail})" if detail else ""))


def symmetrise(P: np.ndarray) -> np.ndarray:
    """Return (P + P^T) / 2, the nearest symmetric matrix (Frobenius norm)."""
    return 0.5 * (P + P.T)


def assert_positive_definite(P: np.ndarray, what: str = "P") -> None:
    """Raise CovarianceError unless P is finite, symmetric (to 1e-9 relative) and a Cholesky
    factorisation exists (strictly positive definite)."""
    P = np.asarray(P, dtype=np.float64)
    if P.ndim != 2 or P.shape[0] != P.shape[1]:
        raise CovarianceError(what, f"shape {P.shape} is not square")
    if not np.isfinite(P).all():
        raise CovarianceError(what, "contains NaN or inf")
    scale = float(np.abs(P).max()) if P.size else 0.0
    if scale > 0.0 and float(np.abs(P - P.T).max()) > 1e-9 * scale:
        raise CovarianceError(what, "not symmetric")
    try:
        np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        d = np.diagonal(P)
        raise CovarianceError(what, f"Cholesky failed; min diagonal {d.min():.3g}") from None


def joseph_update(P: np.ndarray, K: np.ndarray, H: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Joseph-form covariance update (I - K H) P (I - K H)^T + K R K^T, symmetrised.

    Valid for any gain K (not only the optimal one), which is what makes it robust.
    """
    A = np.eye(P.shape[0]) - K @ H
    return symmetrise(A @ P @ A.T + K @ R @ K.T)


def numerical_jacobian(fun, x: np.ndarray, out_dim: int | None = None) -> np.ndarray:
    """Central-difference Jacobian d fun / d x at x, shape (len(fun(x)), len(x)).

    Step per coordinate: eps^(1/3) * max(1, |x_j|), the usual balance between truncation
    (O(h^2)) and roundoff (O(eps / h)) errors of a central difference.
    """
    x = np.asarray(x, dtype=np.float64)
    n = x.shape[0]
    step = 6.055454452393343e-06 * np.maximum(1.0, np.abs(x))  # eps ** (1/3)
    cols = []
    xp = x.copy()
    for j in range(n):
        hj = float(step[j])
        xj = x[j]
        xp[j] = xj + hj
        fp = np.array(fun(xp), dtype=np.float64).ravel()  # copy: fun may return xp
        xp[j] = xj - hj
        fm = np.array(fun(xp), dtype=np.float64).ravel()
        xp[j] = xj
        cols.append((fp - fm) / (2.0 * hj))
    J = np.column_stack(cols) if cols else np.zeros((out_dim or 0, 0))
    return J
