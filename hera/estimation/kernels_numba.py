"""Compiled kernels (numba) for the KF/EKF/UKF hot path; imported only by ``backend``.

Every kernel is a plain loop nest over float64 arrays with no temporaries beyond a few
small scratch arrays, so at n <= 9 and m <= 3 the cost is the call itself (~0.5 us), not
numpy's per-call overhead. Each kernel:

* reads its inputs and writes *only* into output arrays it is given (never into x or P),
  so a failed step leaves the filter untouched;
* checks finiteness and positive definiteness itself and returns a status code instead of
  raising: ``OK``, ``ALL_REJECTED`` (every block gated out; outputs not written) or a
  negative code. On a negative code the caller re-runs the step on the numpy path, which
  raises the precise, labelled error (``NonFiniteInputError`` / ``CovarianceError``) or,
  in borderline roundoff cases, produces the result; the two backends therefore share one
  error behaviour.

Equations are the same as on the numpy path (``correction``, ``kalman``, ``ekf``, ``ukf``)
and are cited there: predict P = F P F^T + Q (seed 003 eq. 5), the joint update with the
Joseph form P = (I - K H) P (I - K H)^T + K R K^T (seed 000), sequential scalar updates,
the unscented transform (seed 003 eqs. 9-17). Innovation covariances are factorised by
Cholesky (S = L L^T), which also is the positive-definiteness test; NIS = |L^-1 y|^2.

The functions below are compiled lazily by ``backend`` with the signatures in ``SIGNATURES``
(any layout, read-only inputs accepted) and ``cache=True``.

Hot-path kernels (``lin_update1``, the predicts) allocate nothing: their intermediates live
in a scratch array ``ws`` the caller passes (``stacking.SCRATCH``), and they check every
array shape themselves (returning ``BAD_SHAPE``), so no argument can make them read or
write out of bounds; numba's dispatch checks dtypes and ranks.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba import types

OK = 0
ALL_REJECTED = 1
NONFINITE = -1
NOT_PD = -2
BAD_P = -3
WS_SMALL = -4  # the scratch array ws is too short: the caller grows it and retries
BAD_SHAPE = -5  # inconsistent array shapes: the numpy path raises the precise error

_isfinite = math.isfinite
_jit = numba.njit(
    cache=True, error_model="numpy"
)  # helpers: compiled into the kernels that call them


@_jit
def _chol(S, rows, k, L):
    """Lower Cholesky factor of S[rows[:k]][:, rows[:k]] into L[:k, :k]; False unless the
    sub-matrix is finite and positive definite."""
    for j in range(k):
        rj = rows[j]
        s = S[rj, rj]
        for p in range(j):
            s -= L[j, p] * L[j, p]
        if not (s > 0.0) or not _isfinite(s):
            return False
        d = math.sqrt(s)
        L[j, j] = d
        for i in range(j + 1, k):
            t = S[rows[i], rj]
            for p in range(j):
                t -= L[i, p] * L[j, p]
            L[i, j] = t / d
    return True


@_jit
def _solve(L, k, b):
    """b <- (L L^T)^-1 b in place (forward then backward substitution)."""
    for i in range(k):
        t = b[i]
        for p in range(i):
            t -= L[i, p] * b[p]
        b[i] = t / L[i, i]
    for i in range(k - 1, -1, -1):
        t = b[i]
        for p in range(i + 1, k):
            t -= L[p, i] * b[p]
        b[i] = t / L[i, i]


@_jit
def _nis_and_keep(S, y, ends, thr, L, nis_out, keep):
    """NIS of every block from its diagonal sub-block of S, the gate test, and the kept
    rows. Returns the number of kept rows, or -1 when a sub-block is not PD."""
    m = y.shape[0]
    rows = np.arange(m)
    w = np.empty(m)
    nk = 0
    o = 0
    for b in range(ends.shape[0]):
        e = ends[b]
        d = e - o
        if not _chol(S, rows[o:e], d, L):
            return -1
        nis = 0.0
        for i in range(d):
            t = y[o + i]
            for p in range(i):
                t -= L[i, p] * w[p]
            w[i] = t / L[i, i]
            nis += w[i] * w[i]
        nis_out[b] = nis
        if nis <= thr[b]:
            for r in range(o, e):
                keep[nk] = r
                nk += 1
        o = e
    return nk


@_jit
def _finish(P_out):
    """Symmetrise P_out in place; False if a diagonal entry is not > 0 or a value is not
    finite."""
    n = P_out.shape[0]
    for i in range(n):
        for j in range(i + 1, n):
            v = 0.5 * (P_out[i, j] + P_out[j, i])
            if not _isfinite(v):
                return False
            P_out[i, j] = v
            P_out[j, i] = v
        if not (P_out[i, i] > 0.0) or not _isfinite(P_out[i, i]):
            return False
    return True


@_jit
def _square(A, n):
    return A.shape[0] == n and A.shape[1] == n


@_jit
def _predict_shapes(P, F, Q, x_out, P_out, n):
    """True when P, F, Q, P_out are (n, n) and x_out is (n,)."""
    return (
        _square(P, n) and _square(F, n) and _square(Q, n) and _square(P_out, n)
    ) and x_out.shape[0] == n


@_jit
def _cov_predict(P, F, Q, ws, P_out):
    """P_out = sym(F P F^T) + Q, with F P kept in ws[:n * n]; False if not finite."""
    n = P.shape[0]
    for i in range(n):
        for j in range(n):
            t = 0.0
            for k in range(n):
                t += F[i, k] * P[k, j]
            ws[i * n + j] = t
    for i in range(n):
        for j in range(i, n):
            v = 0.0
            for k in range(n):
                v += ws[i * n + k] * F[j, k]
            # F P F^T is symmetric: compute the upper triangle and mirror it (exactly
            # symmetric, as the numpy path's (A + A^T) / 2), then add Q.
            P_out[i, j] = v + Q[i, j]
            P_out[j, i] = v + Q[j, i]
            if not _isfinite(P_out[i, j]) or not _isfinite(P_out[j, i]):
                return False
    return True


def kf_predict(x, P, F, Q, ws, x_out, P_out):
    """x_out = F x, P_out = sym(F P F^T) + Q (seed 003 eq. 5); ws: scratch of >= n * n."""
    n = x.shape[0]
    if not _predict_shapes(P, F, Q, x_out, P_out, n):
        return BAD_SHAPE
    if ws.shape[0] < n * n:
        return WS_SMALL
    for i in range(n):
        t = 0.0
        for k in range(n):
            t += F[i, k] * x[k]
        if not _isfinite(t):
            return NONFINITE
        x_out[i] = t
    if not _cov_predict(P, F, Q, ws, P_out):
        return NONFINITE
    return OK


def kf_predict_u(x, P, F, Q, B, u, ws, x_out, P_out):
    """x_out = F x + B u, P_out = sym(F P F^T) + Q (seed 003 eq. 5); ws as kf_predict."""
    n = x.shape[0]
    if not _predict_shapes(P, F, Q, x_out, P_out, n) or B.shape[0] != n or B.shape[1] != u.shape[0]:
        return BAD_SHAPE
    if ws.shape[0] < n * n:
        return WS_SMALL
    for i in range(n):
        t = 0.0
        for k in range(n):
            t += F[i, k] * x[k]
        for k in range(u.shape[0]):
            t += B[i, k] * u[k]
        if not _isfinite(t):
            return NONFINITE
        x_out[i] = t
    if not _cov_predict(P, F, Q, ws, P_out):
        return NONFINITE
    return OK


def ekf_predict(xn, P, F, Q, ws, P_out):
    """P_out = sym(F P F^T) + Q with the process Jacobian F; checks that xn = f(x) is
    finite (seed 003 eq. 7); ws as kf_predict."""
    n = xn.shape[0]
    if not _predict_shapes(P, F, Q, xn, P_out, n):
        return BAD_SHAPE
    if ws.shape[0] < n * n:
        return WS_SMALL
    for i in range(n):
        if not _isfinite(xn[i]):
            return NONFINITE
    if not _cov_predict(P, F, Q, ws, P_out):
        return NONFINITE
    return OK


MODE_LINEAR = 0  # flags bits 0-1: innovation y = z - H x
MODE_HX = 1  # y = z - hx
MODE_GIVEN = 2  # y = z (the caller passed the innovation)
DIAG = 4  # R = diag(var), else the full block-diagonal R
JOSEPH = 8  # Joseph form, else P - K H P
SEQUENTIAL = 16  # scalar updates row by row (needs DIAG)


def lin_update(x, P, H, z, hx, var, R, ends, thr, flags, x_out, P_out, nis_out):
    """Linearised correction of the stacked blocks (see ``correction.linearised_update``).

    ``flags``: innovation mode | DIAG | JOSEPH | SEQUENTIAL (constants above). ``ends``:
    cumulative row count after each block; ``thr``: each block's NIS gate (inf: none).
    Writes x_out, P_out and nis_out (per block); returns a status code.
    """
    return _lin_update(x, P, H, z, hx, var, R, ends, thr, flags, x_out, P_out, nis_out)


@_jit
def _update_row(x, P, H, z, hx, r, thr, flags, ws, x_out, P_out):
    """``lin_update1`` for a block of one row (m = 1), shapes already checked: S is the
    scalar s = h P h^T + r, so K = P h^T / s needs no factorisation, and the Joseph form is
    written out as for m <= 3 (P + (E + E^T) with E = k (s k^T / 2 - g), g = h P).
    ws: c = P h^T (n), k (n), d = s k / 2 - g (n). Returns the NIS or a status code."""
    n = x.shape[0]
    mode = flags & 3
    if mode == 0:
        t = 0.0
        for k in range(n):
            t += H[0, k] * x[k]
        y = z[0] - t
    elif mode == 1:
        y = z[0] - hx[0]
    else:
        y = z[0]
    if not _isfinite(y):
        return float(NONFINITE)
    s = 0.0
    for i in range(n):
        t = 0.0
        for k in range(n):
            t += P[i, k] * H[0, k]
        ws[i] = t
        s += H[0, i] * t
    s += r
    if not _isfinite(s):
        return float(NONFINITE)
    if not s > 0.0:
        return float(NOT_PD)
    nis = y * y / s
    if not nis <= thr:
        return nis
    for i in range(n):
        kv = ws[i] / s
        ws[n + i] = kv
        x_out[i] = x[i] + kv * y
    if flags & JOSEPH:
        for j in range(n):  # d = s k / 2 - h P
            t = 0.0
            for k in range(n):
                t += H[0, k] * P[k, j]
            ws[2 * n + j] = 0.5 * s * ws[n + j] - t
        for i in range(n):
            ki = ws[n + i]
            di = ws[2 * n + i]
            for j in range(i, n):
                e = ki * ws[2 * n + j] + ws[n + j] * di
                P_out[i, j] = P[i, j] + e
                P_out[j, i] = P[j, i] + e
    else:
        for i in range(n):
            ki = ws[n + i]
            for j in range(n):
                P_out[i, j] = P[i, j] - ki * ws[j]
    if not _finish(P_out):
        return float(BAD_P)
    return nis


def lin_update1(x, P, H, z, hx, var, R, thr, flags, ws, x_out, P_out):
    """``lin_update`` for a single block (joint update, no ``SEQUENTIAL`` flag) with NIS
    gate ``thr``, allocating nothing: every intermediate lives in ``ws`` (at least
    4 m + 4 n m + 2 m^2 + n^2 values; the same arithmetic, in the same order, as
    ``_lin_update`` on one block, except that a single row takes ``_update_row``).

    Returns the NIS (>= 0): the block was fused and x_out, P_out written iff NIS <= thr.
    A negative value is a status code (NONFINITE, NOT_PD, BAD_P, BAD_SHAPE, WS_SMALL) as a
    float. Every shape is checked here, so the caller need not (dtypes and ranks are
    checked by numba's dispatch against the signature).
    """
    mode = flags & 3
    diag = (flags & DIAG) != 0
    n = x.shape[0]
    m = H.shape[0]
    if (
        H.shape[1] != n
        or z.shape[0] != m
        or (mode == 1 and hx.shape[0] != m)
        or (var.shape[0] != m if diag else (R.shape[0] != m or R.shape[1] != m))
        or not _square(P, n)
        or not _square(P_out, n)
        or x_out.shape[0] != n
    ):
        return float(BAD_SHAPE)
    if ws.shape[0] < 4 * m + 4 * n * m + 2 * m * m + n * n:
        return float(WS_SMALL)
    if m == 1:
        return _update_row(
            x, P, H, z, hx, var[0] if diag else R[0, 0], thr, flags, ws, x_out, P_out
        )
    # Scratch layout, row-major: y (m), PHt (n, m), S (m, m), L (m, m), w (m), K^T (m, n),
    # b (m), G = H P (m, n), T (n, n), W (n, m).
    o_ph = m
    o_s = o_ph + n * m
    o_l = o_s + m * m
    o_w = o_l + m * m
    o_kt = o_w + m
    o_b = o_kt + m * n
    o_g = o_b + m
    o_t = o_g + m * n
    o_wk = o_t + n * n
    for i in range(m):
        if mode == 0:
            t = 0.0
            for k in range(n):
                t += H[i, k] * x[k]
            v = z[i] - t
        elif mode == 1:
            v = z[i] - hx[i]
        else:
            v = z[i]
        if not _isfinite(v):
            return float(NONFINITE)
        ws[i] = v
    for i in range(n):
        for j in range(m):
            t = 0.0
            for k in range(n):
                t += P[i, k] * H[j, k]
            ws[o_ph + i * m + j] = t
    for i in range(m):
        for j in range(m):
            t = 0.0
            for k in range(n):
                t += H[i, k] * ws[o_ph + k * m + j]
            if diag:
                if i == j:
                    t += var[i]
            else:
                t += R[i, j]
            if not _isfinite(t):
                return float(NONFINITE)
            ws[o_s + i * m + j] = t
    # Cholesky S = L L^T (lower triangle of S read), the positive-definiteness test.
    for j in range(m):
        s = ws[o_s + j * m + j]
        for p in range(j):
            s -= ws[o_l + j * m + p] * ws[o_l + j * m + p]
        if not (s > 0.0) or not _isfinite(s):
            return float(NOT_PD)
        d = math.sqrt(s)
        ws[o_l + j * m + j] = d
        for i in range(j + 1, m):
            t = ws[o_s + i * m + j]
            for p in range(j):
                t -= ws[o_l + i * m + p] * ws[o_l + j * m + p]
            ws[o_l + i * m + j] = t / d
    nis = 0.0  # |L^-1 y|^2
    for i in range(m):
        t = ws[i]
        for p in range(i):
            t -= ws[o_l + i * m + p] * ws[o_w + p]
        t = t / ws[o_l + i * m + i]
        ws[o_w + i] = t
        nis += t * t
    if not nis <= thr:
        return nis
    for j in range(n):  # K^T = S^-1 (P H^T)^T, column by column
        for r in range(m):
            ws[o_b + r] = ws[o_ph + j * m + r]
        for i in range(m):
            t = ws[o_b + i]
            for p in range(i):
                t -= ws[o_l + i * m + p] * ws[o_b + p]
            ws[o_b + i] = t / ws[o_l + i * m + i]
        for i in range(m - 1, -1, -1):
            t = ws[o_b + i]
            for p in range(i + 1, m):
                t -= ws[o_l + p * m + i] * ws[o_b + p]
            ws[o_b + i] = t / ws[o_l + i * m + i]
        for r in range(m):
            ws[o_kt + r * n + j] = ws[o_b + r]
    for i in range(n):
        t = x[i]
        for r in range(m):
            t += ws[o_kt + r * n + i] * ws[r]
        x_out[i] = t
    sym = True  # P exactly symmetric (as the filter keeps it): then H P = (P H^T)^T
    for i in range(n):
        for j in range(i + 1, n):
            if P[i, j] != P[j, i]:
                sym = False
    if flags & JOSEPH:
        for r in range(m):  # G = H P
            for j in range(n):
                if sym:
                    t = ws[o_ph + j * m + r]
                else:
                    t = 0.0
                    for q in range(n):
                        t += H[r, q] * P[q, j]
                ws[o_g + r * n + j] = t
    if flags & JOSEPH and diag and m <= 3:
        # The Joseph form written out, as the numpy path does for this case (one block of
        # 1-3 rows, diagonal R): P - K G - G^T K^T + K S K^T = P + (E + E^T) with
        # E = K (S K^T / 2 - G), exactly symmetric, in O(n^2 m).
        for r in range(m):  # G <- S K^T / 2 - G, in place
            for j in range(n):
                t = 0.0
                for c in range(m):
                    t += ws[o_s + r * m + c] * ws[o_kt + c * n + j]
                ws[o_g + r * n + j] = 0.5 * t - ws[o_g + r * n + j]
        for i in range(n):  # E into P_out
            for j in range(n):
                t = 0.0
                for r in range(m):
                    t += ws[o_kt + r * n + i] * ws[o_g + r * n + j]
                P_out[i, j] = t
        for i in range(n):
            for j in range(i, n):
                e = P_out[i, j] + P_out[j, i]
                P_out[i, j] = P[i, j] + e
                P_out[j, i] = P[j, i] + e
    elif flags & JOSEPH:
        # As _lin_update: T = P - K (H P), W = K R - T H^T, P_out = T + W K^T.
        for i in range(n):
            for j in range(n):
                t = P[i, j]
                for r in range(m):
                    t -= ws[o_kt + r * n + i] * ws[o_g + r * n + j]
                ws[o_t + i * n + j] = t
        for i in range(n):
            for c in range(m):
                if diag:
                    t = ws[o_kt + c * n + i] * var[c]
                else:
                    t = 0.0
                    for r in range(m):
                        t += ws[o_kt + r * n + i] * R[r, c]
                for q in range(n):
                    t -= ws[o_t + i * n + q] * H[c, q]
                ws[o_wk + i * m + c] = t
        for i in range(n):
            for j in range(n):
                t = ws[o_t + i * n + j]
                for c in range(m):
                    t += ws[o_wk + i * m + c] * ws[o_kt + c * n + j]
                P_out[i, j] = t
    else:
        for i in range(n):
            for j in range(n):
                t = P[i, j]
                for r in range(m):
                    t -= ws[o_kt + r * n + i] * ws[o_ph + j * m + r]
                P_out[i, j] = t
    if not _finish(P_out):
        return float(BAD_P)
    return nis


@_jit
def _lin_update(x, P, H, z, hx, var, R, ends, thr, flags, x_out, P_out, nis_out):
    mode = flags & 3
    diag = (flags & DIAG) != 0
    joseph = (flags & JOSEPH) != 0
    sequential = (flags & SEQUENTIAL) != 0
    n = x.shape[0]
    m = H.shape[0]
    y = np.empty(m)
    for i in range(m):
        if mode == 0:
            t = 0.0
            for k in range(n):
                t += H[i, k] * x[k]
            v = z[i] - t
        elif mode == 1:
            v = z[i] - hx[i]
        else:
            v = z[i]
        if not _isfinite(v):
            return NONFINITE
        y[i] = v
    PHt = np.empty((n, m))
    for i in range(n):
        for j in range(m):
            t = 0.0
            for k in range(n):
                t += P[i, k] * H[j, k]
            PHt[i, j] = t
    S = np.empty((m, m))
    for i in range(m):
        for j in range(m):
            t = 0.0
            for k in range(n):
                t += H[i, k] * PHt[k, j]
            if diag:
                if i == j:
                    t += var[i]
            else:
                t += R[i, j]
            if not _isfinite(t):
                return NONFINITE
            S[i, j] = t
    L = np.empty((m, m))
    rows = np.arange(m)
    if not _chol(S, rows, m, L):
        return NOT_PD
    keep = np.empty(m, np.int64)
    nk = _nis_and_keep(S, y, ends, thr, L, nis_out, keep)
    if nk < 0:
        return NOT_PD
    if nk == 0:
        return ALL_REJECTED
    if sequential:
        return _sequential(x, P, H, y, var, keep, nk, joseph, x_out, P_out)
    if not _chol(S, keep, nk, L):
        return NOT_PD
    Kt = np.empty((nk, n))  # K^T = S_kk^-1 (P H_k^T)^T
    b = np.empty(nk)
    for j in range(n):
        for r in range(nk):
            b[r] = PHt[j, keep[r]]
        _solve(L, nk, b)
        for r in range(nk):
            Kt[r, j] = b[r]
    for i in range(n):
        t = x[i]
        for r in range(nk):
            t += Kt[r, i] * y[keep[r]]
        x_out[i] = t
    if joseph:
        # Joseph form (I - K H) P (I - K H)^T + K R K^T, with A = I - K H applied by
        # associativity in O(n^2 m): T = A P = P - K (H P), then T A^T = T - (T H^T) K^T.
        G = np.empty((nk, n))  # H_k P
        for r in range(nk):
            for j in range(n):
                t = 0.0
                for q in range(n):
                    t += H[keep[r], q] * P[q, j]
                G[r, j] = t
        T = np.empty((n, n))
        for i in range(n):
            for j in range(n):
                t = P[i, j]
                for r in range(nk):
                    t -= Kt[r, i] * G[r, j]
                T[i, j] = t
        W = np.empty((n, nk))  # K R_kk - T H_k^T
        for i in range(n):
            for c in range(nk):
                if diag:
                    t = Kt[c, i] * var[keep[c]]
                else:
                    t = 0.0
                    for r in range(nk):
                        t += Kt[r, i] * R[keep[r], keep[c]]
                for q in range(n):
                    t -= T[i, q] * H[keep[c], q]
                W[i, c] = t
        for i in range(n):
            for j in range(n):
                t = T[i, j]
                for c in range(nk):
                    t += W[i, c] * Kt[c, j]
                P_out[i, j] = t
    else:
        for i in range(n):
            for j in range(n):
                t = P[i, j]
                for r in range(nk):
                    t -= Kt[r, i] * PHt[j, keep[r]]
                P_out[i, j] = t
    if not _finish(P_out):
        return BAD_P
    return OK


@_jit
def _sequential(x, P, H, y, var, keep, nk, joseph, x_out, P_out):
    """Scalar updates over the kept rows (R diagonal); each row's innovation is taken about
    the prior point, y_i - H_i (x_c - x), so the result equals the joint update."""
    n = x.shape[0]
    for i in range(n):
        x_out[i] = x[i]
        for j in range(n):
            P_out[i, j] = P[i, j]
    c = np.empty(n)
    k = np.empty(n)
    g = np.empty(n)
    g2 = np.empty(n)
    T = np.empty((n, n))
    for r in range(nk):
        row = keep[r]
        s = var[row]
        for i in range(n):
            t = 0.0
            for j in range(n):
                t += P_out[i, j] * H[row, j]
            c[i] = t
            s += H[row, i] * t
        if not (s > 0.0) or not _isfinite(s):
            return NOT_PD
        yi = y[row]
        if r > 0:
            for j in range(n):
                yi -= H[row, j] * (x_out[j] - x[j])
        for i in range(n):
            k[i] = c[i] / s
        for i in range(n):
            x_out[i] += k[i] * yi
        if joseph:
            # (I - k h^T) P (I - k h^T)^T + v k k^T in O(n^2): T = P - k (h^T P), then
            # T - (T h) k^T + v k k^T.
            vr = var[row]
            for j in range(n):
                t = 0.0
                for q in range(n):
                    t += H[row, q] * P_out[q, j]
                g[j] = t
            for i in range(n):
                for j in range(n):
                    T[i, j] = P_out[i, j] - k[i] * g[j]
            for i in range(n):
                t = 0.0
                for q in range(n):
                    t += T[i, q] * H[row, q]
                g2[i] = vr * k[i] - t
            for i in range(n):
                for j in range(n):
                    P_out[i, j] = T[i, j] + g2[i] * k[j]
        else:
            for i in range(n):
                for j in range(n):
                    P_out[i, j] -= k[i] * c[j]
    if not _finish(P_out):
        return BAD_P
    return OK


def ukf_sigmas(x, P, scale, sig_out):
    """Merwe sigma points: row 0 = x, rows 1..n = x + scale L[:, i], rows n+1..2n =
    x - scale L[:, i] with P = L L^T (seed 003 eq. 9)."""
    n = x.shape[0]
    L = np.zeros((n, n))
    rows = np.arange(n)
    if not _chol(P, rows, n, L):
        return NOT_PD
    for a in range(n):
        sig_out[0, a] = x[a]
    for i in range(n):
        for a in range(n):
            d = L[a, i] * scale
            sig_out[1 + i, a] = x[a] + d
            sig_out[1 + n + i, a] = x[a] - d
    return OK


def ukf_predict(Xf, Wm, Wc, Q, x_out, P_out):
    """Weighted mean and covariance of the propagated sigma points plus Q, symmetrised
    (seed 003 eqs. 10-11)."""
    N = Xf.shape[0]
    n = Xf.shape[1]
    for a in range(n):
        t = 0.0
        for i in range(N):
            t += Wm[i] * Xf[i, a]
        if not _isfinite(t):
            return NONFINITE
        x_out[a] = t
    D = np.empty((N, n))
    for i in range(N):
        for a in range(n):
            D[i, a] = Xf[i, a] - x_out[a]
    for a in range(n):
        for b in range(n):
            t = 0.0
            for i in range(N):
                t += D[i, a] * Wc[i] * D[i, b]
            P_out[a, b] = t + Q[a, b]
    for a in range(n):
        for b in range(a + 1, n):
            v = 0.5 * (P_out[a, b] + P_out[b, a])
            P_out[a, b] = v
            P_out[b, a] = v
    for a in range(n):
        for b in range(n):
            if not _isfinite(P_out[a, b]):
                return NONFINITE
    return OK


def ukf_update(x, P, sig, Y, z, var, R, diag, ends, thr, Wm, Wc, x_out, P_out, nis_out):
    """Unscented correction of the stacked blocks (seed 003 eqs. 12-17): y_mean = Wm Y,
    S = Dy^T diag(Wc) Dy + R, Pxy = (sig - x)^T diag(Wc) Dy, K = Pxy S^-1 over the kept
    rows, x += K y, P -= K S K^T. Writes x_out, P_out, nis_out; returns a status code."""
    return _ukf_update(x, P, sig, Y, z, var, R, diag, ends, thr, Wm, Wc, x_out, P_out, nis_out)


def ukf_update1(x, P, sig, Y, z, var, R, diag, thr, Wm, Wc, x_out, P_out):
    """``ukf_update`` for a single block with NIS gate ``thr``; returns (status, NIS)."""
    ends = np.empty(1, np.int64)
    ends[0] = Y.shape[1]
    th = np.empty(1)
    th[0] = thr
    nis = np.zeros(1)
    st = _ukf_update(x, P, sig, Y, z, var, R, diag, ends, th, Wm, Wc, x_out, P_out, nis)
    return st, nis[0]


@_jit
def _ukf_update(x, P, sig, Y, z, var, R, diag, ends, thr, Wm, Wc, x_out, P_out, nis_out):
    N = sig.shape[0]
    n = x.shape[0]
    m = Y.shape[1]
    yp = np.empty(m)
    y = np.empty(m)
    for j in range(m):
        t = 0.0
        for i in range(N):
            t += Wm[i] * Y[i, j]
        yp[j] = t
        v = z[j] - t
        if not _isfinite(v):
            return NONFINITE
        y[j] = v
    Dy = np.empty((N, m))
    for i in range(N):
        for j in range(m):
            Dy[i, j] = Y[i, j] - yp[j]
    S = np.empty((m, m))
    for a in range(m):
        for b in range(m):
            t = 0.0
            for i in range(N):
                t += Dy[i, a] * Wc[i] * Dy[i, b]
            if diag:
                if a == b:
                    t += var[a]
            else:
                t += R[a, b]
            if not _isfinite(t):
                return NONFINITE
            S[a, b] = t
    L = np.empty((m, m))
    rows = np.arange(m)
    if not _chol(S, rows, m, L):
        return NOT_PD
    keep = np.empty(m, np.int64)
    nk = _nis_and_keep(S, y, ends, thr, L, nis_out, keep)
    if nk < 0:
        return NOT_PD
    if nk == 0:
        return ALL_REJECTED
    if not _chol(S, keep, nk, L):
        return NOT_PD
    Pxy = np.empty((n, nk))
    for a in range(n):
        for r in range(nk):
            c = keep[r]
            t = 0.0
            for i in range(N):
                t += (sig[i, a] - x[a]) * Wc[i] * Dy[i, c]
            Pxy[a, r] = t
    Kt = np.empty((nk, n))
    b = np.empty(nk)
    for a in range(n):
        for r in range(nk):
            b[r] = Pxy[a, r]
        _solve(L, nk, b)
        for r in range(nk):
            Kt[r, a] = b[r]
    for a in range(n):
        t = x[a]
        for r in range(nk):
            t += Kt[r, a] * y[keep[r]]
        x_out[a] = t
    KS = np.empty((n, nk))  # K S_kk
    for a in range(n):
        for c in range(nk):
            t = 0.0
            for r in range(nk):
                t += Kt[r, a] * S[keep[r], keep[c]]
            KS[a, c] = t
    for a in range(n):
        for b2 in range(n):
            t = P[a, b2]
            for c in range(nk):
                t -= KS[a, c] * Kt[c, b2]
            P_out[a, b2] = t
    if not _finish(P_out):
        return BAD_P
    return OK


_F = types.float64
_I = types.int64
_B = types.boolean
# Arrays the filter owns (x, P, outputs) are C-contiguous; user-supplied ones (H, z, h(x),
# R, F/Q overrides, f(x)) may have any layout and may be read-only.
_c1 = types.Array(_F, 1, "C")
_c2 = types.Array(_F, 2, "C")
_c1r = types.Array(_F, 1, "C", readonly=True)
_c2r = types.Array(_F, 2, "C", readonly=True)
_r1 = types.Array(_F, 1, "A", readonly=True)
_r2 = types.Array(_F, 2, "A", readonly=True)
_ri = types.Array(_I, 1, "A", readonly=True)
_pair = types.Tuple((_I, _F))

# The hot kernels also get an exact signature for the usual case (every array C-contiguous
# and writable, as numpy creates them): numba's dispatch matches it directly instead of
# converting to the general one, and the loops index without strides.
SIGNATURES = {
    "kf_predict": [
        _I(_c1, _c2, _c2, _c2, _c1, _c1, _c2),
        _I(_c1, _c2, _r2, _r2, _c1, _c1, _c2),
    ],
    "kf_predict_u": [_I(_c1, _c2, _r2, _r2, _r2, _r1, _c1, _c1, _c2)],
    "ekf_predict": [
        _I(_c1, _c2, _c2, _c2, _c1, _c2),
        _I(_r1, _c2, _r2, _r2, _c1, _c2),
    ],
    "lin_update1": [
        _F(_c1, _c2, _c2, _c1, _c1, _c1, _c2, _F, _I, _c1, _c1, _c2),
        _F(_c1, _c2, _r2, _r1, _r1, _r1, _r2, _F, _I, _c1, _c1, _c2),
    ],
    "lin_update": [_I(_c1, _c2, _r2, _r1, _r1, _r1, _r2, _ri, _r1, _I, _c1, _c2, _c1)],
    "ukf_sigmas": [_I(_c1, _c2, _F, _c2)],
    "ukf_predict": [_I(_r2, _c1r, _c1r, _r2, _c1, _c2)],
    "ukf_update1": [_pair(_c1, _c2, _c2, _r2, _r1, _r1, _r2, _B, _F, _c1r, _c1r, _c1, _c2)],
    "ukf_update": [_I(_c1, _c2, _c2, _r2, _r1, _r1, _r2, _B, _ri, _r1, _c1r, _c1r, _c1, _c2, _c1)],
}
