"""Linear Kalman filter with control input (seed 003 eqs. 3-6).

Predict: x = F x + B u, P = F P F^T + Q; dt is explicit on every call (seconds, >= 0) and
F, Q (and B) may be functions of dt. Update: the shared linearised correction (see
``correction``) on the variadic observation blocks.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from . import backend as _bk
from .correction import (
    _WS_SMALL,
    LinearisedFilter,
    _as_matrix,
    check_dt,
    process_noise,
)
from .numerics import finite
from .stacking import SCRATCH, grow_scratch

__all__ = ["KalmanFilter"]

MatrixOrFn = np.ndarray | Callable[[float], Any]
_INF = math.inf


class KalmanFilter(LinearisedFilter):
    """Linear KF on float64 arrays.

    ``F``: state transition, an (n, n) matrix or a function ``F(dt)``; ``Q``: process noise
    covariance (a scalar means Q I, a vector its diagonal, or a matrix; or a function
    ``Q(dt)`` returning one; in state units squared, positive semi-definite: checked);
    ``B``: optional control matrix (n, k) or ``B(dt)``.

    ``cache_dt``: F(dt), Q(dt), B(dt) are pure functions of dt, evaluated (and checked)
    once per distinct dt (default); pass False when they read anything else (a parameter
    that changes), and they are evaluated on every predict. Assigning ``kf.F``, ``kf.Q`` or
    ``kf.B`` clears the cache.
    """

    def __init__(
        self,
        x0: Any,
        P0: Any,
        F: MatrixOrFn,
        Q: MatrixOrFn,
        B: MatrixOrFn | None = None,
        *,
        joseph: bool = True,
        gate: float | None = None,
        cache_dt: bool = True,
    ) -> None:
        super().__init__(x0, P0, joseph=joseph, gate=gate)
        self.cache_dt = cache_dt
        self.F = F
        self.Q = Q
        self.B = B

    @property
    def F(self) -> MatrixOrFn:
        """The transition matrix or function F(dt)."""
        return self._F

    @F.setter
    def F(self, F: MatrixOrFn) -> None:
        self._F = F if callable(F) else _as_matrix(F, self.n, "F")
        self._dt: float | None = None

    @property
    def Q(self) -> MatrixOrFn:
        """The process noise covariance or function Q(dt)."""
        return self._Q

    @Q.setter
    def Q(self, Q: MatrixOrFn) -> None:
        self._Q = Q if callable(Q) else process_noise(Q, self.n, "Q")
        self._dt = None

    @property
    def B(self) -> MatrixOrFn | None:
        """The control matrix or function B(dt), or None."""
        return self._B

    @B.setter
    def B(self, B: MatrixOrFn | None) -> None:
        self._B = B if B is None or callable(B) else self._control(B, "B")
        self._dt = None

    def _control(self, B: Any, what: str) -> np.ndarray:
        Bm = np.array(B, dtype=np.float64)
        if Bm.ndim == 1:
            Bm = Bm.reshape(-1, 1)
        if Bm.ndim != 2 or Bm.shape[0] != self.n:
            raise ValueError(f"{what} has shape {Bm.shape}, expected ({self.n}, k)")
        if not finite(Bm):
            raise ValueError(f"{what} contains NaN or inf")
        return Bm

    def _matrices(self, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """(F, Q, B) at dt, evaluated and checked; kept for the next predict with the same
        dt when ``cache_dt`` (``_dt`` stays None otherwise, so it never matches)."""
        n = self.n
        F = _as_matrix(self._F(dt), n, "F(dt)") if callable(self._F) else self._F
        Q = process_noise(self._Q(dt), n, "Q(dt)") if callable(self._Q) else self._Q
        B = self._B
        if callable(B):
            B = self._control(B(dt), "B(dt)")
        self._cache = (F, Q, B)
        self._dt = dt if self.cache_dt else None
        return self._cache

    def predict(
        self,
        dt: float,
        u: Any = None,
        *,
        F: Any = None,
        Q: Any = None,
    ) -> None:
        """Propagate by dt seconds (>= 0): x = F x + B u, P = F P F^T + Q (seed 003 eq. 5).

        ``F``/``Q`` override the filter's matrices for this call only (Q: scalar, vector
        or matrix, checked as at construction). The state is unchanged on error."""
        if not 0.0 <= dt < _INF:
            check_dt(dt)
        Fm, Qm, B = self._cache if dt == self._dt else self._matrices(dt)
        k = _bk._active
        if k is not None and F is None and Q is None and u is None:
            n = self.n
            x = np.empty(n)
            P = np.empty((n, n))
            try:
                status = k.kf_predict(self._x, self._P, Fm, Qm, SCRATCH[0], x, P)
                if status == _WS_SMALL:
                    status = k.kf_predict(self._x, self._P, Fm, Qm, grow_scratch(n * n), x, P)
            except TypeError:  # pragma: no cover - x, P, F, Q are float64 by construction
                status = -1
            if not status:
                self._x = self.x_prior = x
                self._P = self.P_prior = P
                if self.history is not None:
                    self.history._predicted(self, dt, Fm)
                return
        if F is not None:
            Fm = _as_matrix(F, self.n, "F")
        if Q is not None:
            Qm = process_noise(Q, self.n, "Q")
        um = None
        if u is not None:
            if B is None:
                raise ValueError("predict: control input u given but the filter has no B")
            um = np.asarray(u, dtype=np.float64).reshape(-1)
            if um.shape[0] != B.shape[1]:
                raise ValueError(f"predict: u has {um.shape[0]} values, B has {B.shape[1]} columns")
        if k is not None and self._predict_compiled(k, Fm, Qm, B, um, dt):
            return
        x = Fm @ self._x
        if um is not None:
            x = x + B @ um
        P = Fm @ self._P @ Fm.T
        P += P.T  # exact symmetry (the update relies on it), then halve and add Q
        P *= 0.5
        P += Qm
        if not (finite(x) and finite(P)):
            self._diagnose_predict("F, Q or B u")
        self._commit_predict(x, P, Fm, dt)

    def _predict_compiled(
        self,
        k: Any,
        F: np.ndarray,
        Q: np.ndarray,
        B: np.ndarray | None,
        u: np.ndarray | None,
        dt: float,
    ) -> bool:
        """Predict on the compiled kernel; False (nothing changed) when the numpy path must
        run instead (a non-finite result: it raises the precise error)."""
        n = self.n
        x = np.empty(n)
        P = np.empty((n, n))
        ws = grow_scratch(n * n)
        try:
            if u is None:
                status = k.kf_predict(self._x, self._P, F, Q, ws, x, P)
            else:
                status = k.kf_predict_u(self._x, self._P, F, Q, B, u, ws, x, P)
        except TypeError:  # pragma: no cover - every array is float64 by now
            return False
        if status:
            return False
        self._commit_predict(x, P, F, dt)
        return True
