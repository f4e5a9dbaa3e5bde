"""The arithmetic of the multiplicative (error-state) EKF of :mod:`.mekf`, on numpy.

The filter keeps a unit quaternion ``q`` (body -> reference, scalar first), the gyroscope's
calibration ``g`` (6 numbers: its bias ``b = g[0:3]``, rad/s, and its scale errors ``k =
g[3:6]``, relative) and the covariance ``P`` of the error state ``dx = [dtheta, db]`` (6
states: the scale errors are not estimated and stay as they are, 0) or ``[dtheta, db, dk]``
(9 states; the size of ``P`` tells): ``dtheta`` a small rotation in the **body** frame,
``q_true = q * Exp(dtheta)`` (Markley 2003, "Attitude error representations for Kalman
filtering"; Sola 2017, "Quaternion kinematics for the error-state Kalman filter", sections 5
and 7). Every function updates ``q``, ``g`` and ``P`` in place and writes what the caller
needs to decide into ``out``.

- :func:`predict` (Sola eq. 269-270, with a scale factor in the gyroscope's model: Markley &
  Crassidis 2014, "Fundamentals of Spacecraft Attitude Determination and Control", ch. 4
  and 6 (sensor model, calibration states), per axis ``w_m = (1 + k) w + b + n``):
  ``w = (w_m - b) / (1 + k)``, ``q <- q * Exp(w dt)``, ``P <- Phi P Phi^T + Q`` with
  ``Phi = [[Exp(w dt)^T, -D dt, -D W dt], [0, I, 0], [0, 0, I]]`` (``D = diag(1 / (1 +
  k))``, ``W = diag(w)``: the derivatives of ``w`` with respect to ``b`` and ``k``; the
  last block row and column only with 9 states) and ``Q = diag(q_att, q_bias I, q_scale
  I)`` (``q_att`` one variance per gyroscope axis). A scale error is thus seen only while
  the body turns about that axis, as the heading or tilt it accumulates, which the
  magnetometer and accelerometer then observe;
- the accelerometer is fused by two paths, two models of the linear acceleration, one
  right where the other is wrong, which share its information so that together they claim
  no more than the data hold: the block means take the share ``w = tr(Cb) / (tr(Cb) + 3
  r_var)`` of it (``Cb`` the per-sample path's added covariance below: the part of the
  per-sample noise that is motion; 0 when ``par[8]`` is 0, at most 0.99), each sample the
  rest, their noise divided by ``w`` and ``1 - w``. With no motion measured the filter is
  the per-sample one; under a shake that dwarfs the sensor's noise the block means carry it:
- :func:`vector_update`, every sample: a reference vector seen in the body, ``z = s R(q)^T
  r + v`` (``s`` its length, g for the accelerometer): ``H = [s [v x], 0]`` with ``v =
  R^T r``; its noise ``r_var I + R^T C R``, where ``C`` is the covariance of ``R z`` in
  the reference frame, averaged exponentially (weight ``alpha`` per sample, West 1979's
  update): what moves ``z`` there beyond the noise is not the reference vector (for the
  accelerometer: linear acceleration), and it is measured without the filter's own gain.
  ``C`` is first shrunk by the share of its trace the sensor's noise ``3 r_var`` explains
  (that is in ``r_var`` already), then counted ``kappa`` times, the samples per
  independent one: linear acceleration is not white (a shake at f Hz repeats itself), and
  a filter that took each of its samples as independent would follow it. ``kappa = pi
  sqrt(var / var_step)`` (``var`` and ``var_step`` the exponential variances of the vector
  and of its steps from one sample to the next), the sample rate over twice the motion's
  frequency for a sinusoid, clipped to [1, ``par[5]``]. Right for slow or irregular
  motion; for a periodic one it counts the motion's power, most of which the filter's
  slow tilt never sees, and stays 10-20 times too wary;
- :func:`block_update`, once per block of ``T`` s: what tells the tilt is the linear
  acceleration's content at the low frequencies the filter runs at. Each sample is turned
  into the reference frame with the current estimate (there gravity does not move while
  the body turns) and summed; every ``T`` s the triangular mean of the last two blocks (a
  Bartlett window of ``2 T`` s: its side lobes fall as ``1 / f^2``, so a shake above ``1 /
  T`` Hz leaves little in it) is turned back into the body and fused like a sample. Its
  noise is ``R^T D R`` plus the sensor's own noise over the block, ``D`` the covariance of
  the differences of successive means (Allan 1966's two-sample variance, doubled: the
  variance of a mean, times ``1 + 2 rho`` for the 1/4 correlation of overlapping Bartlett
  windows, is ``E[d d^T]``), averaged exponentially over ``tau`` s (the first ones counted
  equally), started from the alignment's spread: it measures, without the filter's own
  gain, what moves the mean beyond gravity. The means are kept in the frame of the
  estimate that made them: an update turns the stored mean and half-block with it, so the
  filter's own corrections are not counted as motion. Right for a shake; slow to correct
  and easily fooled by an acceleration slow enough to change little from one block to the
  next, which it takes for a tilt and a gyroscope bias over several blocks; there the
  per-sample path, whose many small updates follow such a motion and let go of it as soon
  as it turns, holds the estimate;
- :func:`mag_update`, in one of two modes. *Vector*: the field's direction, a unit vector,
  observed as ``R(q)^T m_ref`` like the accelerometer (``m_ref`` from the learnt dip angle
  and ``north``; noise ``r_rel^2`` per axis), so that the magnetometer helps the tilt too
  (it is not disturbed by linear acceleration). *Heading*: the magnetometer's heading,
  correcting the heading only, so that the field cannot tilt the estimate at all: the
  measured field turned into the reference frame,
  its part across ``up``, and the angle ``alpha`` from ``north`` to it about ``up``. To
  first order ``alpha = -(up + tan(dip) north)^T R(q) dtheta``: a tilt error about north
  leaks into the measured heading through the dip angle, and is so accounted for in S;
  the gain is then projected onto the heading axis (the tilt and the x/y bias states are
  "considered", Schmidt 1966: their uncertainty is counted, they are not corrected; the
  Joseph form keeps P consistent with that gain). The scale errors keep their gain: what
  the heading tells of them comes only through their correlation with it, built while the
  body turns. Noise ``(r_rel |m| / |m_h|)^2`` rad^2 (a
  relative field noise seen on the horizontal part). The field's norm and dip angle are
  checked against a window first, and the heading innovation against a step window: a
  field whose heading jumps while the gyroscope saw no turn is a disturbance, whatever
  the filter's own (possibly wide) heading variance would let through.

Updates use the Joseph form ``P = (I - K H) P (I - K H)^T + K R K^T``, then the error is
injected, ``q <- q * Exp(dtheta)``, ``b <- b + db``, ``k <- k + dk``, and ``q`` is
normalised (the reset's covariance Jacobian, ``I - [dtheta/2 x]``, is taken as I: dtheta is small).

:mod:`.kernels_numba` holds the same functions as compiled loops; a test holds the two to
the same numbers.
"""

from __future__ import annotations

import math

import numpy as np

ACC_PARAMS = 9
"""``par`` of :func:`vector_update` and :func:`block_update`: reference vector (3), its
length s, the sensor's noise variance per sample, the largest correlation factor, the
block's length (s), the time (s) over which the covariance of the block means is averaged,
and whether the block means are fused (1) or not (0)."""
STATS = 17
"""``stats`` of :func:`vector_update`: the exponential mean (3) and covariance (3x3, rows) of
the observed vector in the reference frame, the last such vector (3), the exponential
mean of its squared step from one sample to the next (1), and whether there was a last
one (1)."""
BLOCK = 27
"""``blk`` of :func:`block_update`: the time into the block (s); the block's sums of ``R(q)
z dt`` (3) and of ``R(q) z dt u`` (3, ``u`` the fraction of the block gone), of ``dt`` and
of ``dt u``; the previous block's rising sum (3) and its weight (0: none yet); the last
mean (3) and whether there is one; the covariance ``D`` of the means (3x3, rows); the
number of differences folded into ``D``."""
MAG_PARAMS = 14
"""``par`` of :func:`mag_update`: up (3), north (3), r_rel, the field's expected norm (0: no
window) and relative tolerance, its expected dip angle and tolerance (rad; widened by three
standard deviations of the filter's own tilt), the mode (1: the field's direction as a
vector, 0: its heading only), and the step window of the heading innovation: its recent
mean and the largest step from it (rad; inf: none)."""

ACCEPTED, REJECTED, OUT_OF_WINDOW, UNUSABLE, PENDING = 1.0, 0.0, -1.0, -2.0, 2.0
"""Status written to ``out[1]`` of an update: fused, gated out by the chi-square test,
outside the norm/dip window, unusable (field along ``up``, a singular S), or folded into a
block that is not over."""


def rotvec_quat(v: np.ndarray) -> np.ndarray:
    """``Exp(v)``: the unit quaternion of the rotation vector ``v`` (rad)."""
    a = float(np.sqrt(v @ v))
    if a < 1e-8:
        return np.array((1.0, 0.5 * v[0], 0.5 * v[1], 0.5 * v[2])) / math.sqrt(1.0 + 0.25 * a * a)
    s = math.sin(0.5 * a) / a
    return np.array((math.cos(0.5 * a), s * v[0], s * v[1], s * v[2]))


def quat_mul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product ``p * q``."""
    w1, x1, y1, z1 = p
    w2, x2, y2, z2 = q
    return np.array(
        (
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        )
    )


def quat_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion (body -> reference)."""
    w, x, y, z = q
    return np.array(
        (
            (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
            (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
            (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
        )
    )


def skew(v: np.ndarray) -> np.ndarray:
    """``[v x]``: ``skew(v) @ u == cross(v, u)``."""
    return np.array(((0.0, -v[2], v[1]), (v[2], 0.0, -v[0]), (-v[1], v[0], 0.0)))


def _inject(q: np.ndarray, g: np.ndarray, dx: np.ndarray) -> None:
    qn = quat_mul(q, rotvec_quat(dx[:3]))
    q[:] = qn / math.sqrt(float(qn @ qn))
    g[: dx.size - 3] += dx[3:]


def _joseph(P: np.ndarray, K: np.ndarray, H: np.ndarray, r_var: float) -> None:
    A = np.eye(P.shape[0]) - K @ H
    Pn = A @ P @ A.T + r_var * (K @ K.T)
    P[:] = 0.5 * (Pn + Pn.T)


def predict(
    q: np.ndarray,
    g: np.ndarray,
    P: np.ndarray,
    wx: float,
    wy: float,
    wz: float,
    dt: float,
    q_att: np.ndarray,
    q_bias: float,
    q_scale: float,
) -> None:
    """Propagate by ``dt`` s with the measured body rate ``(wx, wy, wz)`` (rad/s); ``q_att``
    (rad^2, one per axis), ``q_bias`` ((rad/s)^2) and ``q_scale`` (1, unused with 6 states)
    are the process noise added over ``dt``."""
    n = P.shape[0]
    d = 1.0 / (1.0 + g[3:6])
    w = np.array((wx - g[0], wy - g[1], wz - g[2])) * d
    dq = rotvec_quat(w * dt)
    qn = quat_mul(q, dq)
    q[:] = qn / math.sqrt(float(qn @ qn))
    Phi = np.eye(n)
    Phi[:3, :3] = quat_matrix(dq).T
    Phi[:3, 3:6] = np.diag(-dt * d)
    if n > 6:
        Phi[:3, 6:9] = np.diag(-dt * d * w)
    Pn = Phi @ P @ Phi.T
    Pn[:3, :3] += np.diag(q_att)
    Pn[3:6, 3:6] += q_bias * np.eye(3)
    if n > 6:
        Pn[6:9, 6:9] += q_scale * np.eye(3)
    P[:] = 0.5 * (Pn + Pn.T)


def _vector_core(
    q: np.ndarray,
    g: np.ndarray,
    P: np.ndarray,
    z: np.ndarray,
    v: np.ndarray,
    s: float,
    Rn: np.ndarray,
    gate: float,
    out: np.ndarray,
) -> None:
    """Fuse ``z`` seen as ``s v`` (``v`` a unit vector in the body frame, ``R(q)^T`` of the
    reference one) with noise covariance ``Rn``: NIS into ``out[0]``, status ``out[1]``."""
    nu = z - s * v
    n = P.shape[0]
    H = np.zeros((3, n))
    H[:, :3] = s * skew(v)
    S = H @ P @ H.T + Rn
    try:
        L = np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        out[0], out[1] = math.inf, UNUSABLE
        return
    y = np.linalg.solve(L, nu)
    out[0] = nis = float(y @ y)
    if not nis <= gate:
        out[1] = REJECTED
        return
    K = np.linalg.solve(S, H @ P).T  # P H^T S^-1 (S and P symmetric)
    dx = K @ nu
    A = np.eye(n) - K @ H
    Pn = A @ P @ A.T + K @ Rn @ K.T
    P[:] = 0.5 * (Pn + Pn.T)
    _inject(q, g, dx)
    out[1] = ACCEPTED


def vector_update(
    q: np.ndarray,
    g: np.ndarray,
    P: np.ndarray,
    zx: float,
    zy: float,
    zz: float,
    par: np.ndarray,
    stats: np.ndarray,
    alpha: float,
    gate: float,
    out: np.ndarray,
) -> None:
    """Fuse ``z`` (body frame) seen as ``par[3] * R(q)^T par[0:3]``, if its NIS is at most
    ``gate``; first fold ``R(q) z`` into ``stats`` with weight ``alpha``. ``out``: NIS,
    status, |innovation|^2, trace of the added covariance ``R^T C R``, and the share ``w`` of
    the information left to :func:`block_update` (this path's noise is divided by ``1 -
    w``)."""
    s, r_var = par[3], par[4]
    Rq = quat_matrix(q)
    z = np.array((zx, zy, zz))
    zn = Rq @ z
    d = zn - stats[0:3]
    stats[0:3] += alpha * d
    C = (1.0 - alpha) * (stats[3:12].reshape(3, 3) + alpha * np.outer(d, d))
    stats[3:12] = C.reshape(9)
    if stats[16] > 0.0:
        step = zn - stats[12:15]
        stats[15] += alpha * (float(step @ step) - stats[15])
    stats[12:15] = zn
    stats[16] = 1.0
    var = float(np.trace(C))
    kappa = 1.0
    if stats[15] > 0.0:
        kappa = min(max(math.pi * math.sqrt(var / stats[15]), 1.0), par[5])
    # the sensor's own noise is in r_var already: only the excess is motion
    shrink = max(0.0, 1.0 - 3.0 * r_var / var) if var > 0.0 else 0.0
    Cb = (kappa * shrink) * (Rq.T @ C @ Rq)
    v = Rq.T @ par[0:3]
    tr = float(np.trace(Cb))
    share = min(par[8] * tr / (tr + 3.0 * r_var), 0.99)  # the block means' share
    Rn = (r_var * np.eye(3) + Cb) / (1.0 - share)
    out[4] = share
    out[2] = float(np.sum((z - s * v) ** 2))
    out[3] = tr
    _vector_core(q, g, P, z, v, s, Rn, gate, out)


def block_update(
    q: np.ndarray,
    g: np.ndarray,
    P: np.ndarray,
    zx: float,
    zy: float,
    zz: float,
    dt: float,
    par: np.ndarray,
    blk: np.ndarray,
    share: float,
    gate: float,
    out: np.ndarray,
) -> None:
    """Fold the sample ``z`` (body frame), which covers the last ``dt`` s, into the block
    sums ``blk`` (see :data:`BLOCK`) turned into the reference frame with the current ``q``;
    at the end of a block of ``par[6]`` s, fuse the triangular mean of the last two blocks,
    seen as ``par[3] * R(q)^T par[0:3]``, with the noise covariance the successive means'
    differences give (averaged over ``par[7]`` s) divided by ``share`` (its share of the
    information, from :func:`vector_update`; below 1e-3 the mean is not fused), if its NIS
    is at most ``gate``. ``out``: NIS, status (``PENDING`` between block ends and when not
    fused), |innovation|^2, the trace of the means' covariance ``D``."""
    T = par[6]
    R = quat_matrix(q)
    zn = R @ np.array((zx, zy, zz))
    blk[0] += dt
    u = min(max(blk[0] / T, 0.0), 1.0)
    blk[1:4] += zn * dt
    blk[4:7] += zn * (dt * u)
    blk[7] += dt
    blk[8] += dt * u
    out[0], out[1] = 0.0, PENDING
    if blk[0] < T:
        return
    C = np.eye(3)  # the turn the update gives the reference frame
    if blk[12] > 0.0:  # the rising half of the previous block is there (not at the start)
        w_all = blk[12] + blk[7] - blk[8]
        m = (blk[9:12] + blk[1:4] - blk[4:7]) / w_all
        D = blk[17:26].reshape(3, 3)
        if blk[16] > 0.0:
            d = m - blk[13:16]
            blk[26] += 1.0
            w = max(min(1.0, T / par[7]), 1.0 / (blk[26] + 1.0))
            D = (1.0 - w) * D + w * np.outer(d, d)
            blk[17:26] = D.reshape(9)
        blk[13:16] = m
        blk[16] = 1.0
        z = R.T @ m
        v = R.T @ par[0:3]
        out[2] = float(np.sum((z - par[3] * v) ** 2))
        out[3] = float(np.trace(D))
        if share >= 1e-3:
            Rn = (R.T @ (D + (par[4] * dt / T) * np.eye(3)) @ R) / share
            _vector_core(q, g, P, z, v, par[3], Rn, gate, out)
        if out[1] == ACCEPTED:
            C = quat_matrix(q) @ R.T
            blk[13:16] = C @ m
    blk[9:12] = C @ blk[4:7]
    blk[12] = blk[8]
    blk[1:9] = 0.0
    blk[0] = blk[0] - T if blk[0] < 2.0 * T else 0.0


def mag_update(
    q: np.ndarray,
    g: np.ndarray,
    P: np.ndarray,
    mx: float,
    my: float,
    mz: float,
    par: np.ndarray,
    gate: float,
    out: np.ndarray,
) -> None:
    """Fuse the field ``m`` (body frame), if its norm and dip angle lie in their windows
    (``par``, see :data:`MAG_PARAMS`) and its NIS is at most ``gate``: its direction as a
    unit vector (``par[11]`` = 1, once the dip is known) or its heading only. ``out``: NIS,
    status, |m|, dip angle (rad, positive below the horizontal), alpha (rad)."""
    up, north = par[0:3], par[3:6]
    r_rel = par[6]
    R = quat_matrix(q)
    m = np.array((mx, my, mz))
    norm = float(np.sqrt(m @ m))
    mn = R @ m
    mu = float(up @ mn)
    mh = mn - mu * up
    h = float(np.sqrt(mh @ mh))
    out[2] = norm
    out[3] = dip = math.atan2(-mu, h)
    out[4] = 0.0
    if not h > 1e-9 * (norm + 1e-300):
        out[0], out[1] = math.inf, UNUSABLE
        return
    ub = R.T @ up  # the heading axis in the body frame
    if par[7] > 0.0:
        Pa = P[:3, :3]
        tilt_sd = math.sqrt(max(0.0, float(np.trace(Pa)) - float(ub @ Pa @ ub)) / 2.0)
        tol = par[10] + 3.0 * tilt_sd
        if not (abs(norm - par[7]) <= par[8] * par[7] and abs(dip - par[9]) <= tol):
            out[0], out[1] = math.inf, OUT_OF_WINDOW
            return
    alpha = math.atan2(float(up @ np.cross(north, mh)), float(north @ mh))
    out[4] = alpha
    if abs(alpha - par[12]) > par[13]:  # the field's heading jumped: not the body's
        out[0], out[1] = math.inf, OUT_OF_WINDOW
        return
    if par[11] > 0.0 and par[7] > 0.0:  # the direction as a unit vector
        mref = math.cos(par[9]) * north - math.sin(par[9]) * up
        _vector_core(q, g, P, m / norm, R.T @ mref, 1.0, r_rel * r_rel * np.eye(3), gate, out)
        return
    r_var = (r_rel * norm / h) ** 2
    H = np.zeros((1, P.shape[0]))
    H[0, :3] = -(ub + (-mu / h) * (R.T @ north))
    S = float((H @ P @ H.T)[0, 0]) + r_var
    if not S > 0.0:
        out[0], out[1] = math.inf, UNUSABLE
        return
    out[0] = nis = alpha * alpha / S
    if not nis <= gate:
        out[1] = REJECTED
        return
    K = (P @ H.T) / S
    Pu = np.outer(ub, ub)
    K[:3] = Pu @ K[:3]
    K[3:6] = Pu @ K[3:6]  # (the scale errors' gain is kept: only turns inform them)
    dx = K[:, 0] * alpha
    _joseph(P, K, H, r_var)
    _inject(q, g, dx)
    out[1] = ACCEPTED
