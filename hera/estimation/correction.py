"""The measurement update shared by the linear KF and the EKF (linearised correction).

For the stacked blocks: innovation y = z - h(x) (or the block's residual), G = H P,
S = G H^T + R, factorised by Cholesky S = L L^T (also the positive-definiteness test), NIS
per block from the diagonal sub-blocks of S, chi-square gating, then either

* the joint update K^T = S^-1 G = L^-T (L^-1 G), x += K y, and the Joseph form
  P = (I - K H) P (I - K H)^T + K R K^T (seed 000), evaluated as T = P - K G (that is,
  (I - K H) P) and P = T + (K R - T H^T) K^T (that is, T (I - K H)^T + K R K^T), or the
  short form P = P - K H P; or
* sequential scalar updates when R is diagonal (seed 000, "sequential update"), which
  need no matrix inverse and give the same result as the joint update (the innovation of
  each row is taken about the prior linearisation point, so this also holds for the EKF).

Nothing is written to the filter before every input has been checked: a block whose
shapes do not fit the state raises ValueError naming it, a non-finite z, R, H, Jacobian or
h(x) raises :class:`NonFiniteInputError` naming the block, and a non-positive-definite S
or P raises :class:`CovarianceError`.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from . import backend as _bk
from . import unrolled
from .consider import consider_indices, restore_considered
from .gating import gate_threshold
from .numerics import CovarianceError, NonFiniteInputError, finite, numerical_jacobian
from .observations import Block, Observations, _bad_variance
from .results import (
    BlockOutcome,
    DetailedResult,
    UpdateDetails,
    UpdateResult,
    gaussian_log_likelihood,
    make_outcome,
    make_result,
    single_result,
)
from .small import block_nis, chol_small, lower_inverse, nis_small
from .stacking import EMPTY1, SCRATCH, block_layout, grow_scratch, stack_noise
from .state import FilterState, check_dt, process_noise

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
    "check_dt",
    "process_noise",
]

_EYE: dict[int, np.ndarray] = {}
_isfinite = math.isfinite
_empty = np.empty
_ND = np.ndarray
_INF = math.inf
_F64 = np.float64
_new = object.__new__
_errstate = np.errstate


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


def _vector(v: Any, m: int, label: str, what: str) -> np.ndarray:
    """A block's h(x) or residual as a float64 vector of m values (ValueError otherwise)."""
    if type(v) is not _ND or v.ndim != 1 or v.dtype != _F64:
        v = np.asarray(v, dtype=_F64).reshape(-1)
    if v.shape[0] != m:
        raise ValueError(f"block {label!r}: {what} has {v.shape[0]} values, z has {m}")
    return v


def _linearise(b: Block, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(H, h(x)) of one block at x, shapes checked against z and the state (ValueError
    naming the block). A numerical Jacobian differences h through the block's residual."""
    n = x.shape[0]
    m = b.dim
    if b.H is not None:
        H = b.H
        if H.shape[1] != n:
            raise ValueError(f"block {b.label!r}: H has {H.shape[1]} columns, the state has {n}")
        return H, H @ x
    hx = _vector(b.h(x), m, b.label, "h(x)")  # type: ignore[misc]
    if b.jacobian is not None:
        Hj = b.jacobian(x)
        if type(Hj) is not _ND or Hj.ndim != 2 or Hj.dtype != _F64:
            Hj = np.asarray(Hj, dtype=_F64)
            if Hj.size == m * n:
                Hj = Hj.reshape(m, n)
        what = "its Jacobian"
    else:
        Hj = numerical_jacobian(b.h, x, m, residual=b.residual)  # type: ignore[arg-type]
        what = "its numerical Jacobian (h(x) of varying size?)"
    if Hj.shape != (m, n):
        raise ValueError(f"block {b.label!r}: {what} has shape {Hj.shape}, expected ({m}, {n})")
    return Hj, hx


def _innovation(b: Block, hx: np.ndarray) -> np.ndarray:
    if b.residual is None:
        return b.z - hx
    return _vector(b.residual(b.z, hx), b.dim, b.label, "residual(z, h(x))")


def _check_variances(b: Block) -> None:
    """The block's variances are in (0, inf) (checked by Block; again here because the
    compiled kernels check them too, so both backends raise the same error)."""
    if b.var is not None:
        for i, v in enumerate(b.var.tolist()):
            if not 0.0 < v < _INF:
                raise _bad_variance(b.label, v, f"R[{i}]")


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
    parts = []
    for b in blocks:
        _check_variances(b)
        H, hx = _linearise(b, x)
        parts.append((H, hx, _innovation(b, hx)))
    if len(blocks) == 1:
        b = blocks[0]
        H, _, y = parts[0]
        return H, y, b.var, b.R, parts
    H = np.concatenate([p[0] for p in parts])
    y = np.concatenate([p[2] for p in parts])
    var, R = stack_noise(blocks, y.shape[0])
    return H, y, var, R, parts


def _cholesky(S: np.ndarray) -> np.ndarray | None:
    """Lower Cholesky factor of a symmetric S (lower triangle read), None if not PD."""
    m = S.shape[0]
    if m <= 3:
        L = chol_small(S.tolist())
        return None if L is None else np.array(L)
    if not _all_finite(S):
        return None
    try:
        return np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        return None


def _lower_solve(L: np.ndarray, B: np.ndarray) -> np.ndarray:
    """L^-1 B for a lower-triangular L (forward substitution, as a small inverse for m <=
    3)."""
    if L.shape[0] <= 3:
        return np.array(lower_inverse(L.tolist())) @ B
    return np.linalg.solve(L, B)


def _chol_solve(L: np.ndarray, B: np.ndarray) -> np.ndarray:
    """S^-1 B = L^-T (L^-1 B) with S = L L^T."""
    if L.shape[0] <= 3:
        Li = np.array(lower_inverse(L.tolist()))
        return Li.T @ (Li @ B)
    return np.linalg.solve(L.T, np.linalg.solve(L, B))


def _block_nis(blocks: Sequence[Block], S: np.ndarray, y: np.ndarray) -> list[float] | None:
    """NIS of every block, |L_b^-1 y_b|^2 from the Cholesky factor of its diagonal sub-block
    of S; None if one is not PD."""
    out = []
    o = 0
    for b in blocks:
        d = b.dim
        L = _cholesky(S[o : o + d, o : o + d])
        if L is None:
            return None
        w = _lower_solve(L, y[o : o + d])
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
    *,
    details: bool = False,
) -> tuple[np.ndarray, np.ndarray, UpdateResult]:
    """One correction step; returns new (x, P) and the result. Pure: x and P are not
    modified (P is checked as a covariance first). ``method``: "joint", "sequential"
    (R diagonal) or "auto" (joint up to 3 rows, sequential above when R is diagonal). Runs
    the compiled kernel when the numba backend is active (same results to roundoff, same
    errors), else ``linearised_update_numpy``."""
    filt = LinearisedFilter(x, P, joseph=joseph)
    # Unchanged input arrays (already float64, C-contiguous and exactly symmetric) are kept,
    # so a step that fuses nothing returns the caller's x and P themselves.
    if _same_array(filt._x, x):
        filt._x = x
    if _same_array(filt._P, P):
        filt._P = P
    result = filt.update(blocks, gate, method=method, details=details)
    return filt._x, filt._P, result


def _same_array(converted: np.ndarray, given: Any) -> bool:
    return (
        type(given) is _ND
        and given.dtype == _F64
        and given.flags.c_contiguous
        and given.shape == converted.shape
        and bool(np.array_equal(converted, given))
    )


def _kernel_inputs(b: Block, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """(H, z, hx, innovation mode) of one block for ``lin_update1``, for the blocks the
    hot path of ``LinearisedFilter.update`` does not write out: no Jacobian (a numerical
    one) or a residual function (the innovation is then computed here)."""
    H, hx = _linearise(b, x)
    if b.residual is None:
        return H, b.z, hx, b.kflags | _MODE_HX
    return H, _innovation(b, hx), hx, b.kflags | _MODE_GIVEN


def _compiled_stacked(
    k: Any,
    x: np.ndarray,
    P: np.ndarray,
    blocks: Sequence[Block],
    gate: float | None,
    joseph: bool,
    method: str,
) -> tuple[np.ndarray, np.ndarray, UpdateResult] | None:
    """Several blocks, or sequential updates: the general kernel ``lin_update``. When every
    block is linear (an H of the state's width, no residual function) the kernel takes z
    and computes z - H x itself; otherwise each block is linearised here (which names a
    block of the wrong shape) and the kernel takes the innovations."""
    n = x.shape[0]
    flags = _JOSEPH if joseph else 0
    if all(b.H is not None and b.residual is None and b.H.shape[1] == n for b in blocks):
        H = np.concatenate([b.H for b in blocks])
        z = np.concatenate([b.z for b in blocks])
    else:
        parts = []
        for b in blocks:
            Hb, hx = _linearise(b, x)
            parts.append((Hb, _innovation(b, hx)))
        H = np.concatenate([p[0] for p in parts])
        z = np.concatenate([p[1] for p in parts])
        flags |= _MODE_GIVEN
    m = z.shape[0]
    dims = tuple(b.dim for b in blocks)
    var, R = stack_noise(blocks, m)
    if var is not None:
        flags |= _DIAG
        noise = var
    else:
        noise = R.reshape(-1)  # type: ignore[union-attr]
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
            x, P, H, z, EMPTY1, noise, ends, thr_arr, flags, x_out, P_out, nis_arr
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


def _joseph_numpy(
    P: np.ndarray,
    H: np.ndarray,
    Kt: np.ndarray,
    G: np.ndarray,
    var: np.ndarray | None,
    R: np.ndarray | None,
    joseph: bool,
) -> np.ndarray:
    """(I - K H) P (I - K H)^T + K R K^T as T = P - K G, T + (K R - T H^T) K^T (or the
    short form T), symmetrised; G = H P, Kt = K^T."""
    K = Kt.T
    T = P - K @ G
    if joseph:
        W = K * var if var is not None else K @ R
        W -= T @ H.T
        T += W @ Kt
    out = T + T.T
    out *= 0.5
    return out


def linearised_update_numpy(
    x: np.ndarray,
    P: np.ndarray,
    blocks: Sequence[Block],
    gate: float | None = None,
    joseph: bool = True,
    method: str = "auto",
    details: bool = False,
) -> tuple[np.ndarray, np.ndarray, UpdateResult]:
    """``linearised_update`` on numpy only (the reference the compiled kernel is tested
    against; it also computes the details)."""
    if method != "sequential" and not details:
        if len(blocks) == 1:
            if blocks[0].dim <= 3:
                fast = _fast_single(x, P, blocks[0], gate, joseph)
                if fast is not None:
                    return fast
        elif sum(b.dim for b in blocks) <= 3:
            fast = _fast_stacked(x, P, blocks, gate, joseph)
            if fast is not None:
                return fast
    with _errstate(all="ignore"):
        return _general_update(x, P, blocks, gate, joseph, method, details)


def _general_update(
    x: np.ndarray,
    P: np.ndarray,
    blocks: Sequence[Block],
    gate: float | None,
    joseph: bool,
    method: str,
    details: bool,
) -> tuple[np.ndarray, np.ndarray, UpdateResult]:
    """The stacked update of any blocks on numpy (module docstring). Its caller silences
    numpy's floating-point warnings: a NaN, inf or overflow here is always diagnosed and
    raised as the error that names it, and a warning before that error would add nothing."""
    H, y, var, R, parts = _stack(x, blocks)
    m = y.shape[0]
    G = H @ P
    S = G @ H.T
    if var is not None:
        S.flat[:: m + 1] += var
    else:
        S += R
    S = 0.5 * (S + S.T)
    # Finite S and y imply finite z, R, H (P is PD, so inf * P_jj never cancels to finite).
    if not (finite(S) and finite(y)):
        diagnose_nonfinite(blocks, parts, P)
        raise NonFiniteInputError(
            ", ".join(b.label for b in blocks),
            "the innovation y or its covariance S = H P H^T + R",
            "observation block" if len(blocks) == 1 else "observation blocks",
            problem="overflowed (every input is finite)",
        )
    nis = _block_nis(blocks, S, y)
    if nis is None:
        labels = ", ".join(repr(b.label) for b in blocks)
        raise CovarianceError(f"innovation covariance S of blocks {labels}")
    if gate is not None:
        thr = [gate_threshold(gate, b.dim) for b in blocks]
        acc = [v <= t for v, t in zip(nis, thr, strict=True)]
        res_outs = [
            BlockOutcome(b.label, b.dim, v, a, t)
            for b, v, a, t in zip(blocks, nis, acc, thr, strict=True)
        ]
        if not all(acc):
            kept = [b for b, a in zip(blocks, acc, strict=True) if a]
            if not kept:
                return x, P, UpdateResult(res_outs)
            x2, P2, r2 = linearised_update_numpy(x, P, kept, None, joseph, method, details)
            if details:
                return x2, P2, DetailedResult(res_outs, r2.details)
            return x2, P2, UpdateResult(res_outs)
        outs = res_outs
    else:
        outs = [BlockOutcome(b.label, b.dim, v, True) for b, v in zip(blocks, nis, strict=True)]

    sequential = method == "sequential" or (method == "auto" and m > 3 and var is not None)
    L = None
    if sequential:
        if var is None:
            raise ValueError("sequential updates need a diagonal R (variances) in every block")
        x_new, P_new = _sequential(x, P, H, y, var, joseph)
    else:
        L = _joint_factor(S, blocks)
        Kt = _chol_solve(L, G)
        x_new = x + y @ Kt
        P_new = _joseph_numpy(P, H, Kt, G, var, R, joseph)
    if not min(P_new.diagonal().tolist()) > 0.0 or not finite(P_new):
        raise CovarianceError("P after update", "non-positive diagonal")
    if not details:
        return x_new, P_new, UpdateResult(outs)
    if L is None:  # sequential: the details are those of the equal joint update
        L = _joint_factor(S, blocks)
        Kt = _chol_solve(L, G)
    w = _lower_solve(L, y)
    log_det = 2.0 * float(np.log(np.diagonal(L)).sum())
    det = UpdateDetails(
        tuple(b.label for b in blocks),
        y,
        S,
        Kt.T.copy(),
        H,
        gaussian_log_likelihood(float(w @ w), log_det, m),
    )
    return x_new, P_new, DetailedResult(outs, det)


def _joint_factor(S: np.ndarray, blocks: Sequence[Block]) -> np.ndarray:
    """The Cholesky factor of the stacked S, or CovarianceError naming the blocks."""
    L = _cholesky(S)
    if L is None:
        labels = ", ".join(repr(b.label) for b in blocks)
        raise CovarianceError(f"innovation covariance S of blocks {labels}")
    return L


def _fast_single(
    x: np.ndarray, P: np.ndarray, b: Block, gate: float | None, joseph: bool
) -> tuple[np.ndarray, np.ndarray, UpdateResult] | None:
    """Joint update of one block of 1-3 rows with as few numpy calls as possible: at
    n <= ``unrolled.MAX_N`` all of it on Python floats (``unrolled``); above, S is
    factorised and its factor inverted in closed form on Python floats (``small``), the
    covariance is the Joseph form as in ``_joseph_numpy`` (``_joint_small``). Returns None
    to fall back to the general path (non-finite input, S not PD, gated out above MAX_N,
    P' not valid) which then diagnoses."""
    _check_variances(b)
    n = x.shape[0]
    if n <= unrolled.MAX_N:
        thr = _INF if gate is None else gate_threshold(gate, b.dim)
        H = b.H
        if H is not None and b.residual is None and H.shape[1] == n:  # y = z - H x there
            out = unrolled.update_block(x, P, H, b.z, b.var, b.R, thr, joseph, True)
        else:
            H, hx = _linearise(b, x)
            out = unrolled.update_block(x, P, H, _innovation(b, hx), b.var, b.R, thr, joseph)
        if out is None:
            return None
        nis, x_new, P_new = out
        t = None if gate is None else thr
        if x_new is None:  # gated out: the state stays as it is
            return x, P, single_result(b.label, b.dim, nis, False, t)
        return x_new, P_new, single_result(b.label, b.dim, nis, True, t)
    H, hx = _linearise(b, x)
    y = _innovation(b, hx)
    out = _joint_small(x, P, H, y, b.var, b.R, joseph)
    if out is None:
        return None
    x_new, P_new, _, Li, yl = out
    nis = nis_small(Li, yl)
    thr = None
    if gate is not None:
        thr = gate_threshold(gate, b.dim)
        if not nis <= thr:
            return None
    return x_new, P_new, UpdateResult([BlockOutcome(b.label, b.dim, nis, True, thr)])


def _joint_small(
    x: np.ndarray,
    P: np.ndarray,
    H: np.ndarray,
    y: np.ndarray,
    var: np.ndarray | None,
    R: np.ndarray | None,
    joseph: bool,
) -> tuple[np.ndarray, np.ndarray, list[list[float]], list[list[float]], list[float]] | None:
    """The joint update of 1-3 stacked rows (H, innovation y, variances ``var`` or R) at
    any n: S = H P H^T + R factorised and its factor inverted on Python floats (``small``),
    K^T = L^-T (L^-1 G) with G = H P, the covariance as ``_joseph_numpy``. Returns (x', P',
    S as nested lists, L^-1, y as a list), or None for the general path to diagnose: y or
    S not finite, S not positive definite, P' with a diagonal entry <= 0 or not finite."""
    G = H @ P
    Sl = (G @ H.T).tolist()
    if var is not None:
        for i, v in enumerate(var.tolist()):
            Sl[i][i] += v
    else:
        Rl = R.tolist()  # type: ignore[union-attr]
        Sl = [[a + r for a, r in zip(sr, rr, strict=True)] for sr, rr in zip(Sl, Rl, strict=True)]
    L = chol_small(Sl)
    yl = y.tolist()
    if L is None or not all(map(_isfinite, yl)):
        return None
    Li = lower_inverse(L)
    Lia = np.array(Li)
    Kt = Lia.T @ (Lia @ G)  # K^T = S^-1 G
    x_new = x + y @ Kt
    P_new = _joseph_numpy(P, H, Kt, G, var, R, joseph)
    if not min(P_new.diagonal().tolist()) > 0.0 or not finite(P_new):
        return None
    return x_new, P_new, Sl, Li, yl


def _fast_stacked(
    x: np.ndarray, P: np.ndarray, blocks: Sequence[Block], gate: float | None, joseph: bool
) -> tuple[np.ndarray, np.ndarray, UpdateResult] | None:
    """The joint update of several blocks of 2-3 rows in all (a model's sensors fused in
    one step) as one stacked block on Python floats: unrolled at n <= ``unrolled.MAX_N``,
    ``_joint_small`` above; each block's NIS from its diagonal sub-block of S
    (``small.block_nis``), as ``_block_nis``. Returns None to fall back to the general
    path (which then diagnoses, or drops the blocks a gate rejects): non-finite input, S
    or a sub-block not positive definite, a block gated out, P' not valid."""
    if x.shape[0] <= unrolled.MAX_N:
        Hl, yl, noise, full = _rows(x, blocks)
        out = unrolled.update_rows(x, P, Hl, yl, noise, full, _INF, joseph, with_s=True)
        if out is None:
            return None
        _, x_new, P_new, Sl = out
    else:
        H, y, var, R, _ = _stack(x, blocks)
        got = _joint_small(x, P, H, y, var, R, joseph)
        if got is None:
            return None
        x_new, P_new, Sl, _, yl = got
    dims = tuple(b.dim for b in blocks)
    nis = block_nis(Sl, yl, dims)
    if nis is None:
        return None
    thr: list[float | None] = [None] * len(blocks)
    if gate is not None:
        thr = [gate_threshold(gate, d) for d in dims]
        if not all(v <= t for v, t in zip(nis, thr, strict=True)):  # type: ignore[operator]
            return None
    return x_new, P_new, outcomes(blocks, nis, thr)


def _rows(x: np.ndarray, blocks: Sequence[Block]) -> tuple[list, list, list, bool]:
    """The blocks stacked on Python floats, as ``_stack``: H row-major, the innovations,
    the noise (the variances, or the block-diagonal R row-major when a block has a full R)
    and whether it is full. A linear block's z - H x is computed here, where a NaN or inf
    in H gives a NaN that the update refuses, not a numpy warning first."""
    n = x.shape[0]
    xl = x.tolist()
    Hl: list[float] = []
    yl: list[float] = []
    for b in blocks:
        _check_variances(b)
        H = b.H
        if H is not None and b.residual is None and H.shape[1] == n:
            for row, z in zip(H.tolist(), b.z.tolist(), strict=True):
                Hl += row
                yl.append(z - sum([h * v for h, v in zip(row, xl, strict=True)]))
        else:
            H, hx = _linearise(b, x)
            Hl += H.ravel().tolist()
            yl += _innovation(b, hx).tolist()
    if all(b.var is not None for b in blocks):
        return Hl, yl, [v for b in blocks for v in b.var.tolist()], False  # type: ignore[union-attr]
    return Hl, yl, stack_noise(blocks, len(yl))[1].ravel().tolist(), True  # type: ignore[union-attr]


def _sequential(
    x: np.ndarray, P: np.ndarray, H: np.ndarray, y: np.ndarray, var: np.ndarray, joseph: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Scalar updates row by row (R diagonal); no inverse. Row i's innovation is taken about
    the prior point: y_i - H_i (x_i - x_prior), which makes the result equal the joint one.
    Each row's covariance is the Joseph form (I - k h^T) P (I - k h^T)^T + v k k^T as
    T = P - k (h^T P), T - (T h) k^T + v k k^T (or the short form T), symmetrised."""
    xc = x
    Pc = P
    yl = y.tolist()
    vl = var.tolist()
    for i in range(H.shape[0]):
        hi = H[i]
        c = hi @ Pc
        s = float(c @ hi) + vl[i]
        if not 0.0 < s < _INF:
            raise CovarianceError("innovation variance", f"row {i}: {s!r}")
        k = c / s
        yi = yl[i] - float(hi @ (xc - x)) if i else yl[i]
        xc = xc + k * yi
        T = Pc - np.outer(k, c)
        if joseph:
            T += np.outer(vl[i] * k - T @ hi, k)
        Pc = 0.5 * (T + T.T)
    return xc, Pc


def _as_matrix(a: Any, n: int, what: str) -> np.ndarray:
    """A finite (n, n) float64 matrix (a scalar means a * I) - for F and B, not covariances."""
    try:
        m = np.array(a, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a number or an ({n}, {n}) matrix, got {a!r}") from None
    if m.ndim == 0:
        m = m * np.eye(n)
    if m.shape != (n, n):
        raise ValueError(f"{what} has shape {m.shape}, expected ({n}, {n})")
    if not _all_finite(m):
        raise NonFiniteInputError(what, "the matrix", "model")
    return m


class LinearisedFilter(FilterState):
    """State (x, P) and the shared linearised correction of the KF and the EKF.

    ``x`` and ``P`` are checked properties, ``x_prior``/``P_prior`` the state after the
    last predict, ``x_post``/``P_post`` after the last update (see ``state.FilterState``).

    ``joseph``: use the Joseph-form covariance update (default) or the short form
    P = P - K H P. ``gate``: default gate probability for ``update`` (None: no gating).
    """

    residual_x = None  # the state's residual function (EKF); None: plain subtraction
    _unrolled: unrolled.Memo | None = None  # None in a filter pickled before memos existed

    def __init__(self, x0: Any, P0: Any, *, joseph: bool = True, gate: float | None = None) -> None:
        super().__init__(x0, P0)
        self._unrolled = unrolled.Memo()  # the predict's unrolled step for this F
        self.joseph = joseph
        self.gate = gate

    @property
    def joseph(self) -> bool:
        """Joseph-form covariance update (True) or the short form P - K H P."""
        return self._jflag != 0

    @joseph.setter
    def joseph(self, on: bool) -> None:
        self._jflag = _JOSEPH if on else 0

    def update(
        self,
        obs: Observations | Sequence[Block] | Block | None,
        gate: float | None = ...,  # type: ignore[assignment]
        *,
        method: str = "auto",
        details: bool = False,
        consider: Sequence[int] | np.ndarray | None = None,
    ) -> UpdateResult:
        """Fuse the present observation blocks (thesis listing 4.1). No blocks: no-op.

        ``gate``: chi-square probability per block (e.g. 0.999) or None; defaults to the
        filter's ``gate``. Returns which blocks were accepted/rejected with their NIS;
        ``details=True`` adds y, S, K, H and the log-likelihood of the fused rows
        (``result.details``; computed on the numpy path). ``consider``: states (indices or
        a boolean mask) this update must not change, Schmidt "consider" states
        (:mod:`.consider`): their gain rows are zero, the covariance stays consistent
        (Joseph form). On any exception the state is unchanged.
        """
        if consider is not None:
            return self._update_considering(obs, gate, method, details, consider)
        blocks = obs.blocks if type(obs) is Observations else as_blocks(obs)
        if gate is ...:
            gate = self.gate
        k = _bk._active
        out = None
        if k is not None and len(blocks) == 1 and method != "sequential" and not details:
            b = blocks[0]
            m = b.dim
            if m <= 3 or b.var is None or method != "auto":  # else sequential rows
                # One block on the allocation-free kernel lin_update1: the hot path of a
                # fusion model (one sensor sample per step), written out here because at
                # n <= 9 each Python call layer costs as much as the arithmetic. The kernel
                # checks every shape and numba's dispatch every dtype and rank, so only
                # what is not an array is converted; a failed kernel falls through to the
                # numpy path, which diagnoses.
                x = self._x
                h = b.h
                if h is None and b.residual is None:  # linear: the kernel computes z - H x
                    H, z, hx, flags = b.H, b.z, EMPTY1, b.kflags
                elif b.residual is not None or b.jacobian is None:
                    H, z, hx, flags = _kernel_inputs(b, x)
                else:  # as _linearise, the shape checks left to the kernel
                    hx = h(x)
                    if type(hx) is not _ND:
                        hx = np.asarray(hx, dtype=np.float64).reshape(-1)
                    H = b.jacobian(x)
                    if type(H) is not _ND:
                        H = np.asarray(H, dtype=np.float64).reshape(m, -1)
                    z, flags = b.z, b.kflags | _MODE_HX
                thr = _INF if gate is None else gate_threshold(gate, m)
                x_out = _empty(self.n)
                P_out = _empty(self._nn)
                try:
                    nis = k.lin_update1(
                        x, self._P, H, z, hx, b.noise, thr, flags | self._jflag, SCRATCH[0],
                        x_out, P_out,
                    )  # fmt: skip
                    if nis == _WS_SMALL:
                        ws = grow_scratch(2 * m + 2 * m * m + 3 * self.n * m)
                        nis = k.lin_update1(
                            x, self._P, H, z, hx, b.noise, thr, flags | self._jflag, ws,
                            x_out, P_out,
                        )  # fmt: skip
                except TypeError:  # e.g. an integer Jacobian or h(x): numpy converts it
                    nis = -1.0
                if nis >= 0.0:  # else a status code: the numpy path below decides
                    # results.single_result written out (no call layer; the outcome is
                    # built when read).
                    res = _new(UpdateResult)
                    if nis > thr:  # gated out: the state stays as it is
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
        if not blocks:
            return make_result([])
        if k is not None and not details and out is None:
            out = _compiled_stacked(k, self._x, self._P, blocks, gate, self.joseph, method)
        if out is None:
            out = linearised_update_numpy(
                self._x, self._P, blocks, gate, self.joseph, method, details
            )
        x_new, P_new, res = out
        if x_new is not self._x:
            self._commit_update(x_new, P_new, res)
        return res

    def _update_considering(
        self,
        obs: Observations | Sequence[Block] | Block | None,
        gate: float | None,
        method: str,
        details: bool,
        consider: Sequence[int] | np.ndarray,
    ) -> UpdateResult:
        """The Schmidt update: the joint update, then the considered states' x and P block
        restored (equal to zeroing their gain rows, see :mod:`.consider`); the restored
        state is the step's posterior (``x_post``, the history)."""
        if method == "sequential":
            raise ValueError("consider states need the joint update, not method='sequential'")
        idx = consider_indices(consider, self.n)
        x0, P0 = self._x, self._P
        joint = "joint" if method == "auto" else method
        result = self.update(obs, gate, method=joint, details=details)
        if len(idx) and self._x is not x0:
            x, P = restore_considered(x0, P0, self._x, self._P, idx)
            self._commit_update(x, P, None)  # None: the log-likelihood is counted once
        return result
