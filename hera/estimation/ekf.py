"""Extended Kalman filter (seed 003 eqs. 7-8).

Predict: x = f(x, dt, u), P = F P F^T + Q with F = df/dx at the prior x (the user's Jacobian
``F(x, dt, u)`` or a central-difference one, differenced through the state's residual so
that a wrapped heading does not break it). Update: the shared linearised correction with
each block's h(x) and Jacobian (or a linear H).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from . import backend as _bk
from .correction import _WS_SMALL, LinearisedFilter, check_dt, process_noise
from .numerics import finite, numerical_jacobian
from .stacking import SCRATCH, grow_scratch

__all__ = ["ExtendedKalmanFilter"]

_ND = np.ndarray
_F64 = np.float64
_empty = np.empty
_INF = math.inf


class ExtendedKalmanFilter(LinearisedFilter):
    """EKF on float64 arrays.

    ``f(x, dt, u) -> x'``: process model; ``F(x, dt, u) -> (n, n)``: its Jacobian (optional,
    central differences otherwise); ``Q``: process noise covariance (a scalar means Q I, a
    vector its diagonal, or a matrix; or a function ``Q(dt)`` returning one; positive
    semi-definite: checked). ``residual_x(a, b)``: the difference a - b of two states
    (e.g. ``state_residual(angles=[2])`` when x[2] is a heading that f wraps); used by the
    numerical Jacobian of f and by the smoother. ``cache_dt``: Q(dt) is a pure function of
    dt, evaluated once per distinct dt (default); False evaluates it on every predict.
    """

    def __init__(
        self,
        x0: Any,
        P0: Any,
        f: Callable[[np.ndarray, float, Any], Any],
        Q: Any,
        F: Callable[[np.ndarray, float, Any], Any] | None = None,
        *,
        joseph: bool = True,
        gate: float | None = None,
        residual_x: Callable[[np.ndarray, np.ndarray], Any] | None = None,
        cache_dt: bool = True,
    ) -> None:
        super().__init__(x0, P0, joseph=joseph, gate=gate)
        self.f = f
        self.F = F
        self.residual_x = residual_x
        self.cache_dt = cache_dt
        self.Q = Q

    @property
    def Q(self) -> Any:
        """The process noise covariance or function Q(dt)."""
        return self._Q

    @Q.setter
    def Q(self, Q: Any) -> None:
        self._Q = Q if callable(Q) else process_noise(Q, self.n, "Q")
        self._dt: float | None = None
        self._Qdt: np.ndarray | None = None

    def predict(self, dt: float, u: Any = None, *, Q: Any = None) -> None:
        """Propagate by dt seconds (>= 0; seed 003 eq. 7). ``Q`` overrides the process noise
        for this call (checked as at construction). The state is unchanged on error."""
        if not 0.0 <= dt < _INF:
            check_dt(dt)
        x = self._x
        f = self.f
        jac = self.F
        if jac is not None:
            Fj = jac(x, dt, u)
            if type(Fj) is not _ND:
                Fj = np.asarray(Fj, dtype=_F64)
        else:
            Fj = numerical_jacobian(lambda s: f(s, dt, u), x, self.n, residual=self.residual_x)
        xn = f(x, dt, u)
        if Q is None:
            Qm = self._Q
            if type(Qm) is not _ND:  # a function of dt
                if dt != self._dt or self._Qdt is None or not self.cache_dt:
                    self._Qdt = process_noise(Qm(dt), self.n, "Q(dt)")
                    self._dt = dt
                Qm = self._Qdt
        else:
            Qm = process_noise(Q, self.n, "Q")
        k = _bk._active
        if k is not None and type(xn) is _ND:
            # The kernel checks every shape and that f(x) is finite, numba's dispatch every
            # dtype and rank.
            n = self.n
            P = _empty((n, n))
            try:
                status = k.ekf_predict(xn, self._P, Fj, Qm, SCRATCH[0], P)
                if status == _WS_SMALL:
                    status = k.ekf_predict(xn, self._P, Fj, Qm, grow_scratch(n * n), P)
            except TypeError:  # e.g. an integer Jacobian: the numpy path converts it
                status = -1
            if not status:
                self._x = self.x_prior = xn
                self._P = self.P_prior = P
                if self.history is not None:
                    self.history._predicted(self, dt, Fj)
                return
        n = self.n
        if type(xn) is not _ND or xn.ndim != 1 or xn.dtype != _F64:
            xn = np.asarray(xn, dtype=_F64).reshape(-1)
        if xn.shape != (n,):
            raise ValueError(f"predict: f(x) has {xn.shape[0]} values, the state has {n}")
        if Fj.dtype != _F64:
            Fj = Fj.astype(_F64)
        if Fj.shape != (n, n):
            raise ValueError(f"predict: the Jacobian F has shape {Fj.shape}, expected ({n}, {n})")
        if not finite(Fj):
            self._diagnose_predict("the Jacobian F")
        P = Fj @ self._P @ Fj.T
        P += P.T  # exact symmetry, then halve and add Q
        P *= 0.5
        P += Qm
        if not (finite(xn) and finite(P)):
            self._diagnose_predict("f(x) or Q")
        self._commit_predict(xn, P, Fj, dt)
