"""Linear Kalman filter with control input (seed 003 eqs. 3-6).

Predict: x = F x + B u, P = F P F^T + Q; dt is explicit on every call (seconds, >= 0) and
F, Q (and B) may be functions of dt. Update: the shared linearised correction (see
``correction``) on the variadic observation blocks.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from . import backend as _bk
from . import unrolled
from .correction import (
    _WS_SMALL,
    LinearisedFilter,
    _as_matrix,
    _new,
    as_blocks,
    check_dt,
    process_noise,
)
from .gating import gate_threshold
from .numerics import finite
from .observations import Block, Observations
from .results import UpdateResult
from .stacking import SCRATCH, grow_scratch

__all__ = ["KalmanFilter"]

MatrixOrFn = np.ndarray | Callable[[float], Any]
_INF = math.inf
_PREDICTED = "F x + B u or F P F^T + Q"  # what overflowed when every input is finite
_empty = np.empty
_STEP_PREDICT = -7.0  # kernels_numba.STEP_PREDICT: the step kernel's predict part failed
_BAD_SHAPE = -5.0


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
        if um is None and self.n <= unrolled.MAX_N:
            out = unrolled.predict(self._x, self._P, Fm, Qm, self._unrolled)
            if out is None:  # not finite: no numpy rerun (its warnings would come first)
                self._diagnose_predict([("F", Fm), ("Q", Qm)], _PREDICTED)
            self._commit_predict(out[0], out[1], Fm, dt)
            return
        x = Fm @ self._x
        if um is not None:
            x = x + B @ um
        P = Fm @ self._P @ Fm.T
        P += P.T  # exact symmetry (the update relies on it), then halve and add Q
        P *= 0.5
        P += Qm
        if not (finite(x) and finite(P)):
            inputs = [("F", Fm), ("Q", Qm), ("the control input u", um), ("B", B)]
            self._diagnose_predict(inputs, _PREDICTED)
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

    def step(
        self,
        dt: float,
        obs: Observations | Sequence[Block] | Block | None,
        u: Any = None,
        *,
        gate: float | None = ...,  # type: ignore[assignment]
        F: Any = None,
        Q: Any = None,
    ) -> UpdateResult:
        """``predict(dt, u, F=F, Q=Q)`` then ``update(obs, gate)``, the same results and
        errors (and x_prior/P_prior, history), in one compiled call when the numba backend
        runs and obs is one linear block (H, no residual) with the filter's own F and Q;
        else the two calls."""
        blocks = obs.blocks if type(obs) is Observations else as_blocks(obs)
        k = _bk._active
        b = blocks[0] if len(blocks) == 1 else None
        if (
            k is None
            or b is None
            or u is not None
            or F is not None
            or Q is not None
            or b.h is not None
            or b.residual is not None
            or not (b.dim <= 3 or b.var is None)
            or not 0.0 <= dt < _INF
        ):
            self.predict(dt, u, F=F, Q=Q)
            return self.update(blocks, gate)
        Fm, Qm, _ = self._cache if dt == self._dt else self._matrices(dt)
        if gate is ...:
            gate = self.gate
        m = b.dim
        thr = _INF if gate is None else gate_threshold(gate, m)
        n = self.n
        x_prior = _empty(n)
        P_prior = _empty(self._nn)
        x_out = _empty(n)
        P_out = _empty(self._nn)
        flags = b.kflags | self._jflag
        H, z, noise, P = b.H, b.z, b.noise, self._P
        try:
            nis = k.kf_step(
                self._x, P, Fm, Qm, H, z, noise, thr, flags, SCRATCH[0], x_prior, P_prior,
                x_out, P_out,
            )  # fmt: skip
            if nis == _WS_SMALL:
                ws = grow_scratch(max(n * n, 2 * m + 2 * m * m + 3 * n * m))
                nis = k.kf_step(
                    self._x, P, Fm, Qm, H, z, noise, thr, flags, ws, x_prior, P_prior,
                    x_out, P_out,
                )  # fmt: skip
        except TypeError:  # pragma: no cover - Block and the filter give float64 arrays
            nis = _STEP_PREDICT
        if nis in (_STEP_PREDICT, _BAD_SHAPE):  # nothing computed: the two calls
            self.predict(dt)
            return self.update(blocks, gate)
        self._commit_predict(x_prior, P_prior, Fm, dt)
        if nis < 0.0:  # the update part failed: the numpy path raises the precise error
            return self.update(blocks, gate)
        res = _new(UpdateResult)
        if nis > thr:
            res._one = (b.label, m, nis, False, thr)
            res._outcomes = None
            return res
        t = None if gate is None else thr
        res._one = (b.label, m, nis, True, t)
        res._outcomes = None
        self._commit_update(x_out, P_out, res)
        return res
