"""Our AHRS: a multiplicative (error-state) EKF on the unit quaternion with gyroscope-bias
states; the accelerometer and the magnetometer are vector observations, each gated.

Beyond the thesis's filter (e11, :mod:`.thesis`), whose state is the quaternion itself and
whose observation is the quaternion the accelerometer and magnetometer give together:

- the error is a 3-vector rotation (no unit-norm constraint fought by the update, no sign
  ambiguity), and the gyroscope's bias is estimated (6 error states; Markley 2003) and its
  scale errors, one per axis (9 error states, unless ``scale_std0`` is 0; Markley &
  Crassidis 2014, ch. 6): while the magnetometer is refused the heading rides on the
  gyroscope alone, and a MEMS gyroscope's 1-3 % scale error turns each full turn into
  4-11 deg of heading; the scale errors are learnt while the board turns with the
  magnetometer and accelerometer trusted, and drift by ``scale_walk``;
- prediction runs at every gyroscope sample (trapezoidal rate between two samples), with a
  process noise that grows with the rate: what is left of the gyroscope's scale error and
  its cross-axis sensitivity turn a fast rotation into an angle error (``gyro_scale``);
- the accelerometer observes gravity as a vector (its magnitude too), under two models of
  the linear acceleration the body undergoes, which share its information. Every sample,
  with a covariance that adapts to the linear acceleration: the covariance of the
  accelerometer turned into the reference frame, averaged over ``ext_tau`` s and counted
  for its correlation time, is added to it (gravity does not move there, linear
  acceleration does; in the spirit of Suh 2010's external-acceleration handling, but
  measured without the filter's own gain, so a filter that follows a shake cannot talk
  itself into trusting it). And every ``acc_block`` s, as the mean of the last two blocks
  under a triangular window in the reference frame, with the covariance the successive
  means' differences show (averaged over ``block_tau`` s): what tells the tilt is the
  linear acceleration at the low frequencies the filter runs at, and a shake at a few Hz
  averages out of such a mean. The block means take the share of the information that the
  per-sample path counts as motion (none at rest, nearly all in a hard shake). Alone, the
  per-sample path is 10-20 times too wary of a 3 Hz shake (its power is large, its mean
  small), so the tilt's variance, and through the dip angle the heading's, stays wide and
  the magnetometer cannot hold the heading (worst of 30 shaking runs 0.92 deg; 0.29 with
  the block means); alone, the block means are slow to correct and take a slow
  acceleration for a tilt and a gyroscope bias (``target3d``: 1.38 deg mean against 0.55).
  A sample or mean whose innovation fails the chi-square test at ``acc_gate`` (a jolt) is
  rejected;
- the magnetometer observes its heading only (``mag_mode = "heading"``, the default: no
  field can tilt the estimate) or the field's direction (``"vector"``: it helps the tilt
  too, and is not disturbed by linear acceleration), and is rejected when the field's norm
  or dip angle leaves its window around the values learnt from the accepted samples (a
  magnetic disturbance), when its heading innovation jumps away from its recent values by
  more than ``mag_step_sigma`` times their jitter (a disturbance that keeps norm and dip,
  while the filter's heading variance is wide, as in a shake), or when its innovation fails
  the chi-square test at ``mag_gate``. After ``reacquire_s`` s of refusals (the field has
  changed for good, or the heading is wrong) the next sample is taken whatever it says, the
  heading's variance reopened, and the norm and dip are learnt again;
- the filter starts with a coarse alignment (as an inertial navigator does): over the first
  ``align_s`` s the accelerometer and magnetometer samples are turned into the first
  sample's frame with the gyroscope and averaged; the attitude of the means (TRIAD, thesis
  eq. 7.1), turned on to the last sample, starts the filter, with a covariance and a linear
  acceleration power taken from the samples' spread. A board that starts moving (shaken,
  carried) thus starts neither from one jolted sample nor overconfident.

Units: rad, rad/s, m/s^2; the magnetometer in any unit (only its direction and the ratio
to its learnt norm are used). Backends: the arithmetic (:mod:`.kernels`) runs on numpy or,
when ``hera.estimation``'s backend is numba, as compiled loops (:mod:`.kernels_numba`),
with the same results.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from hera.estimation import active_backend, chi2_ppf, matrix_to_quat
from hera.models.ahrs import kernels as npk
from hera.models.ahrs.frames import Reference, triad_quat


@dataclass(frozen=True)
class MekfSettings:
    """The filter's noise model and gates (defaults suit a MEMS IMU such as the LSM9DS1 of
    the Pmod NAV, with a margin over its data sheet figures).

    ``gyro_noise``: angle random walk (rad/sqrt(s)), or one per axis; ``gyro_scale``:
    relative scale error of the gyroscope left unestimated (1: 100 %), a white noise on the
    angle growing with the rate (cross-axis sensitivity, and the scale error itself when it
    is not estimated); ``scale_std0``: initial standard deviation of each axis's scale
    error, estimated (1: 100 %; 0: not estimated, 6 error states; a MEMS gyroscope's data
    sheet gives 1-3 %); ``scale_walk``: its random walk (1/sqrt(s)); ``bias_walk``: bias
    random walk (rad/s/sqrt(s)); ``acc_noise``: accelerometer noise and residual bias (m/s^2,
    per axis);
    ``gravity``: m/s^2; ``mag_noise``: magnetometer noise and calibration residual relative
    to the field; ``acc_gate`` / ``mag_gate``: chi-square gate probabilities; ``ext_tau``:
    s over which the linear acceleration's power is averaged; ``ext_kappa_max``: the
    largest correlation factor of that power (samples per independent one);
    ``acc_block``: s of one block of the accelerometer's block means (the mean fused spans
    two; 0: none, the per-sample path takes all the information); ``block_tau``: s over which
    the covariance of the block means is averaged; ``mag_norm_tol``: relative
    window of the field's norm; ``mag_dip_tol_deg``: window of its dip angle (deg);
    ``ref_tau``: s over which the field's norm and dip are learnt; ``reacquire_s``: s of
    rejected headings before the heading is taken again; ``align_s``: s of coarse
    alignment; ``bias_std0``: initial standard deviation of the gyroscope's bias (rad/s);
    ``gyro_trapezoid``: a gyroscope sample is the rate at its time, so the rate over the
    interval to it is the mean of the two ends (True), or it is already the mean rate since
    the previous sample (False: an integrating gyroscope, or data made by differencing
    orientations, like the ``ahrs`` package's ``Sensors``); ``mag_mode``: ``"vector"``
    (the field's direction corrects tilt and heading) or ``"heading"`` (the heading only:
    no magnetic field can tilt the estimate, whatever gets past the gates); ``dip_deg``:
    the field's dip angle below the horizontal (deg; from a geomagnetic model: about 65 deg
    in Belgium), or None to learn it with the norm; ``mag_step_sigma``: the step window of
    the heading innovation, in standard deviations of its recent jitter (exponential over
    ``step_tau`` s) and of the magnetometer's noise (0: none).
    """

    gyro_noise: float | tuple[float, float, float] = 5e-4
    gyro_scale: float = 0.005
    scale_std0: float = 0.03
    scale_walk: float = 1e-4
    bias_walk: float = 2e-4
    acc_noise: float = 0.3
    gravity: float = 9.81
    mag_noise: float = 0.01
    acc_gate: float = 0.9999
    mag_gate: float = 0.9999
    ext_tau: float = 0.5
    acc_block: float = 1.0
    block_tau: float = 2.0
    ext_kappa_max: float = 100.0
    mag_norm_tol: float = 0.08
    mag_dip_tol_deg: float = 4.0
    ref_tau: float = 30.0
    reacquire_s: float = 20.0
    align_s: float = 1.0
    bias_std0: float = 0.01
    gyro_trapezoid: bool = True
    mag_mode: str = "heading"
    mag_step_sigma: float = 5.0
    step_tau: float = 1.0
    dip_deg: float | None = None

    def __post_init__(self) -> None:
        g = self.gyro_noise
        if isinstance(g, (list, tuple)):
            if len(g) != 3 or not all(
                isinstance(v, (int, float)) and math.isfinite(v) and v > 0 for v in g
            ):
                raise ValueError(f"gyro_noise must be a number > 0 or 3 of them, got {g!r}")
            object.__setattr__(self, "gyro_noise", tuple(float(v) for v in g))
        elif not (isinstance(g, (int, float)) and math.isfinite(g) and g > 0):
            raise ValueError(f"gyro_noise must be a number > 0 or 3 of them, got {g!r}")
        for name in (
            "bias_walk",
            "acc_noise",
            "gravity",
            "mag_noise",
            "ext_tau",
            "block_tau",
            "step_tau",
        ):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a number > 0, got {v!r}")
        if not (isinstance(self.scale_std0, (int, float)) and 0.0 <= self.scale_std0 < 0.5):
            raise ValueError(f"scale_std0 must be a number in [0, 0.5), got {self.scale_std0!r}")
        if self.mag_mode not in ("vector", "heading"):
            raise ValueError(f"mag_mode must be 'vector' or 'heading', got {self.mag_mode!r}")
        for name in ("acc_gate", "mag_gate"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0.0 < v < 1.0):
                raise ValueError(f"{name} must be a probability in (0, 1), got {v!r}")
        for name in (
            "acc_block",
            "gyro_scale",
            "scale_std0",
            "scale_walk",
            "mag_norm_tol",
            "mag_dip_tol_deg",
            "ref_tau",
            "reacquire_s",
            "align_s",
            "bias_std0",
            "mag_step_sigma",
        ):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be a number >= 0, got {v!r}")


def _kernels() -> Any:
    """The kernel module of the active ``hera.estimation`` backend."""
    if active_backend() == "numba":
        from hera.models.ahrs import kernels_numba

        return kernels_numba.compiled()
    return npk


class Mekf:
    """The multiplicative EKF (see module docstring). Feed it samples in time order with
    :meth:`step`; read :attr:`q`, :attr:`b` (the gyroscope's bias, rad/s), :attr:`scale`
    (its scale errors, relative), :meth:`std_deg` and the :attr:`counters`."""

    def __init__(self, ref: Reference, settings: MekfSettings | None = None) -> None:
        self.ref = ref
        self.s = s = settings or MekfSettings()
        self.k = _kernels()
        self.q = np.array((1.0, 0.0, 0.0, 0.0))
        self.g = np.zeros(6)  # the gyroscope's calibration: bias (rad/s), scale errors
        self.b = self.g[0:3]
        self.scale = self.g[3:6]
        self.P = np.zeros((9, 9) if s.scale_std0 > 0 else (6, 6))
        self.t: float | None = None
        self._w = (0.0, 0.0, 0.0)
        self.acc_par = np.zeros(npk.ACC_PARAMS)
        self.acc_par[0:3] = ref.up
        self.acc_par[3] = s.gravity
        self.acc_par[4] = s.acc_noise**2
        self.acc_par[5] = s.ext_kappa_max
        self.acc_par[6] = s.acc_block
        self.acc_par[7] = s.block_tau
        self.acc_par[8] = 1.0 if s.acc_block > 0 else 0.0  # the block means are fused
        self.ext = 0.0  # linear acceleration's power per axis, (m/s^2)^2 (a diagnostic)
        self.mag_par = np.zeros(npk.MAG_PARAMS)
        self.mag_par[0:3] = ref.up
        self.mag_par[3:6] = ref.north
        self.mag_par[6] = s.mag_noise
        self.mag_par[8] = s.mag_norm_tol
        self.mag_par[10] = math.radians(s.mag_dip_tol_deg)
        self.mag_par[11] = 1.0 if s.mag_mode == "vector" else 0.0
        self.mag_par[13] = math.inf  # no step window until the innovations are known
        self._alpha_mean = 0.0  # heading innovations of accepted samples: mean, variance
        self._alpha_var: float | None = None
        self.out = np.zeros(5)
        g = s.gyro_noise
        self._arw2 = tuple(float(x) ** 2 for x in (g if isinstance(g, (tuple, list)) else (g,) * 3))
        self._q_att = np.zeros(3)
        self.acc_gate = chi2_ppf(s.acc_gate, 3)
        self.mag_gate = chi2_ppf(s.mag_gate, 3 if s.mag_mode == "vector" else 1)
        self.acc_stats = np.zeros(npk.STATS)  # acc in the reference frame: mean, covariance
        self.acc_blk = np.zeros(npk.BLOCK)  # the accelerometer's block sums and means
        self.mag_norm: float | None = None
        self.mag_dip: float | None = None
        self._mag_refused_since: float | None = None
        self._alignment: _Alignment | None = None
        self.counters = {
            "acc_fused": 0,
            "acc_rejected": 0,
            "block_fused": 0,
            "block_rejected": 0,
            "mag_fused": 0,
            "mag_rejected": 0,
            "mag_disturbed": 0,
            "reacquired": 0,
            "skipped": 0,
        }

    @property
    def started(self) -> bool:
        """Whether the coarse alignment is over (the estimate means something)."""
        return self.t is not None

    def _align(self, t: float, acc: Any, gyro: Any, mag: Any) -> bool:
        """One sample of the coarse alignment; starts the filter when ``align_s`` is over."""
        al = self._alignment
        if al is None:
            al = self._alignment = _Alignment(t, gyro)
        elif not al.add(t, acc, gyro, mag):
            self._alignment = None  # time went backwards: start over
            return False
        if mag is not None:
            al.sample(acc, mag)
        if t - al.t0 < self.s.align_s or al.n < 2:
            return False
        start = al.result(self.ref, self.s)
        self._alignment = None
        if start is None:
            return False
        q, P, stats, D, norm, dip = start
        self.q[:] = q
        self.g[:] = 0.0
        self.P[:] = 0.0
        self.P[:6, :6] = P
        if self.P.shape[0] > 6:
            self.P[6:, 6:] = self.s.scale_std0**2 * np.eye(3)
        self.acc_stats[:] = stats
        self.acc_blk[:] = 0.0
        self.acc_blk[17:26] = D.reshape(9)
        self.mag_norm, self.mag_dip = norm, dip
        self.t = t
        self._w = (float(gyro[0]), float(gyro[1]), float(gyro[2]))
        return True

    def step(
        self,
        t: float,
        acc: tuple[float, float, float],
        gyro: tuple[float, float, float],
        mag: tuple[float, float, float] | None,
    ) -> bool:
        """Predict to time ``t`` (s) with the gyroscope (rad/s), then fuse the accelerometer
        (m/s^2) and the magnetometer (any unit, or None). False if the sample was not used
        (older than the filter, or the first sample could not start it)."""
        if self.t is None:
            return self._align(t, acc, gyro, mag)
        dt = t - self.t
        if dt < 0:
            self.counters["skipped"] += 1
            return False
        k, s = self.k, self.s
        if dt > 0:
            w0 = self._w if s.gyro_trapezoid else gyro
            wx, wy, wz = 0.5 * (w0[0] + gyro[0]), 0.5 * (w0[1] + gyro[1]), 0.5 * (w0[2] + gyro[2])
            scale = (s.gyro_scale * s.gyro_scale) * (wx * wx + wy * wy + wz * wz)
            qa, arw = self._q_att, self._arw2
            qa[0] = (arw[0] + scale) * dt
            qa[1] = (arw[1] + scale) * dt
            qa[2] = (arw[2] + scale) * dt
            k.predict(self.q, self.g, self.P, wx, wy, wz, dt, qa, s.bias_walk**2 * dt,
                      s.scale_walk**2 * dt)  # fmt: skip
            self.t = t
        self._w = (float(gyro[0]), float(gyro[1]), float(gyro[2]))
        self._acc(acc, dt)
        if mag is not None:
            self._mag(t, mag, dt)
        return True

    def _acc(self, acc: tuple[float, float, float], dt: float) -> None:
        s, out = self.s, self.out
        a = min(1.0, dt / s.ext_tau) if dt > 0 else 0.0
        self.k.vector_update(self.q, self.g, self.P, acc[0], acc[1], acc[2], self.acc_par,
                             self.acc_stats, a, self.acc_gate, out)  # fmt: skip
        self.ext = float(out[3]) / 3.0
        share = float(out[4])
        if out[1] == npk.ACCEPTED:
            self.counters["acc_fused"] += 1
        else:
            self.counters["acc_rejected"] += 1
        if not (dt > 0 and s.acc_block > 0):
            return
        self.k.block_update(self.q, self.g, self.P, acc[0], acc[1], acc[2], dt, self.acc_par,
                            self.acc_blk, share, self.acc_gate, out)  # fmt: skip
        status = out[1]
        if status != npk.PENDING:
            self.counters["block_fused" if status == npk.ACCEPTED else "block_rejected"] += 1

    def _mag(self, t: float, mag: tuple[float, float, float], dt: float) -> None:
        s, out, par = self.s, self.out, self.mag_par
        since = self._mag_refused_since
        reacquire = since is not None and t - since >= s.reacquire_s
        gate = self.mag_gate
        if reacquire:  # refused for long: the field changed for good, or the heading is wrong
            gate = math.inf
            self._mag_refused_since = since = t  # one reopening per reacquire_s
            self.mag_norm = self.mag_dip = None
            u = self.ref_up_body()
            self.P[:3, :3] += np.outer(u, u) * math.pi**2
        learnt = self.mag_norm is not None
        if learnt:
            par[7] = self.mag_norm
            par[9] = self.mag_dip if s.dip_deg is None else math.radians(s.dip_deg)
        else:
            par[7] = 0.0  # nothing learnt yet: any field
        var = self._alpha_var
        if reacquire or var is None or not s.mag_step_sigma:
            par[13] = math.inf
        else:  # the step window: a jump of the field's heading the noise cannot explain
            r = s.mag_noise / max(math.cos(par[9]), 0.1) if learnt else s.mag_noise
            par[12] = self._alpha_mean
            par[13] = s.mag_step_sigma * math.sqrt(var + r * r)
        self.k.mag_update(self.q, self.g, self.P, mag[0], mag[1], mag[2], par, gate, out)
        status = out[1]
        if status == npk.ACCEPTED:
            self.counters["mag_fused"] += 1
            if reacquire:
                self.counters["reacquired"] += 1
            self._mag_refused_since = None
            alpha = float(out[4])
            if reacquire or self._alpha_var is None:
                self._alpha_mean, self._alpha_var = alpha, 0.0
            else:
                w = min(1.0, dt / s.step_tau) if dt > 0 else 0.0
                d = alpha - self._alpha_mean
                self._alpha_mean += w * d
                self._alpha_var = (1.0 - w) * (self._alpha_var + w * d * d)
            if not learnt:
                self.mag_norm, self.mag_dip = float(out[2]), float(out[3])
            else:
                a = min(1.0, dt / s.ref_tau) if dt > 0 else 0.0
                self.mag_norm += a * (float(out[2]) - self.mag_norm)
                self.mag_dip += a * (float(out[3]) - self.mag_dip)
        else:
            self.counters["mag_rejected" if status == npk.REJECTED else "mag_disturbed"] += 1
            if since is None:
                self._mag_refused_since = t

    def ref_up_body(self) -> np.ndarray:
        """The reference ``up`` seen in the body frame, ``R(q)^T up``."""
        return npk.quat_matrix(self.q).T @ self.ref.up

    def std_deg(self) -> tuple[float, float]:
        """Standard deviations (deg) of the tilt (the two axes across ``up``) and of the
        heading (about ``up``), from P."""
        R = npk.quat_matrix(self.q)
        Pw = R @ self.P[:3, :3] @ R.T  # the attitude error in the reference frame
        u = self.ref.up
        var_h = float(u @ Pw @ u)
        var_t = max(0.0, float(np.trace(Pw)) - var_h)
        return math.degrees(math.sqrt(var_t / 2.0)), math.degrees(math.sqrt(max(var_h, 0.0)))


class _Alignment:
    """Coarse alignment: samples turned into the first sample's body frame with the
    gyroscope (trapezoidal rates, bias not yet known) and summed."""

    def __init__(self, t: float, gyro: Any) -> None:
        self.t0 = self.t = t
        self.w = np.array(gyro, dtype=np.float64)
        self.R = np.eye(3)  # body now -> body at t0
        self.n = 0
        self.sa = np.zeros(3)
        self.saa = np.zeros((3, 3))
        self.sm = np.zeros(3)
        self.last: np.ndarray | None = None
        self.steps = 0.0  # sum of the squared steps between successive samples

    def add(self, t: float, acc: Any, gyro: Any, mag: Any) -> bool:
        """Turn the frame on to time ``t``; False if ``t`` is older than the last sample."""
        dt = t - self.t
        if dt < 0:
            return False
        w = np.array(gyro, dtype=np.float64)
        dq = npk.rotvec_quat(0.5 * (self.w + w) * dt)
        self.R = self.R @ npk.quat_matrix(dq)
        self.w, self.t = w, t
        return True

    def sample(self, acc: Any, mag: Any) -> None:
        a = self.R @ np.asarray(acc, dtype=np.float64)
        if self.last is not None:
            d = a - self.last
            self.steps += float(d @ d)
        self.last = a
        self.sa += a
        self.saa += np.outer(a, a)
        self.sm += self.R @ np.asarray(mag, dtype=np.float64)
        self.n += 1

    def result(
        self, ref: Reference, s: MekfSettings
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, float] | None:
        """(q now, P, the accelerometer's statistics in the reference frame, the first
        covariance ``D`` of its block means there, the field's norm and dip angle), or None
        when the means give no attitude. The tilt's variance is the mean's: the samples'
        spread over the number of independent samples among them (their number over their
        correlation factor ``kappa = pi sqrt(var / var_step)``, ``var`` and ``var_step`` the
        variances of the vector and of its steps from one sample to the next: the sample
        rate over twice the motion's frequency for a sinusoid, clipped to [1,
        ``ext_kappa_max``]; a periodic motion is not white); the heading's adds the tilt's
        leak through the dip angle. ``D`` is the spread beyond the sensor's noise as one
        block's mean would see it were it white with that correlation (``kappa`` samples'
        worth each): wary, until the filter has measured the means' own differences."""
        n = self.n
        a, m = self.sa / n, self.sm / n
        q0 = triad_quat(a, m, ref)
        if q0 is None:
            return None
        q = npk.quat_mul(q0, matrix_to_quat(self.R))
        cov = self.saa / n - np.outer(a, a)  # in the first sample's frame
        var = float(np.trace(cov))
        kappa = 1.0
        if self.steps > 0.0:
            kappa = min(max(math.pi * math.sqrt(var * (n - 1) / self.steps), 1.0), s.ext_kappa_max)
        g2 = float(a @ a)
        tilt_var = (s.acc_noise**2 + var / 3.0) * kappa / (g2 * n)
        up = a / math.sqrt(g2)
        mu = float(m @ up)
        norm = float(np.linalg.norm(m))
        h = math.sqrt(max(norm * norm - mu * mu, 1e-300))
        dip = math.atan2(-mu, h)
        head_var = (s.mag_noise * norm / h) ** 2 + tilt_var * (mu / h) ** 2
        Rq = npk.quat_matrix(q)
        u = Rq.T @ ref.up  # the heading axis in the body frame
        P = np.zeros((6, 6))
        P[:3, :3] = tilt_var * (np.eye(3) - np.outer(u, u)) + head_var * np.outer(u, u)
        P[3:, 3:] = s.bias_std0**2 * np.eye(3)
        R0 = npk.quat_matrix(q0)  # the first sample's frame -> reference
        r_var = s.acc_noise**2
        shrink = max(0.0, 1.0 - 3.0 * r_var / var) if var > 0.0 else 0.0
        dt = (self.t - self.t0) / max(n - 1, 1)  # the mean sample interval
        per_block = kappa * shrink * dt / s.acc_block if s.acc_block > 0 else 0.0
        D = per_block * (R0 @ cov @ R0.T)
        stats = np.zeros(npk.STATS)
        stats[0:3] = R0 @ a
        stats[3:12] = (R0 @ cov @ R0.T).reshape(9)
        stats[15] = self.steps / (n - 1) if n > 1 else 0.0
        return q / np.linalg.norm(q), P, stats, D, norm, dip
