"""Unscented Kalman filter with scaled sigma points (seed 003 eqs. 9-17, Appendix A).

Sigma points (Merwe's scaled form, parameters alpha, beta, kappa):
lambda = alpha^2 (n + kappa) - n, chi_0 = x, chi_i = x +/- column i of sqrt((n + lambda) P)
(Cholesky factor), weights Wm_0 = lambda / (n + lambda), Wc_0 = Wm_0 + 1 - alpha^2 + beta,
Wm_i = Wc_i = 1 / (2 (n + lambda)). Predict propagates the points through f (eqs. 10-11);
update redraws points from the predicted (x, P) (eq. 12), maps them through each block's
h (eq. 13), and corrects with K = Pxy Pyy^-1, x += K (z - y_mean), P -= K Pyy K^T
(eqs. 14-17).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from .backend import active_kernels
from .correction import ALL_REJECTED, _all_finite, _as_matrix, _block_nis, as_blocks, outcomes
from .gating import gate_threshold
from .numerics import CovarianceError, NonFiniteInputError
from .observations import Block, Observations
from .results import BlockOutcome, UpdateResult, make_outcome
from .small import inv_small, quad_form_small
from .stacking import EMPTY1, EMPTY2, block_layout, stack_noise

__all__ = ["MerweSigmaPoints", "UnscentedKalmanFilter"]


class MerweSigmaPoints:
    """Scaled sigma points and weights for an n-dimensional state (seed 003 eq. 9)."""

    def __init__(self, n: int, alpha: float = 1e-3, beta: float = 2.0, kappa: float = 0.0):
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
        self._buf = np.empty((2 * n + 1, n))

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


class UnscentedKalmanFilter:
    """UKF on float64 arrays.

    ``f(x, dt, u) -> x'`` process model (``batched=True``: f takes and returns (N, n) arrays
    of sigma points); ``Q``: process noise (matrix or ``Q(dt)``). ``gate``: default gate
    probability. Observation blocks are the same as for the KF/EKF; a block's ``h`` is
    applied to every sigma point (once on the whole (N, n) batch if the block is
    ``vectorized``); linear blocks use ``sigmas @ H.T``.
    """

    def __init__(
        self,
        x0: Any,
        P0: Any,
        f: Callable[..., Any],
        Q: np.ndarray | Callable[[float], Any],
        *,
        alpha: float = 1e-3,
        beta: float = 2.0,
        kappa: float = 0.0,
        batched: bool = False,
        gate: float | None = None,
    ) -> None:
        self.x = np.array(x0, dtype=np.float64).reshape(-1)
        self.n = n = self.x.shape[0]
        self.P = _as_matrix(P0, n, "P0")
        self.f = f
        self.batched = batched
        self.gate = gate
        self._Q = Q if callable(Q) else _as_matrix(Q, n, "Q")
        self._dt: float | None = None
        self._Qdt: np.ndarray | None = None
        self.sigma = MerweSigmaPoints(n, alpha, beta, kappa)

    def reset(self, x: Any, P: Any) -> None:
        """Re-initialise the state."""
        x = np.array(x, dtype=np.float64).reshape(-1)
        if x.shape != (self.n,) or not _all_finite(x):
            raise ValueError(f"reset: x must be {self.n} finite values")
        self.P = _as_matrix(P, self.n, "P")
        self.x = x

    def _q(self, dt: float) -> np.ndarray:
        Q = self._Q
        if not callable(Q):
            return Q
        if dt != self._dt or self._Qdt is None:
            self._Qdt = _as_matrix(Q(dt), self.n, "Q(dt)")
            self._dt = dt
        return self._Qdt

    def predict(self, dt: float, u: Any = None, *, Q: np.ndarray | None = None) -> None:
        """Propagate the sigma points through f over dt seconds and take their weighted mean
        and covariance plus Q (seed 003 eqs. 9-11). The state is unchanged on error."""
        sp = self.sigma
        sig = sp.points(self.x, self.P)
        f = self.f
        if self.batched:
            Xf = np.asarray(f(sig, dt, u), dtype=np.float64)
        else:
            Xf = np.array([f(s, dt, u) for s in sig], dtype=np.float64)
        Qm = self._q(dt) if Q is None else np.asarray(Q, dtype=np.float64)
        k = active_kernels()
        n = self.n
        if k is not None and Xf.shape == (2 * n + 1, n) and Qm.shape == (n, n):
            x = np.empty(n)
            P = np.empty((n, n))
            try:
                status = k.ukf_predict(Xf, sp.Wm, sp.Wc, Qm, x, P)
            except TypeError:  # pragma: no cover - Xf is float64 by construction
                status = -1
            if not status:
                self.x = x
                self.P = P
                return
        x = sp.Wm @ Xf
        D = Xf - x
        P = (D.T * sp.Wc) @ D + Qm
        P = 0.5 * (P + P.T)
        if not (math.isfinite(float(x.sum())) and math.isfinite(float(P.sum()))):
            raise NonFiniteInputError("predict", "f(sigma points) or Q", "step")
        self.x = x
        self.P = P

    def _measure(self, b: Block, sig: np.ndarray) -> np.ndarray:
        if b.H is not None:
            return sig @ b.H.T
        h = b.h
        if b.vectorized:
            Y = np.asarray(h(sig), dtype=np.float64)  # type: ignore[misc]
        else:
            Y = np.array([h(s) for s in sig], dtype=np.float64)  # type: ignore[misc]
        return Y.reshape(sig.shape[0], b.dim)

    def update(
        self,
        obs: Observations | Sequence[Block] | Block | None,
        gate: float | None = ...,  # type: ignore[assignment]
    ) -> UpdateResult:
        """Fuse the present blocks (seed 003 eqs. 12-17); no blocks: no-op. Gating and the
        result object are as for the KF. On any exception the state is unchanged."""
        blocks = as_blocks(obs)
        if not blocks:
            return UpdateResult([])
        g = self.gate if gate is ... else gate
        x, P, res = self._correct(blocks, g)
        self.x = x
        self.P = P
        return res

    def _correct(
        self, blocks: Sequence[Block], gate: float | None
    ) -> tuple[np.ndarray, np.ndarray, UpdateResult]:
        sp = self.sigma
        x = self.x
        sig = sp.points(x, self.P)
        k = active_kernels()
        if k is not None:
            out = self._correct_compiled(k, blocks, gate, sig)
            if out is not None:
                return out
        Wm, Wc = sp.Wm, sp.Wc
        if len(blocks) == 1:
            b = blocks[0]
            Y = self._measure(b, sig)
            yp = Wm @ Y
            if b.residual is None:
                Dy = Y - yp
                y = b.z - yp
            else:
                Dy = np.array([b.residual(r, yp) for r in Y], dtype=np.float64)
                y = np.asarray(b.residual(b.z, yp), dtype=np.float64).reshape(-1)
            var, R = b.var, b.R
        else:
            Ys, ys, Dys = [], [], []
            for b in blocks:
                Yb = self._measure(b, sig)
                yb = Wm @ Yb
                if b.residual is None:
                    Dys.append(Yb - yb)
                    ys.append(b.z - yb)
                else:
                    Dys.append(np.array([b.residual(r, yb) for r in Yb], dtype=np.float64))
                    ys.append(np.asarray(b.residual(b.z, yb), dtype=np.float64).reshape(-1))
                Ys.append(Yb)
            Dy = np.concatenate(Dys, axis=1)
            y = np.concatenate(ys)
            if all(b.var is not None for b in blocks):
                var, R = np.concatenate([b.var for b in blocks]), None
            else:
                m = y.shape[0]
                var, R = None, np.zeros((m, m))
                o = 0
                for b in blocks:
                    R[o : o + b.dim, o : o + b.dim] = b.cov()
                    o += b.dim
        m = y.shape[0]
        DyW = Dy.T * Wc
        S = DyW @ Dy
        if var is not None:
            S.flat[:: m + 1] += var
        else:
            S += R
        Sinv = None
        if m <= 3:
            Sl, yl = S.tolist(), y.tolist()
            Sinv = inv_small(Sl)
            ok = Sinv is not None and all(map(math.isfinite, yl))
        else:
            Sl = yl = None
            ok = _all_finite(S) and _all_finite(y)
        if not ok:
            self._diagnose(blocks, sig)
        if len(blocks) == 1 and Sinv is not None:
            nis = [quad_form_small(yl, Sinv)]  # type: ignore[arg-type]
        else:
            nis = _block_nis(blocks, S, y, Sl, yl)
        if nis is None or (m <= 3 and Sinv is None):
            labels = ", ".join(repr(b.label) for b in blocks)
            raise CovarianceError(f"innovation covariance S of blocks {labels}")
        thr: list[float | None] = [None] * len(blocks)
        if gate is not None:
            thr = [gate_threshold(gate, b.dim) for b in blocks]
            acc = [v <= t for v, t in zip(nis, thr, strict=True)]
            if not all(acc):
                res = UpdateResult(
                    [
                        BlockOutcome(b.label, b.dim, v, a, t)
                        for b, v, a, t in zip(blocks, nis, acc, thr, strict=True)
                    ]
                )
                kept = [b for b, a in zip(blocks, acc, strict=True) if a]
                if not kept:
                    return x, self.P, res
                x2, P2, _ = self._correct(kept, None)
                return x2, P2, res
        rows = zip(blocks, nis, thr, strict=True)
        outs = [BlockOutcome(b.label, b.dim, v, True, t) for b, v, t in rows]
        result = UpdateResult(outs)
        Pxy = ((sig - x).T * Wc) @ Dy
        K = Pxy @ np.array(Sinv) if Sinv is not None else np.linalg.solve(S, Pxy.T).T
        x_new = x + K @ y
        P_new = self.P - K @ S @ K.T
        P_new = 0.5 * (P_new + P_new.T)
        if not min(P_new.diagonal().tolist()) > 0.0:
            raise CovarianceError("P after update", "non-positive diagonal")
        return x_new, P_new, result

    def _correct_compiled(
        self, k: Any, blocks: Sequence[Block], gate: float | None, sig: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, UpdateResult] | None:
        """The correction on the compiled kernels ``ukf_update1`` / ``ukf_update``; None
        when the numpy path must run (a residual function, unusual shapes, non-finite
        input, S not PD), which re-evaluates h on the sigma points and raises the labelled
        error."""
        n = self.n
        sp = self.sigma
        x_out = np.empty(n)
        P_out = np.empty((n, n))
        if len(blocks) == 1:
            b = blocks[0]
            if b.residual is not None:
                return None
            Y = self._measure(b, sig)
            m = b.dim
            if Y.shape != (2 * n + 1, m):
                return None
            var = b.var
            diag = var is not None
            thr = math.inf if gate is None else gate_threshold(gate, m)
            try:
                status, nis = k.ukf_update1(
                    self.x,
                    self.P,
                    sig,
                    Y,
                    b.z,
                    var if diag else EMPTY1,
                    EMPTY2 if diag else b.R,
                    diag,
                    thr,
                    sp.Wm,
                    sp.Wc,
                    x_out,
                    P_out,
                )
            except TypeError:  # x or P replaced by the user with another dtype or layout
                return None
            if status < 0:
                return None
            t = None if gate is None else thr
            result = UpdateResult([make_outcome(b.label, m, nis, t is None or nis <= thr, t)])
        else:
            for b in blocks:
                if b.residual is not None:
                    return None
            Y = np.concatenate([self._measure(b, sig) for b in blocks], axis=1)
            z = np.concatenate([b.z for b in blocks])
            m = z.shape[0]
            if Y.shape != (2 * n + 1, m):
                return None
            var, R = stack_noise(blocks, m)
            diag = var is not None
            ends, thr_arr, thr_list = block_layout(gate, tuple(b.dim for b in blocks))
            nis_arr = np.empty(len(blocks))
            try:
                status = k.ukf_update(
                    self.x,
                    self.P,
                    sig,
                    Y,
                    z,
                    var if diag else EMPTY1,
                    EMPTY2 if diag else R,
                    diag,
                    ends,
                    thr_arr,
                    sp.Wm,
                    sp.Wc,
                    x_out,
                    P_out,
                    nis_arr,
                )
            except TypeError:
                return None
            if status < 0:
                return None
            result = outcomes(blocks, nis_arr.tolist(), thr_list)
        if status == ALL_REJECTED:
            return self.x, self.P, result
        return x_out, P_out, result

    def _diagnose(self, blocks: Sequence[Block], sig: np.ndarray) -> None:
        for b in blocks:
            if not _all_finite(b.z):
                raise NonFiniteInputError(b.label, "z")
            if not _all_finite(b.var if b.var is not None else b.R):
                raise NonFiniteInputError(b.label, "R")
            if b.H is not None and not _all_finite(b.H):
                raise NonFiniteInputError(b.label, "H")
            if not _all_finite(self._measure(b, sig)):
                raise NonFiniteInputError(b.label, "h(sigma points)")
        raise NonFiniteInputError(", ".join(b.label for b in blocks), "innovation")

    def __repr__(self) -> str:
        return f"UnscentedKalmanFilter(n={self.n}, x={self.x!r})"
