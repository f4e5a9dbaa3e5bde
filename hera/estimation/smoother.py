"""Rauch-Tung-Striebel fixed-interval smoother for linear and linearised (EKF) filters.

Given the filtered posteriors (x_k, P_k), the priors of the next steps (x_{k+1}^-,
P_{k+1}^-) and the transitions F_{k+1} between them, the smoothed estimates run backwards
from the last step (Rauch, Tung, Striebel 1965; Saerkkae, "Bayesian Filtering and
Smoothing", 2013, eqs. 8.6 and 9.3 for the extended form):

    C_k = P_k F_{k+1}^T (P_{k+1}^-)^-1                    (smoother gain)
    x_k^s = x_k + C_k (x_{k+1}^s - x_{k+1}^-)
    P_k^s = P_k + C_k (P_{k+1}^s - P_{k+1}^-) C_k^T

P_{k+1}^- is factorised by Cholesky (C_k^T = P^- \\ (F P_k) by two triangular solves). For an
EKF, F_{k+1} is the Jacobian the filter used and x_{k+1}^- = f(x_k) its prediction; the
difference x^s - x^- goes through the state's residual (``residual_x``) so angles wrap.

:func:`smooth` takes a recorded :class:`~hera.estimation.history.StepHistory` (``record``
or ``batch_filter``) and is what ``hera replay --smooth`` calls; :func:`rts_smoother` is the
same on plain arrays.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np

from .history import StepHistory
from .numerics import CovarianceError

__all__ = ["Smoothed", "rts_smoother", "smooth"]


class Smoothed(NamedTuple):
    """Smoothed estimates: ``t`` (N,) seconds, ``x`` (N, n), ``P`` (N, n, n)."""

    t: np.ndarray
    x: np.ndarray
    P: np.ndarray

    def at(self, t: float, tol: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
        """(x, P) of the last step at or before time t (within ``tol`` seconds: step times
        are sums of dt), e.g. the smoothed state behind a filtered estimate written at t.
        ValueError before the first step."""
        i = int(np.searchsorted(self.t, t + tol, side="right")) - 1
        if i < 0:
            raise ValueError(f"Smoothed.at: t = {t} is before the first step ({self.t[0]})")
        return self.x[i], self.P[i]


def rts_smoother(
    x_post: Any,
    P_post: Any,
    x_prior: Any,
    P_prior: Any,
    F: Sequence[Any],
    *,
    residual_x: Callable[[np.ndarray, np.ndarray], Any] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """RTS smoothing of N filtered steps (module docstring): ``x_post`` (N, n) and
    ``P_post`` (N, n, n) after each step's update, ``x_prior``/``P_prior`` after each
    step's predict, ``F[k]`` the (n, n) transition from step k-1 to step k (``F[0]`` is not
    used). Returns (xs (N, n), Ps (N, n, n)); the last step equals its filtered estimate.
    CovarianceError names a step whose predicted covariance is not positive definite."""
    xf = np.asarray(x_post, dtype=np.float64)
    Pf = np.asarray(P_post, dtype=np.float64)
    xp = np.asarray(x_prior, dtype=np.float64)
    Pp = np.asarray(P_prior, dtype=np.float64)
    N = xf.shape[0]
    if xf.ndim != 2 or Pf.shape != (N, *xf.shape[1:], xf.shape[1]):
        raise ValueError(f"rts_smoother: x_post {xf.shape} and P_post {Pf.shape} do not match")
    if xp.shape != xf.shape or Pp.shape != Pf.shape or len(F) != N:
        raise ValueError(
            f"rts_smoother: {N} posteriors but priors {xp.shape}, {Pp.shape} and {len(F)} F"
        )
    n = xf.shape[1]
    xs = xf.copy()
    Ps = Pf.copy()
    for k in range(N - 2, -1, -1):
        Fk = F[k + 1]
        if Fk is None:
            raise ValueError(f"rts_smoother: step {k + 1} has no transition matrix F")
        Fk = np.asarray(Fk, dtype=np.float64)
        if Fk.shape != (n, n):
            raise ValueError(f"rts_smoother: F[{k + 1}] has shape {Fk.shape}, expected ({n}, {n})")
        try:
            L = np.linalg.cholesky(Pp[k + 1])
        except np.linalg.LinAlgError:
            raise CovarianceError(f"predicted covariance P_prior[{k + 1}]") from None
        # C^T = (P^-)^-1 F P_k, by two triangular solves with the Cholesky factor.
        Ct = np.linalg.solve(L.T, np.linalg.solve(L, Fk @ Pf[k]))
        if residual_x is None:
            dx = xs[k + 1] - xp[k + 1]
        else:
            dx = np.asarray(residual_x(xs[k + 1], xp[k + 1]), dtype=np.float64).reshape(n)
        xs[k] = xf[k] + dx @ Ct
        Pk = Pf[k] + Ct.T @ (Ps[k + 1] - Pp[k + 1]) @ Ct
        Ps[k] = 0.5 * (Pk + Pk.T)
    return xs, Ps


def smooth(history: StepHistory) -> Smoothed:
    """Smoothed (t, x, P) of every step of a recorded linear (KF) or linearised (EKF)
    filter: ``history = record(filt, t0)`` before the steps (or ``batch_filter``), then
    ``smooth(history)``. Raises ValueError for a history without transition matrices
    (a UKF) or with fewer than one step."""
    if not len(history):
        raise ValueError("smooth: the history is empty")
    if len(history) > 1 and any(F is None for F in history.Fs[1:]):
        raise ValueError(
            "smooth: RTS smoothing needs a linear or linearised filter (KF or EKF); "
            "this history has steps without a transition matrix (a UKF)"
        )
    xs, Ps = rts_smoother(
        history.x_post,
        history.P_post,
        history.x_prior,
        history.P_prior,
        history.Fs,
        residual_x=history.residual_x,
    )
    return Smoothed(history.t, xs, Ps)
