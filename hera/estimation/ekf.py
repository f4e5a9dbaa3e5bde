"""Extended Kalman filter (seed 003 eqs. 7-8).

Predict: x = f(x, dt, u), P = F P F^T + Q with F = df/dx at the prior x (the user's Jacobian
``F(x, dt, u)`` or a central-difference one, differenced through the state's residual so
that a wrapped heading does not break it). Update: the shared linearised correction with
each block's h(x) and Jacobian (or a linear H).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from . import backend as _bk
from . import unrolled
from .correction import (
    _MODE_HX,
    _WS_SMALL,
    EMPTY1,
    LinearisedFilter,
    _kernel_inputs,
    _new,
    as_blocks,
    check_dt,
    process_noise,
)
from .gating import gate_threshold
from .numerics import finite, numerical_jacobian
from .observations import Block, Observations
from .results import UpdateResult
from .stacking import SCRATCH, grow_scratch

__all__ = ["ExtendedKalmanFilter"]

_ND = np.ndarray
_F64 = np.float64
_empty = np.empty
_INF = math.inf
_STEP_PREDICT = -7.0  # kernels_numba.STEP_PREDICT: the step kernel's predict part failed
_BAD_SHAPE = -5.0


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

    def _Q_at(self, dt: float) -> np.ndarray:
        """Q(dt) of a process noise given as a function, checked, and kept for the next
        call with the same dt when ``cache_dt`` (as ``predict`` does, written out there)."""
        if dt != self._dt or self._Qdt is None or not self.cache_dt:
            self._Qdt = process_noise(self._Q(dt), self.n, "Q(dt)")
            self._dt = dt
        return self._Qdt

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
            P = _empty(self._nn)
            try:
                status = k.ekf_predict(xn, self._P, Fj, Qm, SCRATCH[0], P)
                if status == _WS_SMALL:
                    status = k.ekf_predict(xn, self._P, Fj, Qm, grow_scratch(self.n**2), P)
            except TypeError:  # e.g. an integer Jacobian: the numpy path converts it
                status = -1
            if not status:
                self._x = self.x_prior = xn
                self._P = self.P_prior = P
                if self.history is not None:
                    self.history._predicted(self, dt, Fj)
                return
        self._predict_numpy(xn, Fj, Qm, dt)

    def _predict_numpy(self, xn: Any, Fj: np.ndarray, Qm: np.ndarray, dt: float) -> None:
        """The predict from f(x), its Jacobian and Q on numpy: converts what the kernel
        could not take and raises the precise error of what it refused."""
        n = self.n
        if type(xn) is not _ND or xn.ndim != 1 or xn.dtype != _F64:
            xn = np.asarray(xn, dtype=_F64).reshape(-1)
        if xn.shape != (n,):
            raise ValueError(f"predict: f(x) has {xn.shape[0]} values, the state has {n}")
        if Fj.dtype != _F64:
            Fj = Fj.astype(_F64)
        if Fj.shape != (n, n):
            raise ValueError(f"predict: the Jacobian F has shape {Fj.shape}, expected ({n}, {n})")
        if n <= unrolled.MAX_N:
            P = unrolled.predict_covariance(self._P, Fj, Qm, self._unrolled)
            if P is None or not finite(xn):  # no numpy rerun: its warnings would come first
                self._diagnose_predict([("f(x)", xn), ("the Jacobian F", Fj)], "F P F^T + Q")
            self._commit_predict(xn, P, Fj, dt)
            return
        P = Fj @ self._P @ Fj.T
        P += P.T  # exact symmetry, then halve and add Q
        P *= 0.5
        P += Qm
        if not (finite(xn) and finite(P)):  # a NaN or inf in F shows in P (P_jj > 0) or x
            self._diagnose_predict([("f(x)", xn), ("the Jacobian F", Fj)], "F P F^T + Q")
        self._commit_predict(xn, P, Fj, dt)

    def step(
        self,
        dt: float,
        obs: Observations | Sequence[Block] | Block | None,
        u: Any = None,
        *,
        gate: float | None = ...,  # type: ignore[assignment]
        Q: Any = None,
    ) -> UpdateResult:
        """``predict(dt, u, Q=Q)`` then ``update(obs, gate)``, the same results and errors
        (and x_prior/P_prior, history), in one compiled call when the numba backend runs
        and obs is one block the kernel takes (the usual fusion step: one sensor sample);
        else the two calls."""
        # predict()'s first lines, written out: a call layer costs about what fusing saves
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
            if type(Qm) is not _ND:
                if dt != self._dt or self._Qdt is None or not self.cache_dt:
                    self._Qdt = process_noise(Qm(dt), self.n, "Q(dt)")
                    self._dt = dt
                Qm = self._Qdt
        else:
            Qm = process_noise(Q, self.n, "Q")
        blocks = obs.blocks if type(obs) is Observations else as_blocks(obs)
        k = _bk._active
        if k is None or len(blocks) != 1 or type(xn) is not _ND:
            self._predict_given(k, xn, Fj, Qm, dt)
            return self.update(blocks, gate)
        b = blocks[0]
        m = b.dim
        if not (m <= 3 or b.var is None):
            self._predict_given(k, xn, Fj, Qm, dt)
            return self.update(blocks, gate)
        if gate is ...:
            gate = self.gate
        h = b.h
        try:  # the block at the predicted state, as update() prepares it for lin_update1
            if h is not None and b.jacobian is not None and b.residual is None:
                hx = h(xn)
                if type(hx) is not _ND:
                    hx = np.asarray(hx, dtype=_F64).reshape(-1)
                H = b.jacobian(xn)
                if type(H) is not _ND:
                    H = np.asarray(H, dtype=_F64).reshape(m, -1)
                z, flags = b.z, b.kflags | _MODE_HX
            elif h is None and b.residual is None:  # linear: the kernel computes z - H xn
                H, z, hx, flags = b.H, b.z, EMPTY1, b.kflags
            else:
                H, z, hx, flags = _kernel_inputs(b, xn)
        except Exception:  # as the two calls: the predict stands, update raises the error
            self._predict_given(k, xn, Fj, Qm, dt)
            return self.update(blocks, gate)
        thr = _INF if gate is None else gate_threshold(gate, m)
        n = self.n
        P_prior = _empty(self._nn)
        x_out = _empty(n)
        P_out = _empty(self._nn)
        flags |= self._jflag
        P = self._P
        noise = b.noise
        try:
            nis = k.ekf_step(
                xn, P, Fj, Qm, H, z, hx, noise, thr, flags, SCRATCH[0], P_prior, x_out, P_out
            )
            if nis == _WS_SMALL:
                ws = grow_scratch(max(n * n, 2 * m + 2 * m * m + 3 * n * m))
                nis = k.ekf_step(
                    xn, P, Fj, Qm, H, z, hx, noise, thr, flags, ws, P_prior, x_out, P_out
                )
        except TypeError:  # a user array of another dtype: the two calls convert it
            nis = _STEP_PREDICT
        if nis in (_STEP_PREDICT, _BAD_SHAPE):  # nothing computed: the two calls
            self._predict_given(k, xn, Fj, Qm, dt)
            return self.update(blocks, gate)
        self._x = self.x_prior = xn
        self._P = self.P_prior = P_prior
        if self.history is not None:
            self.history._predicted(self, dt, Fj)
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
        self._x = self.x_post = x_out
        self._P = self.P_post = P_out
        if self.history is not None:
            self.history._updated(self, res)
        return res

    def _predict_given(self, k: Any, xn: Any, Fj: np.ndarray, Qm: np.ndarray, dt: float) -> None:
        """The predict from already evaluated f(x), F and Q (kernel, else numpy)."""
        if k is not None and type(xn) is _ND:
            n = self.n
            P = _empty(self._nn)
            try:
                status = k.ekf_predict(xn, self._P, Fj, Qm, grow_scratch(n * n), P)
            except TypeError:
                status = -1
            if not status:
                self._commit_predict(xn, P, Fj, dt)
                return
        self._predict_numpy(xn, Fj, Qm, dt)
