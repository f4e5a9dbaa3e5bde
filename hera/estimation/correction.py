"""The measurement update shared by the linear KF and the EKF (linearised correction).

For the stacked blocks: innovation y = z - h(x) (or the block's residual), S = H P H^T + R,
NIS per block from the diagonal sub-blocks of S, chi-square gating, then either

* the joint update K = P H^T S^-1, x += K y, and the Joseph form
  P = (I - K H) P (I - K H)^T + K R K^T (seed 000) or the short form P = P - K H P; or
* sequential scalar updates when R is diagonal (seed 000, "sequential update"), which
  need no matrix inverse and give the same result as the joint update (the innovation of
  each row is taken about the prior linearisation point, so this also holds for the EKF).

Nothing is written to the filter before every input has been checked: a non-finite z, R,
H, Jacobian or h(x) raises :class:`NonFiniteInputError` naming the block, and a
non-positive-definite S or P raises :class:`CovarianceError`.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from .backend import active_kernels
from .consider import consider_indices, restore_considered
from .gating import gate_threshold
from .numerics import CovarianceError, NonFiniteInputError, numerical_jacobian
from .observations import Block, Observations
from .results import BlockOutcome, UpdateResult, make_outcome, make_result, make_result1
from .small import inv_small, quad_form_small
from .stacking import EMPTY1, EMPTY2, SCRATCH, block_layout, grow_scratch, stack_noise

# Kernel protocol (mirrors kernels_numba, which may not be importable): status and flags.
ALL_REJECTED = 1
_MODE_HX = 1
_MODE_GIVEN = 2
_DIAG = 4
_JOSEPH = 8
_SEQUENTIAL = 16
_WS_SMALL = -4  # scratch array too short (kernels_numba.WS_SMALL)

__all__ = [
    "LinearisedFilter",
    "as_blocks",
    "eye",
    "linearised_update",
    "linearised_update_numpy",
    "outcomes",
]

_EYE: dict[int, np.ndarray] = {}
_isfinite = math.isfinite
_empty = np.empty
_ND = np.ndarray
_INF = math.inf


def eye(n: int) -> np.ndarray:
    """Cached read-only identity matrix."""
    e = _EYE.get(n)
    if e is None:
        e = np.eye(n)
        e.flags.writeable = False
        _EYE[n] = e
    return e


def as_blocks(obs: Observations | Sequence[Block] | Block | None) -> Sequence[Block]:
    """Accept Observations, a sequence of blocks, one block or None."""
    if obs is None:
        return ()
    if type(obs) is Observations:
        return obs.blocks
    if isinstance(obs, Block):
        return (obs,)
    return obs  # type: ignore[return-value]


def _linearise(b: Block, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(H, h(x)) of one block at x."""
    if b.H is not None:
        return b.H, b.H @ x
    hx = b.h(x)  # type: ignore[misc]
    if type(hx) is not np.ndarray or hx.ndim != 1:
        hx = np.asarray(hx, dtype=np.float64).reshape(-1)
    if b.jacobian is not None:
        Hj = b.jacobian(x)
        if type(Hj) is not np.ndarray or Hj.ndim != 2:
            Hj = np.asarray(Hj, dtype=np.float64).reshape(b.dim, -1)
    else:
        Hj = numerical_jacobian(b.h, x, b.dim).reshape(b.dim, -1)
    if hx.shape[0] != b.dim or Hj.shape != (b.dim, x.shape[0]):
        raise ValueError(
            f"block {b.label!r}: h(x) has shape {hx.shape} and its Jacobian {Hj.shape}; "
            f"expected ({b.dim},) and ({b.dim}, {x.shape[0]})"
        )
    return Hj, hx


def _innovation(b: Block, hx: np.ndarray) -> np.ndarray:
    if b.residual is None:
        return b.z - hx
    y = b.residual(b.z, hx)
    if type(y) is not np.ndarray or y.ndim != 1:
        y = np.asarray(y, dtype=np.float64).reshape(-1)
    return y


def _all_finite(a: np.ndarray) -> bool:
    return bool(np.isfinite(a).all())


def diagnose_nonfinite(
    blocks: Iterable[Block], parts: Iterable[tuple[Any, Any, Any]], P: np.ndarray
) -> None:
    """Raise NonFiniteInputError for the first block with a non-finite input, else
    CovarianceError if P itself is bad. Returns when nothing non-finite was found."""
    for b, (H, hx, y) in zip(blocks, parts, strict=False):
        if not _all_finite(b.z):
            raise NonFiniteInputError(b.label, "z")
        if not _all_finite(b.var if b.var is not None else b.R):
            raise NonFiniteInputError(b.label, "R")
        if H is not None and not _all_finite(H):
            raise NonFiniteInputError(b.label, "H" if b.H is not None else "Jacobian")
        if hx is not None and not _all_finite(hx):
            raise NonFiniteInputError(b.label, "h(x)")
        if y is not None and not _all_finite(y):
            raise NonFiniteInputError(b.label, "residual")
    if not _all_finite(P):
        raise CovarianceError("P", "contains NaN or inf")


def _stack(
    x: np.ndarray, blocks: Sequence[Block]
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None, list]:
    """Stack the blocks: (H, y, var or None, R or None, parts)."""
    if len(blocks) == 1:
        b = blocks[0]
        H, hx = _linearise(b, x)
        y = _innovation(b, hx)
        return H, y, b.var, b.R, [(H, hx, y)]
    parts = []
    for b in blocks:
        H, hx = _linearise(b, x)
        parts.append((H, hx, _innovation(b, hx)))
    H = np.concatenate([p[0] for p in parts])
    y = np.concatenate([p[2] for p in parts])
    if all(b.var is not None for b in blocks):
        return H, y, np.concatenate([b.var for b in blocks]), None, parts
    m = y.shape[0]
    R = np.zeros((m, m))
    o = 0
    for b in blocks:
        d = b.dim
        R[o : o + d, o : o + d] = b.cov()
        o += d
    return H, y, None, R, parts


def _block_nis(
    blocks: Sequence[Block], S: np.ndarray, y: np.ndarray, Sl: list | None, yl: list | None
) -> list[float] | None:
    """NIS of every block from the diagonal sub-blocks of S; None if one is not PD."""
    out = []
    o = 0
    for b in blocks:
        d = b.dim
        if Sl is not None and d <= 3:
            sub = [row[o : o + d] for row in Sl[o : o + d]]
            inv = inv_small(sub)
            if inv is None:
                return None
            out.append(quad_form_small(yl[o : o + d], inv))  # type: ignore[index]
        else:
            Sb = S[o : o + d, o : o + d] if Sl is None else np.array(Sl)[o : o + d, o : o + d]
            yb = y[o : o + d]
            try:
                L = np.linalg.cholesky(Sb)
            except np.linalg.LinAlgError:
                return None
            w = np.linalg.solve(L, yb)
            out.append(float(w @ w))
        o += d
    return out


def linearised_update(
    x: np.ndarray,
    P: np.ndarray,
    blocks: Sequence[Block],
    gate: float | None = None,
    joseph: bool = True,
    method: str = "auto",
) -> tuple[np.ndarray, np.ndarray, UpdateResult]:
    """One correction step; returns new (x, P) and the result. Pure: x and P are not
    modified. ``method``: "joint", "sequential" (R diagonal) or "auto" (joint up to 3 rows,
    sequential above when R is diagonal). Runs the compiled kernel when the numba backend
    is active (same results to roundoff, same errors), else ``linearised_update_numpy``."""
    filt = object.__new__(LinearisedFilter)  # no copies: x and P are only read
    filt.x, filt.P, filt.n, filt.joseph, filt.gate = x, P, x.shape[0], joseph, None
    result = filt.update(blocks, gate, method=method)
    return filt.x, filt.P, result


def _kernel_inputs(b: Block, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """(H, z, hx, innovation mode) of one block for ``lin_update1``, for the blocks the
    hot path of ``LinearisedFilter.update`` does not write out: no Jacobian (a numerical
    one) or a residual function (the innovation is then computed here)."""
    H, hx = _linearise(b, x)
    if b.residual is None:
        return H, b.z, hx, _MODE_HX
    return H, _innovation(b, hx), hx, _MODE_GIVEN


def _compiled_stacked(
    k: Any,
    x: np.ndarray,
    P: np.ndarray,
    blocks: Sequence[Block],
    gate: float | None,
    joseph: bool,
    method: str,
) -> tuple[np.ndarray, np.ndarray, UpdateResult] | None:
    """Several blocks, or sequential updates: the general kernel ``lin_update``."""
    n = x.shape[0]
    flags = _JOSEPH if joseph else 0
    parts = []
    for b in blocks:
        Hb, hx = _linearise(b, x)
        parts.append((Hb, _innovation(b, hx)))
    H = np.concatenate([p[0] for p in parts])
    z = np.concatenate([p[1] for p in parts])
    m = z.shape[0]
    dims = tuple(b.dim for b in blocks)
    if H.shape != (m, n) or sum(dims) != m:
        return None
    flags |= _MODE_GIVEN
    var, R = stack_noise(blocks, m)
    if var is not None:
        flags |= _DIAG
        R = EMPTY2
    else:
        var = EMPTY1
    if method == "sequential" or (m > 3 and method == "auto" and flags & _DIAG):
        if not flags & _DIAG:
            return None
        flags |= _SEQUENTIAL
    ends, thr_arr, thr_list = block_layout(gate, dims)
    x_out = np.empty(n)
    P_out = np.empty((n, n))
    nis_arr = np.empty(len(blocks))
    try:
        status = k.lin_update(
            x, P, H, z, EMPTY1, var, R, ends, thr_arr, flags, x_out, P_out, nis_arr
        )
    except TypeError:
        return None
    if status < 0:
        return None
    res = outcomes(blocks, nis_arr.tolist(), thr_list)
    if status == ALL_REJECTED:
        return x, P, res
    return x_out, P_out, res


def outcomes(blocks: Sequence[Block], nis: list[float], thr: list[float | None]) -> UpdateResult:
    """The UpdateResult of blocks with their NIS and gate thresholds (None: no gate); a
    block is accepted when its NIS is within its threshold."""
    return UpdateResult(
        [
            make_outcome(b.label, b.dim, v, t is None or v <= t, t)
            for b, v, t in zip(blocks, nis, thr, strict=True)
        ]
    )


def linearised_update_numpy(
    x: np.ndarray,
    P: np.ndarray,
    blocks: Sequence[Block],
    gate: float | None = None,
    joseph: bool = True,
    method: str = "auto",
) -> tuple[np.ndarray, np.ndarray, UpdateResult]:
    """``linearised_update`` on numpy only (the reference the compiled kernel is tested
    against)."""
    if len(blocks) == 1 and method != "sequential":
        b = blocks[0]
        if b.dim <= 3 and b.var is not None:
            fast = _fast_single(x, P, b, gate, joseph)
            if fast is not None:
                return fast
    H, y, var, R, parts = _stack(x, blocks)
    m = y.shape[0]
    PHt = P @ H.T
    S = H @ PHt
    if var is not None:
        S.flat[:: m + 1] += var
    else:
        S += R
    # Finite S and y imply finite z, R, H (P is PD, so inf * P_jj never cancels to finite).
    Sinv = None
    if m <= 3:
        Sl = S.tolist()
        yl = y.tolist()
        Sinv = inv_small(Sl)
        ok = Sinv is not None and all(map(_isfinite, yl))
    else:
        Sl = yl = None
        ok = _all_finite(S) and _all_finite(y)
    if not ok:
        diagnose_nonfinite(blocks, parts, P)
        if m > 3 and not _all_finite(S):  # pragma: no cover - defensive
            raise CovarianceError("S")
    if len(blocks) == 1 and Sinv is not None:
        nis = [quad_form_small(yl, Sinv)]  # type: ignore[arg-type]
    else:
        nis = _block_nis(blocks, S, y, Sl, yl)
    if nis is None or (m <= 3 and Sinv is None):
        labels = ", ".join(repr(b.label) for b in blocks)
        raise CovarianceError(f"innovation covariance S of blocks {labels}")
    if gate is not None:
        thr = [gate_threshold(gate, b.dim) for b in blocks]
        acc = [v <= t for v, t in zip(nis, thr, strict=True)]
        if not all(acc):
            kept = [b for b, a in zip(blocks, acc, strict=True) if a]
            res = UpdateResult(
                [
                    BlockOutcome(b.label, b.dim, v, a, t)
                    for b, v, a, t in zip(blocks, nis, acc, thr, strict=True)
                ]
            )
            if not kept:
                return x, P, res
            x2, P2, _ = linearised_update_numpy(x, P, kept, None, joseph, method)
            return x2, P2, res
        rows = zip(blocks, nis, thr, strict=True)
        outs = [BlockOutcome(b.label, b.dim, v, True, t) for b, v, t in rows]
        result = UpdateResult(outs)
    else:
        pairs = zip(blocks, nis, strict=True)
        result = UpdateResult([BlockOutcome(b.label, b.dim, v, True) for b, v in pairs])

    sequential = method == "sequential" or (method == "auto" and m > 3 and var is not None)
    if sequential:
        if var is None:
            raise ValueError("sequential updates need a diagonal R (variances) in every block")
        x_new, P_new = _sequential(x, P, H, y, var, joseph)
    else:
        if Sinv is not None:
            K = PHt @ np.array(Sinv)
        else:
            try:
                K = np.linalg.solve(S, PHt.T).T
            except np.linalg.LinAlgError:
                raise CovarianceError("innovation covariance S", "singular") from None
        x_new = x + K @ y
        if joseph:
            A = eye(x.shape[0]) - K @ H
            KRKt = (K * var) @ K.T if var is not None else K @ R @ K.T
            P_new = A @ P @ A.T + KRKt
        else:
            P_new = P - K @ PHt.T
        P_new = 0.5 * (P_new + P_new.T)
    if not min(P_new.diagonal().tolist()) > 0.0:
        raise CovarianceError("P after update", "non-positive diagonal")
    return x_new, P_new, result


def _fast_single(
    x: np.ndarray, P: np.ndarray, b: Block, gate: float | None, joseph: bool
) -> tuple[np.ndarray, np.ndarray, UpdateResult] | None:
    """Joint update of one block of 1-3 rows with diagonal R, with as few numpy calls as
    possible (S is inverted in closed form on Python floats). Returns None to fall back to
    the general path (non-finite input, S not PD, gated out) which then diagnoses.

    Covariance: the Joseph form written out, P - K G - G^T K^T + K S K^T with G = H P
    (algebraically equal to (I - K H) P (I - K H)^T + K R K^T for any gain K), evaluated as
    P + (E + E^T) with E = K (S K^T / 2 - G), which is exactly symmetric; or the short
    form P - K G, symmetrised.
    """
    H, hx = _linearise(b, x)
    y = _innovation(b, hx)
    dot = np.dot
    G = dot(H, P)
    Sl = dot(G, H.T).tolist()
    vl = b.var.tolist()  # type: ignore[union-attr]
    for i, v in enumerate(vl):
        Sl[i][i] += v
    Sinv = inv_small(Sl)
    yl = y.tolist()
    if Sinv is None or not all(map(_isfinite, yl)):
        return None
    nis = quad_form_small(yl, Sinv)
    thr = None
    if gate is not None:
        thr = gate_threshold(gate, b.dim)
        if not nis <= thr:
            return None
    Kt = dot(np.array(Sinv), G)  # K^T, m x n
    x_new = x + dot(y, Kt)
    if joseph:
        Sh = np.array(Sl)
        Sh *= 0.5
        E = dot(Kt.T, dot(Sh, Kt) - G)
        P_new = P + (E + E.T)
    else:
        P_new = P - dot(Kt.T, G)
        P_new = 0.5 * (P_new + P_new.T)
    if not min(P_new.diagonal().tolist()) > 0.0:
        raise CovarianceError("P after update", "non-positive diagonal")
    return x_new, P_new, UpdateResult([BlockOutcome(b.label, b.dim, nis, True, thr)])


def _sequential(
    x: np.ndarray, P: np.ndarray, H: np.ndarray, y: np.ndarray, var: np.ndarray, joseph: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Scalar updates row by row (R diagonal); no inverse. Row i's innovation is taken about
    the prior point: y_i - H_i (x_i - x_prior), which makes the result equal the joint one."""
    n = x.shape[0]
    ident = eye(n)
    xc = x
    Pc = P
    yl = y.tolist()
    vl = var.tolist()
    for i in range(H.shape[0]):
        hi = H[i]
        c = Pc @ hi
        s = float(hi @ c) + vl[i]
        if not s > 0.0:
            raise CovarianceError("innovation variance", f"row {i}: {s!r}")
        k = c / s
        yi = yl[i] - float(hi @ (xc - x)) if i else yl[i]
        xc = xc + k * yi
        if joseph:
            A = ident - np.outer(k, hi)
            Pc = A @ Pc @ A.T + vl[i] * np.outer(k, k)
        else:
            Pc = Pc - np.outer(k, c)
    return xc, 0.5 * (Pc + Pc.T)


def _as_matrix(a: Any, n: int, what: str) -> np.ndarray:
    m = np.array(a, dtype=np.float64)
    if m.ndim == 0:
        m = m * np.eye(n)
    if m.shape != (n, n):
        raise ValueError(f"{what} has shape {m.shape}, expected ({n}, {n})")
    if not _all_finite(m):
        raise ValueError(f"{what} contains NaN or inf")
    return m


class LinearisedFilter:
    """State (x, P) and the shared linearised correction of the KF and the EKF.

    ``joseph``: use the Joseph-form covariance update (default) or the short form
    P = P - K H P. ``gate``: default gate probability for ``update`` (None: no gating).
    """

    def __init__(self, x0: Any, P0: Any, *, joseph: bool = True, gate: float | None = None) -> None:
        self.x = np.array(x0, dtype=np.float64).reshape(-1)
        self.n = self.x.shape[0]
        self.P = _as_matrix(P0, self.n, "P0")
        if not _all_finite(self.x):
            raise ValueError("x0 contains NaN or inf")
        self.joseph = joseph
        self.gate = gate

    def reset(self, x: Any, P: Any) -> None:
        """Re-initialise the state (e.g. from a health monitor's reset hook)."""
        x = np.array(x, dtype=np.float64).reshape(-1)
        if x.shape != (self.n,) or not _all_finite(x):
            raise ValueError(f"reset: x must be {self.n} finite values")
        self.P = _as_matrix(P, self.n, "P")
        self.x = x

    def update(
        self,
        obs: Observations | Sequence[Block] | Block | None,
        gate: float | None = ...,  # type: ignore[assignment]
        *,
        method: str = "auto",
        consider: Sequence[int] | np.ndarray | None = None,
    ) -> UpdateResult:
        """Fuse the present observation blocks (thesis listing 4.1). No blocks: no-op.

        ``gate``: chi-square probability per block (e.g. 0.999) or None; defaults to the
        filter's ``gate``. ``consider``: states (indices or a boolean mask) this update must
        not change, Schmidt "consider" states (:mod:`.consider`): their gain rows are zero,
        the covariance stays consistent (Joseph form). Returns which blocks were
        accepted/rejected with their NIS. On any exception the state is unchanged.
        """
        if consider is not None:
            return self._update_considering(obs, gate, method, consider)
        blocks = obs.blocks if type(obs) is Observations else as_blocks(obs)
        if gate is ...:
            gate = self.gate
        k = active_kernels()
        out = None
        b = blocks[0] if len(blocks) == 1 else None
        if (
            k is not None
            and b is not None
            and method != "sequential"
            and (b.dim <= 3 or b.var is None or method != "auto")  # else sequential rows
        ):
            # One block on the allocation-free kernel lin_update1: the hot path of a fusion
            # model (one sensor sample per step), written out here because at n <= 9 each
            # Python call layer costs as much as the arithmetic. The kernel checks every
            # shape and numba's dispatch every dtype and rank, so only what is not an array
            # is converted; a failed kernel falls through to the numpy path, which diagnoses.
            m = b.dim
            var = b.var
            x = self.x
            h = b.h
            jac = b.jacobian
            if b.residual is not None or (h is not None and jac is None):
                H, z, hx, flags = _kernel_inputs(b, x)
            elif h is None:  # linear: the kernel computes y = z - H x
                H, z, hx, flags = b.H, b.z, EMPTY1, 0
            else:  # as _linearise, the shape checks left to the kernel
                hx = h(x)
                if type(hx) is not _ND:
                    hx = np.asarray(hx, dtype=np.float64).reshape(-1)
                H = jac(x)
                if type(H) is not _ND:
                    H = np.asarray(H, dtype=np.float64).reshape(m, -1)
                z, flags = b.z, _MODE_HX
            if var is not None:
                flags |= _DIAG
                R = EMPTY2
            else:
                var, R = EMPTY1, b.R
            if self.joseph:
                flags |= _JOSEPH
            thr = _INF if gate is None else gate_threshold(gate, m)
            n = x.shape[0]
            x_out = _empty(n)
            P_out = _empty((n, n))
            P = self.P
            try:
                nis = k.lin_update1(x, P, H, z, hx, var, R, thr, flags, SCRATCH[0], x_out, P_out)
                if nis == _WS_SMALL:
                    ws = grow_scratch(4 * m + 4 * n * m + 2 * m * m + n * n)
                    nis = k.lin_update1(x, P, H, z, hx, var, R, thr, flags, ws, x_out, P_out)
            except TypeError:  # e.g. an integer Jacobian or h(x): numpy converts it
                nis = -1.0
            if nis >= 0.0:  # else a status code: the numpy path below decides
                if nis > thr:  # gated out: the state stays as it is
                    return make_result1(b.label, m, nis, False, thr)
                self.x = x_out
                self.P = P_out
                return make_result1(b.label, m, nis, True, None if gate is None else thr)
        elif not blocks:
            return make_result([])
        elif k is not None:
            out = _compiled_stacked(k, self.x, self.P, blocks, gate, self.joseph, method)
        if out is None:
            out = linearised_update_numpy(self.x, self.P, blocks, gate, self.joseph, method)
        self.x, self.P, res = out
        return res

    def _update_considering(
        self,
        obs: Observations | Sequence[Block] | Block | None,
        gate: float | None,
        method: str,
        consider: Sequence[int] | np.ndarray,
    ) -> UpdateResult:
        """The Schmidt update: the joint update, then the considered states' x and P block
        restored (equal to zeroing their gain rows, see :mod:`.consider`)."""
        if method == "sequential":
            raise ValueError("consider states need the joint update, not method='sequential'")
        idx = consider_indices(consider, self.n)
        x0, P0 = self.x, self.P
        result = self.update(obs, gate, method="joint" if method == "auto" else method)
        if len(idx) and self.x is not x0:
            self.x, self.P = restore_considered(x0, P0, self.x, self.P, idx)
        return result

    def _commit_predict(self, x: np.ndarray, P: np.ndarray, what: str) -> None:
        """Store a predicted state after a finiteness check (state unchanged on error)."""
        if x.shape != (self.n,) or P.shape != (self.n, self.n):
            raise ValueError(f"{what}: predicted shapes {x.shape}, {P.shape}")
        if not (_isfinite(float(x.sum())) and _isfinite(float(P.sum()))) and not (
            _all_finite(x) and _all_finite(P)
        ):
            raise NonFiniteInputError("predict", what, "step")
        self.x = x
        self.P = P

    def __repr__(self) -> str:
        return f"{type(self).__name__}(n={self.n}, x={self.x!r})"
