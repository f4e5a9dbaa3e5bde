"""The arithmetic of :mod:`.kernels` as compiled loops (numba), for the AHRS's hot path.

Same functions, same arguments, same results to roundoff; the equations are cited in
:mod:`.kernels`. Written as plain loops over small float64 arrays so that one call costs
about a microsecond. Imported only when ``hera.estimation``'s backend is numba (numba is an
optional dependency); :func:`compiled` compiles every kernel once per process (or loads it
from numba's cache) and returns them.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numba
import numpy as np

from hera.models.ahrs.kernels import ACCEPTED, OUT_OF_WINDOW, PENDING, REJECTED, UNUSABLE

_jit = numba.njit(cache=True, error_model="numpy")


@_jit
def _qmat(q0, q1, q2, q3, R):
    R[0, 0] = 1.0 - 2.0 * (q2 * q2 + q3 * q3)
    R[0, 1] = 2.0 * (q1 * q2 - q0 * q3)
    R[0, 2] = 2.0 * (q1 * q3 + q0 * q2)
    R[1, 0] = 2.0 * (q1 * q2 + q0 * q3)
    R[1, 1] = 1.0 - 2.0 * (q1 * q1 + q3 * q3)
    R[1, 2] = 2.0 * (q2 * q3 - q0 * q1)
    R[2, 0] = 2.0 * (q1 * q3 - q0 * q2)
    R[2, 1] = 2.0 * (q2 * q3 + q0 * q1)
    R[2, 2] = 1.0 - 2.0 * (q1 * q1 + q2 * q2)


@_jit
def _rotvec(vx, vy, vz):
    a = math.sqrt(vx * vx + vy * vy + vz * vz)
    if a < 1e-8:
        k = 1.0 / math.sqrt(1.0 + 0.25 * a * a)
        return k, 0.5 * vx * k, 0.5 * vy * k, 0.5 * vz * k
    s = math.sin(0.5 * a) / a
    return math.cos(0.5 * a), s * vx, s * vy, s * vz


@_jit
def _qmul(w1, x1, y1, z1, w2, x2, y2, z2):
    return (
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    )


@_jit
def _inject(q, g, dx):
    dw, dx1, dy1, dz1 = _rotvec(dx[0], dx[1], dx[2])
    w, x, y, z = _qmul(q[0], q[1], q[2], q[3], dw, dx1, dy1, dz1)
    n = math.sqrt(w * w + x * x + y * y + z * z)
    q[0], q[1], q[2], q[3] = w / n, x / n, y / n, z / n
    for i in range(dx.shape[0] - 3):
        g[i] += dx[3 + i]


@_jit
def _joseph(P, K, HP, S, m):
    """The Joseph form for an H whose columns past the third are zero, expanded:
    ``(I - K H) P (I - K H)^T + K R K^T = P - K HP - (K HP)^T + K S K^T`` with ``HP = H P``
    (m, n) and ``S = H P H^T + R`` (m, m), for any gain K (n, m): O(m n^2)."""
    n = P.shape[0]
    KHP = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            s = 0.0
            for k in range(m):
                s += K[i, k] * HP[k, j]
            KHP[i, j] = s
    KS = np.empty((n, m))
    for i in range(n):
        for j in range(m):
            s = 0.0
            for k in range(m):
                s += K[i, k] * S[k, j]
            KS[i, j] = s
    for i in range(n):
        for j in range(i, n):
            s = 0.0
            for k in range(m):
                s += KS[i, k] * K[j, k]
            v = P[i, j] - KHP[i, j] - KHP[j, i] + s
            w = P[j, i] - KHP[j, i] - KHP[i, j] + s
            P[i, j] = P[j, i] = 0.5 * (v + w)


@_jit
def _vector_core(q, g, P, z, v, s, Rn, gate, out):
    n = P.shape[0]
    nu = np.empty(3)
    for i in range(3):
        nu[i] = z[i] - s * v[i]
    H = np.zeros((3, 3))  # its first three columns, the others are zero
    H[0, 1], H[0, 2] = -s * v[2], s * v[1]
    H[1, 0], H[1, 2] = s * v[2], -s * v[0]
    H[2, 0], H[2, 1] = -s * v[1], s * v[0]
    PHt = np.empty((n, 3))
    for i in range(n):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += P[i, k] * H[j, k]
            PHt[i, j] = acc
    S = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            acc = Rn[i, j]
            for k in range(3):
                acc += H[i, k] * PHt[k, j]
            S[i, j] = acc
    # Cholesky S = L L^T
    L = np.zeros((3, 3))
    for j in range(3):
        acc = S[j, j]
        for k in range(j):
            acc -= L[j, k] * L[j, k]
        if not acc > 0.0:
            out[0] = math.inf
            out[1] = UNUSABLE
            return
        L[j, j] = math.sqrt(acc)
        for i in range(j + 1, 3):
            acc = S[i, j]
            for k in range(j):
                acc -= L[i, k] * L[j, k]
            L[i, j] = acc / L[j, j]
    y = np.empty(3)
    nis = 0.0
    for i in range(3):
        acc = nu[i]
        for k in range(i):
            acc -= L[i, k] * y[k]
        y[i] = acc / L[i, i]
        nis += y[i] * y[i]
    out[0] = nis
    if not nis <= gate:
        out[1] = REJECTED
        return
    # S^-1 = L^-T L^-1
    Li = np.zeros((3, 3))
    for j in range(3):
        Li[j, j] = 1.0 / L[j, j]
        for i in range(j + 1, 3):
            acc = 0.0
            for k in range(j, i):
                acc -= L[i, k] * Li[k, j]
            Li[i, j] = acc / L[i, i]
    Si = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += Li[k, i] * Li[k, j]
            Si[i, j] = acc
    K = np.empty((n, 3))
    for i in range(n):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += PHt[i, k] * Si[k, j]
            K[i, j] = acc
    dx = np.empty(n)
    for i in range(n):
        dx[i] = K[i, 0] * nu[0] + K[i, 1] * nu[1] + K[i, 2] * nu[2]
    HP = np.empty((3, n))
    for i in range(3):
        for j in range(n):
            HP[i, j] = PHt[j, i]
    _joseph(P, K, HP, S, 3)
    _inject(q, g, dx)
    out[1] = ACCEPTED


@_jit
def predict(q, g, P, wx, wy, wz, dt, q_att, q_bias, q_scale):
    n = P.shape[0]
    d0, d1, d2 = 1.0 / (1.0 + g[3]), 1.0 / (1.0 + g[4]), 1.0 / (1.0 + g[5])
    wx = (wx - g[0]) * d0
    wy = (wy - g[1]) * d1
    wz = (wz - g[2]) * d2
    dw, dx, dy, dz = _rotvec(wx * dt, wy * dt, wz * dt)
    w, x, y, z = _qmul(q[0], q[1], q[2], q[3], dw, dx, dy, dz)
    nq = math.sqrt(w * w + x * x + y * y + z * z)
    q[0], q[1], q[2], q[3] = w / nq, x / nq, y / nq, z / nq
    Rd = np.empty((3, 3))
    _qmat(dw, dx, dy, dz, Rd)
    # Phi = [[A, B, C], [0, I, 0], [0, 0, I]], A = Rd^T, B = diag(beta), C = diag(gamma):
    # only the attitude rows of Phi P differ from P's (T), and P's other blocks stay
    beta = np.empty(3)
    gamma = np.empty(3)
    beta[0], beta[1], beta[2] = -dt * d0, -dt * d1, -dt * d2
    gamma[0], gamma[1], gamma[2] = beta[0] * wx, beta[1] * wy, beta[2] * wz
    T = np.empty((3, n))
    for i in range(3):
        for j in range(n):
            s = Rd[0, i] * P[0, j] + Rd[1, i] * P[1, j] + Rd[2, i] * P[2, j]
            s += beta[i] * P[3 + i, j]
            if n > 6:
                s += gamma[i] * P[6 + i, j]
            T[i, j] = s
    A = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            s = Rd[0, j] * T[i, 0] + Rd[1, j] * T[i, 1] + Rd[2, j] * T[i, 2]
            s += beta[j] * T[i, 3 + j]
            if n > 6:
                s += gamma[j] * T[i, 6 + j]
            A[i, j] = s
    for i in range(3):
        for j in range(3):
            P[i, j] = 0.5 * (A[i, j] + A[j, i])
        P[i, i] += q_att[i]
        for j in range(3, n):
            P[i, j] = P[j, i] = T[i, j]
    for i in range(3, 6):
        P[i, i] += q_bias
    for i in range(6, n):
        P[i, i] += q_scale


@_jit
def _to_body(M, R):
    """``R^T M R``: a 3x3 covariance in the reference frame, seen in the body frame."""
    MR = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += M[i, k] * R[k, j]
            MR[i, j] = acc
    out = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += R[k, i] * MR[k, j]
            out[i, j] = acc
    return out


@_jit
def vector_update(q, g, P, zx, zy, zz, par, stats, alpha, gate, out):
    s = par[3]
    r_var = par[4]
    R = np.empty((3, 3))
    _qmat(q[0], q[1], q[2], q[3], R)
    z = np.empty(3)
    z[0], z[1], z[2] = zx, zy, zz
    zn = np.empty(3)
    d = np.empty(3)
    for i in range(3):
        zn[i] = R[i, 0] * zx + R[i, 1] * zy + R[i, 2] * zz
        d[i] = zn[i] - stats[i]
    for i in range(3):
        stats[i] += alpha * d[i]
    C = np.empty((3, 3))
    var = 0.0
    for i in range(3):
        for j in range(3):
            C[i, j] = (1.0 - alpha) * (stats[3 + 3 * i + j] + alpha * d[i] * d[j])
            stats[3 + 3 * i + j] = C[i, j]
        var += C[i, i]
    if stats[16] > 0.0:
        st = 0.0
        for i in range(3):
            e = zn[i] - stats[12 + i]
            st += e * e
        stats[15] += alpha * (st - stats[15])
    for i in range(3):
        stats[12 + i] = zn[i]
    stats[16] = 1.0
    kappa = 1.0
    if stats[15] > 0.0:
        kappa = min(max(math.pi * math.sqrt(var / stats[15]), 1.0), par[5])
    shrink = max(0.0, 1.0 - 3.0 * r_var / var) if var > 0.0 else 0.0
    kappa *= shrink
    # Cb = kappa R^T C R; Rn = r_var I + Cb
    Rn = _to_body(C, R)
    tr = 0.0
    for i in range(3):
        for j in range(3):
            Rn[i, j] *= kappa
        tr += Rn[i, i]
    for i in range(3):
        Rn[i, i] += r_var
    share = min(par[8] * tr / (tr + 3.0 * r_var), 0.99)  # the block means' share
    for i in range(3):
        for j in range(3):
            Rn[i, j] /= 1.0 - share
    out[4] = share
    v = np.empty(3)
    for i in range(3):
        v[i] = R[0, i] * par[0] + R[1, i] * par[1] + R[2, i] * par[2]
    nu2 = 0.0
    for i in range(3):
        e = z[i] - s * v[i]
        nu2 += e * e
    out[2] = nu2
    out[3] = tr
    _vector_core(q, g, P, z, v, s, Rn, gate, out)


@_jit
def block_update(q, g, P, zx, zy, zz, dt, par, blk, share, gate, out):
    T = par[6]
    R = np.empty((3, 3))
    _qmat(q[0], q[1], q[2], q[3], R)
    blk[0] += dt
    u = min(max(blk[0] / T, 0.0), 1.0)
    for i in range(3):
        zn = R[i, 0] * zx + R[i, 1] * zy + R[i, 2] * zz
        blk[1 + i] += zn * dt
        blk[4 + i] += zn * (dt * u)
    blk[7] += dt
    blk[8] += dt * u
    out[0], out[1] = 0.0, PENDING
    if blk[0] < T:
        return
    C = np.eye(3)  # the turn the update gives the reference frame
    if blk[12] > 0.0:  # the rising half of the previous block is there
        w_all = blk[12] + blk[7] - blk[8]
        m = np.empty(3)
        for i in range(3):
            m[i] = (blk[9 + i] + blk[1 + i] - blk[4 + i]) / w_all
        if blk[16] > 0.0:
            blk[26] += 1.0
            w = max(min(1.0, T / par[7]), 1.0 / (blk[26] + 1.0))
            for i in range(3):
                di = m[i] - blk[13 + i]
                for j in range(3):
                    dj = m[j] - blk[13 + j]
                    blk[17 + 3 * i + j] = (1.0 - w) * blk[17 + 3 * i + j] + w * di * dj
        noise = par[4] * dt / T
        tr = 0.0
        for i in range(3):
            blk[13 + i] = m[i]
            tr += blk[17 + 4 * i]
        blk[16] = 1.0
        z = np.empty(3)
        v = np.empty(3)
        s = par[3]
        nu2 = 0.0
        for i in range(3):
            z[i] = R[0, i] * m[0] + R[1, i] * m[1] + R[2, i] * m[2]
            v[i] = R[0, i] * par[0] + R[1, i] * par[1] + R[2, i] * par[2]
            e = z[i] - s * v[i]
            nu2 += e * e
        out[2] = nu2
        out[3] = tr
        if share >= 1e-3:
            Rn = _to_body(blk[17:26].reshape((3, 3)), R)  # R^T (D + noise I) R / share
            for i in range(3):
                Rn[i, i] += noise
                for j in range(3):
                    Rn[i, j] /= share
            _vector_core(q, g, P, z, v, s, Rn, gate, out)
        if out[1] == ACCEPTED:
            Rq = np.empty((3, 3))
            _qmat(q[0], q[1], q[2], q[3], Rq)
            for i in range(3):
                for j in range(3):
                    acc = 0.0
                    for k in range(3):
                        acc += Rq[i, k] * R[j, k]
                    C[i, j] = acc
            for i in range(3):
                blk[13 + i] = C[i, 0] * m[0] + C[i, 1] * m[1] + C[i, 2] * m[2]
    for i in range(3):
        blk[9 + i] = C[i, 0] * blk[4] + C[i, 1] * blk[5] + C[i, 2] * blk[6]
    blk[12] = blk[8]
    for i in range(1, 9):
        blk[i] = 0.0
    blk[0] = blk[0] - T if blk[0] < 2.0 * T else 0.0


@_jit
def mag_update(q, g, P, mx, my, mz, par, gate, out):
    n = P.shape[0]
    ux, uy, uz = par[0], par[1], par[2]
    nx, ny, nz = par[3], par[4], par[5]
    r_rel = par[6]
    R = np.empty((3, 3))
    _qmat(q[0], q[1], q[2], q[3], R)
    norm = math.sqrt(mx * mx + my * my + mz * mz)
    m0 = R[0, 0] * mx + R[0, 1] * my + R[0, 2] * mz
    m1 = R[1, 0] * mx + R[1, 1] * my + R[1, 2] * mz
    m2 = R[2, 0] * mx + R[2, 1] * my + R[2, 2] * mz
    mu = ux * m0 + uy * m1 + uz * m2
    h0, h1, h2 = m0 - mu * ux, m1 - mu * uy, m2 - mu * uz
    h = math.sqrt(h0 * h0 + h1 * h1 + h2 * h2)
    out[2] = norm
    dip = math.atan2(-mu, h)
    out[3] = dip
    out[4] = 0.0
    if not h > 1e-9 * (norm + 1e-300):
        out[0] = math.inf
        out[1] = UNUSABLE
        return
    ub = np.empty(3)
    for i in range(3):
        ub[i] = R[0, i] * ux + R[1, i] * uy + R[2, i] * uz
    if par[7] > 0.0:
        tr = P[0, 0] + P[1, 1] + P[2, 2]
        uPu = 0.0
        for i in range(3):
            for j in range(3):
                uPu += ub[i] * P[i, j] * ub[j]
        tilt_sd = math.sqrt(max(0.0, tr - uPu) / 2.0)
        tol = par[10] + 3.0 * tilt_sd
        if not (abs(norm - par[7]) <= par[8] * par[7] and abs(dip - par[9]) <= tol):
            out[0] = math.inf
            out[1] = OUT_OF_WINDOW
            return
    cx = ny * h2 - nz * h1
    cy = nz * h0 - nx * h2
    cz = nx * h1 - ny * h0
    alpha = math.atan2(ux * cx + uy * cy + uz * cz, nx * h0 + ny * h1 + nz * h2)
    out[4] = alpha
    if abs(alpha - par[12]) > par[13]:  # the field's heading jumped: not the body's
        out[0] = math.inf
        out[1] = OUT_OF_WINDOW
        return
    if par[11] > 0.0 and par[7] > 0.0:  # the direction as a unit vector
        cd, sd = math.cos(par[9]), math.sin(par[9])
        z = np.empty(3)
        z[0], z[1], z[2] = mx / norm, my / norm, mz / norm
        v = np.empty(3)
        for i in range(3):
            v[i] = (
                R[0, i] * (cd * nx - sd * ux)
                + R[1, i] * (cd * ny - sd * uy)
                + R[2, i] * (cd * nz - sd * uz)
            )
        Rn = np.zeros((3, 3))
        for i in range(3):
            Rn[i, i] = r_rel * r_rel
        _vector_core(q, g, P, z, v, 1.0, Rn, gate, out)
        return
    r_var = (r_rel * norm / h) ** 2
    t = -mu / h
    H = np.empty(3)  # its first three columns, the others are zero
    for i in range(3):
        H[i] = -(ub[i] + t * (R[0, i] * nx + R[1, i] * ny + R[2, i] * nz))
    PHt = np.empty(n)
    for i in range(n):
        acc = 0.0
        for k in range(3):
            acc += P[i, k] * H[k]
        PHt[i] = acc
    S = r_var
    for k in range(3):
        S += H[k] * PHt[k]
    if not S > 0.0:
        out[0] = math.inf
        out[1] = UNUSABLE
        return
    nis = alpha * alpha / S
    out[0] = nis
    if not nis <= gate:
        out[1] = REJECTED
        return
    K = np.empty((n, 1))
    pa = (ub[0] * PHt[0] + ub[1] * PHt[1] + ub[2] * PHt[2]) / S
    pb = (ub[0] * PHt[3] + ub[1] * PHt[4] + ub[2] * PHt[5]) / S
    for i in range(3):
        K[i, 0] = ub[i] * pa
        K[3 + i, 0] = ub[i] * pb
    for i in range(6, n):  # the scale errors keep their gain
        K[i, 0] = PHt[i] / S
    dx = np.empty(n)
    for i in range(n):
        dx[i] = K[i, 0] * alpha
    HP = np.empty((1, n))
    for j in range(n):
        HP[0, j] = PHt[j]
    Sm = np.empty((1, 1))
    Sm[0, 0] = S
    _joseph(P, K, HP, Sm, 1)
    _inject(q, g, dx)
    out[1] = ACCEPTED


_COMPILED: SimpleNamespace | None = None


def compiled() -> SimpleNamespace:
    """The kernels, compiled (or loaded from numba's cache) on the first call: call it
    while a model is built, never in a measure's first step, where compiling would look like
    a hang."""
    global _COMPILED
    if _COMPILED is None:
        q, g, P = np.array((1.0, 0.0, 0.0, 0.0)), np.zeros(6), np.eye(9) * 1e-4
        par, blk, out = np.zeros(14), np.zeros(27), np.zeros(5)
        par[0:3] = (0.0, 0.0, 1.0)
        par[13] = np.inf
        predict(q, g, P, 0.0, 0.0, 0.0, 0.01, np.zeros(3), 0.0, 0.0)
        acc_par = np.array((0.0, 0.0, 1.0, 9.8, 0.09, 100.0, 0.01, 1.0, 2.0))
        vector_update(q, g, P, 0.0, 0.0, 9.8, acc_par, np.zeros(17), 0.1, 1.0, out)
        for _ in range(3):
            block_update(q, g, P, 0.0, 0.0, 9.8, 0.01, acc_par, blk, 0.5, 1.0, out)
        mag_update(q, g, P, 0.0, 0.2, -0.4, par, 1.0, out)
        _COMPILED = SimpleNamespace(
            predict=predict,
            vector_update=vector_update,
            block_update=block_update,
            mag_update=mag_update,
        )
    return _COMPILED
