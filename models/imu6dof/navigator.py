"""The 6-DOF IMU (thesis ch. 7.3, fig. 7.12): position, velocity and linear acceleration from
the accelerometer turned into the world by the AHRS, bounded by the sonars' position.

Two filters, as in the thesis:

- the attitude: our AHRS (:class:`hera.models.ahrs.mekf.Mekf`), fed every ``nav3`` sample;
  it copes with linear acceleration itself (its accelerometer variance adapts). With
  ``feedback = True`` it sees, as thesis eqs. 7.9-7.10 propose, the accelerometer less the
  linear acceleration the navigation filter estimates (turned into the body frame). Off by
  default: as the thesis found (ch. 7.4), the loop does not clean gravity up, since that
  estimate is itself made from the accelerometer and a tilt error becomes a linear
  acceleration the loop then keeps (on ``target3d`` the AHRS's mean error grew from 0.5 to
  1.6-2.5 deg with it);
- the navigation: per world axis a constant-acceleration model [p, v, a] (thesis e13;
  white jerk of spectral density ``q_jerk``, m^2/s^5: ``Q = q_jerk [[dt^5/20, dt^4/8,
  dt^3/6], [dt^4/8, dt^3/3, dt^2/2], [dt^3/6, dt^2/2, dt]]``), plus a slowly wandering
  accelerometer bias b in the world frame (random walk ``q_bias``, m^2/s^5: a residual
  tilt of the AHRS shows as one). Observed by the linear acceleration, thesis eqs. 7.7-7.8:
  ``R(q) a_body - g up = a + b`` (variance ``var_acc`` per axis), and, when the sonars'
  position model publishes, by its position (its own reported variance, times
  ``fix_inflation`` because successive estimates of a filter are not independent, and at
  least ``fix_var_min``). A fix a little older than the filter (it is published after
  the reading it rests on) is carried on to the filter's time with the estimated velocity,
  its variance grown accordingly; one older by more than ``max_lag`` s is dropped.

Without fixes (``aiding = False``, or no sonar model running) the position drifts, as
inertial navigation does: the application reports that drift per 10 s.

Inputs: ``nav3`` (a ``calibration = "full"`` board: body frame), and the position model's
output (``position``, default ``position3d``: x, y, z and their standard deviations, m).
Units: m, m/s, m/s^2, rad.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from hera.estimation import KalmanFilter, Observations
from hera.models.ahrs.frames import world_reference
from hera.models.ahrs.kernels import quat_matrix
from hera.models.ahrs.mekf import Mekf, MekfSettings
from hera.store import Sample

COLUMNS = (
    "x [m]",
    "y [m]",
    "z [m]",
    "vx [m/s]",
    "vy [m/s]",
    "vz [m/s]",
    "ax [m/s^2]",
    "ay [m/s^2]",
    "az [m/s^2]",
    "std x [m]",
    "std y [m]",
    "std z [m]",
    "qw",
    "qx",
    "qy",
    "qz",
)

# State layout: for axis i, p = i, v = 3 + i, a = 6 + i, bias = 9 + i.
_N = 12


def _check_numbers(**values: Any) -> None:
    for name, v in values.items():
        if isinstance(v, bool) or not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be a number > 0, got {v!r}")


class Navigator:
    """The 6-DOF IMU (see module docstring). Settings: ``aiding`` (True), ``position``
    ("position3d"), ``position_node`` (None: the first node publishing it, and the next
    when that one falls silent for a second), ``board`` (None: the first ``nav3``
    node seen), ``x0`` ([0, 0, 0] m, the start until a fix says better), ``pos_std0`` (1 m;
    0.01 m when not aided: the start is then taken as known), ``north_deg`` (90),
    ``gravity`` (9.81 m/s^2), ``q_jerk`` (1.0), ``q_bias`` (1e-4), ``var_acc`` (0.1
    (m/s^2)^2: the accelerometer's noise and the AHRS's tilt error, g times it),
    ``bias_std0`` (0.1 m/s^2), ``fix_inflation`` (1), ``fix_var_min`` (1e-4 m^2),
    ``max_lag`` (0.5 s), ``feedback`` (False)."""

    columns = COLUMNS

    def __init__(
        self,
        aiding: bool = True,
        position: str = "position3d",
        position_node: str | None = None,
        board: str | None = None,
        x0: list[float] | None = None,
        pos_std0: float | None = None,
        north_deg: float = 90.0,
        gravity: float = 9.81,
        q_jerk: float = 1.0,
        q_bias: float = 1e-4,
        var_acc: float = 0.1,
        bias_std0: float = 0.1,
        fix_inflation: float = 1.0,
        fix_var_min: float = 1e-4,
        max_lag: float = 0.5,
        feedback: bool = False,
    ) -> None:
        _check_numbers(
            gravity=gravity,
            q_jerk=q_jerk,
            q_bias=q_bias,
            var_acc=var_acc,
            fix_inflation=fix_inflation,
            fix_var_min=fix_var_min,
            max_lag=max_lag,
            bias_std0=bias_std0,
        )
        self.aiding = bool(aiding)
        self.feedback = bool(feedback)
        self.position = str(position)
        self.inputs = ("nav3", self.position) if self.aiding else ("nav3",)
        self.position_node = position_node
        self._may_switch = position_node is None  # may another publisher take over?
        self._fix_t: float | None = None
        self.board = board
        self.ref = world_reference(north_deg)
        self.ahrs = Mekf(self.ref, MekfSettings(gravity=gravity))
        self.g = float(gravity)
        self.q_jerk, self.q_bias = float(q_jerk), float(q_bias)
        self.var_acc = float(var_acc)
        self.fix_inflation, self.fix_var_min = float(fix_inflation), float(fix_var_min)
        self.max_lag = float(max_lag)
        p0 = np.zeros(3) if x0 is None else np.array(x0, dtype=np.float64).reshape(3)
        sd = (1.0 if self.aiding else 0.01) if pos_std0 is None else float(pos_std0)
        P0 = np.diag([sd**2] * 3 + [0.01] * 3 + [1.0] * 3 + [float(bias_std0) ** 2] * 3)
        self.kf = KalmanFilter(np.concatenate((p0, np.zeros(9))), P0, self._F, self._Q)
        self.t: float | None = None
        self._fixed = not self.aiding  # no estimate before the first fix when aided
        self._H_acc = np.zeros((3, _N))
        self._H_pos = np.zeros((3, _N))
        for i in range(3):
            self._H_acc[i, 6 + i] = self._H_acc[i, 9 + i] = 1.0
            self._H_pos[i, i] = 1.0
        self.counts = {"fixes": 0, "fixes_late": 0, "other": 0}

    @classmethod
    def check(cls, settings: dict[str, Any]) -> None:
        """Raise ValueError naming a bad setting, without building the filters (the AHRS's
        kernels may be compiled)."""
        import inspect

        params = inspect.signature(cls).parameters
        values = {k: p.default for k, p in params.items()} | dict(settings)
        numbers = ("gravity", "q_jerk", "q_bias", "var_acc", "fix_inflation", "fix_var_min")
        _check_numbers(**{k: values[k] for k in (*numbers, "max_lag", "bias_std0")})
        for key in ("x0",):
            if values[key] is not None:
                try:
                    np.array(values[key], dtype=np.float64).reshape(3)
                except (TypeError, ValueError):
                    raise ValueError(f"{key} must be 3 numbers, got {values[key]!r}") from None
        MekfSettings(gravity=values["gravity"])

    @staticmethod
    def _F(dt: float) -> np.ndarray:
        F = np.eye(_N)
        for i in range(3):
            F[i, 3 + i] = dt
            F[i, 6 + i] = 0.5 * dt * dt
            F[3 + i, 6 + i] = dt
        return F

    def _Q(self, dt: float) -> np.ndarray:
        q = self.q_jerk
        b = q * np.array(
            (
                (dt**5 / 20.0, dt**4 / 8.0, dt**3 / 6.0),
                (dt**4 / 8.0, dt**3 / 3.0, dt**2 / 2.0),
                (dt**3 / 6.0, dt**2 / 2.0, dt),
            )
        )
        Q = np.zeros((_N, _N))
        for i in range(3):
            idx = (i, 3 + i, 6 + i)
            for r in range(3):
                for c in range(3):
                    Q[idx[r], idx[c]] = b[r, c]
            Q[9 + i, 9 + i] = self.q_bias * dt
        return Q

    def _advance(self, t: float) -> bool:
        """Predict the navigation filter to ``t``; False if ``t`` is older than it."""
        if self.t is None:
            self.t = t
            return True
        dt = t - self.t
        if dt < 0:
            return False
        if dt > 0:
            self.kf.predict(dt)
            self.t = t
        return True

    def process(self, sample: Sample) -> bool:
        """Fuse one ``nav3`` sample or one position fix; True if the estimate changed."""
        if sample.name == "nav3":
            return self._imu(sample)
        if sample.name == self.position and self.aiding:
            return self._fix(sample)
        return False

    def _imu(self, sample: Sample) -> bool:
        v = sample.values
        if len(v) < 9:
            return False
        if self.board is None:
            self.board = sample.node
        if sample.node != self.board:
            self.counts["other"] += 1
            return False
        ahrs = self.ahrs
        acc = np.asarray(v[0:3], dtype=np.float64)
        if self.feedback and ahrs.started:  # thesis eqs. 7.9-7.10
            R = quat_matrix(ahrs.q)
            acc_g = acc - R.T @ self.kf.x[6:9]
        else:
            acc_g = acc
        if not ahrs.step(sample.t, tuple(acc_g), tuple(v[3:6]), tuple(v[6:9])):
            return False
        if not self._advance(sample.t):
            return False
        R = quat_matrix(ahrs.q)
        lin = R @ acc - self.g * self.ref.up  # thesis eqs. 7.7-7.8, in the world frame
        obs = Observations().add("acc", lin, H=self._H_acc, R=self.var_acc)
        self.kf.update(obs)
        return self._fixed

    def _fix(self, sample: Sample) -> bool:
        v = sample.values
        if len(v) < 3:
            return False
        if sample.node != self.position_node:
            # follow one publisher (several nodes run the same position model: their
            # estimates are one piece of information, not several); another one takes over
            # when it has been silent for a second
            last = self._fix_t
            if self.position_node is not None and (
                not self._may_switch or last is None or sample.t - last < 1.0
            ):
                self.counts["other"] += 1
                return False
            self.position_node = sample.node
        self._fix_t = sample.t
        if self.t is not None and sample.t < self.t - self.max_lag:
            self.counts["fixes_late"] += 1
            return False
        var = [max(self.fix_var_min, self.fix_inflation * (v[3 + i] ** 2 if len(v) >= 6 else 0.0))
               for i in range(3)]  # fmt: skip
        z = np.array(v[0:3], dtype=np.float64)
        kf = self.kf
        lag = 0.0 if self.t is None else self.t - sample.t
        if lag > 0 and self._fixed:  # a fix of a moment ago: carried on to now
            z += kf.x[3:6] * lag
            var = [var[i] + float(kf.P[3 + i, 3 + i]) * lag * lag for i in range(3)]
        if not self._fixed:  # the first fix starts the position
            x = kf.x.copy()
            x[0:3] = z
            P = kf.P.copy()
            P[0:3, :] = 0.0
            P[:, 0:3] = 0.0
            P[0:3, 0:3] = np.diag(var)
            kf.reset(x, P)
            self._fixed = True
            self.counts["fixes"] += 1
            return True
        if sample.t > (self.t if self.t is not None else sample.t):
            self._advance(sample.t)
        kf.update(Observations().add("fix", z, H=self._H_pos, R=var))
        self.counts["fixes"] += 1
        return True

    def estimate(self) -> tuple[float, list[float]] | None:
        if self.t is None or not self._fixed or not self.ahrs.started:
            return None
        x, P = self.kf.x, self.kf.P
        std = [math.sqrt(max(float(P[i, i]), 0.0)) for i in range(3)]
        return self.t, [*(float(a) for a in x[:9]), *std, *(float(a) for a in self.ahrs.q)]

    def counters(self) -> dict[str, Any]:
        """Position ``fixes`` fused or too late (``fixes_late``), ``nav3`` samples of another
        board (``other``), and the AHRS's counters (``ahrs_...``)."""
        return {**self.counts, **{f"ahrs_{k}": n for k, n in self.ahrs.counters.items()}}
