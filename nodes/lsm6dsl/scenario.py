"""The ``balancing`` scenario: a two-wheeled self-balancing robot (seed 003, fig. 4).

The robot's body turns about its wheel axle by theta (rad, about the body y axis; positive
leans its top forward, towards +x). Timeline (s since the epoch):

- ``[0, still_s)``: on its stand, still, leaning ``lean_deg``, motors off;
- then it rises (``rise_s``, minimum jerk) and balances: a sway of ``sway_deg`` at
  ``sway_hz`` (the balancing loop's limit cycle) plus a slow wander of ``wander_deg`` at
  ``wander_hz``;
- pushes every ``push_every_s`` from ``first_push_s``: a kick that starts a damped swing
  theta = A exp(-zeta w t) sin(w_d t) of ``push_deg`` (+/- 30 %, random sign; ``push_hz``,
  damping ratio ``push_damping``);
- ``parked``: a list of [start, end] windows (s) when it is back on its stand (still).

Each push's size and sign come from ``seed``. Only theta is the truth the tilt models are
scored on. The accelerometer feels the wheels: balancing, the axle accelerates by
a_w = (g sin theta - L theta'') / cos theta (an inverted pendulum of effective length
``pendulum_m`` on a cart), so at ``sensor_m`` up the body the board reads, besides gravity,
(sensor_m - L) theta'' along x and the centripetal sensor_m theta'^2: what the seed calls
"parasite accelerations". The motion's position and velocity are the board's relative to
the axle; its acceleration is absolute. The motors shake the body (``vibration_acc``
m/s^2, ``vibration_gyro`` rad/s, while they run).

By default the wheels need no torque to turn (massless, of no size), so the board reads no
tilt while the robot balances. ``reaction_k`` > 0 gives them the motor torque that drives
them, tau = r (M a_w + m l theta''), which pushes back on the body (r = ``wheel_radius_m``,
m and l the body's mass and its centre of mass over the axle, M the robot's mass plus the
wheels' inertia I_w / r^2, ``reaction_k`` = r M / (m l)): the axle then accelerates by
a_w = (g sin theta - (L + r) theta'') / ((1 + k) cos theta), and the board reads a share
k / (1 + k) of the slow tilt (linearised wheeled inverted pendulum).

The axle's travel along the world's x (+ forward; what wheel encoders count,
:mod:`hera.nodes.wheels`) is :meth:`Balancing.axle`: the double integral of the a_w above
from 0 m, 0 m/s at the epoch (so 0 until the robot first rises). A push is an external
impulse on the body: theta' steps at its kick, the axle's velocity does not. Nothing brings
the robot back: each rise and each push leave it driving on at some speed (a random walk of
speeds over the pushes), as a_w says; parked, it coasts at the speed it had (a_w is 0 on the
stand).
"""

from __future__ import annotations

import math
import random
import threading
from array import array
from bisect import bisect_right
from collections.abc import Mapping, Sequence
from typing import Any

from hera.nodes import geometry as gm
from hera.nodes.tof.scenario import min_jerk
from hera.nodes.world import G, Motion, Scenario, number, register_scenario

PUSH_WINDOW_S = 4.0
"""A push counts as under way for this long after the kick (the segment ``push``)."""

AXLE_STEP_S = 0.01
"""Step (s) of the axle's integration grid (3-point Gauss-Legendre per step)."""
AXLE_CHECKPOINT_S = 1.0
"""Seconds between two kept checkpoints (position, velocity) of the axle's integration."""
AXLE_MAX_S = 1.0e6
"""How far from the epoch (s, 11.6 days) the axle is tracked: further is refused (a wrong
epoch, rather than hours of integration)."""

_GAUSS = tuple(
    (0.5 + c, w)
    for c, w in (
        (-math.sqrt(15.0) / 10.0, 5.0 / 18.0),
        (0.0, 8.0 / 18.0),
        (math.sqrt(15.0) / 10.0, 5.0 / 18.0),
    )
)
"""Nodes (fractions of a step) and weights of 3-point Gauss-Legendre quadrature: exact for
polynomials up to degree 5, and it never evaluates a step's ends (where a_w may jump)."""


class Balancing(Scenario):
    """See the module docstring. Angles in degrees, times in s, lengths in m."""

    kind = "balancing"

    def __init__(
        self,
        still_s: float = 8.0,
        lean_deg: float = 3.0,
        rise_s: float = 1.0,
        sway_deg: float = 1.5,
        sway_hz: float = 1.1,
        wander_deg: float = 0.8,
        wander_hz: float = 0.13,
        first_push_s: float | None = None,
        push_every_s: float = 10.0,
        push_deg: float = 20.0,
        push_hz: float = 0.8,
        push_damping: float = 0.25,
        pendulum_m: float = 0.12,
        sensor_m: float = 0.18,
        parked: Sequence[Sequence[float]] = (),
        seed: int = 0,
        reaction_k: float = 0.0,
        wheel_radius_m: float = 0.0,
    ) -> None:
        for key, value in (("reaction_k", reaction_k), ("wheel_radius_m", wheel_radius_m)):
            if not 0.0 <= value < math.inf:
                raise ValueError(f"balancing {key} must be a number >= 0, got {value}")
        if still_s < 0 or rise_s <= 0 or push_every_s <= 0:
            raise ValueError("balancing still_s must be >= 0 s, rise_s and push_every_s > 0 s")
        if not 0.0 <= push_damping < 1.0:
            raise ValueError(f"balancing push_damping must be within [0, 1), got {push_damping}")
        if abs(push_deg) >= 60.0:
            raise ValueError(f"balancing push_deg must be below 60 deg, got {push_deg}")
        windows = []
        for w in parked:
            if len(w) != 2 or not w[0] < w[1]:
                raise ValueError(f"balancing parked windows must be [start, end], got {w!r}")
            windows.append((float(w[0]), float(w[1])))
        self.still_s, self.rise_s = still_s, rise_s
        self.lean = math.radians(lean_deg)
        self.sway, self.sway_w = math.radians(sway_deg), 2.0 * math.pi * sway_hz
        self.wander, self.wander_w = math.radians(wander_deg), 2.0 * math.pi * wander_hz
        self.first_push = still_s + 5.0 if first_push_s is None else first_push_s
        self.push_every, self.push = push_every_s, math.radians(push_deg)
        self.push_w, self.zeta = 2.0 * math.pi * push_hz, push_damping
        self.pendulum, self.sensor = pendulum_m, sensor_m
        self.reaction_k, self.wheel_radius = reaction_k, wheel_radius_m
        self.parked = sorted(windows)
        self.seed = int(seed)
        self.vibration_acc = 0.2
        self.vibration_gyro = 0.005

    # -- the plan ---------------------------------------------------------------------------
    def _standing(self, tau: float) -> tuple[float, float, float]:
        """w(tau) in [0, 1] (0: on the stand, 1: balancing) and its two derivatives."""
        w, dw, ddw = self._ramp(tau - self.still_s, 1.0)
        for start, end in self.parked:
            a, da, dda = self._ramp(tau - start, -1.0)
            b, db, ddb = self._ramp(tau - end, 1.0)
            w, dw, ddw = w + a + b, dw + da + db, ddw + dda + ddb
        return w, dw, ddw

    def _ramp(self, t: float, sign: float) -> tuple[float, float, float]:
        s, ds, dds = min_jerk(t / self.rise_s)
        return sign * s, sign * ds / self.rise_s, sign * dds / self.rise_s**2

    def _push(self, k: int) -> float:
        r = random.Random(f"balancing|{self.seed}|{k}")
        return self.push * r.uniform(0.7, 1.3) * r.choice((-1.0, 1.0))

    def _balance(self, tau: float) -> tuple[float, float, float]:
        """theta of the balancing robot (sway, wander, pushes) and its two derivatives."""
        th = dth = ddth = 0.0
        for amp, w, ph in (
            (self.sway, self.sway_w, 0.4),
            (self.wander, self.wander_w, 1.3 + self.seed),
        ):
            th += amp * math.sin(w * tau + ph)
            dth += amp * w * math.cos(w * tau + ph)
            ddth -= amp * w * w * math.sin(w * tau + ph)
        if tau >= self.first_push:
            k_last = int((tau - self.first_push) // self.push_every)
            decay = self.zeta * self.push_w
            wd = self.push_w * math.sqrt(1.0 - self.zeta**2)
            horizon = 6.0 / max(decay, 1e-3)
            k = k_last
            while k >= 0 and tau - (self.first_push + k * self.push_every) <= horizon:
                t = tau - (self.first_push + k * self.push_every)
                a = self._push(k) * math.exp(-decay * t)
                s, c = math.sin(wd * t), math.cos(wd * t)
                th += a * s
                dth += a * (wd * c - decay * s)
                ddth += a * ((decay * decay - wd * wd) * s - 2.0 * decay * wd * c)
                k -= 1
        return th, dth, ddth

    def theta(self, tau: float) -> tuple[float, float, float]:
        """theta (rad) and its first two derivatives at ``tau``."""
        w, dw, ddw = self._standing(tau)
        if w <= 0.0 and dw == 0.0:
            return self.lean, 0.0, 0.0
        b, db, ddb = self._balance(tau)
        lean = self.lean
        return (
            (1.0 - w) * lean + w * b,
            dw * (b - lean) + w * db,
            ddw * (b - lean) + 2.0 * dw * db + w * ddb,
        )

    def motors_on(self, tau: float) -> bool:
        """Whether the motors run (the robot is off its stand)."""
        return self._standing(tau)[0] > 0.0

    def balancing(self, tau: float) -> bool:
        """Whether the robot balances on its wheels: off its stand, up and not getting up
        or down (its controller's balance loop runs)."""
        return self._standing(tau)[0] >= 1.0

    def axle(self, tau: float) -> tuple[float, float]:
        """The axle's position (m) and velocity (m/s) along the world's x at ``tau`` s since
        the epoch: the double integral of the a_w :meth:`motion` uses, from 0, 0 at tau <= 0.
        A pure function of ``tau`` (see :class:`_AxleTrack`); ValueError beyond
        :data:`AXLE_MAX_S`."""
        return self._axle_track().at(tau)

    def axle_acc(self, tau: float) -> float:
        """The axle's acceleration a_w (m/s^2, world x) at ``tau``: what :meth:`motion` adds
        to the board's."""
        th, _, ddth = self.theta(tau)
        return self._a_w(tau, th, ddth)

    def _a_w(self, tau: float, th: float, ddth: float) -> float:
        """a_w (module docstring) at ``tau`` for the tilt ``th`` and its ``ddth`` there."""
        w = max(0.0, min(1.0, self._standing(tau)[0]))
        if w == 0.0:
            return 0.0
        return (
            w
            * (G * math.sin(th) - (self.pendulum + self.wheel_radius) * ddth)
            / ((1 + self.reaction_k) * math.cos(th))
        )

    def axle_breaks(self, t0: float, t1: float) -> list[float]:
        """The times within (t0, t1), sorted, where a_w jumps or turns sharply: a push's kick
        (theta'' steps) and the end of its horizon (its swing is dropped), the start and end
        of each rise and parking (minimum-jerk ramps)."""
        out = []
        for start in (self.still_s, *(t for w in self.parked for t in w)):
            out += [start, start + self.rise_s]
        decay = self.zeta * self.push_w
        horizon = 6.0 / max(decay, 1e-3)
        k = max(0, math.floor((t0 - horizon - self.first_push) / self.push_every))
        while (kick := self.first_push + k * self.push_every) < t1:
            out += [kick, kick + horizon]
            k += 1
        return sorted({t for t in out if t0 < t < t1})

    def _axle_track(self) -> _AxleTrack:
        track = self.__dict__.get("_track")
        if track is None:
            track = self.__dict__.setdefault("_track", _AxleTrack(self))
        return track

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state.pop("_track", None)  # a cache, with a lock
        return state

    def segment(self, tau: float) -> str:
        """``still`` (on the stand), ``rise`` (getting up or down), ``push`` (a push under
        way) or ``sway`` (balancing)."""
        w = self._standing(tau)[0]
        if w <= 0.0:
            return "still"
        if w < 1.0:
            return "rise"
        if tau >= self.first_push:
            k = int((tau - self.first_push) // self.push_every)
            if tau - (self.first_push + k * self.push_every) < PUSH_WINDOW_S:
                return "push"
        return "sway"

    # -- the motion -------------------------------------------------------------------------
    def motion(self, tau: float) -> Motion:
        th, dth, ddth = self.theta(tau)
        s, c = math.sin(th), math.cos(th)
        a_w = self._a_w(tau, th, ddth)
        h = self.sensor
        return Motion(
            position=(h * s, 0.0, h * c),
            velocity=(h * c * dth, 0.0, -h * s * dth),
            acceleration=(
                a_w + h * (ddth * c - dth * dth * s),
                0.0,
                -h * (ddth * s + dth * dth * c),
            ),
            orientation=gm.axis_angle((0.0, 1.0, 0.0), th),
            angular_rate=(0.0, dth, 0.0),
        )

    def rest_motion(self) -> Motion:
        return Motion(
            position=(self.sensor * math.sin(self.lean), 0.0, self.sensor * math.cos(self.lean)),
            orientation=gm.axis_angle((0.0, 1.0, 0.0), self.lean),
        )


class _AxleTrack:
    """The axle's travel of one :class:`Balancing`: a_w integrated on a fixed grid.

    The grid: every :data:`AXLE_STEP_S` from the epoch, plus each of the scenario's
    :meth:`~Balancing.axle_breaks` (so no step straddles a jump of a_w); each step is one
    3-point Gauss-Legendre quadrature of v' = a_w and of x'' = a_w (x(t0 + d) = x0 + v0 d +
    d^2 int_0^1 (1 - c) a(t0 + c d) dc). Checkpoints (x, v) every :data:`AXLE_CHECKPOINT_S`
    are made in order, once, and kept (16 bytes each: 1.4 MB a day); the grid of the last
    second read is cached, and a read is its grid node at or before ``tau`` and one more
    quadrature step to ``tau``. So a value depends on ``tau`` alone, whatever was read
    before (reads in any order); reads moving forward cost a few a_w evaluations each, and
    about 300 a_w evaluations per second crossed. Thread-safe."""

    def __init__(self, scenario: Balancing) -> None:
        self.sc = scenario
        self.xs = array("d", [0.0])  # checkpoint k: at k * AXLE_CHECKPOINT_S
        self.vs = array("d", [0.0])
        self._lock = threading.Lock()
        self._window: tuple[int, list[float], list[float], list[float]] | None = None

    def at(self, tau: float) -> tuple[float, float]:
        if not tau > 0.0:
            return 0.0, 0.0
        if not tau <= AXLE_MAX_S:
            raise ValueError(
                f"the balancing robot's axle is tracked for {AXLE_MAX_S:g} s from the epoch, "
                f"asked at {tau:g} s: is the world's epoch right?"
            )
        i = int(tau // AXLE_CHECKPOINT_S)
        with self._lock:
            while len(self.xs) <= i:
                self._grid(len(self.xs) - 1)
            times, xs, vs = self._grid(i)
        j = bisect_right(times, tau) - 1
        if times[j] == tau:
            return xs[j], vs[j]
        return self._step(times[j], xs[j], vs[j], tau)

    def _grid(self, i: int) -> tuple[list[float], list[float], list[float]]:
        """The grid of second ``i`` (times, positions, velocities) from its checkpoint; the
        next checkpoint is appended when it is the first to reach it."""
        if self._window is not None and self._window[0] == i:
            return self._window[1:]
        t0 = i * AXLE_CHECKPOINT_S
        t1 = (i + 1) * AXLE_CHECKPOINT_S
        n = round(AXLE_CHECKPOINT_S / AXLE_STEP_S)
        times = [t0 + j * AXLE_STEP_S for j in range(n)] + [t1]
        breaks = [b for b in self.sc.axle_breaks(t0, t1) if _far(times, b)]
        if breaks:
            times = sorted(times + breaks)
        xs, vs = [self.xs[i]], [self.vs[i]]
        for a, b in zip(times, times[1:], strict=False):
            x, v = self._step(a, xs[-1], vs[-1], b)
            xs.append(x)
            vs.append(v)
        if len(self.xs) == i + 1:
            self.xs.append(xs[-1])
            self.vs.append(vs[-1])
        self._window = (i, times, xs, vs)
        return times, xs, vs

    def _step(self, t0: float, x0: float, v0: float, t1: float) -> tuple[float, float]:
        """(x, v) at ``t1`` from (x0, v0) at ``t0``: one Gauss-Legendre step."""
        d = t1 - t0
        dv = dx = 0.0
        for c, w in _GAUSS:
            a = w * self.sc.axle_acc(t0 + c * d)
            dv += a
            dx += (1.0 - c) * a
        return x0 + v0 * d + d * d * dx, v0 + d * dv


def _far(times: list[float], t: float, tol: float = 1e-9) -> bool:
    """Whether ``t`` is more than ``tol`` from every one of the sorted ``times``."""
    j = bisect_right(times, t)
    return all(abs(times[k] - t) > tol for k in (j - 1, j) if 0 <= k < len(times))


def _parked(w: Mapping[str, Any]) -> list[list[float]]:
    value = w.get("parked", [])
    if not isinstance(value, (list, tuple)) or not all(
        isinstance(x, (list, tuple)) and len(x) == 2 for x in value
    ):
        raise ValueError(f"world 'parked' must be a list of [start, end] (s), got {value!r}")
    try:
        return [[float(a), float(b)] for a, b in value]
    except (TypeError, ValueError):
        raise ValueError(f"world 'parked' must hold numbers, got {value!r}") from None


def _build(w: Mapping[str, Any]) -> Balancing:
    seed = w.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise ValueError(f"world 'seed' must be an integer, got {seed!r}")
    first = w.get("first_push_s")
    sc = Balancing(
        number(w, "still_s", 8.0),
        number(w, "lean_deg", 3.0),
        number(w, "rise_s", 1.0),
        number(w, "sway_deg", 1.5),
        number(w, "sway_hz", 1.1),
        number(w, "wander_deg", 0.8),
        number(w, "wander_hz", 0.13),
        None if first is None else number(w, "first_push_s", 0.0),
        number(w, "push_every_s", 10.0),
        number(w, "push_deg", 20.0),
        number(w, "push_hz", 0.8),
        number(w, "push_damping", 0.25),
        number(w, "pendulum_m", 0.12),
        number(w, "sensor_m", 0.18),
        _parked(w),
        seed,
        number(w, "reaction_k", 0.0),
        number(w, "wheel_radius_m", 0.0),
    )
    return sc


register_scenario(
    "balancing",
    {
        "still_s",
        "lean_deg",
        "rise_s",
        "sway_deg",
        "sway_hz",
        "wander_deg",
        "wander_hz",
        "first_push_s",
        "push_every_s",
        "push_deg",
        "push_hz",
        "push_damping",
        "pendulum_m",
        "sensor_m",
        "parked",
        "reaction_k",
        "wheel_radius_m",
    },
    _build,
)
