"""Linear Kalman filter with control input (seed 003 eqs. 3-6).

Predict: x = F x + B u, P = F P F^T + Q; dt is explicit on every call and F, Q (and B) may
be functions of dt. Update: the shared linearised correction (see ``correction``) on the
variadic observation blocks.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from .backend import active_kernels
from .correction import _WS_SMALL, LinearisedFilter, _as_matrix
from .stacking import SCRATCH, grow_scratch

__all__ = ["KalmanFilter"]

MatrixOrFn = np.ndarray | Callable[[float], Any]


class KalmanFilter(LinearisedFilter):
    """Linear KF on float64 arrays.

    ``F``: state transition, an (n, n) matrix or a function ``F(dt)``; ``Q``: process noise
    covariance (matrix or ``Q(dt)``, in state units squared); ``B``: optional control matrix
    (n, k) or ``B(dt)``. Functions of dt are re-evaluated only when dt changes.
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
    ) -> None:
        super().__init__(x0, P0, joseph=joseph, gate=gate)
        n = self.n
        self._F = F if callable(F) else _as_matrix(F, n, "F")
        self._Q = Q if callable(Q) else _as_matrix(Q, n, "Q")
        if B is not None and not callable(B):
            B = np.array(B, dtype=np.float64).reshape(n, -1)
        self._B = B
        self._dt: float | None = None
        self._cache: tuple[np.ndarray, np.ndarray, np.ndarray | None] | None = None

    def _matrices(self, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        if dt == self._dt and self._cache is not None:
            return self._cache
        n = self.n
        F = _as_matrix(self._F(dt), n, "F(dt)") if callable(self._F) else self._F
        Q = _as_matrix(self._Q(dt), n, "Q(dt)") if callable(self._Q) else self._Q
        B = self._B
        if callable(B):
            B = np.array(B(dt), dtype=np.float64).reshape(n, -1)
        self._cache = (F, Q, B)
        self._dt = dt
        return self._cache

    def predict(
        self,
        dt: float,
        u: Any = None,
        *,
        F: np.ndarray | None = None,
        Q: np.ndarray | None = None,
    ) -> None:
        """Propagate by dt seconds: x = F x + B u, P = F P F^T + Q (seed 003 eq. 5).

        ``F``/``Q`` override the filter's matrices for this call only. The state is unchanged
        on error."""
        Fm, Qm, B = self._cache if dt == self._dt else self._matrices(dt)  # type: ignore[misc]
        k = active_kernels()
        if k is not None and F is None and Q is None and u is None:
            n = self.n
            x = np.empty(n)
            P = np.empty((n, n))
            try:
                status = k.kf_predict(self.x, self.P, Fm, Qm, SCRATCH[0], x, P)
                if status == _WS_SMALL:
                    status = k.kf_predict(self.x, self.P, Fm, Qm, grow_scratch(n * n), x, P)
            except TypeError:  # x or P replaced by the user with another dtype or layout
                status = -1
            if not status:
                self.x = x
                self.P = P
                return
        if F is not None:
            Fm = np.asarray(F, dtype=np.float64)
        if Q is not None:
            Qm = np.asarray(Q, dtype=np.float64)
        if k is not None and self._predict_compiled(k, Fm, Qm, B, u):
            return
        x = Fm @ self.x
        if u is not None:
            if B is None:
                raise ValueError("control input u given but the filter has no B")
            x = x + B @ np.asarray(u, dtype=np.float64).reshape(-1)
        P = Fm @ self.P @ Fm.T
        P += P.T  # exact symmetry (the update relies on it), then halve and add Q
        P *= 0.5
        P += Qm
        if F is None and Q is None and u is None:
            self.x = x  # inputs were checked when cached: finite in, finite out
            self.P = P
        else:
            self._commit_predict(x, P, "F, Q or u")

    def _predict_compiled(
        self, k: Any, F: np.ndarray, Q: np.ndarray, B: np.ndarray | None, u: Any
    ) -> bool:
        """Predict on the compiled kernel; False (nothing changed) when the numpy path must
        run instead (unusual shapes, non-finite result: it raises the precise error)."""
        n = self.n
        if F.shape != (n, n) or Q.shape != (n, n):
            return False
        x = np.empty(n)
        P = np.empty((n, n))
        ws = grow_scratch(n * n)
        try:
            if u is None:
                status = k.kf_predict(self.x, self.P, F, Q, ws, x, P)
            else:
                if B is None:
                    raise ValueError("control input u given but the filter has no B")
                um = np.asarray(u, dtype=np.float64).reshape(-1)
                if B.shape != (n, um.shape[0]):
                    return False
                status = k.kf_predict_u(self.x, self.P, F, Q, B, um, ws, x, P)
        except TypeError:
            return False
        if status:
            return False
        self.x = x
        self.P = P
        return True
