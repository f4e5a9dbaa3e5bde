"""The ``wheels`` tilt filter: the gyroscope bias estimated against the robot's wheels.

Seed 003 names two things as future work: the continuous estimation of the gyroscope bias,
and "the integration of the whole system model (i.e., the robot-relative behavior)". The
``bias`` filter does the first on the IMU alone, and there the bias is weakly observable:
while the robot balances, its wheels cancel gravity's pull in the accelerometer (see
:mod:`hera.nodes.lsm6dsl.scenario`). This filter adds the robot's model and its wheel
encoders: a balancing robot that leans keeps accelerating, so the wheels' travel tells the
lean that the accelerometer cannot.

The model (an inverted pendulum of effective length ``L`` on a cart, the cart's acceleration
a_w = (g sin theta - L theta'') / cos theta): the point of the body at ``L`` over the axle,
p = x + L sin theta (x the axle's travel), moves with

    p'' = a_w + L cos theta theta'' - L sin theta theta'^2
        = g tan theta - L sin theta (tan theta theta'' + theta'^2)

in which the theta'' term is of second order in theta and is left out. State
[theta (rad), b_gyro (rad/s), p (m), u = p' (m/s)]; over a step of dt with the gyroscope's
mean rate w = g_Y - b over it, theta moves by w dt (seed eq. 25a) and p, u by the
acceleration at the interval's mid tilt. While the robot does not balance (on its stand, or
getting up or down) the model does not hold: u = 0, p follows theta, and the wheels are not
used.

A push is an impulse on the body: theta' steps while the axle's speed does not, so u steps
by L cos theta times the rate's step. The model cannot tell a push from the balancing
loop's own motion, so each step adds, to u's process noise, a velocity impulse of
(``kick`` L dw)^2 (dw the change of the gyroscope's mean rate since the step before) at an
unknown time within the step (variances j on u, j dt^2 / 3 on p, covariance j dt / 2).

Measurements: the encoders' travel x_wheel at their own time t_e, before the step's time t
by delta: x = p - L sin theta - delta (u - L cos theta w), R = ``sigma_wheel``^2; the
accelerometer's tilt atan2(a_X, a_Z) = theta, R = (sigma_acc / |a|)^2 times the scale the
caller gives, times ``r_balancing`` while the robot balances and the wheels report (it then
reads the robot's accelerations more than its tilt). Units: rad, rad/s, m, m/s, s.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from hera.estimation import ExtendedKalmanFilter, Observations
from hera.models.tilt.filters import OnLibrary
from hera.store import Sample

G = 9.80665
UNKNOWN_SPEED = 5.0
"""m/s: the axle's speed when a balancing spell starts is this uncertain."""


class WheelsFilter(OnLibrary):
    """An EKF on the state of the module docstring; ``step`` and ``wheels`` are its two
    halves (the IMU's sample, then the encoders' reading if one came)."""

    def __init__(
        self,
        theta0: float,
        b0: float,
        var0: Sequence[float],
        q: Sequence[float],
        r_acc: float,
        pendulum_m: float,
        sigma_wheel: float,
        kick: float,
        r_balancing: float,
    ) -> None:
        self.L = float(pendulum_m)
        self.q_theta, self.q_bias, self.q_u = (float(v) for v in q)
        self.r_acc, self.r_wheel = float(r_acc), float(sigma_wheel) ** 2
        self.kick, self.r_balancing = float(kick), float(r_balancing)
        self.balancing = False
        """Whether the robot balances (the last encoder reading's word)."""
        self.anchored = False
        """Whether p and u are tied to the encoders (False until their first reading)."""
        self.rate: float | None = None
        P0 = np.diag([var0[0], var0[1], 1.0, 1.0])
        self.f = ExtendedKalmanFilter([theta0, b0, 0.0, 0.0], P0, self._f, self._q0(), self._F)

    def _q0(self) -> np.ndarray:
        return np.diag([self.q_theta, self.q_bias, 0.0, self.q_u])

    # -- the process model ---------------------------------------------------------------
    def _f(self, x: np.ndarray, dt: float, u: tuple[float, bool]) -> np.ndarray:
        rate, balancing = u
        th, b, p, v = x
        w = rate - b
        thn = th + w * dt
        if not balancing:
            return np.array([thn, b, p + self.L * (math.sin(thn) - math.sin(th)), 0.0])
        tm = th + 0.5 * w * dt
        a = G * math.tan(tm) - self.L * math.sin(tm) * w * w
        return np.array([thn, b, p + v * dt + 0.5 * a * dt * dt, v + a * dt])

    def _F(self, x: np.ndarray, dt: float, u: tuple[float, bool]) -> np.ndarray:
        rate, balancing = u
        th, b = float(x[0]), float(x[1])
        w = rate - b
        F = np.eye(4)
        F[0, 1] = -dt
        if not balancing:
            thn = th + w * dt
            F[2, 0] = self.L * (math.cos(thn) - math.cos(th))
            F[2, 1] = -self.L * math.cos(thn) * dt
            F[3, 3] = 0.0
            return F
        tm = th + 0.5 * w * dt
        c = math.cos(tm)
        da_dth = G / (c * c) - self.L * c * w * w
        da_db = -0.5 * dt * da_dth + 2.0 * self.L * math.sin(tm) * w
        F[2, 0], F[2, 1], F[2, 3] = 0.5 * dt * dt * da_dth, 0.5 * dt * dt * da_db, dt
        F[3, 0], F[3, 1] = dt * da_dth, dt * da_db
        return F

    def _q(self, dt: float, dw: float) -> np.ndarray:
        Q = self._q0() * dt
        if not self.balancing:
            return Q
        j = (self.kick * self.L * dw) ** 2
        Q[2, 2] += j * dt * dt / 3.0
        Q[3, 3] += j
        Q[2, 3] = Q[3, 2] = j * dt / 2.0
        return Q

    # -- the two halves of a step --------------------------------------------------------
    def step(
        self,
        dt: float,
        g_y: float,
        acc: Sequence[float],
        gate: float | None = None,
        r_scale: float = 1.0,
    ) -> bool:
        """Predict over ``dt`` with the gyroscope's mean rate ``g_y`` (rad/s), then correct
        with the accelerometer's tilt; False when the gate refuses it (the prediction is
        kept)."""
        dw = 0.0 if self.rate is None else g_y - self.rate
        self.rate = g_y
        self.f.predict(dt, (g_y, self.balancing), Q=self._q(dt, dw))
        a_x, a_z = float(acc[0]), float(acc[1])
        norm2 = a_x * a_x + a_z * a_z
        if norm2 <= 0.0:
            return False
        r = self.r_acc * r_scale / norm2
        if self.balancing and self.anchored:
            r *= self.r_balancing
        obs = Observations().add(
            "acc", [math.atan2(a_x, a_z)], H=np.array([[1.0, 0.0, 0.0, 0.0]]), R=r
        )
        return bool(self.f.update(obs, gate=gate).accepted)

    def wheels(
        self, x_wheel: float, balancing: bool, delta: float, gate: float | None = None
    ) -> bool:
        """Correct with the encoders' travel ``x_wheel`` (m) read ``delta`` s (>= 0) before
        the last step's time; False when the chi-square gate (a probability, 1 degree of
        freedom) refuses the reading. ``balancing``: whether the robot balances off its
        stand (the controller's word). Only then does the model hold: on the stand, and
        while it gets up or down, the wheels tell nothing of the tilt, and the first reading
        of a new balancing spell places p again, the axle's speed unknown."""
        if not balancing:
            self.anchored = self.balancing = False
            return True
        th, b = float(self.f.x[0]), float(self.f.x[1])
        w = self._turn_rate(b)
        s, c = math.sin(th), math.cos(th)
        L = self.L
        if not self.anchored:
            # p = x_wheel + L sin theta + delta v and u = v + L cos theta w, the axle's own
            # speed v not known (taken as 0 +/- UNKNOWN_SPEED): P = J S J^T over
            # (theta, b, x_wheel, v).
            J = np.array(
                [
                    [1.0, 0.0, 0.0, 0.0],
                    [0.0, 1.0, 0.0, 0.0],
                    [L * c, 0.0, 1.0, delta],
                    [-L * s * w, -L * c, 0.0, 1.0],
                ]
            )
            S = np.zeros((4, 4))
            S[:2, :2] = self.f.P[:2, :2]
            S[2, 2], S[3, 3] = self.r_wheel, UNKNOWN_SPEED**2
            self.f.reset([th, b, x_wheel + L * s, L * c * w], J @ S @ J.T)
            self.anchored = self.balancing = True
            return True

        # x = p - L sin theta - delta (u - L cos theta w), linearised at the prior (the EKF's
        # correction), given as z - h(x) + H x = H x so the library takes its linear path.
        x0 = self.f.x
        h0 = float(x0[2]) - L * s - delta * (float(x0[3]) - L * c * w)
        Hm = np.array([[-L * c - delta * L * s * w, -delta * L * c, 1.0, -delta]])
        z = x_wheel - h0 + float(Hm[0] @ x0)
        obs = Observations().add("wheels", [z], H=Hm, R=self.r_wheel)
        return bool(self.f.update(obs, gate=gate).accepted)

    def _turn_rate(self, b: float) -> float:
        """The body's turn rate (rad/s): the last gyroscope rate less the bias ``b``."""
        return (self.rate if self.rate is not None else b) - b

    def output(self) -> list[float]:
        """[theta (rad), b_gyro (rad/s), the axle's speed (m/s)]: u less the body's turn."""
        th, b, _, v = (float(s) for s in self.f.x)
        w = self._turn_rate(b)
        return [th, b, v - self.L * math.cos(th) * w if self.anchored else 0.0]

    def lose_wheels(self) -> None:
        """Let the encoders go (silent, faulty, or the axle moved through lost samples): p
        and u are no longer tied to them (the next balancing reading places p again), and
        the accelerometer is weighted as without wheels."""
        self.anchored = False
        self.balancing = False


class WheelInput:
    """The encoders' readings for a :class:`WheelsFilter`: the latest one kept for the next
    IMU step, from one pair of wheels (the first heard), and the faults that let them go.

    - silent: no reading for ``max_dt`` s (``wheel_gaps``);
    - refused: ``refusals`` readings in a row refused by the chi-square gate (``gate``, a
      probability; ``wheel_refused`` counts each), a counter that jumped or wheels that
      slip: let go for ``hold_s`` s (``wheel_faults``);
    - stuck: the same travel for ``stuck_s`` s while the robot balances (a balancing
      robot's wheels never stop that long, its balance loop sways it): let go until the
      travel changes (``wheel_faults``).
    """

    def __init__(
        self,
        max_dt: float,
        gate: float | None = 0.9999,
        refusals: int = 5,
        hold_s: float = 5.0,
        stuck_s: float | None = 1.0,
    ) -> None:
        if gate is not None and not 0.0 < gate < 1.0:
            raise ValueError(f"wheel_gate must be a probability in (0, 1) or None, got {gate!r}")
        if isinstance(refusals, bool) or not (isinstance(refusals, int) and refusals >= 1):
            raise ValueError(f"wheel_refusals must be a whole number >= 1, got {refusals!r}")
        if not (isinstance(hold_s, (int, float)) and hold_s >= 0):
            raise ValueError(f"wheel_hold_s must be >= 0 s, got {hold_s!r}")
        if stuck_s is not None and not (isinstance(stuck_s, (int, float)) and stuck_s > 0):
            raise ValueError(f"wheel_stuck_s must be > 0 s or None, got {stuck_s!r}")
        self.max_dt, self.gate, self.refusals = float(max_dt), gate, int(refusals)
        self.hold_s, self.stuck_s = float(hold_s), stuck_s
        self.counts = {"wheel_readings": 0, "wheel_gaps": 0, "wheel_refused": 0, "wheel_faults": 0}
        self.source: tuple[str, str] | None = None
        self._latest: tuple[float, float, bool] | None = None  # (t, x_wheel, balancing)
        self._used_t: float | None = None
        self._same: tuple[float, float] | None = None  # (travel, since when it reads so)
        self._stuck = False
        self._refused = 0
        self._held_until: float | None = None

    def keep(self, sample: Sample) -> bool:
        """Keep the reading ``[x_wheel (m), balancing]`` for the next IMU step; False for a
        malformed one or one of another pair of wheels (not kept)."""
        v = sample.values
        if len(v) < 2 or not all(math.isfinite(x) for x in v[:2]):
            return False
        key = (sample.name, sample.node)
        if self.source is None:
            self.source = key
        elif key != self.source:
            return False
        self._latest = (sample.t, float(v[0]), v[1] > 0.5)
        if self._same is None or self._same[0] != self._latest[1]:
            self._same = (self._latest[1], sample.t)
        return True

    def _stuck_now(self, t: float, x: float, balancing: bool) -> bool:
        if self.stuck_s is None or not balancing or self._same is None:
            return False
        return self._same[0] == x and t - self._same[1] >= self.stuck_s

    def use(self, f: WheelsFilter, t: float) -> None:
        """After ``f``'s IMU step at ``t``: correct it with the reading kept, if one was read
        by then, or let the wheels go (see the class docstring)."""
        w = self._latest
        if w is not None and w[0] <= t:
            self._latest = None
            tw, x, balancing = w
            if self._held_until is not None and tw < self._held_until:
                return
            if self._stuck_now(tw, x, balancing):
                if not self._stuck:
                    self._stuck = True
                    self.counts["wheel_faults"] += 1
                    f.lose_wheels()
                return
            self._stuck = False
            if t - tw <= self.max_dt:
                self.counts["wheel_readings"] += 1
                self._used_t = tw
                if f.wheels(x, balancing, t - tw, self.gate):
                    self._refused = 0
                    return
                self.counts["wheel_refused"] += 1
                self._refused += 1
                if self._refused >= self.refusals:
                    self.counts["wheel_faults"] += 1
                    self._refused = 0
                    self._held_until = tw + self.hold_s
                    f.lose_wheels()
                return
        if f.anchored and (self._used_t is None or t - self._used_t > self.max_dt):
            self.counts["wheel_gaps"] += 1
            f.lose_wheels()
