"""Compiled kernels (numba) for the KF/EKF/UKF hot path; imported only by ``backend``.

Every kernel is a plain loop nest over float64 arrays with no temporaries beyond a few
small scratch arrays, so at n <= 9 and m <= 3 the cost is the call itself (~0.5 us), not
numpy's per-call overhead. Each kernel:

* reads its inputs and writes *only* into output arrays it is given (never into x or P),
  so a failed step leaves the filter untouched;
* checks finiteness, variances and positive definiteness itself and returns a status code
  instead of raising: ``OK``, ``ALL_REJECTED`` (every block gated out; outputs not written)
  or a negative code. On a negative code the caller re-runs the step on the numpy path,
  which raises the precise, labelled error (``NonFiniteInputError`` / ``CovarianceError`` /
  ``ValueError``) or, in borderline roundoff cases, produces the result; the two backends
  therefore share one error behaviour.

Equations are the same as on the numpy path (``correction``, ``kalman``, ``ekf``, ``ukf``)
and are cited there: predict P = F P F^T + Q (seed 003 eq. 5), the joint update with the
Joseph form P = (I - K H) P (I - K H)^T + K R K^T (seed 000), evaluated as
T = (I - K H) P = P - K (H P), then T (I - K H)^T + K R K^T = T + (K R - T H^T) K^T (the
textbook product, associated so that it costs O(n^2 m); never the expanded
P - K H P - P H^T K^T + K S K^T, which cancels catastrophically when R << H P H^T),
sequential scalar updates, the unscented transform (seed 003 eqs. 9-17). Innovation
covariances are factorised by Cholesky (S = L L^T), which also is the positive-definiteness
test; NIS = |L^-1 y|^2 and K^T = L^-T L^-1 (H P).

The functions below are compiled lazily by ``backend`` with the signatures in ``SIGNATURES``
(any layout, read-only inputs accepted) and ``cache=True``.

Hot-path kernels (``lin_update1``, the predicts) allocate nothing: their intermediates live
in a scratch array ``ws`` the caller passes (``stacking.SCRATCH``), and they check every
array shape themselves (returning ``BAD_SHAPE``), so no argument can make them read or
write out of bounds; numba's dispatch checks dtypes and ranks.

A block's measurement noise reaches the kernels as one vector ``noise``: the m variances
when the ``DIAG`` flag is set, else the (m, m) covariance row by row.
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
BAD_R = -6  # a variance not in (0, inf): the numpy path raises the precise error
STEP_PREDICT = -7  # a step kernel's predict part failed (non-finite): nothing is valid

MODE_LINEAR = 0  # flags bits 0-1: innovation y = z - H x
MODE_HX = 1  # y = z - hx
MODE_GIVEN = 2  # y = z (the caller passed the innovation)
DIAG = 4  # noise = the variances, else the (m, m) covariance row by row
JOSEPH = 8  # Joseph form, else P - K H P
SEQUENTIAL = 16  # scalar updates row by row (needs DIAG)

_INF = math.inf
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
    """Symmetrise P_out in place, (P + P^T) / 2 as on the numpy path; False if a diagonal
    entry is not > 0 or a value is not finite."""
    n = P_out.shape[0]
    for i in range(n):
        for j in range(i + 1, n):
            v = 0.5 * (P_out[i, j] + P_out[j, i])
            if not _isfinite(v):
                return False
            P_out[i, j] = v
            P_out[j, i] = v
        if not (0.0 < P_out[i, i] < _INF):
            return False
    return True


@_jit
def _variances_ok(noise, m):
    for i in range(m):  # noqa: SIM110 - a generator is not compiled as tightly by numba
        if not (0.0 < noise[i] < _INF):
            return False
    return True


@_jit
def _square(A, n):
    return A.shape[0] == n and A.shape[1] == n


def _row_times(A, i, P, ws, o):
    """ws[o + j] = (A P)[i, j] for every column j of P: row i of A times P, as dot products
    two entries at a time so that two independent sums are in flight (each still summed
    left to right: the same result to the bit). Inlined where it is used."""
    n = P.shape[0]
    j = 0
    while j + 1 < n:
        t = 0.0
        s = 0.0
        for k in range(n):
            a = A[i, k]
            t += a * P[k, j]
            s += a * P[k, j + 1]
        ws[o + j] = t
        ws[o + j + 1] = s
        j += 2
    if j < n:
        t = 0.0
        for k in range(n):
            t += A[i, k] * P[k, j]
        ws[o + j] = t


_row_times = numba.njit(cache=True, error_model="numpy", inline="always")(_row_times)


def _predict_cov(P, F, Q, ws, P_out, bad):
    """P_out = F P F^T + Q (upper triangle, mirrored: exactly symmetric), F P kept in
    ws[:n * n]; returns ``bad`` plus P_out * 0 (NaN iff an entry is not finite). Both
    products as dot products accumulated in registers (faster here than row updates in
    memory), two entries at a time so that two independent sums are in flight (each still
    summed left to right: the same result to the bit; about 20 % faster at n = 9);
    inlined into each predict kernel, a call passing arrays costs more than the
    arithmetic at n <= 9."""
    n = P.shape[0]
    for i in range(n):  # F P
        _row_times(F, i, P, ws, i * n)
    for i in range(n):
        o = i * n
        j = i
        while j + 1 < n:  # (F P) F^T + Q, row i from its diagonal on
            v = Q[i, j]
            u = Q[i, j + 1]
            for k in range(n):
                w = ws[o + k]
                v += w * F[j, k]
                u += w * F[j + 1, k]
            bad += v * 0.0 + u * 0.0
            P_out[i, j] = v
            P_out[j, i] = v
            P_out[i, j + 1] = u
            P_out[j + 1, i] = u
            j += 2
        if j < n:
            v = Q[i, j]
            for k in range(n):
                v += ws[o + k] * F[j, k]
            bad += v * 0.0
            P_out[i, j] = v
            P_out[j, i] = v
    return bad


_predict_cov = numba.njit(cache=True, error_model="numpy", inline="always")(_predict_cov)


def kf_predict(x, P, F, Q, ws, x_out, P_out):
    """x_out = F x, P_out = F P F^T + Q (seed 003 eq. 5); ws: scratch of >= n * n."""
    n = x.shape[0]
    if not (
        (P.shape[0] == n)
        & (P.shape[1] == n)
        & (F.shape[0] == n)
        & (F.shape[1] == n)
        & (Q.shape[0] == n)
        & (Q.shape[1] == n)
        & (P_out.shape[0] == n)
        & (P_out.shape[1] == n)
        & (x_out.shape[0] == n)
    ):
        return BAD_SHAPE
    if ws.shape[0] < n * n:
        return WS_SMALL
    bad = 0.0
    for i in range(n):
        t = 0.0
        for k in range(n):
            t += F[i, k] * x[k]
        bad += t * 0.0
        x_out[i] = t
    if _predict_cov(P, F, Q, ws, P_out, bad) != 0.0:
        return NONFINITE
    return OK


def kf_predict_u(x, P, F, Q, B, u, ws, x_out, P_out):
    """x_out = F x + B u, P_out = F P F^T + Q (seed 003 eq. 5); ws as kf_predict."""
    n = x.shape[0]
    if not (
        (P.shape[0] == n)
        & (P.shape[1] == n)
        & (F.shape[0] == n)
        & (F.shape[1] == n)
        & (Q.shape[0] == n)
        & (Q.shape[1] == n)
        & (P_out.shape[0] == n)
        & (P_out.shape[1] == n)
        & (x_out.shape[0] == n)
        & (B.shape[0] == n)
        & (B.shape[1] == u.shape[0])
    ):
        return BAD_SHAPE
    if ws.shape[0] < n * n:
        return WS_SMALL
    bad = 0.0
    for i in range(n):
        t = 0.0
        for k in range(n):
            t += F[i, k] * x[k]
        for k in range(u.shape[0]):
            t += B[i, k] * u[k]
        bad += t * 0.0
        x_out[i] = t
    if _predict_cov(P, F, Q, ws, P_out, bad) != 0.0:
        return NONFINITE
    return OK


def ekf_predict(xn, P, F, Q, ws, P_out):
    """P_out = F P F^T + Q with the process Jacobian F; checks that xn = f(x) is finite
    (seed 003 eq. 7); ws as kf_predict."""
    n = xn.shape[0]
    if not (
        (P.shape[0] == n)
        & (P.shape[1] == n)
        & (F.shape[0] == n)
        & (F.shape[1] == n)
        & (Q.shape[0] == n)
        & (Q.shape[1] == n)
        & (P_out.shape[0] == n)
        & (P_out.shape[1] == n)
    ):
        return BAD_SHAPE
    if ws.shape[0] < n * n:
        return WS_SMALL
    bad = 0.0
    for i in range(n):
        bad += xn[i] * 0.0
    if _predict_cov(P, F, Q, ws, P_out, bad) != 0.0:
        return NONFINITE
    return OK


def _update_row(x, P, H, z, hx, r, thr, flags, ws, x_out, P_out):
    """``lin_update1`` for one row (m = 1), shapes checked: S is the scalar
    s = h P h^T + r, so L = sqrt(s) and K = (h P)^T / s; the same Joseph form (T = P - k g,
    w = k r - T h, P_out = T + w k^T). ws: g = h P (n), k (n), w (n)."""
    n = x.shape[0]
    if not r > 0.0:
        return float(BAD_R)
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
    s = r
    j = 0
    while j + 1 < n:  # g = h P (two entries at a time as in _predict_cov), s = g h^T + r
        t = 0.0
        u = 0.0
        for k in range(n):
            h = H[0, k]
            t += h * P[k, j]
            u += h * P[k, j + 1]
        ws[j] = t
        ws[j + 1] = u
        s += t * H[0, j]
        s += u * H[0, j + 1]
        j += 2
    if j < n:
        t = 0.0
        for k in range(n):
            t += H[0, k] * P[k, j]
        ws[j] = t
        s += t * H[0, j]
    if (y * 0.0 + s * 0.0) != 0.0:
        return float(NONFINITE)
    if not s > 0.0:
        return float(NOT_PD)
    w = y / math.sqrt(s)
    nis = w * w
    if not nis <= thr:
        return nis
    for i in range(n):
        kv = ws[i] / s
        ws[n + i] = kv
        x_out[i] = x[i] + kv * y
    for i in range(n):  # T = P - k g
        kv = ws[n + i]
        for j in range(n):
            P_out[i, j] = P[i, j] - kv * ws[j]
    if flags & JOSEPH:
        for i in range(n):  # w = k r - T h^T
            t = ws[n + i] * r
            for q in range(n):
                t -= P_out[i, q] * H[0, q]
            ws[2 * n + i] = t
        for i in range(n):  # P_out = T + w k^T
            wv = ws[2 * n + i]
            for j in range(n):
                P_out[i, j] += wv * ws[n + j]
    bad = 0.0
    for i in range(n):  # symmetrise, (P + P^T) / 2 as on the numpy path
        bad += x_out[i] * 0.0
        for j in range(i + 1, n):
            v = 0.5 * (P_out[i, j] + P_out[j, i])
            bad += v * 0.0
            P_out[i, j] = v
            P_out[j, i] = v
        if not 0.0 < P_out[i, i] < _INF:
            return float(BAD_P)
    if bad != 0.0:
        return float(BAD_P)
    return nis


_update_row = numba.njit(cache=True, error_model="numpy", inline="always")(_update_row)


def _update_block(x, P, H, z, hx, noise, thr, flags, ws, x_out, P_out):
    """The algebra of ``lin_update1`` (shapes and ws already checked): one row on
    ``_update_row``, inlined here (the hot path: no call), several rows on
    ``_update_rows``, called. Inlined into the kernels that call it."""
    if H.shape[0] == 1:
        return _update_row(x, P, H, z, hx, noise[0], thr, flags, ws, x_out, P_out)
    return _update_rows(x, P, H, z, hx, noise, thr, flags, ws, x_out, P_out)


_update_block = numba.njit(cache=True, error_model="numpy", inline="always")(_update_block)


def _update_rows(x, P, H, z, hx, noise, thr, flags, ws, x_out, P_out):
    """``_update_block`` for m > 1 rows, through the Cholesky factor of S.

    Compiled once for each set of argument types and called by ``lin_update1``,
    ``ekf_step`` and ``kf_step``, not inlined into each: it is most of their code, and
    inlined it was compiled six times (three kernels, two signatures each) instead of three
    (the distinct argument types), and the first compile took a third more CPU time (59 s
    against 45 s in one process on a 2-vCPU machine). Called from kernels without NRT
    (``NO_NRT``) and compiled without it too, so a call passes plain array structs, no
    reference counting: the kernels' call times measured the same either way (within the
    machine's noise of about 10 %), their results identical to the bit."""
    mode = flags & 3
    diag = (flags & DIAG) != 0
    n = x.shape[0]
    m = H.shape[0]
    o_w = m
    o_s = 2 * m
    o_l = o_s + m * m
    o_g = o_l + m * m
    o_k = o_g + m * n
    o_v = o_k + m * n
    bad = 0.0  # stays 0.0 while every value it collects is finite
    if diag:
        for r in range(m):
            if not noise[r] > 0.0:
                return float(BAD_R)
    for r in range(m):
        if mode == 0:
            t = 0.0
            for k in range(n):
                t += H[r, k] * x[k]
            v = z[r] - t
        elif mode == 1:
            v = z[r] - hx[r]
        else:
            v = z[r]
        bad += v * 0.0
        ws[r] = v
    for r in range(m):  # G = H P
        _row_times(H, r, P, ws, o_g + r * n)
    for r in range(m):  # S = G H^T + R
        g = o_g + r * n
        for c in range(m):
            t = 0.0
            for j in range(n):
                t += ws[g + j] * H[c, j]
            if diag:
                if r == c:
                    t += noise[r]
            else:
                t += noise[r * m + c]
            bad += t * 0.0
            ws[o_s + r * m + c] = t
    if bad != 0.0:
        return float(NONFINITE)
    for j in range(m):  # Cholesky S = L L^T (lower triangle of S read)
        s = ws[o_s + j * m + j]
        for p in range(j):
            s -= ws[o_l + j * m + p] * ws[o_l + j * m + p]
        if not s > 0.0:
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
        t /= ws[o_l + i * m + i]
        ws[o_w + i] = t
        nis += t * t
    if not nis <= thr:
        return nis
    # K^T = L^-T L^-1 G by forward then backward substitution, and x_out = x + K y. For
    # m = 2, 3 column by column of K^T with L's entries in registers, each column's two
    # substitutions and x_out's entry together: the same operations in the same order as
    # the general loops (the same result to the bit), a third of their time at n = 9.
    if m == 2:
        l00 = ws[o_l]
        l10 = ws[o_l + 2]
        l11 = ws[o_l + 3]
        y0 = ws[0]
        y1 = ws[1]
        for j in range(n):
            c0 = ws[o_g + j] / l00
            c1 = (ws[o_g + n + j] - l10 * c0) / l11
            c1 = c1 / l11
            c0 = (c0 - l10 * c1) / l00
            ws[o_k + j] = c0
            ws[o_k + n + j] = c1
            x_out[j] = x[j] + c0 * y0 + c1 * y1
    elif m == 3:
        l00 = ws[o_l]
        l10 = ws[o_l + 3]
        l11 = ws[o_l + 4]
        l20 = ws[o_l + 6]
        l21 = ws[o_l + 7]
        l22 = ws[o_l + 8]
        y0 = ws[0]
        y1 = ws[1]
        y2 = ws[2]
        for j in range(n):
            c0 = ws[o_g + j] / l00
            c1 = (ws[o_g + n + j] - l10 * c0) / l11
            c2 = (ws[o_g + 2 * n + j] - l20 * c0 - l21 * c1) / l22
            c2 = c2 / l22
            c1 = (c1 - l21 * c2) / l11
            c0 = (c0 - l10 * c1 - l20 * c2) / l00
            ws[o_k + j] = c0
            ws[o_k + n + j] = c1
            ws[o_k + 2 * n + j] = c2
            x_out[j] = x[j] + c0 * y0 + c1 * y1 + c2 * y2
    else:
        for i in range(m):  # K^T = L^-1 G (forward substitution on the rows of G) ...
            ki = o_k + i * n
            for j in range(n):
                t = ws[o_g + i * n + j]
                for p in range(i):
                    t -= ws[o_l + i * m + p] * ws[o_k + p * n + j]
                ws[ki + j] = t / ws[o_l + i * m + i]
        for i in range(m - 1, -1, -1):  # ... then L^-T (backward substitution)
            ki = o_k + i * n
            for j in range(n):
                t = ws[ki + j]
                for p in range(i + 1, m):
                    t -= ws[o_l + p * m + i] * ws[o_k + p * n + j]
                ws[ki + j] = t / ws[o_l + i * m + i]
        for i in range(n):
            t = x[i]
            for r in range(m):
                t += ws[o_k + r * n + i] * ws[r]
            x_out[i] = t
    # T = (I - K H) P = P - K G, W = K R - T H^T and P_out = T (I - K H)^T + K R K^T
    # = T + W K^T. Row i of W needs only row i of T, and row i of the result only row i of
    # T and of W, so for m = 2, 3 (the usual sensor block) the three go row by row with K's
    # and W's entries in registers: every sum as in the general loops, term by term in the
    # same order (the same result to the bit), about 15 % faster at n = 9.
    joseph = (flags & JOSEPH) != 0
    if m == 2:
        k0 = o_k
        k1 = o_k + n
        g0 = o_g
        g1 = o_g + n
        for i in range(n):
            a0 = ws[k0 + i]
            a1 = ws[k1 + i]
            if diag:
                w0 = a0 * noise[0]
                w1 = a1 * noise[1]
            else:
                w0 = 0.0 + a0 * noise[0] + a1 * noise[2]
                w1 = 0.0 + a0 * noise[1] + a1 * noise[3]
            for q in range(n):  # row i of T = P - K G, and W = K R - T H^T
                t = P[i, q]
                t -= a0 * ws[g0 + q]
                t -= a1 * ws[g1 + q]
                P_out[i, q] = t
                w0 -= t * H[0, q]
                w1 -= t * H[1, q]
            if joseph:  # row i of T + W K^T
                for j in range(n):
                    t = P_out[i, j]
                    t += w0 * ws[k0 + j]
                    t += w1 * ws[k1 + j]
                    P_out[i, j] = t
    elif m == 3:
        k0 = o_k
        k1 = o_k + n
        k2 = o_k + 2 * n
        g0 = o_g
        g1 = o_g + n
        g2 = o_g + 2 * n
        for i in range(n):
            a0 = ws[k0 + i]
            a1 = ws[k1 + i]
            a2 = ws[k2 + i]
            if diag:
                w0 = a0 * noise[0]
                w1 = a1 * noise[1]
                w2 = a2 * noise[2]
            else:
                w0 = 0.0 + a0 * noise[0] + a1 * noise[3] + a2 * noise[6]
                w1 = 0.0 + a0 * noise[1] + a1 * noise[4] + a2 * noise[7]
                w2 = 0.0 + a0 * noise[2] + a1 * noise[5] + a2 * noise[8]
            for q in range(n):
                t = P[i, q]
                t -= a0 * ws[g0 + q]
                t -= a1 * ws[g1 + q]
                t -= a2 * ws[g2 + q]
                P_out[i, q] = t
                w0 -= t * H[0, q]
                w1 -= t * H[1, q]
                w2 -= t * H[2, q]
            if joseph:
                for j in range(n):
                    t = P_out[i, j]
                    t += w0 * ws[k0 + j]
                    t += w1 * ws[k1 + j]
                    t += w2 * ws[k2 + j]
                    P_out[i, j] = t
    else:
        for i in range(n):  # T = (I - K H) P = P - K G, into P_out (row by row)
            for j in range(n):
                P_out[i, j] = P[i, j]
            for r in range(m):
                kv = ws[o_k + r * n + i]
                g = o_g + r * n
                for j in range(n):
                    P_out[i, j] -= kv * ws[g + j]
        if flags & JOSEPH:
            for i in range(n):  # W = K R - T H^T
                for c in range(m):
                    if diag:
                        t = ws[o_k + c * n + i] * noise[c]
                    else:
                        t = 0.0
                        for r in range(m):
                            t += ws[o_k + r * n + i] * noise[r * m + c]
                    for q in range(n):
                        t -= P_out[i, q] * H[c, q]
                    ws[o_v + i * m + c] = t
            for i in range(n):  # P_out = T (I - K H)^T + K R K^T = T + W K^T (row by row)
                for c in range(m):
                    wv = ws[o_v + i * m + c]
                    kc = o_k + c * n
                    for j in range(n):
                        P_out[i, j] += wv * ws[kc + j]
    for i in range(n):  # symmetrise, (P + P^T) / 2 as on the numpy path
        bad += x_out[i] * 0.0
        for j in range(i + 1, n):
            v = 0.5 * (P_out[i, j] + P_out[j, i])
            bad += v * 0.0
            P_out[i, j] = v
            P_out[j, i] = v
        if not 0.0 < P_out[i, i] < _INF:
            return float(BAD_P)
    if bad != 0.0:
        return float(BAD_P)
    return nis


_update_rows = numba.njit(cache=True, error_model="numpy", _nrt=False)(_update_rows)


def _update_ws(n, m):
    """Scratch values ``lin_update1`` needs: y, w (m each), S, L (m^2 each), G, K^T, W."""
    return 2 * m + 2 * m * m + 3 * n * m


_update_ws = numba.njit(cache=True, inline="always")(_update_ws)


def lin_update1(x, P, H, z, hx, noise, thr, flags, ws, x_out, P_out):
    """Linearised correction by one block of m rows (joint update, no ``SEQUENTIAL``
    flag) with NIS gate ``thr``, allocating nothing: every intermediate lives in ``ws``
    (at least 2 m + 2 m^2 + 3 n m values).

    Steps: y (by the innovation mode), G = H P, S = G H^T + R, S = L L^T (Cholesky),
    NIS = |L^-1 y|^2 and the gate, K^T = L^-T L^-1 G, x_out = x + K y, then the Joseph form
    T = P - K G, P_out = T + (K R - T H^T) K^T (or the short form P_out = T), symmetrised.

    Returns the NIS (>= 0): the block was fused and x_out, P_out written iff NIS <= thr.
    A negative value is a status code (NONFINITE, NOT_PD, BAD_P, BAD_R, BAD_SHAPE,
    WS_SMALL) as a float. Every shape is checked here, so the caller need not (dtypes and
    ranks are checked by numba's dispatch against the signature).

    Written without calls on the one-row path (``_update_row``, inlined) and with
    finiteness tested by accumulating v * 0 (NaN iff some v is NaN or inf) instead of a
    test per value: at n <= 9 a test per value costs more than the algebra. Several rows
    call ``_update_rows`` (see there).
    """
    mode = flags & 3
    diag = (flags & DIAG) != 0
    n = x.shape[0]
    m = H.shape[0]
    if not (
        (m > 0)
        & (H.shape[1] == n)
        & (z.shape[0] == m)
        & ((mode != 1) | (hx.shape[0] == m))
        & (noise.shape[0] == (m if diag else m * m))
        & (P.shape[0] == n)
        & (P.shape[1] == n)
        & (P_out.shape[0] == n)
        & (P_out.shape[1] == n)
        & (x_out.shape[0] == n)
    ):
        return float(BAD_SHAPE)
    # Scratch layout, row-major: y (m), w (m), S (m, m), L (m, m), G = H P (m, n),
    # K^T (m, n), W = K R - T H^T (n, m).
    if ws.shape[0] < _update_ws(n, m):
        return float(WS_SMALL)
    return _update_block(x, P, H, z, hx, noise, thr, flags, ws, x_out, P_out)


def _step_shapes(P, F, Q, H, z, hx, noise, flags, P_prior, x_out, P_out, n):
    """True when the arrays of a step kernel fit a state of n and a block of H's rows."""
    m = H.shape[0]
    diag = (flags & DIAG) != 0
    return (
        (m > 0)
        & (P.shape[0] == n)
        & (P.shape[1] == n)
        & (F.shape[0] == n)
        & (F.shape[1] == n)
        & (Q.shape[0] == n)
        & (Q.shape[1] == n)
        & (H.shape[1] == n)
        & (z.shape[0] == m)
        & (((flags & 3) != 1) | (hx.shape[0] == m))
        & (noise.shape[0] == (m if diag else m * m))
        & (P_prior.shape[0] == n)
        & (P_prior.shape[1] == n)
        & (P_out.shape[0] == n)
        & (P_out.shape[1] == n)
        & (x_out.shape[0] == n)
    )


_step_shapes = numba.njit(cache=True, inline="always")(_step_shapes)


def ekf_step(xn, P, F, Q, H, z, hx, noise, thr, flags, ws, P_prior, x_out, P_out):
    """``ekf_predict`` then ``lin_update1`` in one call (``Filter.step``): P_prior = F P F^T
    + Q with xn = f(x) checked finite, then the block (H, hx evaluated at xn by the caller)
    fused at (xn, P_prior). Returns the NIS (>= 0; fused iff NIS <= thr) or a status as a
    float: STEP_PREDICT when the predict part failed (P_prior not valid), any other
    negative code when the update part did (P_prior valid: the predict stands)."""
    n = xn.shape[0]
    m = H.shape[0]
    if not _step_shapes(P, F, Q, H, z, hx, noise, flags, P_prior, x_out, P_out, n):
        return float(BAD_SHAPE)
    if ws.shape[0] < max(n * n, _update_ws(n, m)):
        return float(WS_SMALL)
    bad = 0.0
    for i in range(n):
        bad += xn[i] * 0.0
    if _predict_cov(P, F, Q, ws, P_prior, bad) != 0.0:
        return float(STEP_PREDICT)
    return _update_block(xn, P_prior, H, z, hx, noise, thr, flags, ws, x_out, P_out)


def kf_step(x, P, F, Q, H, z, noise, thr, flags, ws, x_prior, P_prior, x_out, P_out):
    """``kf_predict`` then ``lin_update1`` of a linear block (y = z - H x_prior) in one
    call; returns as ``ekf_step`` (x_prior and P_prior valid unless STEP_PREDICT)."""
    n = x.shape[0]
    m = H.shape[0]
    if not (
        _step_shapes(P, F, Q, H, z, z, noise, flags, P_prior, x_out, P_out, n)
        & (x_prior.shape[0] == n)
    ):
        return float(BAD_SHAPE)
    if ws.shape[0] < max(n * n, _update_ws(n, m)):
        return float(WS_SMALL)
    bad = 0.0
    for i in range(n):
        t = 0.0
        for k in range(n):
            t += F[i, k] * x[k]
        bad += t * 0.0
        x_prior[i] = t
    if _predict_cov(P, F, Q, ws, P_prior, bad) != 0.0:
        return float(STEP_PREDICT)
    return _update_block(x_prior, P_prior, H, z, z, noise, thr, flags & ~3, ws, x_out, P_out)


def lin_update(x, P, H, z, hx, noise, ends, thr, flags, x_out, P_out, nis_out):
    """Linearised correction of the stacked blocks (see ``correction.linearised_update``).

    ``flags``: innovation mode | DIAG | JOSEPH | SEQUENTIAL (constants above). ``ends``:
    cumulative row count after each block; ``thr``: each block's NIS gate (inf: none).
    Writes x_out, P_out and nis_out (per block); returns a status code.
    """
    n = x.shape[0]
    m = H.shape[0]
    diag = (flags & DIAG) != 0
    if (
        m == 0
        or H.shape[1] != n
        or z.shape[0] != m
        or ((flags & 3) == 1 and hx.shape[0] != m)
        or noise.shape[0] != (m if diag else m * m)
        or not _square(P, n)
        or not _square(P_out, n)
        or x_out.shape[0] != n
        or ends.shape[0] != thr.shape[0]
        or ends.shape[0] != nis_out.shape[0]
        or ends.shape[0] == 0
        or ends[ends.shape[0] - 1] != m
    ):
        return BAD_SHAPE
    if diag and not _variances_ok(noise, m):
        return BAD_R
    return _lin_update(x, P, H, z, hx, noise, ends, thr, flags, x_out, P_out, nis_out)


@_jit
def _lin_update(x, P, H, z, hx, noise, ends, thr, flags, x_out, P_out, nis_out):
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
    G = np.zeros((m, n))  # H P, row by row
    for r in range(m):
        for k in range(n):
            h = H[r, k]
            for j in range(n):
                G[r, j] += h * P[k, j]
    S = np.empty((m, m))
    for i in range(m):
        for j in range(m):
            t = 0.0
            for k in range(n):
                t += G[i, k] * H[j, k]
            if diag:
                if i == j:
                    t += noise[i]
            else:
                t += noise[i * m + j]
            if not _isfinite(t):
                return NONFINITE
            S[i, j] = t
    L = np.empty((m, m))
    keep = np.empty(m, np.int64)
    nk = _nis_and_keep(S, y, ends, thr, L, nis_out, keep)
    if nk < 0:
        return NOT_PD
    if nk == 0:
        return ALL_REJECTED
    if sequential:
        return _sequential(x, P, H, y, noise, keep, nk, joseph, x_out, P_out)
    if not _chol(S, keep, nk, L):
        return NOT_PD
    Kt = np.empty((nk, n))  # K^T = S_kk^-1 (H_k P)
    b = np.empty(nk)
    for j in range(n):
        for r in range(nk):
            b[r] = G[keep[r], j]
        _solve(L, nk, b)
        for r in range(nk):
            Kt[r, j] = b[r]
    for i in range(n):
        t = x[i]
        for r in range(nk):
            t += Kt[r, i] * y[keep[r]]
        x_out[i] = t
    for i in range(n):  # T = P - K (H_k P), into P_out
        for j in range(n):
            t = P[i, j]
            for r in range(nk):
                t -= Kt[r, i] * G[keep[r], j]
            P_out[i, j] = t
    if joseph:
        # Joseph form (I - K H) P (I - K H)^T + K R K^T = T + (K R_kk - T H_k^T) K^T.
        W = np.empty((n, nk))
        for i in range(n):
            for c in range(nk):
                if diag:
                    t = Kt[c, i] * noise[keep[c]]
                else:
                    t = 0.0
                    for r in range(nk):
                        t += Kt[r, i] * noise[keep[r] * m + keep[c]]
                for q in range(n):
                    t -= P_out[i, q] * H[keep[c], q]
                W[i, c] = t
        for i in range(n):
            for j in range(n):
                t = P_out[i, j]
                for c in range(nk):
                    t += W[i, c] * Kt[c, j]
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
    g2 = np.empty(n)
    T = np.empty((n, n))
    for r in range(nk):
        row = keep[r]
        s = var[row]
        for j in range(n):  # c = h^T P (a row; P_out symmetric after each row)
            t = 0.0
            for q in range(n):
                t += H[row, q] * P_out[q, j]
            c[j] = t
            s += H[row, j] * t
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
        # T = P - k (h^T P); Joseph: T - (T h) k^T + v k k^T, else T; then symmetrise.
        for i in range(n):
            for j in range(n):
                T[i, j] = P_out[i, j] - k[i] * c[j]
        if joseph:
            vr = var[row]
            for i in range(n):
                t = 0.0
                for q in range(n):
                    t += T[i, q] * H[row, q]
                g2[i] = vr * k[i] - t
            for i in range(n):
                for j in range(n):
                    T[i, j] += g2[i] * k[j]
        for i in range(n):
            for j in range(n):
                P_out[i, j] = 0.5 * (T[i, j] + T[j, i])
    if not _finish(P_out):
        return BAD_P
    return OK


def ukf_sigmas(x, P, scale, sig_out):
    """Merwe sigma points: row 0 = x, rows 1..n = x + scale L[:, i], rows n+1..2n =
    x - scale L[:, i] with P = L L^T (seed 003 eq. 9)."""
    n = x.shape[0]
    if not _square(P, n) or sig_out.shape[0] != 2 * n + 1 or sig_out.shape[1] != n:
        return BAD_SHAPE
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


@_jit
def _weighted_cov(D, Wc, Q, P_out):
    """P_out = sum_i Wc_i D_i D_i^T + Q (upper triangle, mirrored); False if not finite."""
    N = D.shape[0]
    n = D.shape[1]
    for a in range(n):
        for b in range(a, n):
            t = 0.0
            for i in range(N):
                t += D[i, a] * Wc[i] * D[i, b]
            v = t + Q[a, b]
            if not _isfinite(v):
                return False
            P_out[a, b] = v
            P_out[b, a] = v
    return True


def ukf_predict(Xf, Wm, Wc, Q, x_out, P_out):
    """Weighted mean and covariance of the propagated sigma points plus Q (seed 003
    eqs. 10-11); exactly symmetric."""
    N = Xf.shape[0]
    n = Xf.shape[1]
    if Wm.shape[0] != N or Wc.shape[0] != N or not _square(Q, n) or not _square(P_out, n):
        return BAD_SHAPE
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
    if not _weighted_cov(D, Wc, Q, P_out):
        return NONFINITE
    return OK


def ukf_predict_dev(D, Wc, Q, P_out):
    """P_out = sum_i Wc_i D_i D_i^T + Q from the deviations D_i = residual_x(X_i, x) the
    caller computed with the filter's state residual (seed 003 eq. 11)."""
    N = D.shape[0]
    n = D.shape[1]
    if Wc.shape[0] != N or not _square(Q, n) or not _square(P_out, n):
        return BAD_SHAPE
    if not _weighted_cov(D, Wc, Q, P_out):
        return NONFINITE
    return OK


def ukf_update(x, P, sig, Y, z, noise, diag, ends, thr, Wm, Wc, x_out, P_out, nis_out):
    """Unscented correction of the stacked blocks (seed 003 eqs. 12-17) with arithmetic
    means: y_mean = Wm Y, Dy = Y - y_mean, Dx = sig - x, then as ``ukf_update_dev``."""
    N = sig.shape[0]
    n = x.shape[0]
    m = Y.shape[1]
    if (
        Y.shape[0] != N
        or sig.shape[1] != n
        or z.shape[0] != m
        or Wm.shape[0] != N
        or Wc.shape[0] != N
    ):
        return BAD_SHAPE
    y = np.empty(m)
    Dy = np.empty((N, m))
    for j in range(m):
        t = 0.0
        for i in range(N):
            t += Wm[i] * Y[i, j]
        y[j] = z[j] - t
        for i in range(N):
            Dy[i, j] = Y[i, j] - t
    Dx = np.empty((N, n))
    for i in range(N):
        for a in range(n):
            Dx[i, a] = sig[i, a] - x[a]
    return _ukf_core(x, P, Dx, Dy, y, noise, diag, ends, thr, Wc, x_out, P_out, nis_out)


def ukf_update_dev(x, P, Dx, Dy, y, noise, diag, ends, thr, Wc, x_out, P_out, nis_out):
    """``ukf_update`` from deviations the caller computed (see ``_ukf_core``)."""
    return _ukf_core(x, P, Dx, Dy, y, noise, diag, ends, thr, Wc, x_out, P_out, nis_out)


@_jit
def _ukf_core(x, P, Dx, Dy, y, noise, diag, ends, thr, Wc, x_out, P_out, nis_out):
    """Unscented correction from deviations the caller computed with its mean and residual
    functions: Dx_i = residual_x(sigma_i, x), Dy_i = residual_z(Y_i, y_mean), innovation
    y = residual_z(z, y_mean). S = Dy^T diag(Wc) Dy + R, NIS per block and the gate,
    Pxy = Dx^T diag(Wc) Dy, K = Pxy S^-1 over the kept rows (Cholesky), x += K y,
    P -= K S K^T (seed 003 eqs. 14-17). Writes x_out, P_out, nis_out; returns a status."""
    N = Dx.shape[0]
    n = x.shape[0]
    m = Dy.shape[1]
    if (
        m == 0
        or Dy.shape[0] != N
        or Dx.shape[1] != n
        or y.shape[0] != m
        or Wc.shape[0] != N
        or noise.shape[0] != (m if diag else m * m)
        or not _square(P, n)
        or not _square(P_out, n)
        or x_out.shape[0] != n
        or ends.shape[0] != thr.shape[0]
        or ends.shape[0] != nis_out.shape[0]
        or ends.shape[0] == 0
        or ends[ends.shape[0] - 1] != m
    ):
        return BAD_SHAPE
    if diag and not _variances_ok(noise, m):
        return BAD_R
    for j in range(m):
        if not _isfinite(y[j]):
            return NONFINITE
    S = np.empty((m, m))
    for a in range(m):
        for b in range(m):
            t = 0.0
            for i in range(N):
                t += Dy[i, a] * Wc[i] * Dy[i, b]
            if diag:
                if a == b:
                    t += noise[a]
            else:
                t += noise[a * m + b]
            if not _isfinite(t):
                return NONFINITE
            S[a, b] = t
    for a in range(m):  # exactly symmetric, as on the numpy path
        for b in range(a + 1, m):
            v = 0.5 * (S[a, b] + S[b, a])
            S[a, b] = v
            S[b, a] = v
    L = np.empty((m, m))
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
                t += Dx[i, a] * Wc[i] * Dy[i, c]
            if not _isfinite(t):
                return NONFINITE
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
_r1 = types.Array(_F, 1, "A", readonly=True)
_r2 = types.Array(_F, 2, "A", readonly=True)
_ri = types.Array(_I, 1, "A", readonly=True)

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
        _F(_c1, _c2, _c2, _c1, _c1, _c1, _F, _I, _c1, _c1, _c2),
        _F(_c1, _c2, _r2, _r1, _r1, _r1, _F, _I, _c1, _c1, _c2),
    ],
    "lin_update": [_I(_c1, _c2, _r2, _r1, _r1, _r1, _ri, _r1, _I, _c1, _c2, _c1)],
    "ekf_step": [
        _F(_c1, _c2, _c2, _c2, _c2, _c1, _c1, _c1, _F, _I, _c1, _c2, _c1, _c2),
        _F(_r1, _c2, _r2, _r2, _r2, _r1, _r1, _r1, _F, _I, _c1, _c2, _c1, _c2),
    ],
    "kf_step": [
        _F(_c1, _c2, _c2, _c2, _c2, _c1, _c1, _F, _I, _c1, _c1, _c2, _c1, _c2),
        _F(_c1, _c2, _r2, _r2, _r2, _r1, _r1, _F, _I, _c1, _c1, _c2, _c1, _c2),
    ],
    "ukf_sigmas": [_I(_c1, _c2, _F, _c2)],
    "ukf_predict": [_I(_r2, _c1r, _c1r, _r2, _c1, _c2)],
    "ukf_predict_dev": [_I(_r2, _c1r, _r2, _c2)],
    "ukf_update": [_I(_c1, _c2, _c2, _r2, _r1, _r1, _B, _ri, _r1, _c1r, _c1r, _c1, _c2, _c1)],
    "ukf_update_dev": [_I(_c1, _c2, _r2, _r2, _r1, _r1, _B, _ri, _r1, _c1r, _c1, _c2, _c1)],
}

# How ``backend`` compiles every kernel. Kept in this file on purpose: numba's cache is keyed
# by this file's content (and the signature), not by compile options, so an option changed
# anywhere else would load machine code compiled with the old one. error_model="numpy": a
# division by zero gives inf/nan (which the kernels test for) instead of a check and a
# Python exception on every division.
OPTIONS = {"cache": True, "error_model": "numpy"}

# Kernels that allocate nothing (every intermediate in ``ws``, results in the given output
# arrays) are compiled without numba's reference-counted memory manager (NRT): their array
# arguments are then passed as plain pointers, which halves the cost of a call (about
# 0.27 us instead of 0.58 us for 14 arguments). The others allocate and need it.
NO_NRT = frozenset(
    ("kf_predict", "kf_predict_u", "ekf_predict", "lin_update1", "ekf_step", "kf_step")
)
