"""Tracking a toy train on a circle: the model ladder e4 .. e9 of thesis ch. 6.

One extended Kalman filter whose state and observation rows depend on the rung:

====  ====================  ===================  ========================================
rung  name                  state                observation blocks (one per sample)
====  ====================  ===================  ========================================
e4    ``omega_acc``         [w]                  acc: a_c = r w^2 (eq. 6.1)
e5    ``track_bilat``       [x, y, th, w]        acc; bilateration [x, y]
e6    ``track_sonar``       [x, y, th, w]        acc; each sonar range (eqs. 6.2-6.3)
e7    ``track_gyro``        [x, y, th, w]        acc; gyro g = w; sonars (eq. 6.4)
e8    ``track_radius``      [x, y, th, w, r]     acc a_c = r w^2; gyro; sonars (eq. 6.5)
e9    ``track_mag``         [x, y, th, w, r]     + magnetometer heading th (eqs. 6.6-6.9)
====  ====================  ===================  ========================================

Process model (eq. 6.3, 6.5), with th' = th + w dt: x' = c_x + r cos th', y' = c_y + r sin th',
w' = w, r' = r. Units: m, rad, rad/s, m/s^2. The thesis used Q = 0; we add a small process
noise (``q_theta``, ``q_omega``, ``q_radius`` per second, ``q_xy`` per step) so that the
filter keeps listening to its sensors and P stays positive definite (x, y are functions of
th and r).

Improvement over the thesis: a sonar sees the nearest *surface* of the train, not its centre.
With ``target_length``/``target_radius`` set, the range model is the distance from the sonar
to a capsule of that size lying along the direction of travel, instead of the point model
of eq. 6.2 (whose error the thesis absorbed in sigma_d = 0.25 m, half the train's length).

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
from hera.store import Sample

RUNGS = ("e4", "e5", "e6", "e7", "e8", "e9")


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


class TrainTracker:
    """EKF of one rung (see module docstring). Inputs: ``nav`` ([a_c m/s^2, g rad/s]),
    ``sonar`` ([range m, sonar x, sonar y]), ``mag`` ([heading rad]), ``bilateration``
    ([x, y] m).

    Parameters (all optional): ``rung``; ``radius`` (m, the known radius of e4-e7, the
    initial one of e8-e9: 1.0 as in the original), ``radius_var0`` (m^2, its initial
    variance in e8-e9: 1.0 as in the original); ``center`` [x, y] (m);
    ``var_acc`` 0.8 (eq. 6.1), ``var_gyro`` 0.005 (eq. 6.4), ``var_sonar`` 0.02 (the thesis's
    0.0625 of eq. 6.3 absorbed the point model's error, our surface model needs less),
    ``var_mag`` 0.015 (eq. 6.9), ``var_bilat`` 0.25 (m^2: two sonars see different points of
    the train, so bilateration fixes are off by 10-25 cm); ``omega0`` 0.5 rad/s;
    ``target_length``, ``target_radius`` (m, 0: point model); ``gate`` (probability of the
    chi-square gate on sonar and bilateration blocks, None: no gate); ``max_lag`` (s);
    ``beams`` {sonar node: [x, y] pointing direction}, ``half_angle_deg`` (20, the
    MaxSonar's beam), ``beam_margin_deg`` (4): see :meth:`_in_beam`.
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
        q_radius: float = 4e-5,
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
    ) -> None:
        if rung not in LADDER:
            raise ValueError(f"unknown rung {rung!r}: use one of {', '.join(RUNGS)}")
        for label, v in (
            ("var_acc", var_acc),
            ("var_gyro", var_gyro),
            ("var_sonar", var_sonar),
            ("var_mag", var_mag),
            ("var_bilat", var_bilat),
            ("var_sonar_track", var_sonar if var_sonar_track is None else var_sonar_track),
        ):
            if not v > 0:
                raise ValueError(f"{label} must be > 0, got {v!r}")
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
            "sonar_track": var_sonar if var_sonar_track is None else var_sonar_track,
        }
        self.lock_var_theta = float(lock_var_theta)
        self.lock_count, self.unlock_count = int(lock_count), int(unlock_count)
        self.locked = False
        self._streak = 0  # consecutive sonar rows consistent with the tracking variance
        self._misses = 0  # consecutive sonar rows gated out while locked
        self.unlocks = 0
        self.half_length = target_length / 2.0
        self.target_radius = target_radius
        if q_omega is None:  # e6 infers omega from the sonars alone: let it follow them faster
            q_omega = 1e-4 if rung == "e6" else 1e-6
        self.q = (q_theta, q_omega, q_radius, q_xy, q_scale)
        self.q_theta_track = q_theta if q_theta_track is None else float(q_theta_track)
        self.gate = gate
        self.max_lag = max_lag
        self.beams = unit_directions(beams)
        self.beam_cos = math.cos(math.radians(half_angle_deg - beam_margin_deg))
        self.beam_edge = 0
        self.t: float | None = None
        self.omega_sign = 1.0 if omega0 >= 0 else -1.0
        self.direction_fixes = 0
        self.out_of_order = 0
        self.late = 0
        self.rejected = 0
        if r.omega_only:
            x0, p0 = [omega0], [1.0]
        else:  # REFERENCE: x0 = [0, 0, 0, 0.5], P0 = diag(2, 2, pi, 1) (+ r = 1, P 1)
            x0, p0 = [0.0, 0.0, 0.0, omega0], [2.0, 2.0, math.pi, 1.0]
            if r.radius_state:
                x0, p0 = [*x0, self.radius], [*p0, float(radius_var0)]
        self.n_out = len(x0)
        # optional hidden state (not an output column): the gyro's scale error k, g = (1 + k) w
        self.k_i: int | None = None
        if r.gyro and gyro_scale_var0 is not None:
            if not gyro_scale_var0 > 0:
                raise ValueError(f"gyro_scale_var0 must be > 0 or None, got {gyro_scale_var0!r}")
            self.k_i = len(x0)
            x0, p0 = [*x0, 0.0], [*p0, float(gyro_scale_var0)]
        self.n = len(x0)
        self.ekf = ExtendedKalmanFilter(
            np.array(x0), np.diag(p0), self._f, np.zeros((self.n, self.n)), F=self._F
        )
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
        return float(x[4]) if self.rung.radius_state else self.radius

    def _f(self, x: np.ndarray, dt: float, u=None) -> np.ndarray:
        if self.n == 1:
            return x.copy()
        th = x[2] + x[3] * dt
        r = self._r(x)
        out = x.copy()
        out[0] = self.cx + r * math.cos(th)
        out[1] = self.cy + r * math.sin(th)
        out[2] = th
        return out

    def _F(self, x: np.ndarray, dt: float, u=None) -> np.ndarray:
        F = np.eye(self.n)
        if self.n == 1:
            return F
        th = x[2] + x[3] * dt
        r = self._r(x)
        s, c = math.sin(th), math.cos(th)
        F[0, 0] = F[1, 1] = 0.0
        F[0, 2], F[0, 3] = -r * s, -r * s * dt
        F[1, 2], F[1, 3] = r * c, r * c * dt
        F[2, 3] = dt
        if self.rung.radius_state:
            F[0, 4], F[1, 4] = c, s
        return F

    def _Q(self, dt: float) -> np.ndarray:
        q_th, q_w, q_r, q_xy, q_k = self.q
        if self.locked:
            q_th = self.q_theta_track
        if self.n == 1:
            return np.array([[q_w * dt]])
        diag = [q_xy, q_xy, q_th * dt, q_w * dt] + ([q_r * dt] if self.rung.radius_state else [])
        if self.k_i is not None:
            diag.append(q_k * dt)
        return np.diag(diag)

    # -- observation blocks -------------------------------------------------------------
    def _acc_block(self, obs: Observations, a_c: float, x: np.ndarray) -> None:
        w_i = 0 if self.n == 1 else 3
        w, r = float(x[w_i]), self._r(x)
        H = np.zeros((1, self.n))
        H[0, w_i] = 2.0 * r * w
        if self.rung.radius_state:
            H[0, 4] = w * w
        obs.add(
            "acc",
            [a_c],
            h=lambda s, i=w_i: np.array([self._r(s) * s[i] ** 2]),
            jacobian=lambda s, H=H: H,
            R=self.var["acc"],
        )

    def _nearest(self, x: np.ndarray, px: float, py: float) -> tuple[float, float]:
        """Vector from the sonar at (px, py) to the nearest point of the train's axis: its
        centre (eq. 6.2), or the closest point of the segment along the direction of travel
        when the target's length is given."""
        dx, dy = x[0] - px, x[1] - py
        if self.half_length > 0.0:
            tx, ty = -math.sin(x[2]), math.cos(x[2])  # unit tangent (direction of travel)
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
        (P_theta above ``lock_var_theta``: a large R keeps the linearised update of the
        multi-modal range(theta) from jumping to a wrong branch), ``var_sonar_track`` (close to
        the sonar's real error) once theta is known well enough for the linearisation."""
        return self.var["sonar_track"] if self.locked else self.var["sonar"]

    def _update_lock(self, x: np.ndarray, rng: float, px: float, py: float) -> None:
        """Before a sonar row: lock (switch to ``var_sonar_track``) once ``lock_count``
        successive readings are consistent with that variance (NIS < 6.63, 99 %) while
        P_theta < ``lock_var_theta``: a P that merely shrank is not enough, a filter that
        converged on a wrong branch is confident too, its innovations are what betray it."""
        if self.locked or self.var["sonar_track"] == self.var["sonar"]:
            return
        h = lambda s: np.array([self._range(s, px, py)])  # noqa: E731
        H = numerical_jacobian(h, x, 1)
        S = float((H @ self.ekf.P @ H.T)[0, 0]) + self.var["sonar_track"]
        nu = rng - float(h(x)[0])
        self._streak = self._streak + 1 if nu * nu < 6.63 * S else 0
        if self._streak >= self.lock_count and self.ekf.P[2, 2] < self.lock_var_theta:
            self.locked = True
            self._misses = 0

    def _after_sonar(self, rejected: bool) -> None:
        """After a sonar row: ``unlock_count`` successive gated-out readings while locked
        mean the track was lost: back to acquisition (``var_sonar``), theta's variance
        widened so that the sonars can pull it back."""
        if not self.locked:
            return
        self._misses = self._misses + 1 if rejected else 0
        if self._misses >= self.unlock_count:
            self.locked = False
            self._streak = 0
            self.unlocks += 1
            P = self.ekf.P.copy()
            P[2, 2] += self.lock_var_theta * 25.0
            self.ekf.reset(self.ekf.x, P)

    def _sonar_block(self, obs: Observations, label: str, values: tuple[float, ...]) -> None:
        rng, px, py = values[0], values[1], values[2]
        obs.add(label, [rng], h=lambda s: np.array([self._range(s, px, py)]), R=self.sonar_var())

    def _gyro_block(self, obs: Observations, g: float, x: np.ndarray) -> None:
        w_i = 0 if self.n == 1 else 3
        H = np.zeros((1, self.n))
        if self.k_i is None:
            H[0, w_i] = 1.0
            obs.add("gyro", [g], H=H, R=self.var["gyro"])
            return
        k_i = self.k_i
        # k is learnt only while locked (theta's progression from the sonars then tells w
        # from the gyro's scale); before, it is held at its estimate, uncorrelated
        H[0, w_i], H[0, k_i] = 1.0 + float(x[k_i]), float(x[w_i]) if self.locked else 0.0
        obs.add(
            "gyro",
            [g],
            h=lambda s: np.array([(1.0 + s[k_i]) * s[w_i]]),
            jacobian=lambda s, H=H: H,
            R=self.var["gyro"],
        )

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
            self.ekf.predict(dt, Q=self._Q(dt))
            self.t = sample.t
        x = self.ekf.x
        obs = Observations()
        v = sample.values
        if sample.name == "nav" and len(v) >= 2:
            self._acc_block(obs, v[0], x)
            if self.rung.gyro:
                self._gyro_block(obs, v[1], x)
        elif sample.name == "sonar" and len(v) >= 3:
            if not self._in_beam(sample.node, x, v[1], v[2]):
                self.beam_edge += 1
                return False
            self._update_lock(x, v[0], v[1], v[2])
            self._sonar_block(obs, f"sonar@{sample.node}", v)
        elif sample.name == "mag" and len(v) >= 1:
            H = np.zeros((1, self.n))
            H[0, 2] = 1.0
            # eq. 6.7: compare on the branch of theta nearest the measurement
            obs.add("mag", [v[0]], H=H, R=self.var["mag"], residual=angle_residual)
        elif sample.name == "bilateration" and len(v) >= 2:
            H = np.zeros((2, self.n))
            H[0, 0] = H[1, 1] = 1.0
            obs.add("bilateration", [v[0], v[1]], H=H, R=self.var["bilat"])
        else:
            return False
        gated = sample.name in ("sonar", "bilateration") and self.gate is not None
        result = self.ekf.update(obs, gate=self.gate if gated else None)
        self.rejected += len(result.rejected)
        if sample.name == "sonar":
            self._after_sonar(bool(result.rejected))
        self._keep_direction()
        return True

    def _keep_direction(self) -> None:
        """The train runs one way (the sign of ``omega0``): when the estimate of w strays to
        the other sign, mirror it (w <- -w, P unchanged). The accelerometer's a_c = r w^2
        cannot tell w from -w, so the mirrored state fits its data equally well: of the
        posterior's two modes this keeps the right one. (Projecting onto w = 0 instead, the
        nearest point of the constraint, is a trap: there d(a_c)/dw = 2 r w = 0 and the
        accelerometer can never pull w back.)"""
        x = self.ekf.x
        w_i = 0 if self.n == 1 else 3
        if x[w_i] * self.omega_sign >= 0:
            return
        self.direction_fixes += 1
        x = x.copy()
        x[w_i] = -x[w_i]
        self.ekf.reset(x, self.ekf.P)

    def counters(self) -> dict[str, int]:
        """Diagnostic counters: samples ``late`` (dropped), ``out_of_order`` (fused late),
        sonar rows ``rejected`` by the gate or skipped at the ``beam_edge``, w mirrored
        (``direction_fixes``), tracking lost (``unlocks``)."""
        return {
            "late": self.late,
            "out_of_order": self.out_of_order,
            "rejected": self.rejected,
            "beam_edge": self.beam_edge,
            "direction_fixes": self.direction_fixes,
            "unlocks": self.unlocks,
        }

    def estimate(self) -> tuple[float, list[float]] | None:
        """(time, state) of the latest estimate, theta wrapped to (-pi, pi]."""
        if self.t is None:
            return None
        x = [float(v) for v in self.ekf.x[: self.n_out]]
        if self.n > 1:
            x[2] = math.atan2(math.sin(x[2]), math.cos(x[2]))
        return self.t, x

    # -- smoothing (hera replay --smooth) -----------------------------------------------
    @property
    def filter(self) -> ExtendedKalmanFilter:
        """The EKF this model steps (recorded and RTS-smoothed by ``hera replay --smooth``)."""
        return self.ekf

    def estimate_of(self, x: np.ndarray) -> list[float]:
        """The output columns of a state x, as ``estimate`` gives them for the filter's."""
        out = [float(v) for v in x[: self.n_out]]
        if self.n > 1:
            out[2] = math.atan2(math.sin(out[2]), math.cos(out[2]))
        return out
