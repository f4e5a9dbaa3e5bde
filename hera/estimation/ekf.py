"""Extended Kalman filter (seed 003 eqs. 7-8).

Predict: x = f(x, dt, u), P = F P F^T + Q with F = df/dx at the prior x (the user's Jacobian
``F(x, dt, u)`` or a central-difference one). Update: the shared linearised correction with
each block's h(x) and Jacobian (or a linear H).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from .backend import active_kernels
from .correction import _WS_SMALL, LinearisedFilter, _as_matrix
from .numerics import NonFiniteInputError, numerical_jacobian
from .stacking import SCRATCH, grow_scratch

__all__ = ["ExtendedKalmanFilter"]

_ND = np.ndarray
_empty = np.empty


class ExtendedKalmanFilter(LinearisedFilter):
    """EKF on float64 arrays.

    ``f(x, dt, u) -> x'``: process model; ``F(x, dt, u) -> (n, n)``: its Jacobian (optional,
    central differences otherwise); ``Q``: process noise covariance, a matrix or a function
    ``Q(dt)``.
    """

    def __init__(
        self,
        x0: Any,
        P0: Any,
        f: Callable[[np.ndarray, float, Any], Any],
        Q: np.ndarray | Callable[[float], Any],
        F: Callable[[np.ndarray, float, Any], Any] | None = None,
        *,
        joseph: bool = True,
        gate: float | None = None,
    ) -> None:
        super().__init__(x0, P0, joseph=joseph, gate=gate)
        self.f = f
        self.F = F
        self._Q = Q if callable(Q) else _as_matrix(Q, self.n, "Q")
        self._dt: float | None = None
        self._Qdt: np.ndarray | None = None

    def predict(self, dt: float, u: Any = None, *, Q: np.ndarray | None = None) -> None:
        """Propagate by dt seconds (seed 003 eq. 7). The state is unchanged on error."""
        x = self.x
        jac = self.F
        if jac is not None:
            Fj = jac(x, dt, u)
            if type(Fj) is not _ND:
                Fj = np.asarray(Fj, dtype=np.float64)
        else:
            f = self.f
            Fj = numerical_jacobian(lambda s: f(s, dt, u), x, self.n)
        xn = self.f(x, dt, u)
        if Q is None:
            Qm = self._Q
            if type(Qm) is not _ND:  # a function of dt
                if dt != self._dt or self._Qdt is None:
                    self._Qdt = _as_matrix(Qm(dt), self.n, "Q(dt)")
                    self._dt = dt
                Qm = self._Qdt
        else:
            Qm = np.asarray(Q, dtype=np.float64)
        k = active_kernels()
        if k is not None and type(xn) is _ND:
            # The kernel checks every shape, numba's dispatch every dtype and rank.
            n = self.n
            P = _empty((n, n))
            try:
                status = k.ekf_predict(xn, self.P, Fj, Qm, SCRATCH[0], P)
                if status == _WS_SMALL:
                    status = k.ekf_predict(xn, self.P, Fj, Qm, grow_scratch(n * n), P)
            except TypeError:  # e.g. an integer Jacobian: the numpy path converts it
                status = -1
            if not status:
                self.x = xn
                self.P = P
                return
        if type(xn) is not _ND or xn.ndim != 1:
            xn = np.asarray(xn, dtype=np.float64).reshape(-1)
        if Fj.shape != (self.n, self.n):
            raise ValueError(f"Jacobian F has shape {Fj.shape}, expected ({self.n}, {self.n})")
        P = Fj @ self.P @ Fj.T
        P += P.T  # exact symmetry, then halve and add Q
        P *= 0.5
        P += Qm
        try:
            self._commit_predict(xn, P, "f(x) or its Jacobian F")
        except NonFiniteInputError:
            if not np.isfinite(Fj).all():
                raise NonFiniteInputError("predict", "Jacobian F", "step") from None
            raise
