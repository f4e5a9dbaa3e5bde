"""Unscented Kalman filter with scaled sigma points (seed 003 eqs. 9-17, Appendix A).

Sigma points (Merwe's scaled form, parameters alpha, beta, kappa):
lambda = alpha^2 (n + kappa) - n, chi_0 = x, chi_i = x +/- column i of sqrt((n + lambda) P)
(Cholesky factor), weights Wm_0 = lambda / (n + lambda), Wc_0 = Wm_0 + 1 - alpha^2 + beta,
Wm_i = Wc_i = 1 / (2 (n + lambda)). Predict propagates the points through f and takes their
mean and covariance (eqs. 10-11); update redraws points from the predicted (x, P) (eq. 12),
maps them through each block's h (eq. 13), and corrects with K = Pxy S^-1 (Cholesky),
x += K y, P -= K S K^T (eqs. 14-17).

Means and differences go through functions, so angles and quaternions work: the filter's
``x_mean(X, Wm)`` and ``residual_x(a, b)``, each block's ``mean(Y, Wm)`` and ``residual(a,
b)`` (default: the arithmetic mean and plain subtraction; ``means.make_mean`` /
``make_residual`` / ``circular_mean`` / ``angle_residual`` for angles and quaternions). The
compiled kernels get the deviations these functions produce, so both backends use them.

Default alpha = 1 (beta = 2, kappa = 0): lambda = 0, so every weight is >= 0 (Wm_0 = 0,
Wc_0 = 2, the others 1 / 2n) and the predicted covariance sum_i Wc_i D_i D_i^T + Q is
positive semi-definite by construction; the points sit at +-sqrt(n) standard deviations.
The often quoted alpha = 1e-3 gives Wm_0 ~ -1e6 n: the covariance is then a difference of
terms a million times larger than itself and loses about six digits (and can come out
indefinite). Choose a smaller alpha only for strongly nonlinear models with n large, where
sqrt(n) sigma reaches too far.

Recovery policy (guarded Cholesky): sigma points need a Cholesky factor of P. When P is not
positive definite - roundoff after a very informative update, an ill-conditioned model -
P + delta I is tried with delta = 1e-12, 1e-11, ..., 1e-6 times the largest variance; the
first that factorises is used and becomes the filter's P when the step succeeds (counted in
``repairs``, the last delta in ``last_jitter``). If none does, P is indefinite beyond
roundoff: CovarianceError, the state unchanged (``reset`` it).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from . import backend as _bk
from .backend import active_kernels
from .correction import (
    ALL_REJECTED,
    _check_variances,
    _chol_solve,
    _cholesky,
    _lower_solve,
    as_blocks,
)
from .gating import gate_threshold
from .numerics import CovarianceError, NonFiniteInputError, finite
from .observations import Block, Observations
from .results import (
    BlockOutcome,
    DetailedResult,
    UpdateDetails,
    UpdateResult,
    gaussian_log_likelihood,
    make_outcome,
)
from .stacking import block_layout, stack_noise
from .state import FilterState, check_dt, process_noise

__all__ = ["MerweSigmaPoints", "UnscentedKalmanFilter"]

_INF = math.inf
_F64 = np.float64
JITTER_STEPS = tuple(10.0**k for k in range(-12, -5))  # delta / max variance, in order


class MerweSigmaPoints:
    """Scaled sigma points and weights for an n-dimensional state (seed 003 eq. 9).
    Default alpha = 1, beta = 2, kappa = 0: all weights >= 0 (see the module docstring)."""

    def __init__(self, n: int, alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0):
        self.n = n
        self.alpha = alpha
        self.beta = beta
        self.kappa = kappa
        lam = alpha * alpha * (n + kappa) - n
        if not n + lam > 0:
            raise ValueError(f"n + lambda must be > 0 (alpha={alpha}, kappa={kappa})")
        self.lam = lam
        self.scale = math.sqrt(n + lam)
        w = 0.5 / (n + lam)
        self.Wm = np.full(2 * n + 1, w)
        self.Wc = np.full(2 * n + 1, w)
        self.Wm[0] = lam / (n + lam)
        self.Wc[0] = lam / (n + lam) + 1.0 - alpha * alpha + beta
        self.Wm.flags.writeable = False
        self.Wc.flags.writeable = False

    def points(self, x: np.ndarray, P: np.ndarray) -> np.ndarray:
        """(2n+1, n) sigma points, one per row. Raises CovarianceError if P is not PD."""
        k = active_kernels()
        if k is not None and x.shape == (self.n,) and P.shape == (self.n, self.n):
            sig = np.empty((2 * self.n + 1, self.n))
            try:
                status = k.ukf_sigmas(x, P, self.scale, sig)
            except TypeError:  # x or P of another dtype or layout: numpy path
                status = -1
            if not status:
                return sig
        try:
            L = np.linalg.cholesky(P)
        except np.linalg.LinAlgError:
            raise CovarianceError("P", "Cholesky failed while drawing sigma points") from None
        Lt = L.T * self.scale
        n = self.n
        sig = np.empty((2 * n + 1, n))
        sig[0] = x
        np.add(x, Lt, out=sig[1 : n + 1])
        np.subtract(x, Lt, out=sig[n + 1 :])
        return sig


def jitter_repair(P: np.ndarray) -> tuple[np.ndarray, float] | None:
    """(P + delta I, delta) for the first delta in ``JITTER_STEPS`` times the largest
    variance that makes P positive definite (Cholesky), or None."""
    d = np.diagonal(P)
    scale = float(d.max()) if d.size else 0.0
    if not 0.0 < scale < _INF or not finite(P):
        return None
    eye = np.eye(P.shape[0])
    for step in JITTER_STEPS:
        delta = step * scale
        Pj = P + delta * eye
        try:
            np.linalg.cholesky(Pj)
        except np.linalg.LinAlgError:
            continue
        return Pj, delta
    return None


def _rowwise(fn: Callable[..., Any], A: np.ndarray, b: np.ndarray, vectorized: bool) -> np.ndarray:
    """fn(row, b) for every row of A: once on the whole array if fn is vectorized."""
    if vectorized:
        return np.asarray(fn(A, b), dtype=_F64)
    return np.array([fn(r, b) for r in A], dtype=_F64)


def _is_vectorized(fn: Any) -> bool:
    return bool(getattr(fn, "vectorized", False))


class UnscentedKalmanFilter(FilterState):
    """UKF on float64 arrays.

    ``f(x, dt, u) -> x'`` process model (``batched=True``: f takes and returns (N, n) arrays
    of sigma points); ``Q``: process noise (a scalar means Q I, a vector its diagonal, or a
    matrix; or ``Q(dt)``; positive semi-definite: checked). ``x_mean(X, Wm)`` and
    ``residual_x(a, b)``: the state's weighted mean and difference (default arithmetic;
    see ``means``; marked ``vectorized`` functions are called once on all sigma points,
    others row by row). ``gate``: default gate probability. ``cache_dt``: Q(dt) is a pure
    function of dt (evaluated once per distinct dt); False evaluates it every predict.

    Observation blocks are the same as for the KF/EKF; a block's ``h`` is applied to every
    sigma point (once on the whole (N, n) batch if the block is ``vectorized``), linear
    blocks use ``sigmas @ H.T``; its ``mean`` and ``residual`` replace the arithmetic mean
    and difference of the predicted measurements. ``x``, ``P``, ``x_prior`` ... as for the
    other filters (``state.FilterState``); ``repairs``/``last_jitter``: the recovery policy
    of the module docstring.
    """

    def __init__(
        self,
        x0: Any,
        P0: Any,
        f: Callable[..., Any],
        Q: Any,
        *,
        alpha: float = 1.0,
        beta: float = 2.0,
        kappa: float = 0.0,
        batched: bool = False,
        gate: float | None = None,
        x_mean: Callable[[np.ndarray, np.ndarray], Any] | None = None,
        residual_x: Callable[[np.ndarray, np.ndarray], Any] | None = None,
        cache_dt: bool = True,
    ) -> None:
        super().__init__(x0, P0)
        self.f = f
        self.batched = batched
        self.gate = gate
        self.x_mean = x_mean
        self.residual_x = residual_x
        self.cache_dt = cache_dt
        self.Q = Q
        self.sigma = MerweSigmaPoints(self.n, alpha, beta, kappa)
        self.repairs = 0
        self.last_jitter = 0.0

    @property
    def Q(self) -> Any:
        """The process noise covariance or function Q(dt)."""
        return self._Q

    @Q.setter
    def Q(self, Q: Any) -> None:
        self._Q = Q if callable(Q) else process_noise(Q, self.n, "Q")
        self._dt: float | None = None
        self._Qdt: np.ndarray | None = None

    def _q(self, dt: float) -> np.ndarray:
        Q = self._Q
        if not callable(Q):
            return Q
        if dt != self._dt or self._Qdt is None or not self.cache_dt:
            self._Qdt = process_noise(Q(dt), self.n, "Q(dt)")
            self._dt = dt
        return self._Qdt

    def _draw(self) -> tuple[np.ndarray, np.ndarray, float]:
        """Sigma points of (x, P) under the recovery policy: (points, the P they were
        drawn from, the jitter added or 0.0)."""
        P = self._P
        try:
            return self.sigma.points(self._x, P), P, 0.0
        except CovarianceError:
            fixed = jitter_repair(P)
            if fixed is None:
                raise CovarianceError(
                    "P",
                    "not even with a jitter of 1e-6 times the largest variance; reset the filter",
                ) from None
            Pj, delta = fixed
            return self.sigma.points(self._x, Pj), Pj, delta

    def _note_repair(self, delta: float) -> None:
        if delta:
            self.repairs += 1
            self.last_jitter = delta

    def predict(self, dt: float, u: Any = None, *, Q: Any = None) -> None:
        """Propagate the sigma points through f over dt seconds (>= 0) and take their
        weighted mean (``x_mean``) and covariance (of ``residual_x`` deviations) plus Q (seed
        003 eqs. 9-11). The state is unchanged on error."""
        if not 0.0 <= dt < _INF:
            check_dt(dt)
        sp = self.sigma
        n = self.n
        sig, _, delta = self._draw()
        f = self.f
        if self.batched:
            Xf = np.asarray(f(sig, dt, u), dtype=_F64)
        else:
            Xf = np.array([f(s, dt, u) for s in sig], dtype=_F64)
        if Xf.shape != (2 * n + 1, n):
            raise ValueError(
                f"predict: f(sigma points) has shape {Xf.shape}, expected ({2 * n + 1}, {n})"
            )
        Qm = self._q(dt) if Q is None else process_noise(Q, n, "Q")
        k = _bk._active
        x = np.empty(n) if self.x_mean is None else self._mean_x(Xf)
        D = None
        if self.x_mean is not None or self.residual_x is not None:
            if self.x_mean is None:
                x = sp.Wm @ Xf
            D = self._dev_x(Xf, x)
        P = np.empty((n, n))
        status = -1
        if k is not None:
            if D is None:
                status = k.ukf_predict(Xf, sp.Wm, sp.Wc, Qm, x, P)
            else:
                status = k.ukf_predict_dev(D, sp.Wc, Qm, P)
        if status:  # the numpy path (or a kernel that found a non-finite value)
            if D is None:
                x = sp.Wm @ Xf
                D = Xf - x
            P = (D.T * sp.Wc) @ D
            P = 0.5 * (P + P.T) + Qm
            if not (finite(x) and finite(P)):
                self._diagnose_predict(
                    [("f(sigma points)", Xf)], "the covariance of f(sigma points)"
                )
        elif D is not None and not finite(x):  # the kernel checked P, x came from x_mean
            self._diagnose_predict([("x_mean(f(sigma points))", x)], "x_mean")
        self._note_repair(delta)
        self._commit_predict(x, P, None, dt)

    def step(
        self,
        dt: float,
        obs: Observations | Sequence[Block] | Block | None,
        u: Any = None,
        *,
        gate: float | None = ...,  # type: ignore[assignment]
        Q: Any = None,
    ) -> UpdateResult:
        """``predict(dt, u, Q=Q)`` then ``update(obs, gate)`` (the user's f and h run between
        the two, so there is nothing to fuse; the same call as the KF's and EKF's)."""
        self.predict(dt, u, Q=Q)
        return self.update(obs, gate)

    def _mean_x(self, X: np.ndarray) -> np.ndarray:
        x = np.asarray(self.x_mean(X, self.sigma.Wm), dtype=_F64).reshape(-1)  # type: ignore[misc]
        if x.shape != (self.n,):
            raise ValueError(f"x_mean returned {x.shape[0]} values, the state has {self.n}")
        return x

    def _dev_x(self, X: np.ndarray, x: np.ndarray) -> np.ndarray:
        r = self.residual_x
        if r is None:
            return X - x
        D = _rowwise(r, X, x, _is_vectorized(r))
        if D.shape != X.shape:
            raise ValueError(f"residual_x returned shape {D.shape}, expected {X.shape}")
        return D

    def _measure(self, b: Block, sig: np.ndarray) -> np.ndarray:
        n = self.n
        if b.H is not None:
            if b.H.shape[1] != n:
                raise ValueError(
                    f"block {b.label!r}: H has {b.H.shape[1]} columns, the state has {n}"
                )
            return sig @ b.H.T
        h = b.h
        if b.vectorized:
            Y = np.asarray(h(sig), dtype=_F64)  # type: ignore[misc]
        else:
            Y = np.array([h(s) for s in sig], dtype=_F64)  # type: ignore[misc]
        if Y.size != sig.shape[0] * b.dim:
            raise ValueError(
                f"block {b.label!r}: h(sigma points) gave {Y.size} values, expected "
                f"{sig.shape[0]} x {b.dim}"
            )
        return Y.reshape(sig.shape[0], b.dim)

    def _block_moments(
        self, b: Block, Y: np.ndarray
    ) -> tuple[np.ndarray | None, np.ndarray | None]:
        """(Dy, y) of one block from its mean and residual functions, or (None, None) when
        it has neither (arithmetic: the kernel computes them)."""
        if b.mean is None and b.residual is None:
            return None, None
        Wm = self.sigma.Wm
        m = b.dim
        if b.mean is None:
            yp = Wm @ Y
        else:
            yp = np.asarray(b.mean(Y, Wm), dtype=_F64).reshape(-1)
            if yp.shape != (m,):
                raise ValueError(
                    f"block {b.label!r}: mean returned {yp.shape[0]} values, z has {m}"
                )
        if b.residual is None:
            return Y - yp, b.z - yp
        vec = b.vectorized or _is_vectorized(b.residual)
        Dy = _rowwise(b.residual, Y, yp, vec)
        y = np.asarray(b.residual(b.z, yp), dtype=_F64).reshape(-1)
        if Dy.shape != Y.shape or y.shape != (m,):
            raise ValueError(f"block {b.label!r}: residual returned shapes {Dy.shape}, {y.shape}")
        return Dy, y

    def update(
        self,
        obs: Observations | Sequence[Block] | Block | None,
        gate: float | None = ...,  # type: ignore[assignment]
        *,
        details: bool = False,
    ) -> UpdateResult:
        """Fuse the present blocks (seed 003 eqs. 12-17); no blocks: no-op. Gating, the
        result object and ``details`` are as for the KF. On any exception the state is
        unchanged."""
        blocks = as_blocks(obs)
        if not blocks:
            return UpdateResult([])
        g = self.gate if gate is ... else gate
        sig, P, delta = self._draw()
        x = self._x
        Ys = [self._measure(b, sig) for b in blocks]
        moments = [self._block_moments(b, Y) for b, Y in zip(blocks, Ys, strict=True)]
        custom = self.residual_x is not None or any(d is not None for d, _ in moments)
        k = _bk._active
        out = None
        if k is not None and not details and not custom and len(blocks) == 1:
            out = self._correct_one(k, blocks[0], g, x, P, sig, Ys[0])
        if k is not None and not details and out is None:
            out = self._correct_compiled(k, blocks, g, x, P, sig, Ys, moments, custom)
        if out is None:
            for b in blocks:
                _check_variances(b)
            Dys, ys = self._deviations(blocks, Ys, moments)
            out = self._correct_numpy(blocks, g, x, P, self._dev_x(sig, x), Dys, ys, details)
        x_new, P_new, res = out
        self._note_repair(delta)
        if x_new is x:  # everything gated out
            self._P = P
        else:
            self._commit_update(x_new, P_new, res)
        return res

    def _deviations(
        self,
        blocks: Sequence[Block],
        Ys: list[np.ndarray],
        moments: list[tuple[np.ndarray | None, np.ndarray | None]],
    ) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Every block's (Dy, y), arithmetic where it has no mean or residual function."""
        Wm = self.sigma.Wm
        Dys = []
        ys = []
        for b, Y, (Dy, y) in zip(blocks, Ys, moments, strict=True):
            if Dy is None:
                yp = Wm @ Y
                Dy, y = Y - yp, b.z - yp
            Dys.append(Dy)
            ys.append(y)
        return Dys, ys  # type: ignore[return-value]

    def _correct_numpy(
        self,
        blocks: Sequence[Block],
        gate: float | None,
        x: np.ndarray,
        P: np.ndarray,
        Dx: np.ndarray,
        Dys: list[np.ndarray],
        ys: list[np.ndarray],
        details: bool,
    ) -> tuple[np.ndarray, np.ndarray, UpdateResult]:
        Wc = self.sigma.Wc
        Dy = np.concatenate(Dys, axis=1) if len(Dys) > 1 else Dys[0]
        y = np.concatenate(ys) if len(ys) > 1 else ys[0]
        m = y.shape[0]
        var, R = stack_noise(blocks, m)
        S = (Dy.T * Wc) @ Dy
        if var is not None:
            S.flat[:: m + 1] += var
        else:
            S += R
        S = 0.5 * (S + S.T)
        if not (finite(S) and finite(y)):
            self._diagnose(blocks, Dys, ys)
        nis: list[float] = []
        o = 0
        for b in blocks:
            L = _cholesky(S[o : o + b.dim, o : o + b.dim])
            if L is None:
                labels = ", ".join(repr(b.label) for b in blocks)
                raise CovarianceError(f"innovation covariance S of blocks {labels}")
            w = _lower_solve(L, y[o : o + b.dim])
            nis.append(float(w @ w))
            o += b.dim
        thr: list[float | None] = [None] * len(blocks)
        acc = [True] * len(blocks)
        if gate is not None:
            thr = [gate_threshold(gate, b.dim) for b in blocks]
            acc = [v <= t for v, t in zip(nis, thr, strict=True)]  # type: ignore[operator]
        outs = [
            BlockOutcome(b.label, b.dim, v, a, t)
            for b, v, a, t in zip(blocks, nis, acc, thr, strict=True)
        ]
        if not any(acc):
            return x, P, UpdateResult(outs)
        rows: list[int] = []
        o = 0
        for b, a in zip(blocks, acc, strict=True):
            if a:
                rows.extend(range(o, o + b.dim))
            o += b.dim
        if len(rows) < m:
            S = S[np.ix_(rows, rows)]
            Dy = Dy[:, rows]
            y = y[rows]
        L = _cholesky(S)
        if L is None:
            raise CovarianceError("innovation covariance S of the accepted blocks")
        Pxy = (Dx.T * Wc) @ Dy
        Kt = _chol_solve(L, Pxy.T)
        x_new = x + y @ Kt
        P_new = P - Kt.T @ S @ Kt
        P_new = 0.5 * (P_new + P_new.T)
        if not min(P_new.diagonal().tolist()) > 0.0 or not finite(P_new):
            raise CovarianceError("P after update", "non-positive diagonal")
        if not details:
            return x_new, P_new, UpdateResult(outs)
        w = _lower_solve(L, y)
        log_det = 2.0 * float(np.log(np.diagonal(L)).sum())
        labels = tuple(b.label for b, a in zip(blocks, acc, strict=True) if a)
        ll = gaussian_log_likelihood(float(w @ w), log_det, y.shape[0])
        det = UpdateDetails(labels, y, S, Kt.T.copy(), None, ll)
        return x_new, P_new, DetailedResult(outs, det)

    def _correct_one(
        self,
        k: Any,
        b: Block,
        gate: float | None,
        x: np.ndarray,
        P: np.ndarray,
        sig: np.ndarray,
        Y: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, UpdateResult] | None:
        """One block with arithmetic means on ``ukf_update``: the common case, without the
        stacking of ``_correct_compiled``."""
        n = self.n
        sp = self.sigma
        ends, thr_arr, thr_list = block_layout(gate, b.dim)
        x_out = np.empty(n)
        P_out = np.empty((n, n))
        nis = np.empty(1)
        status = k.ukf_update(
            x, P, sig, Y, b.z, b.noise, b.var is not None, ends, thr_arr, sp.Wm, sp.Wc,
            x_out, P_out, nis,
        )  # fmt: skip
        if status < 0:
            return None
        v = float(nis[0])
        t = thr_list[0]
        result = UpdateResult([make_outcome(b.label, b.dim, v, t is None or v <= t, t)])
        if status == ALL_REJECTED:
            return x, P, result
        return x_out, P_out, result

    def _correct_compiled(
        self,
        k: Any,
        blocks: Sequence[Block],
        gate: float | None,
        x: np.ndarray,
        P: np.ndarray,
        sig: np.ndarray,
        Ys: list[np.ndarray],
        moments: list[tuple[np.ndarray | None, np.ndarray | None]],
        custom: bool,
    ) -> tuple[np.ndarray, np.ndarray, UpdateResult] | None:
        """The correction on the compiled kernels ``ukf_update`` (arithmetic means) or
        ``ukf_update_dev`` (deviations from the mean and residual functions); None when the
        numpy path must run (non-finite input, S not PD), which raises the labelled error."""
        n = self.n
        sp = self.sigma
        x_out = np.empty(n)
        P_out = np.empty((n, n))
        m = sum(b.dim for b in blocks)
        var, R = stack_noise(blocks, m)
        diag = var is not None
        noise = var if diag else R.reshape(-1)  # type: ignore[union-attr]
        ends, thr_arr, thr_list = block_layout(gate, tuple(b.dim for b in blocks))
        nis_arr = np.empty(len(blocks))
        try:
            if custom:
                Dx = self._dev_x(sig, x)
                Dys, ys = self._deviations(blocks, Ys, moments)
                Dy = np.concatenate(Dys, axis=1) if len(Dys) > 1 else Dys[0]
                y = np.concatenate(ys) if len(ys) > 1 else ys[0]
                status = k.ukf_update_dev(
                    x, P, Dx, Dy, y, noise, diag, ends, thr_arr, sp.Wc, x_out, P_out, nis_arr
                )
            else:
                Y = np.concatenate(Ys, axis=1) if len(Ys) > 1 else Ys[0]
                z = np.concatenate([b.z for b in blocks]) if len(blocks) > 1 else blocks[0].z
                status = k.ukf_update(
                    x, P, sig, Y, z, noise, diag, ends, thr_arr, sp.Wm, sp.Wc, x_out, P_out, nis_arr
                )
        except TypeError:
            return None
        if status < 0:
            return None
        nl = nis_arr.tolist()
        result = UpdateResult(
            [
                make_outcome(b.label, b.dim, v, t is None or v <= t, t)
                for b, v, t in zip(blocks, nl, thr_list, strict=True)
            ]
        )
        if status == ALL_REJECTED:
            return x, P, result
        return x_out, P_out, result

    def _diagnose(
        self, blocks: Sequence[Block], Dys: list[np.ndarray], ys: list[np.ndarray]
    ) -> None:
        for b, Dy, y in zip(blocks, Dys, ys, strict=True):
            if not finite(b.z):
                raise NonFiniteInputError(b.label, "z")
            if not finite(b.var if b.var is not None else b.R):
                raise NonFiniteInputError(b.label, "R")
            if b.H is not None and not finite(b.H):
                raise NonFiniteInputError(b.label, "H")
            if not (finite(Dy) and finite(y)):
                raise NonFiniteInputError(b.label, "h(sigma points)")
        raise NonFiniteInputError(", ".join(b.label for b in blocks), "innovation")
