"""Tracking a toy train on a circle: the model ladder e4 .. e9 of thesis ch. 6.

One extended Kalman filter whose state and observation rows depend on the rung:

====  ====================  ===================  ========================================
rung  name                  state                observation blocks (one per sample)
====  ====================  ===================  ========================================
e4    ``omega_acc``         [w]                  acc: a_c = r w |w| (eq. 6.1)
e5    ``track_bilat``       [x, y, th, w]        acc; bilateration [x, y]
e6    ``track_sonar``       [x, y, th, w]        acc; each sonar range (eqs. 6.2-6.3)
e7    ``track_gyro``        [x, y, th, w]        acc; gyro g = w; sonars (eq. 6.4)
e8    ``track_radius``      [x, y, th, w, r]     acc a_c = r w |w|; gyro; sonars (eq. 6.5)
e9    ``track_mag``         [x, y, th, w, r]     + magnetometer heading th (eqs. 6.6-6.9)
====  ====================  ===================  ========================================

Process model (eq. 6.3, 6.5), with th' = th + w dt: x' = c_x + r cos th', y' = c_y + r sin th',
w' = w, r' = r. Units: m, rad, rad/s, m/s^2. The thesis used Q = 0; we add a small process
noise (``q_theta``, ``q_omega``, ``q_radius`` per second, ``q_xy`` per step) so that the
filter keeps listening to its sensors and P stays positive definite (x, y are functions of
th and r).

Beyond the thesis (what real rigs need; README "Train tracking"):

- Both directions. The accelerometer's y axis points left of the direction of travel, so it
  reads a_y = r w |w| (negative when the train runs clockwise): the row is signed. A w that
  strays to the wrong sign is mirrored (a_c cannot pull w through 0, where its slope is 0);
  the direction is the gyroscope's sign, else the branch grid's, else the accelerometer's
  (a sequential test on the sign of a_y), else ``omega0``'s.
- The sonar sees the nearest *surface* of the train (a capsule of ``target_length`` and
  ``target_radius`` along the direction of travel), not its centre; readings whose
  predicted nearest point lies at the edge of a beam are skipped.
- Branches. A range is ambiguous in theta: the EKF does not fuse a sonar (or bilateration)
  row until a :class:`~hera.models.train.branches.BranchGrid` of theta hypotheses, weighed
  by every reading (robustly: far-side echoes, bounces), favours one branch; the EKF's theta
  is then *seeded* from it. While *acquiring* (seeded, not locked) the sonar rows use a wide
  variance and may move only x, y and theta: w, r and the scale states are Schmidt
  *consider* states of those rows (:mod:`hera.estimation.consider`), so a wrong echo cannot
  drag them. It *locks* (the sonar's own variance, every state learns) once ``lock_count``
  successive innovations are consistent; it unlocks after ``unlock_count`` gated-out
  readings in a row, or when the grid confidently favours a branch over 45 deg away (then
  re-seeded: re-acquisition).
- Hidden states (not output columns): the gyroscope's scale k (g = (1 + k) w), learnt once
  locked for FREEZE_LAPS (before, a consider state of every row); in e9 the magnetometer's
  heading offset b (heading = th + b: the train is never placed exactly "at 0 deg").
- The accelerometer of a real rig is off (bias, misalignment: a_c / w^2 by up to 20 %):
  ``acc_gain_var0`` adds its gain error c (a = (1 + c) r w |w|) as a consider state of
  every row, never learnt: it keeps the filter from trusting a_c's w more than its bias
  allows (learning c was tried: it changed nothing measurable, the ranges' progression
  outweighs a_c once locked).

dt always comes from the samples' measurement times: samples must be fed in time order; a
sample older than the filter by more than ``max_lag`` s is dropped (counted in ``late``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hera.estimation import (
    ExtendedKalmanFilter,
    Observations,
    angle_residual,
    numerical_jacobian,
)
from hera.models.train.beams import in_cone, unit_directions
from hera.models.train.branches import Branch, BranchGrid, Track, wrap
from hera.store import Sample

RUNGS = ("e4", "e5", "e6", "e7", "e8", "e9")
X, Y, TH, W, R = 0, 1, 2, 3, 4


@dataclass(frozen=True)
class Rung:
    """What one rung of the ladder uses."""

    name: str
    radius_state: bool
    bilateration: bool
    sonar: bool
    gyro: bool
    mag: bool

    @property
    def omega_only(self) -> bool:
        return not (self.bilateration or self.sonar)


LADDER = {
    "e4": Rung("omega_acc", False, False, False, False, False),
    "e5": Rung("track_bilat", False, True, False, False, False),
    "e6": Rung("track_sonar", False, False, True, False, False),
    "e7": Rung("track_gyro", False, False, True, True, False),
    "e8": Rung("track_radius", True, False, True, True, False),
    "e9": Rung("track_mag", True, False, True, True, True),
}

GYRO_RATIOS = (0.97, 0.985, 1.0, 1.015, 1.03)
"""Speed ratios of the branch grid of a rung with a gyroscope (w is known to its scale)."""
ACC_RATIOS = tuple(s * 1.03**k for s in (1.0, -1.0) for k in range(-24, 24))
"""... of one without, relative to ``|omega0|``: from half to twice it in 3 % steps, either
way (a_c alone gives w too late and too noisy at low rates to be the grid's reference)."""
FREEZE_LAPS = 0.5
"""The scale states wait this many laps of lock before they learn: the baseline over which
theta's progression (from the near to the far side) tells w from the gyroscope's scale."""
RESEED_DEG, WRONG_BRANCH_DEG, CONFIDENT = 30.0, 45.0, 0.99
"""Re-seed an acquiring EKF whose theta is RESEED_DEG off the grid's confident branch;
unlock a locked one WRONG_BRANCH_DEG off; the grid is confident at this posterior mass."""


def folded_mean(mu: float, sigma: float) -> float:
    """E|w| for w ~ N(mu, sigma^2) (the folded normal's mean)."""
    if sigma <= 0.0:
        return abs(mu)
    z = mu / sigma
    return sigma * math.sqrt(2.0 / math.pi) * math.exp(-0.5 * z * z) + mu * math.erf(
        z / math.sqrt(2.0)
    )


class TrainTracker:
    """EKF of one rung (see module docstring). Inputs: ``nav`` ([a_y m/s^2, g rad/s]),
    ``sonar`` ([range m, sonar x, sonar y]), ``mag`` ([heading rad]), ``bilateration``
    ([x, y] m, optionally the span of its two readings, s: the fix is of span / 2 earlier).

    Parameters (all optional): ``rung``; ``radius`` (m, the known radius of e4-e7, the
    initial one of e8-e9: 1.0 as in the original), ``radius_var0`` (m^2, its initial
    variance in e8-e9: 1.0 as in the original); ``center`` [x, y] (m);
    ``q_omega`` ((rad/s)^2 per s: w's random walk; 1e-5 for e6, which has nothing but the
    ranges' progression to tell w by, 1e-6 for the others: on the thesis's recordings 1e-5
    beats e6's former 1e-4 on four logs of five and ties on E8, below it E8 degrades, README
    "On the thesis's own recordings"); ``var_acc`` 0.8 (eq. 6.1), ``var_gyro`` 0.005
    (eq. 6.4), ``var_sonar`` 0.02 (while acquiring; the thesis's 0.0625 of eq. 6.3 absorbed
    the point model's error, our surface model needs less), ``var_sonar_track`` 1e-3
    (locked; None: always ``var_sonar``, never locked), ``var_mag`` 0.015 (eq. 6.9),
    ``var_bilat`` 0.25 (m^2: two sonars see different points of the train, so bilateration
    fixes are off by 10-25 cm); ``omega0`` 0.5 rad/s
    (its sign: the direction until the data tell); ``target_length``, ``target_radius`` (m,
    0: point model); ``gate`` (probability of the chi-square gate on sonar and bilateration
    blocks, None: no gate); ``max_lag`` (s); ``beams`` {sonar node: [x, y] pointing
    direction}, ``half_angle_deg`` (20, the MaxSonar's beam), ``beam_margin_deg`` (4): see
    :meth:`_in_beam`; ``lock_var_theta``, ``lock_count``, ``unlock_count``: see
    :meth:`_update_lock`; ``gyro_scale_var0`` (1e-4), ``mag_offset_var0`` (0.25 rad^2),
    ``acc_gain_var0`` (None) the initial variances of the hidden states (None: no such
    state); ``branches`` (72 phases
    per speed ratio; 0: no branch grid, the EKF fuses every range from the start),
    ``branch_memory_s`` (30), ``branch_var_bilat`` (0.05 m^2: the fixes' own error, for the
    grid; the EKF's ``var_bilat`` is wider, as their errors are correlated along a pass),
    ``off_track`` (0.15 m: see :meth:`_bilateration`).
    """

    def __init__(
        self,
        rung: str = "e9",
        radius: float | None = None,
        center: tuple[float, float] = (0.0, 0.0),
        var_acc: float = 0.8,
        var_gyro: float = 0.005,
        var_sonar: float = 0.02,
        var_mag: float = 0.015,
        var_bilat: float = 0.25,
        omega0: float = 0.5,
        radius_var0: float = 1.0,
        target_length: float = 0.0,
        target_radius: float = 0.0,
        q_theta: float = 1e-3,
        q_omega: float | None = None,
        q_radius: float = 4e-6,
        q_xy: float = 1e-8,
        gate: float | None = 0.9999,
        max_lag: float = 0.25,
        beams: dict[str, list[float]] | None = None,
        half_angle_deg: float = 20.0,
        beam_margin_deg: float = 4.0,
        var_sonar_track: float | None = 1e-3,
        lock_var_theta: float = 0.01,
        lock_count: int = 8,
        unlock_count: int = 4,
        gyro_scale_var0: float | None = 1e-4,
        q_theta_track: float | None = 1e-5,
        q_scale: float = 1e-9,
        mag_offset_var0: float | None = 0.25,
        acc_gain_var0: float | None = None,
        branches: int = 72,
        branch_memory_s: float = 30.0,
        branch_var_bilat: float = 0.05,
        off_track: float = 0.15,
    ) -> None:
        if rung not in LADDER:
            raise ValueError(f"unknown rung {rung!r}: use one of {', '.join(RUNGS)}")
        for label, v in (
            ("var_acc", var_acc),
            ("var_gyro", var_gyro),
            ("var_sonar", var_sonar),
            ("var_mag", var_mag),
            ("var_bilat", var_bilat),
            ("branch_var_bilat", branch_var_bilat),
            ("var_sonar_track", var_sonar if var_sonar_track is None else var_sonar_track),
        ):
            if not v > 0:
                raise ValueError(f"{label} must be > 0, got {v!r}")
        for label, v in (
            ("gyro_scale_var0", gyro_scale_var0),
            ("mag_offset_var0", mag_offset_var0),
            ("acc_gain_var0", acc_gain_var0),
        ):
            if v is not None and not v > 0:
                raise ValueError(f"{label} must be > 0 or None, got {v!r}")
        if branches and branches < 8:
            raise ValueError(f"branches must be 0 (no grid) or >= 8, got {branches!r}")
        self.rung = LADDER[rung]
        self.rung_id = rung
        r = self.rung
        self.radius = float(radius if radius is not None else (1.0 if r.radius_state else 0.6))
        self.cx, self.cy = (float(c) for c in center)
        self.var = {
            "acc": var_acc,
            "gyro": var_gyro,
            "sonar": var_sonar,
            "mag": var_mag,
            "bilat": var_bilat,
            "bilat_branch": branch_var_bilat,
            "sonar_track": var_sonar if var_sonar_track is None else var_sonar_track,
        }
        self.lock_var_theta = float(lock_var_theta)
        self.lock_count, self.unlock_count = int(lock_count), int(unlock_count)
        self.locked = False
        self._locked_at = 0.0
        self._streak = 0  # consecutive sonar rows consistent with the tracking variance
        self._misses = 0  # consecutive sonar rows gated out while locked
        self.unlocks = 0
        self.half_length = target_length / 2.0
        self.target_radius = target_radius
        if q_omega is None:  # e6 infers omega from the sonars alone: let it follow them faster
            q_omega = 1e-5 if rung == "e6" else 1e-6
        self.q = (q_theta, q_omega, q_radius, q_xy, q_scale)
        self.q_theta_track = q_theta if q_theta_track is None else float(q_theta_track)
        self.gate = gate
        self.max_lag = max_lag
        self.beams = unit_directions(beams)
        self.beam_cos = math.cos(math.radians(half_angle_deg - beam_margin_deg))
        self.beam_edge = 0
        self.t: float | None = None
        # direction of travel: (sign, how it is known: 0 omega0 (a_y's mean: heading_sign),
        # 2 the branch grid, 3 the gyroscope)
        self.direction = (1.0 if omega0 >= 0 else -1.0, 0)
        self.omega_ref = abs(omega0) or 0.5
        self._acc_sum = 0.0
        self._gyro_sum = self._gyro_n = 0.0
        self.direction_fixes = 0
        self.out_of_order = 0
        self.late = 0
        self.rejected = 0
        self.seeds = 0
        self.off_track_m = float(off_track)
        self.off_track = 0
        if r.omega_only:
            x0, p0 = [omega0], [1.0]
        else:  # REFERENCE: x0 = [0, 0, 0, 0.5], P0 = diag(2, 2, pi, 1) (+ r = 1, P 1)
            x0, p0 = [0.0, 0.0, 0.0, omega0], [2.0, 2.0, math.pi, 1.0]
            if r.radius_state:
                x0, p0 = [*x0, self.radius], [*p0, float(radius_var0)]
        self.n_out = len(x0)
        self.w_i = 0 if r.omega_only else W
        # hidden states (not output columns): the gyro's scale k, g = (1 + k) w; the
        # accelerometer's gain error c, a = (1 + c) r w |w| (a consider state: never
        # learnt); the magnetometer's heading offset b, heading = th + b
        self.k_i = self.c_i = self.b_i = None
        if r.gyro and gyro_scale_var0 is not None:
            self.k_i = len(x0)
            x0, p0 = [*x0, 0.0], [*p0, float(gyro_scale_var0)]
        if acc_gain_var0 is not None:
            self.c_i = len(x0)
            x0, p0 = [*x0, 0.0], [*p0, float(acc_gain_var0)]
        self._b_var0 = float(mag_offset_var0 or 0.0)
        if r.mag and mag_offset_var0 is not None:
            self.b_i = len(x0)
            x0, p0 = [*x0, 0.0], [*p0, float(mag_offset_var0)]
        self.n = len(x0)
        self.ekf = ExtendedKalmanFilter(
            np.array(x0), np.diag(p0), self._f, np.zeros((self.n, self.n)), F=self._F
        )
        # consider states of rows that must not drag them while theta is acquired
        learnt_when_locked = [self.k_i] if self.k_i is not None else []
        self._scales = learnt_when_locked
        self._fixed = [self.c_i] if self.c_i is not None else []
        # w too when a gyroscope tells it; without one, the ranges' progression must
        self._acquiring = sorted(
            ([self.w_i] if r.gyro else [])
            + ([R] if r.radius_state else [])
            + learnt_when_locked
            + self._fixed
            + ([self.b_i] if self.b_i is not None else [])
        )
        self.grid: BranchGrid | None = None
        self.seeded = bool(r.omega_only or not branches)
        if not self.seeded:
            track = Track(
                (self.cx, self.cy),
                self.half_length,
                self.target_radius,
                self.beams,
                self.beam_cos,
                math.cos(math.radians(half_angle_deg + beam_margin_deg)),
            )
            ratios = GYRO_RATIOS if r.gyro else ACC_RATIOS
            self.grid = BranchGrid(track, ratios, bins=branches, memory_s=branch_memory_s)
        self.inputs = (
            ("nav",)
            + (("bilateration",) if r.bilateration else ())
            + (("sonar",) if r.sonar else ())
            + (("mag",) if r.mag else ())
        )
        if r.omega_only:
            self.columns = ("omega [rad/s]",)
        else:
            self.columns = ("x [m]", "y [m]", "theta [rad]", "omega [rad/s]") + (
                ("radius [m]",) if r.radius_state else ()
            )

    # -- process model ------------------------------------------------------------------
    def _r(self, x: np.ndarray) -> float:
        return float(x[R]) if self.rung.radius_state else self.radius

    def _f(self, x: np.ndarray, dt: float, u=None) -> np.ndarray:
        if self.rung.omega_only:
            return x.copy()
        th = x[TH] + x[W] * dt
        r = self._r(x)
        out = x.copy()
        out[X] = self.cx + r * math.cos(th)
        out[Y] = self.cy + r * math.sin(th)
        out[TH] = th
        return out

    def _F(self, x: np.ndarray, dt: float, u=None) -> np.ndarray:
        F = np.eye(self.n)
        if self.rung.omega_only:
            return F
        th = x[TH] + x[W] * dt
        r = self._r(x)
        s, c = math.sin(th), math.cos(th)
        F[X, X] = F[Y, Y] = 0.0
        F[X, TH], F[X, W] = -r * s, -r * s * dt
        F[Y, TH], F[Y, W] = r * c, r * c * dt
        F[TH, W] = dt
        if self.rung.radius_state:
            F[X, R], F[Y, R] = c, s
        return F

    def _Q(self, dt: float) -> np.ndarray:
        """Process noise over dt s, diagonal: the output states' (x, y per step; theta, w,
        r per second), then q_k per second for every hidden state (k, c, b)."""
        q_th, q_w, q_r, q_xy, q_k = self.q
        if self.locked and self.rung.sonar:  # ranges at var_sonar_track hold theta; fixes do not
            q_th = self.q_theta_track
        if self.rung.omega_only:
            diag = [q_w * dt]
        else:
            diag = [q_xy, q_xy, q_th * dt, q_w * dt]
            diag += [q_r * dt] if self.rung.radius_state else []
        diag += [q_k * dt] * (self.n - len(diag))
        return np.diag(diag)

    # -- observation blocks -------------------------------------------------------------
    def _acc_block(self, obs: Observations, a_y: float, x: np.ndarray) -> None:
        """a_y = (1 + c) r w |w| (eq. 6.1, signed: see the module docstring; c: the
        accelerometer's gain error, a consider state, 0 without one). Its slope in w is
        taken statistically, 2 r E|w| under w ~ N(w, P_ww) (statistical linearisation;
        Gelb, "Applied Optimal Estimation", ch. 6.2): the point slope 2 r |w| vanishes at
        w = 0, where a w pushed by noise would stall; far from 0 the two are equal."""
        w_i, c_i = self.w_i, self.c_i
        w, r = float(x[w_i]), self._r(x)
        gain = 1.0 + (float(x[c_i]) if c_i is not None else 0.0)
        H = np.zeros((1, self.n))
        H[0, w_i] = gain * 2.0 * r * folded_mean(w, math.sqrt(self.ekf.P[w_i, w_i]))
        if self.rung.radius_state:
            H[0, R] = gain * w * abs(w)
        if c_i is not None:
            H[0, c_i] = r * w * abs(w)

        def h(s: np.ndarray) -> np.ndarray:
            g = 1.0 + (s[c_i] if c_i is not None else 0.0)
            return np.array([g * self._r(s) * s[w_i] * abs(s[w_i])])

        obs.add("acc", [a_y], h=h, jacobian=lambda s, H=H: H, R=self.var["acc"])

    def _nearest(self, x: np.ndarray, px: float, py: float) -> tuple[float, float]:
        """Vector from the sonar at (px, py) to the nearest point of the train's axis: its
        centre (eq. 6.2), or the closest point of the segment along the direction of travel
        when the target's length is given."""
        dx, dy = x[X] - px, x[Y] - py
        if self.half_length > 0.0:
            tx, ty = -math.sin(x[TH]), math.cos(x[TH])  # unit tangent (direction of travel)
            along = max(-self.half_length, min(self.half_length, -(dx * tx + dy * ty)))
            dx, dy = dx + along * tx, dy + along * ty
        return dx, dy

    def _range(self, x: np.ndarray, px: float, py: float) -> float:
        """Distance from the sonar at (px, py) to the train's surface (m)."""
        dx, dy = self._nearest(x, px, py)
        return math.hypot(dx, dy) - self.target_radius

    def _in_beam(self, node: str, x: np.ndarray, px: float, py: float) -> bool:
        """Whether the predicted nearest point lies well inside the sonar's beam (a cone of
        ``half_angle_deg`` less ``beam_margin_deg``). Near the edge a real sonar reports the
        nearest point *inside* the beam, farther than the model's: such readings are skipped
        rather than fused with a bias. Sonars without a known direction always pass."""
        d = self.beams.get(node)
        if d is None:
            return True
        return in_cone(d, *self._nearest(x, px, py), self.beam_cos)

    def sonar_var(self) -> float:
        """Variance of a sonar row now: ``var_sonar`` while theta is still being acquired
        (a large R keeps the linearised update of the multi-modal range(theta) from jumping
        to a wrong branch), ``var_sonar_track`` (close to the sonar's real error) once
        locked."""
        return self.var["sonar_track"] if self.locked else self.var["sonar"]

    def _update_lock(self, x: np.ndarray, rng: float, px: float, py: float) -> None:
        """Before a sonar row: lock (switch to ``var_sonar_track``) once ``lock_count``
        successive readings are consistent with that variance (NIS < 6.63, 99 %) while
        P_theta < ``lock_var_theta`` or the branch grid confidently favours the same branch:
        a P that merely shrank is not enough, a filter that converged on a wrong branch is
        confident too, its innovations (and the grid) are what betray it."""
        if self.locked or self.var["sonar_track"] == self.var["sonar"]:
            return
        h = lambda s: np.array([self._range(s, px, py)])  # noqa: E731
        H = numerical_jacobian(h, x, 1)
        S = float((H @ self.ekf.P @ H.T)[0, 0]) + self.var["sonar_track"]
        nu = rng - float(h(x)[0])
        self._streak = self._streak + 1 if nu * nu < 6.63 * S else 0
        if self._streak >= self.lock_count and (
            self.ekf.P[TH, TH] < self.lock_var_theta or self._grid_agrees()
        ):
            self._lock_now()

    def _lock_now(self) -> None:
        self.locked = True
        self._misses = 0
        self._locked_at = self.t

    def _grid_agrees(self) -> bool:
        """Whether the branch grid confidently favours the EKF's own branch."""
        if self.grid is None:
            return False
        b = self.grid.best()
        return b.mass >= CONFIDENT and abs(float(wrap(b.theta - self.ekf.x[TH]))) < math.radians(
            RESEED_DEG
        )

    def _after_sonar(self, rejected: bool) -> None:
        """After a sonar row: ``unlock_count`` successive gated-out readings while locked
        mean the track was lost: back to acquisition (``var_sonar``)."""
        if not self.locked:
            return
        self._misses = self._misses + 1 if rejected else 0
        if self._misses >= self.unlock_count:
            self._unlock()

    def _unlock(self) -> None:
        """Back to acquisition: theta's variance widened so that the sonars (or the grid's
        next seed) can pull it back."""
        self.locked = False
        self._streak = 0
        self.unlocks += 1
        P = self.ekf.P.copy()
        P[TH, TH] += self.lock_var_theta * 25.0
        self.ekf.reset(self.ekf.x, P)

    def _gyro_block(self, obs: Observations, g: float, x: np.ndarray) -> None:
        """g = (1 + k) w (eq. 6.4 with the gyro's scale)."""
        w_i, k_i = self.w_i, self.k_i
        H = np.zeros((1, self.n))
        if k_i is None:
            H[0, w_i] = 1.0
            obs.add("gyro", [g], H=H, R=self.var["gyro"])
            return
        H[0, w_i], H[0, k_i] = 1.0 + float(x[k_i]), float(x[w_i])
        obs.add(
            "gyro",
            [g],
            h=lambda s: np.array([(1.0 + s[k_i]) * s[w_i]]),
            jacobian=lambda s, H=H: H,
            R=self.var["gyro"],
        )

    # -- branches -----------------------------------------------------------------------
    def _check_branch(self) -> None:
        """Seed the EKF from the grid's branch when it is confident and the EKF is not
        seeded yet, or is acquiring RESEED_DEG away from it; unlock and re-seed a locked EKF
        WRONG_BRANCH_DEG away (see the module docstring)."""
        if self.grid is None:
            return
        b = self.grid.best()
        if b.mass < CONFIDENT:
            return
        off = abs(float(wrap(b.theta - self.ekf.x[TH])))
        if not self.seeded or (not self.locked and off > math.radians(RESEED_DEG)):
            self._seed(b)
        elif self.locked and off > math.radians(WRONG_BRANCH_DEG):
            self._unlock()
            self._seed(b)

    def _set_theta(self, theta: float, var: float) -> None:
        """Theta set to ``theta`` with variance ``var``, uncorrelated with the rest; x, y
        follow (:meth:`_seed`)."""
        x, P = self.ekf.x.copy(), self.ekf.P.copy()
        x[TH] = x[TH] + float(wrap(theta - x[TH]))
        P[TH, :] = P[:, TH] = 0.0
        P[TH, TH] = var
        self._reset_xy(x, P)

    def _reset_xy(self, x: np.ndarray, P: np.ndarray) -> None:
        """Reset the filter to x, P with x, y recomputed from theta and r (their covariance
        mapped through x = c_x + r cos th, y = c_y + r sin th)."""
        r = self._r(x)
        s, c = math.sin(x[TH]), math.cos(x[TH])
        x[X], x[Y] = self.cx + r * c, self.cy + r * s
        J = np.eye(self.n)
        J[X, X] = J[Y, Y] = 0.0
        J[X, TH], J[Y, TH] = -r * s, r * c
        if self.rung.radius_state:
            J[X, R], J[Y, R] = c, s
        P = J @ P @ J.T
        P[X, X] += self.q[3]
        P[Y, Y] += self.q[3]
        self.ekf.reset(x, 0.5 * (P + P.T))

    def _seed(self, b: Branch) -> None:
        """Set theta (and, without a gyroscope, w) from the grid's branch, uncorrelated with
        the rest, the magnetometer's offset back to its prior variance; x, y follow from
        theta and r (:meth:`_reset_xy`)."""
        x, P = self.ekf.x.copy(), self.ekf.P.copy()
        x[TH] = x[TH] + float(wrap(b.theta - x[TH]))
        P[TH, :] = P[:, TH] = 0.0
        P[TH, TH] = b.var
        if not self.rung.gyro:
            # the grid's speed (its ratio's spread, and a step of the ratios) weighed with
            # the filter's own |w| (from a_c) as two Gaussian estimates; the grid's sign
            w_g = abs(b.ratio) * self.grid_speed
            v_g = b.ratio_var * self.grid_speed**2 + (0.03 * w_g) ** 2
            w_f, v_f = abs(float(x[W])), float(P[W, W])
            w = (w_g * v_f + w_f * v_g) / (v_f + v_g)
            sign = 1.0 if b.ratio >= 0 else -1.0
            x[W] = sign * w
            P[W, :] = P[:, W] = 0.0
            P[W, W] = v_f * v_g / (v_f + v_g)
            self._set_direction(sign, 2)
        if self.b_i is not None:  # an offset learnt against the old theta is unknown again
            P[self.b_i, :] = P[:, self.b_i] = 0.0
            P[self.b_i, self.b_i] = self._b_var0
        self._reset_xy(x, P)
        self.seeded = True
        self._streak = 0
        self.seeds += 1

    @property
    def grid_speed(self) -> float:
        """The angular speed the grid integrates: the EKF's w with a gyroscope, else the
        nominal ``|omega0|`` (the grid's ratios then carry the speed and its sign)."""
        return float(self.ekf.x[self.w_i]) if self.rung.gyro else self.omega_ref

    # -- direction ----------------------------------------------------------------------
    def _set_direction(self, sign: float, source: int) -> None:
        if source >= self.direction[1]:
            self.direction = (sign, source)

    def heading_sign(self) -> float:
        """The direction of travel to hold w to: the decided one (:attr:`direction`), else
        the sign of the mean a_y so far (the likelier one: w = sign(a) sqrt(|a| / r)), else
        ``omega0``'s."""
        sign, source = self.direction
        if source == 0 and self._acc_sum:
            return math.copysign(1.0, self._acc_sum)
        return sign

    def _watch_direction(self, a_y: float, g: float | None) -> None:
        """The gyroscope's sign is decided once its running mean is 3 standard errors from
        0 (12 sigma per reading on a moving train: never wrong); a_y's is only summed, its
        mean's sign is taken afresh every time (:meth:`heading_sign`): a test on it could
        decide wrong on its first noisy readings and never come back."""
        if g is not None and self.direction[1] < 3:
            self._gyro_sum += g
            self._gyro_n += 1
            if abs(self._gyro_sum) > 3.0 * math.sqrt(self.var["gyro"] * self._gyro_n):
                self._set_direction(math.copysign(1.0, self._gyro_sum), 3)
        self._acc_sum += a_y

    # -- the model interface ------------------------------------------------------------
    def process(self, sample: Sample) -> bool:
        """Predict to the sample's measurement time and fuse its rows; False if unused."""
        if sample.name not in self.inputs:
            return False
        if self.t is None:
            self.t = sample.t
        dt = sample.t - self.t
        if dt < -self.max_lag:
            self.late += 1
            return False
        if dt < 0:
            self.out_of_order += 1  # fused at the filter's time, up to max_lag too late
        if dt > 0:
            if self.grid is not None:
                self.grid.advance(sample.t, self.grid_speed)
            self.ekf.predict(dt, Q=self._Q(dt))
            self.t = sample.t
        v = sample.values
        if sample.name == "nav" and len(v) >= 2:
            self._watch_direction(v[0], v[1] if self.rung.gyro else None)
            obs = Observations()
            x = self.ekf.x
            self._acc_block(obs, v[0], x)
            if self.rung.gyro:
                self._gyro_block(obs, v[1], x)
            self.ekf.update(obs, consider=self._nav_considered())
        elif sample.name == "sonar" and len(v) >= 3:
            self._sonar(sample.node, v[0], v[1], v[2])
        elif sample.name == "mag" and len(v) >= 1:
            self._mag(v[0])
        elif sample.name == "bilateration" and len(v) >= 2:
            # a fix that came late is of span / 2 before its own time, fused at the filter's
            late = self.t - sample.t
            self._bilateration(v[0], v[1], (v[2] / 2.0 if len(v) >= 3 else 0.0) + late)
        else:
            return False
        self._keep_direction()
        return True

    def _sonar(self, node: str, rng: float, px: float, py: float) -> None:
        if self.grid is not None:
            self.grid.add_range(node, rng, px, py, self._r(self.ekf.x), self.var["sonar"])
            self._check_branch()
        if not self.seeded:
            return
        x = self.ekf.x
        if not self._in_beam(node, x, px, py):
            self.beam_edge += 1
            return
        self._update_lock(x, rng, px, py)
        obs = Observations()
        obs.add(
            f"sonar@{node}",
            [rng],
            h=lambda s: np.array([self._range(s, px, py)]),
            R=self.sonar_var(),
        )
        result = self.ekf.update(obs, gate=self.gate, consider=self._considered())
        self.rejected += len(result.rejected)
        self._after_sonar(bool(result.rejected))

    def _mag(self, heading: float) -> None:
        """A heading row, h = th + b (eq. 6.9 with the offset). Not weighed by the branch
        grid: every reading shares the unknown offset, so taking them as independent there
        would make the grid sure of a branch that is off by it."""
        b_i = self.b_i
        obs = Observations()
        H = np.zeros((1, self.n))
        H[0, TH] = 1.0
        if b_i is None:
            obs.add("mag", [heading], H=H, R=self.var["mag"], residual=angle_residual)
        else:
            H[0, b_i] = 1.0
            # eq. 6.7: compare on the branch of theta + b nearest the measurement
            obs.add("mag", [heading], H=H, R=self.var["mag"], residual=angle_residual)
        self.ekf.update(obs, consider=self._nav_considered())

    def _bilateration(self, bx: float, by: float, ago: float) -> None:
        """A position fix of where the train was ``ago`` s before the filter's time (half
        the span of its two readings): h = c + r (cos(th - w ago), sin(th - w ago)). A fix
        more than ``off_track`` m off the track's circle is left out (counted in
        ``off_track``): its two readings were not of one point of the train."""
        r = self._r(self.ekf.x)
        if abs(math.hypot(bx - self.cx, by - self.cy) - r) > self.off_track_m:
            self.off_track += 1  # the two ranges were not of one point of the track
            return
        if self.grid is not None:
            self.grid.add_position(bx, by, r, self.var["bilat_branch"], ago, self.grid_speed)
            self._check_branch()
        if not self.seeded and self.ekf.P[TH, TH] > 1.0:
            # theta unknown yet: a fix is no ambiguous range, it tells theta by itself
            th = math.atan2(by - self.cy, bx - self.cx) + float(self.ekf.x[W]) * ago
            var = self.var["bilat"] / (r * r)
            self._set_theta(th, var)
        # fused before the grid has seeded theta too (the grid re-seeds it if it is off)

        def h(s: np.ndarray) -> np.ndarray:
            a, r = s[TH] - s[W] * ago, self._r(s)
            return np.array([self.cx + r * math.cos(a), self.cy + r * math.sin(a)])

        def jac(s: np.ndarray) -> np.ndarray:
            a, r = s[TH] - s[W] * ago, self._r(s)
            c, sn = math.cos(a), math.sin(a)
            H = np.zeros((2, self.n))
            H[0, TH], H[1, TH] = -r * sn, r * c
            H[0, W], H[1, W] = r * sn * ago, -r * c * ago
            if self.rung.radius_state:
                H[0, R], H[1, R] = c, sn
            return H

        if not self.locked:  # lock on consistent fixes (NIS < 9.21: 99 %, 2 dof)
            nu = np.array([bx, by]) - h(self.ekf.x)
            Hj = jac(self.ekf.x)
            S = Hj @ self.ekf.P @ Hj.T + self.var["bilat"] * np.eye(2)
            self._streak = self._streak + 1 if nu @ np.linalg.solve(S, nu) < 9.21 else 0
            if self._streak >= self.lock_count and (
                self.ekf.P[TH, TH] < self.lock_var_theta or self._grid_agrees()
            ):
                self.locked = True
                self._misses = 0
        obs = Observations()
        obs.add("bilateration", [bx, by], h=h, jacobian=jac, R=self.var["bilat"])
        result = self.ekf.update(obs, gate=self.gate, consider=self._considered())
        self.rejected += len(result.rejected)
        self._after_sonar(bool(result.rejected))

    def _nav_considered(self) -> list[int] | None:
        """The consider states of the acc, gyro and heading rows now: c always; k until
        locked for FREEZE_LAPS (what tells w's error from k's is theta's progression over
        a long baseline: over a shorter one, the range model's errors dominate and would
        kick it)."""
        if not self._scales_frozen():
            return self._fixed or None
        return [*self._scales, *self._fixed] or None

    def _scales_frozen(self) -> bool:
        """Whether the scale states are still consider states: until locked for FREEZE_LAPS."""
        lap = 2 * math.pi / max(self.omega_abs, 0.1)
        return not (self.locked and self.t - self._locked_at >= FREEZE_LAPS * lap)

    @property
    def omega_abs(self) -> float:
        """|w| now (rad/s)."""
        return abs(float(self.ekf.x[self.w_i]))

    def _considered(self) -> list[int] | None:
        """The consider states of a position row now: while acquiring, all but x, y, th
        (and w without a gyroscope); then, until locked for FREEZE_LAPS, the scales (see
        :meth:`_nav_considered`) and, with a gyroscope, w (its error is the scale's)."""
        if not self.locked:
            return self._acquiring
        if not self._scales_frozen():
            return self._fixed or None
        # with a gyroscope, w's error is the scale's: theta's progression must go to k
        w = [self.w_i] if self.rung.gyro else []
        return [*w, *self._scales, *self._fixed] or None

    def _keep_direction(self) -> None:
        """The train runs one way (:attr:`direction`): when the estimate of w strays to the
        other sign, mirror it (w <- -w, P unchanged). a_c's slope 2 r |w| vanishes at w = 0,
        so the accelerometer alone cannot pull w through it; and projecting onto w = 0, the
        nearest point of the constraint, would leave it no grip at all."""
        x = self.ekf.x
        w_i = self.w_i
        if x[w_i] * self.heading_sign() >= 0:
            return
        self.direction_fixes += 1
        x = x.copy()
        x[w_i] = -x[w_i]
        self.ekf.reset(x, self.ekf.P)

    def counters(self) -> dict[str, int]:
        """Diagnostic counters: samples ``late`` (dropped), ``out_of_order`` (fused late),
        sonar rows ``rejected`` by the gate or skipped at the ``beam_edge``, w mirrored
        (``direction_fixes``), theta ``seeds`` from the branch grid, tracking lost
        (``unlocks``), bilateration fixes ``off_track``."""
        return {
            "late": self.late,
            "out_of_order": self.out_of_order,
            "rejected": self.rejected,
            "beam_edge": self.beam_edge,
            "direction_fixes": self.direction_fixes,
            "seeds": self.seeds,
            "unlocks": self.unlocks,
            "off_track": self.off_track,
        }

    def estimate(self) -> tuple[float, list[float]] | None:
        """(time, state) of the latest estimate, theta wrapped to (-pi, pi]."""
        if self.t is None:
            return None
        return self.t, self.estimate_of(self.ekf.x)

    # -- smoothing (hera replay --smooth) -----------------------------------------------
    @property
    def filter(self) -> ExtendedKalmanFilter:
        """The EKF this model steps (recorded and RTS-smoothed by ``hera replay --smooth``)."""
        return self.ekf

    def estimate_of(self, x: np.ndarray) -> list[float]:
        """The output columns of a state x, as ``estimate`` gives them for the filter's."""
        out = [float(v) for v in x[: self.n_out]]
        if not self.rung.omega_only:
            out[TH] = math.atan2(math.sin(out[TH]), math.cos(out[TH]))
        return out
