"""The tilt model (seed 003) as a fusion model: one of the filters of :mod:`.filters` over
the samples of an ``lsm6dsl`` measure (and, for ``wheels``, of a ``wheel_encoder`` one).

Input: ``[a_X, a_Z, g_Y, b_gyro, calibration]`` (m/s^2, rad/s; see
:mod:`hera.nodes.lsm6dsl.measures`). Like the seed, the estimation mode starts once the
gyroscope is calibrated (``calibration`` = 2; ``start = "any"`` starts at once, with whatever
bias the sample carries); its first sample sets theta = atan2(a_X, a_Z) and g = |a| (the
seed started from a guess and took about 30 s to converge). Then each sample is one step of
eq. 25: dt is the time since the previous sample (the seed's 1/26 s), the command is
[g_Y, b_gyro] (the ``bias`` filter takes g_Y alone and estimates b_gyro, starting from the
calibrated value), the accelerometer corrects.

Settings (all optional): ``names`` (["imu"]); ``sigma_acc`` (m/s^2, accelerometer noise
including the robot's own accelerations: R = sigma_acc^2 I); ``q_theta`` (rad^2/s),
``q_g`` ((m/s^2)^2/s), ``q_bias`` ((rad/s)^2/s): Q = diag(q) dt; ``q_drift``
((rad/s^2)^2/s; > 0 gives the bias filter a fourth state, the bias's rate of drift);
``theta_var0`` (rad^2), ``g_var0``, ``bias_var0``; ``r_rate`` (rad/s) and ``r_accel``
(rad/s^2): R grows by (1 + (w / r_rate)^2 + (dw/dt / r_accel)^2), w the robot's rate, for
the accelerations it causes (None: the seed's constant R); ``gate`` (probability of the
chi-square gate on the accelerometer, None: none); ``start``; ``gap_rate`` (rad/s: when
samples were lost, the gyroscope's sample covers only its own interval and theta's variance
grows by (gap_rate x the rest)^2); ``max_dt`` (s: a longer gap restarts the filter);
``ukf`` ([alpha, beta, kappa], kappa None: 3 - n).

The ``wheels`` filter (:mod:`.wheels`) takes ``names`` = [imu, wheels] (default ["imu",
"wheels"]): each wheel reading ``[x_wheel (m), balancing]`` is kept and used after the next
IMU step, at its own time; without one for ``max_dt`` s the filter lets the wheels go
(``wheel_gaps``) and runs on the IMU alone until they are back. Its settings:
``pendulum_m`` (m, the robot's effective pendulum length, 0.12), ``sigma_wheel`` (m, the
travel's noise, 0.001), ``q_u`` ((m/s^2)^2/s, what the model leaves out of the pendulum's
acceleration, 0.005), ``kick`` (the share of a rate step taken as a push, 1.0),
``r_balancing`` (the accelerometer's variance times this while it balances, 1e4).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from hera.models.tilt.filters import FILTERS, LibraryFilter, SplitFilter
from hera.models.tilt.wheels import WheelInput, WheelsFilter
from hera.store import Sample

CALIBRATED = 2
GAP_FACTOR = 3.0
"""A sample interval this many times the usual one means samples were lost."""


def columns_of(kind: str) -> tuple[str, ...]:
    """The output columns of a filter."""
    if kind == "wheels":
        return ("theta [rad]", "b_gyro [rad/s]", "v_wheel [m/s]")
    cols = ("theta [rad]", "g_xz [m/s^2]")
    return (*cols, "b_gyro [rad/s]") if kind == "bias" else cols


class Tilt2D:
    """One tilt filter over an IMU's samples (see the module docstring)."""

    def __init__(
        self,
        kind: str = "split",
        names: Sequence[str] | None = None,
        sigma_acc: float = 1.0,
        q_theta: float = 3e-6,
        q_g: float = 1e-4,
        q_bias: float = 1e-6,
        q_drift: float = 0.0,
        theta_var0: float = 0.03,
        g_var0: float = 0.25,
        bias_var0: float = 1e-4,
        gate: float | None = None,
        r_rate: float | None = 0.2,
        r_accel: float | None = 0.5,
        start: str = "calibrated",
        gap_rate: float = 1.0,
        max_dt: float = 1.0,
        ukf: Sequence[float | None] = (1.0, 2.0, None),
        pendulum_m: float = 0.12,
        sigma_wheel: float = 0.001,
        q_u: float = 0.005,
        kick: float = 1.0,
        r_balancing: float = 1e4,
        wheel_gate: float | None = 0.9999,
        wheel_refusals: int = 5,
        wheel_hold_s: float = 5.0,
        wheel_stuck_s: float | None = 1.0,
    ) -> None:
        if kind not in FILTERS:
            raise ValueError(f"unknown filter {kind!r}: use one of {', '.join(FILTERS)}")
        for key, v in (
            ("sigma_acc", sigma_acc),
            ("theta_var0", theta_var0),
            ("g_var0", g_var0),
            ("bias_var0", bias_var0),
            ("max_dt", max_dt),
            ("pendulum_m", pendulum_m),
            ("sigma_wheel", sigma_wheel),
            ("q_u", q_u),
            ("r_balancing", r_balancing),
        ):
            if not (isinstance(v, (int, float)) and v > 0):
                raise ValueError(f"{key} must be > 0, got {v!r}")
        for key, v in (("q_theta", q_theta), ("q_g", q_g), ("q_bias", q_bias)):
            if not (isinstance(v, (int, float)) and v >= 0):
                raise ValueError(f"{key} must be >= 0, got {v!r}")
        if start not in ("calibrated", "any"):
            raise ValueError(f"start must be 'calibrated' or 'any', got {start!r}")
        if gate is not None and not 0.0 < gate < 1.0:
            raise ValueError(f"gate must be a probability in (0, 1) or None, got {gate!r}")
        if names is None:
            names = ("imu", "wheels") if kind == "wheels" else ("imu",)
        if isinstance(names, str) or not names:
            raise ValueError(f"names must be a list of input names, got {names!r}")
        if kind == "wheels" and len(names) != 2:
            raise ValueError(f"the wheels filter's names are [imu, wheels], got {names!r}")
        if not (isinstance(kick, (int, float)) and kick >= 0):
            raise ValueError(f"kick must be >= 0, got {kick!r}")
        self.wheel_args = (pendulum_m, sigma_wheel, q_u, kick, r_balancing)
        self.wheel_input = (
            WheelInput(max_dt, wheel_gate, wheel_refusals, wheel_hold_s, wheel_stuck_s)
            if kind == "wheels"
            else None
        )
        self.kind = kind
        self.inputs = tuple(str(n) for n in names)
        self.columns = columns_of(kind)
        self.r = float(sigma_acc) ** 2
        estimates_bias = kind in ("bias", "wheels")
        self.q = [q_theta, q_g] + ([q_bias] if estimates_bias else [])
        self.var0 = [theta_var0, g_var0] + ([bias_var0] if estimates_bias else [])
        if kind == "bias" and q_drift > 0:
            self.q.append(q_drift)
            self.var0.append(q_drift * 100.0)
        if r_rate is not None and not r_rate > 0:
            raise ValueError(f"r_rate must be > 0 rad/s or None, got {r_rate!r}")
        if not gap_rate >= 0:
            raise ValueError(f"gap_rate must be >= 0 rad/s, got {gap_rate!r}")
        self.gate, self.start, self.max_dt = gate, start, float(max_dt)
        self.gap_rate = float(gap_rate)
        self.dt_nom: float | None = None
        if r_accel is not None and not r_accel > 0:
            raise ValueError(f"r_accel must be > 0 rad/s^2 or None, got {r_accel!r}")
        self.r_rate, self.r_accel = r_rate, r_accel
        self._last_rate: float | None = None
        self.ukf = tuple(ukf)
        self.filter: SplitFilter | LibraryFilter | WheelsFilter | None = None
        self.t: float | None = None
        self.source: tuple[str, str] | None = None
        self.counts = {
            "steps": 0,
            "waiting": 0,
            "gated": 0,
            "gaps": 0,
            "restarts": 0,
            "other": 0,
        }

    def _begin(self, t: float, v: Sequence[float]) -> None:
        a_x, a_z, b_cal = float(v[0]), float(v[1]), float(v[3])
        x0 = [math.atan2(a_x, a_z), math.hypot(a_x, a_z)]
        if self.kind == "bias":
            x0.append(b_cal)
            if len(self.q) == 4:
                x0.append(0.0)
        if self.kind == "wheels":
            L, sigma_wheel, q_u, kick, r_bal = self.wheel_args
            self.filter = WheelsFilter(
                x0[0],
                b_cal,
                (self.var0[0], self.var0[2]),
                (self.q[0], self.q[2], q_u),
                self.r,
                L,
                sigma_wheel,
                kick,
                r_bal,
            )
            self.t = t
            self._last_rate = None
            return
        P0 = np.diag(self.var0)
        if self.kind == "split":
            self.filter = SplitFilter(x0, P0, self.q, self.r)
        else:
            self.filter = LibraryFilter(self.kind, x0, P0, self.q, self.r, self.ukf)
        self.t = t
        self._last_rate = None

    def process(self, sample: Sample) -> bool:
        """Fuse one IMU sample (time order); True when the estimate changed."""
        v = sample.values
        if self.wheel_input is not None and sample.name == self.inputs[1]:
            if not self.wheel_input.keep(sample):
                self.counts["other"] += 1
            return False
        if len(v) < 5 or not all(math.isfinite(x) for x in v):
            self.counts["other"] += 1
            return False
        key = (sample.name, sample.node)
        if self.source is None:
            if self.start == "calibrated" and v[4] < CALIBRATED:
                self.counts["waiting"] += 1
                return False
            self.source = key
        elif key != self.source:
            self.counts["other"] += 1  # one IMU per filter: the first one heard
            return False
        if self.filter is None or self.t is None or sample.t - self.t > self.max_dt:
            if self.filter is not None:
                self.counts["restarts"] += 1
            self._begin(sample.t, v)
            return True
        dt = sample.t - self.t
        if dt <= 0.0:
            return False
        self.t = sample.t
        self.counts["steps"] += 1
        nominal = self.dt_nom
        if nominal is None or dt < 1.5 * nominal:
            self.dt_nom = dt if nominal is None else 0.9 * nominal + 0.1 * dt
        elif dt > GAP_FACTOR * nominal:
            # Samples were lost: this one's rate covers only its own interval (the chip's
            # mean), the rest of the gap turned by an unknown angle.
            self.counts["gaps"] += 1
            self.filter.widen((self.gap_rate * (dt - nominal)) ** 2)
            if isinstance(self.filter, WheelsFilter):
                self.filter.lose_wheels()  # the axle moved by an unknown amount too
            dt = nominal
        rate = float(v[2]) - self._bias(v)
        scale = 1.0 if self.r_rate is None else 1.0 + (rate / self.r_rate) ** 2
        if self.r_accel is not None and self._last_rate is not None:
            scale += ((rate - self._last_rate) / dt / self.r_accel) ** 2
        self._last_rate = rate
        acc = (float(v[0]), float(v[1]))
        if isinstance(self.filter, WheelsFilter):
            ok = self.filter.step(dt, float(v[2]), acc, self.gate, scale)
            assert self.wheel_input is not None
            self.wheel_input.use(self.filter, sample.t)
        else:
            ok = self.filter.step(dt, float(v[2]), float(v[3]), acc, self.gate, scale)
        if not ok:
            self.counts["gated"] += 1
        return True

    def _bias(self, v: Sequence[float]) -> float:
        """The gyroscope bias the step takes off (rad/s): the state's, or the sample's."""
        assert self.filter is not None
        if self.kind == "bias":
            return float(self.filter.x[2])
        if self.kind == "wheels":
            return float(self.filter.x[1])
        return float(v[3])

    def estimate(self) -> tuple[float, list[float]] | None:
        """(time, [theta, g(, b_gyro)]) of the current estimate, None before the start."""
        if self.filter is None or self.t is None:
            return None
        if isinstance(self.filter, WheelsFilter):
            return self.t, self.filter.output()
        return self.t, [float(x) for x in self.filter.x]

    def counters(self) -> dict[str, int]:
        """Steps, samples waited out before the calibration, gated accelerometer readings,
        gaps (lost samples), restarts after a long gap, samples of another IMU or malformed;
        and the wheels filter's (:class:`~hera.models.tilt.wheels.WheelInput`)."""
        wheels = {} if self.wheel_input is None else self.wheel_input.counts
        return {**self.counts, **wheels}
