"""The simulated world: motions that are pure functions of time, and the fixed things in it.

Every node process builds the same scenario from the spec's ``[world]`` table (``ctx.world``)
and evaluates it at ``tau = t - epoch`` (``t`` epoch seconds, ``epoch`` shared through the
spec), so all processes agree on the truth without talking.

Scenarios are registered by name (:func:`register_scenario`: the world keys each takes and a
builder); an application's own scenarios live in its own module, listed in
:data:`EXTRA_SCENARIOS`. World table keys common to every scenario:

- ``scenario``: one of :data:`SCENARIOS` (default ``"still"``);
- ``epoch``: epoch seconds of ``tau = 0`` (the launcher fills it with the cluster start);
- ``target_radius`` / ``target_length``: the shape the sonars see (a capsule of that radius
  whose axis, of that length, lies along the body x axis);
- magnetic field and altitude (see :class:`Environment`).

Scenario parameters (all optional, SI units, angles in rad unless the key says ``_deg``):

- ``still``: ``position`` [x, y, z], ``yaw``;
- ``train`` (thesis ch. 6.1): ``center`` [x, y], ``radius`` (0.6 m), ``omega`` (0.84 rad/s,
  positive = counter-clockwise), ``phase`` (start angle, 0), ``height`` (0);
  ``out_of_round`` (0 m) and ``round_phase_deg`` (0): rails r(theta) = radius + out_of_round
  cos(2 (theta - round_phase)); ``rest_phase_deg`` (0): where the train stands when "placed
  at 0 deg" for calibration; ``gauge`` (0.045 m) between the rails; ``tilt_deg`` (0) and
  ``tilt_axis_deg`` (0): a table that is not level (see :class:`Train`);
- ``train_rough`` (:mod:`hera.nodes.rough`): the train with a real rig's imperfections;
- ``rail`` (thesis ch. 3.2/3.4, fig. A.1): ``start`` [x, y, z], ``axis`` [x, y, z],
  ``length`` (1.1 m), ``period`` (8 s) - back and forth ``start -> start + length * axis``;
- ``hand`` (thesis app. D): ``center``, ``period`` (1.25 s), ``amplitude`` (4 m/s^2, of the
  acceleration) - a circle without rotating the board;
- ``target3d`` (thesis ch. 7.2): ``center`` [x, y, z] (1, 1, 1), ``amplitude`` (0.5 m),
  ``period`` (6 s per back-and-forth) - along x, then y, then z, repeating;
- ``rotation_slow`` / ``rotation_fast`` (thesis ch. 7.1.3): ``axis`` (z), ``duration``
  (12 s / 2 s per 360 deg turn), ``rest`` (2 s still between turns), ``position``;
- ``shaking`` (thesis ch. 7.1.3): ``position``, ``amplitude`` (0.03 m), ``frequency`` (3 Hz)
  - shaking without rotation.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from hera.nodes import geometry as g
from hera.nodes.geometry import IDENTITY, ZERO, Quat, Vec3

G = 9.81
"""Gravity (m/s^2), the value the original measures convert with (REFERENCE: a_y * 9.81)."""


@dataclass(frozen=True, slots=True)
class State:
    """The true motion of the sensed body at one time.

    ``t`` epoch s; ``position`` m, ``velocity`` m/s, ``acceleration`` m/s^2 (world frame);
    ``orientation`` the body-to-world unit quaternion (w, x, y, z); ``angular_rate`` rad/s in
    the body frame (what an ideal gyroscope measures).
    """

    t: float
    position: Vec3
    velocity: Vec3
    acceleration: Vec3
    orientation: Quat
    angular_rate: Vec3

    def as_row(self) -> list[float]:
        """The 16 numbers of :data:`STATE_COLUMNS`, in order."""
        return [
            *self.position,
            *self.velocity,
            *self.acceleration,
            *self.orientation,
            *self.angular_rate,
        ]


STATE_COLUMNS = (
    "x [m]",
    "y [m]",
    "z [m]",
    "vx [m/s]",
    "vy [m/s]",
    "vz [m/s]",
    "ax [m/s^2]",
    "ay [m/s^2]",
    "az [m/s^2]",
    "qw",
    "qx",
    "qy",
    "qz",
    "wx [rad/s]",
    "wy [rad/s]",
    "wz [rad/s]",
)


@dataclass(frozen=True, slots=True)
class Motion:
    """Kinematics at ``tau`` seconds after the epoch (a :class:`State` without the time)."""

    position: Vec3
    velocity: Vec3 = ZERO
    acceleration: Vec3 = ZERO
    orientation: Quat = IDENTITY
    angular_rate: Vec3 = ZERO


@dataclass(frozen=True, slots=True)
class Target:
    """What a sonar sees: a capsule of ``radius`` around a segment of ``length`` along body x.

    Defaults come from the scenario (train: 0.5 m long, thesis ch. 6.3 "sigma_d = 0.25, half
    the length of the train"; others: a GRiSP board on its support, about 10 cm, thesis
    ch. 7.2).
    """

    radius: float = 0.05
    length: float = 0.0


@dataclass(frozen=True, slots=True)
class SonarMount:
    """Where a sonar sits and where it points (world frame, unit ``direction``)."""

    position: Vec3
    direction: Vec3


@dataclass(frozen=True, slots=True)
class Environment:
    """Earth's magnetic field and the air pressure reference.

    World keys: ``mag_horizontal`` (0.205 gauss), ``mag_vertical`` (0.44 gauss, pointing
    down), ``mag_north_deg`` (90: magnetic north along world +y), ``altitude`` (100 m above
    sea level at z = 0), ``sea_level_hpa`` (1013.25). Defaults: the World Magnetic Model
    near Louvain-la-Neuve, where the thesis was written (total about 0.485 gauss,
    inclination about 65 deg; rounded).
    """

    mag_horizontal: float = 0.205
    mag_vertical: float = 0.44
    mag_north: float = math.pi / 2.0
    altitude: float = 100.0
    sea_level_hpa: float = 1013.25

    @property
    def field(self) -> Vec3:
        """Earth's field in the world frame (gauss)."""
        h = self.mag_horizontal
        return (h * math.cos(self.mag_north), h * math.sin(self.mag_north), -self.mag_vertical)

    def pressure(self, z: float) -> float:
        """Barometric pressure (hPa) at world height ``z`` m (international standard
        atmosphere, troposphere: p = p0 (1 - 2.25577e-5 h)^5.25588)."""
        h = self.altitude + z
        return self.sea_level_hpa * (1.0 - 2.25577e-5 * h) ** 5.25588


class Scenario:
    """A motion that is a pure function of ``tau`` (seconds since the epoch)."""

    kind: str = "still"
    target: Target = Target()
    vibration_acc: float = 0.0
    """Std of the vibration the vehicle adds to an accelerometer (m/s^2, white)."""
    vibration_gyro: float = 0.0
    """Std of the vibration the vehicle adds to a gyroscope (rad/s, white)."""
    nav_model: Mapping[str, Any] = {}
    """Defaults of the NAV error model of the boards in this world (``NavModel`` fields; a
    measure's ``model`` arg overrides them): what a preset of real-rig imperfections sets."""
    sonar_model: Mapping[str, Any] = {}
    """Defaults of the sonar error model of the boards in this world (``SonarModel``)."""

    def motion(self, tau: float) -> Motion:
        raise NotImplementedError

    def clutter_range(self, mount: SonarMount, half_angle: float, u: float) -> float | None:
        """The range (m) of a fixed surface (not the target) a sonar at ``mount`` may hear
        along the ray at ``u`` (-1 .. 1) of its beam's half-angle (rad); None: nothing."""
        return None

    def rest_motion(self) -> Motion:
        """The pose in which boards are calibrated, still: the scenario's "0 deg" pose."""
        m = self.motion(0.0)
        return Motion(position=m.position, orientation=m.orientation)

    def default_sonars(self) -> tuple[SonarMount, ...]:
        """Sonar placements used when a sonar measure names none (index = ``sonar`` arg)."""
        return (SonarMount((0.0, -1.0, 0.0), (0.0, 1.0, 0.0)),)


class Still(Scenario):
    kind = "still"

    def __init__(self, position: Vec3 = ZERO, yaw: float = 0.0) -> None:
        self._m = Motion(position=position, orientation=g.yaw(yaw))

    def motion(self, tau: float) -> Motion:
        return self._m

    def default_sonars(self) -> tuple[SonarMount, ...]:
        p = self._m.position
        return (SonarMount((p[0], p[1] - 1.0, p[2]), (0.0, 1.0, 0.0)),)


class Train(Scenario):
    """A toy train on a circle (thesis ch. 6.1): theta = phase + omega tau (thesis eq. 6.8),
    position center + r(theta) (cos theta, sin theta); the board faces the direction of
    travel (x forward, y towards the centre when omega > 0).

    Rails that are not a perfect circle: r(theta) = radius + out_of_round
    cos(2 (theta - round_phase)) (two lobes, m); the polar angle still advances at the
    constant ``omega`` (what a lap count measures), while the heading, hence the gyroscope,
    turns a little faster where the track is tighter. ``gauge`` (m): distance between the
    two rails (thesis ch. 6.5: inner 0.57, outer 0.615 m). ``rest_phase`` (rad): where the
    train really stands when it is "placed at 0 deg" for the calibrations (a magnetometer
    calibrated there reads theta - rest_phase). ``tilt`` (rad) about the horizontal axis at
    ``tilt_axis`` (rad from x): a table that is not level (the board turns with the track's
    plane; gravity then leaks into the accelerometer's y axis once per lap).
    """

    kind = "train"
    target = Target(radius=0.05, length=0.5)
    # Thesis eq. 6.1 / fig. C.1: sigma_ac^2 = 0.8 (m/s^2)^2 measured on the running train,
    # dominated by vibrations; eq. 6.4 / fig. C.3: sigma_g^2 = 0.005 (rad/s)^2.
    vibration_acc = math.sqrt(0.8)
    vibration_gyro = math.sqrt(0.005)

    def __init__(
        self,
        center: tuple[float, float] = (0.0, 0.0),
        radius: float = 0.6,
        omega: float = 0.84,
        phase: float = 0.0,
        height: float = 0.0,
        out_of_round: float = 0.0,
        round_phase: float = 0.0,
        rest_phase: float = 0.0,
        gauge: float = 0.045,
        tilt: float = 0.0,
        tilt_axis: float = 0.0,
    ) -> None:
        if radius <= 0:
            raise ValueError(f"train radius must be > 0 m, got {radius!r}")
        if not 0 <= out_of_round < radius / 4:
            raise ValueError(f"train out_of_round must be in [0, radius / 4), got {out_of_round!r}")
        self.center, self.radius, self.omega = center, radius, omega
        self.phase, self.height = phase, height
        self.out_of_round, self.round_phase = out_of_round, round_phase
        self.rest_phase, self.gauge = rest_phase, gauge
        self._dir = -1.0 if omega < 0 else 1.0
        self._tilt = g.axis_angle((math.cos(tilt_axis), math.sin(tilt_axis), 0.0), tilt)

    def radius_at(self, th: float) -> float:
        """The radius of the track's centre line at polar angle ``th`` (m)."""
        return self.radius + self.out_of_round * math.cos(2.0 * (th - self.round_phase))

    def rails(self) -> tuple[float, float]:
        """The radii of the inner and the outer rail, their extremes over the lap (m)."""
        half = self.gauge / 2.0
        return (self.radius - self.out_of_round - half, self.radius + self.out_of_round + half)

    def polar(self, tau: float) -> tuple[float, float, float]:
        """(theta rad, omega rad/s, radius m) of the train about the centre at ``tau``."""
        th = self.phase + self.omega * tau
        return th, self.omega, self.radius_at(th)

    def motion(self, tau: float) -> Motion:
        th = self.phase + self.omega * tau
        return self._at(th, self.omega)

    def _at(self, th: float, w: float) -> Motion:
        a, k = self.out_of_round, 2.0 * (th - self.round_phase)
        r = self.radius + a * math.cos(k)
        dr, ddr = -2.0 * a * math.sin(k), -4.0 * a * math.cos(k)
        c, s = math.cos(th), math.sin(th)
        # p = center + r u, u = (c, s), n = (-s, c): dp/dth = r' u + r n,
        # d2p/dth2 = (r'' - r) u + 2 r' n; v = w dp/dth, acc = w^2 d2p/dth2 (w constant)
        d1 = (dr * c - r * s, dr * s + r * c)
        d2 = ((ddr - r) * c - 2.0 * dr * s, (ddr - r) * s + 2.0 * dr * c)
        heading = math.atan2(self._dir * d1[1], self._dir * d1[0])
        turn = w * (d1[0] * d2[1] - d1[1] * d2[0]) / (d1[0] ** 2 + d1[1] ** 2)
        return Motion(
            position=(self.center[0] + r * c, self.center[1] + r * s, self.height),
            velocity=(w * d1[0], w * d1[1], 0.0),
            acceleration=(w * w * d2[0], w * w * d2[1], 0.0),
            orientation=g.quat_mul(self._tilt, g.yaw(heading)),
            angular_rate=(0.0, 0.0, turn),
        )

    def rest_motion(self) -> Motion:
        m = self._at(self.rest_phase, 0.0)  # the train stopped where it was "placed at 0 deg"
        return Motion(position=m.position, orientation=m.orientation)

    def clutter_range(self, mount: SonarMount, half_angle: float, u: float) -> float | None:
        """The range of the far side of the track seen by a sonar at ``mount`` along the
        ray at ``u`` (-1 .. 1) of its beam's half-angle ``half_angle`` (rad) in the plane:
        where that ray leaves the outer rail's circle, or None if it misses the track."""
        d = mount.direction
        a = math.atan2(d[1], d[0]) + u * half_angle
        ux, uy = math.cos(a), math.sin(a)
        ox, oy = mount.position[0] - self.center[0], mount.position[1] - self.center[1]
        big = self.rails()[1]
        b = ox * ux + oy * uy
        disc = b * b - (ox * ox + oy * oy - big * big)
        if disc <= 0:
            return None
        far = -b + math.sqrt(disc)
        return far if far > 0 else None

    def default_sonars(self) -> tuple[SonarMount, ...]:
        cx, cy = self.center
        d = self.radius + 0.9
        return (
            SonarMount((cx - 0.3, cy - d, self.height), (0.0, 1.0, 0.0)),
            SonarMount((cx + 0.3, cy - d, self.height), (0.0, 1.0, 0.0)),
        )


class Rail(Scenario):
    """Back and forth on a rail (thesis ch. 3.2, 3.4, fig. A.1):
    p = start + length (1 - cos(2 pi tau / period)) / 2 * axis; no rotation, x along the rail."""

    kind = "rail"

    def __init__(
        self,
        start: Vec3 = (0.5, 0.0, 0.0),
        axis: Vec3 = (1.0, 0.0, 0.0),
        length: float = 1.1,
        period: float = 8.0,
    ) -> None:
        if period <= 0:
            raise ValueError(f"rail period must be > 0 s, got {period!r}")
        self.start, self.axis, self.length, self.period = start, g.unit(axis), length, period
        self._q = g.yaw(math.atan2(self.axis[1], self.axis[0]))

    def motion(self, tau: float) -> Motion:
        k = 2.0 * math.pi / self.period
        half = self.length / 2.0
        p = half * (1.0 - math.cos(k * tau))
        v = half * k * math.sin(k * tau)
        a = half * k * k * math.cos(k * tau)
        return Motion(
            position=g.add(self.start, g.scale(self.axis, p)),
            velocity=g.scale(self.axis, v),
            acceleration=g.scale(self.axis, a),
            orientation=self._q,
        )

    def default_sonars(self) -> tuple[SonarMount, ...]:
        back = g.sub(self.start, g.scale(self.axis, 0.5))
        return (SonarMount(back, self.axis),)


class Hand(Scenario):
    """A hand moving a board on a circle without turning it (thesis app. D, eq. D.1-D.4):
    period 1.25 s, acceleration amplitude A = 4 m/s^2, so radius A / omega^2."""

    kind = "hand"

    def __init__(
        self, center: Vec3 = (0.0, 0.0, 0.0), period: float = 1.25, amplitude: float = 4.0
    ) -> None:
        if period <= 0:
            raise ValueError(f"hand period must be > 0 s, got {period!r}")
        self.center = center
        self.omega = 2.0 * math.pi / period
        self.radius = amplitude / self.omega**2

    def motion(self, tau: float) -> Motion:
        w, r = self.omega, self.radius
        c, s = math.cos(w * tau), math.sin(w * tau)
        return Motion(
            position=(self.center[0] + r * c, self.center[1] + r * s, self.center[2]),
            velocity=(-r * w * s, r * w * c, 0.0),
            acceleration=(-r * w * w * c, -r * w * w * s, 0.0),
        )

    def default_sonars(self) -> tuple[SonarMount, ...]:
        cx, cy, cz = self.center
        return (
            SonarMount((cx - 0.3, cy - 1.0, cz), (0.0, 1.0, 0.0)),
            SonarMount((cx + 0.3, cy - 1.0, cz), (0.0, 1.0, 0.0)),
        )


class Target3D(Scenario):
    """A target moved back and forth along x, then y, then z (thesis ch. 7.2, fig. 7.11):
    on the active axis p = center + amplitude (1 - cos(2 pi tau' / period)) / 2."""

    kind = "target3d"

    def __init__(
        self, center: Vec3 = (1.0, 1.0, 1.0), amplitude: float = 0.5, period: float = 6.0
    ) -> None:
        if period <= 0:
            raise ValueError(f"target3d period must be > 0 s, got {period!r}")
        self.center, self.amplitude, self.period = center, amplitude, period

    def motion(self, tau: float) -> Motion:
        leg = math.floor(tau / self.period)
        axis = int(leg) % 3
        k = 2.0 * math.pi / self.period
        ph = k * (tau - leg * self.period)
        half = self.amplitude / 2.0
        p, v, a = [0.0] * 3, [0.0] * 3, [0.0] * 3
        p[axis] = half * (1.0 - math.cos(ph))
        v[axis] = half * k * math.sin(ph)
        a[axis] = half * k * k * math.cos(ph)
        return Motion(
            position=g.add(self.center, (p[0], p[1], p[2])),
            velocity=(v[0], v[1], v[2]),
            acceleration=(a[0], a[1], a[2]),
        )

    def default_sonars(self) -> tuple[SonarMount, ...]:
        x, y, z = self.center
        return (
            SonarMount((0.0, y, z), (1.0, 0.0, 0.0)),
            SonarMount((x, 0.0, z), (0.0, 1.0, 0.0)),
            SonarMount((x, y, 0.0), (0.0, 0.0, 1.0)),
        )


class Rotation(Scenario):
    """360 deg turns about a fixed axis with rests between them (thesis ch. 7.1.3).

    Within a turn of ``duration`` s, s = (tau_c - rest) / duration and the angle is
    2 pi (s - sin(2 pi s) / (2 pi)): the rate starts and ends at zero.
    """

    kind = "rotation"

    def __init__(
        self,
        duration: float = 12.0,
        rest: float = 2.0,
        axis: Vec3 = (0.0, 0.0, 1.0),
        position: Vec3 = ZERO,
    ) -> None:
        if duration <= 0 or rest < 0:
            raise ValueError("rotation duration must be > 0 s and rest >= 0 s")
        self.duration, self.rest, self.axis, self.position = duration, rest, g.unit(axis), position

    def motion(self, tau: float) -> Motion:
        cycle = self.rest + self.duration
        n = math.floor(tau / cycle)
        tc = tau - n * cycle
        angle, rate = 2.0 * math.pi * n, 0.0
        if tc > self.rest:
            s = (tc - self.rest) / self.duration
            angle += 2.0 * math.pi * s - math.sin(2.0 * math.pi * s)
            rate = 2.0 * math.pi / self.duration * (1.0 - math.cos(2.0 * math.pi * s))
        return Motion(
            position=self.position,
            orientation=g.axis_angle(self.axis, angle),
            angular_rate=g.scale(self.axis, rate),
        )

    def default_sonars(self) -> tuple[SonarMount, ...]:
        p = self.position
        return (SonarMount((p[0], p[1] - 1.0, p[2]), (0.0, 1.0, 0.0)),)


class Shaking(Scenario):
    """Shaking without rotation (thesis ch. 7.1.3): p = position + amplitude *
    (sin(2 pi f tau), sin(2 pi 0.77 f tau) / 2, 0)."""

    kind = "shaking"

    def __init__(
        self, position: Vec3 = ZERO, amplitude: float = 0.03, frequency: float = 3.0
    ) -> None:
        self.position, self.amplitude, self.frequency = position, amplitude, frequency

    def motion(self, tau: float) -> Motion:
        w1 = 2.0 * math.pi * self.frequency
        w2 = 0.77 * w1
        a1, a2 = self.amplitude, self.amplitude / 2.0
        return Motion(
            position=g.add(self.position, (a1 * math.sin(w1 * tau), a2 * math.sin(w2 * tau), 0)),
            velocity=(a1 * w1 * math.cos(w1 * tau), a2 * w2 * math.cos(w2 * tau), 0.0),
            acceleration=(
                -a1 * w1 * w1 * math.sin(w1 * tau),
                -a2 * w2 * w2 * math.sin(w2 * tau),
                0.0,
            ),
        )

    def default_sonars(self) -> tuple[SonarMount, ...]:
        p = self.position
        return (SonarMount((p[0], p[1] - 1.0, p[2]), (0.0, 1.0, 0.0)),)


_COMMON = {
    "scenario",
    "epoch",
    "seed",
    "target_radius",
    "target_length",
    "vibration_acc",
    "vibration_gyro",
    "mag_horizontal",
    "mag_vertical",
    "mag_north_deg",
    "altitude",
    "sea_level_hpa",
    "sonars",
}
"""World keys every scenario accepts (see the module docstring)."""


def number(world: Mapping[str, Any], key: str, default: float) -> float:
    """World key ``key`` as a finite number (ValueError naming the key otherwise)."""
    value = world.get(key, default)
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"world {key!r} must be a number, got {value!r}") from None
    if not math.isfinite(out):
        raise ValueError(f"world {key!r} must be finite, got {value!r}")
    return out


def vector(world: Mapping[str, Any], key: str, default: tuple[float, ...]) -> tuple[float, ...]:
    """World key ``key`` as a list of as many numbers as ``default`` has."""
    value = world.get(key, default)
    try:
        out = tuple(float(x) for x in value)
    except (TypeError, ValueError):
        raise ValueError(f"world {key!r} must be a list of numbers, got {value!r}") from None
    if len(out) != len(default):
        raise ValueError(f"world {key!r} must have {len(default)} numbers, got {value!r}")
    return out


_f, _v = number, vector


@dataclass(frozen=True)
class ScenarioKind:
    """A registered scenario: the world keys it takes and how it is built from them."""

    name: str
    params: frozenset[str]
    build: Callable[[Mapping[str, Any]], Scenario]


_REGISTRY: dict[str, ScenarioKind] = {}
EXTRA_SCENARIOS: tuple[str, ...] = (
    "hera.nodes.rough",
    "hera.nodes.ir.scenarios",
    "hera.nodes.tof.scenario",
    "hera.nodes.lsm6dsl.scenario",
)
"""Modules defining more scenarios (each calls :func:`register_scenario` when imported);
imported on first use of the registry. An application's simulated world adds its module
here."""


def register_scenario(
    name: str, params: set[str] | frozenset[str], build: Callable[[Mapping[str, Any]], Scenario]
) -> None:
    """Make scenario ``name`` (its own world keys ``params``) known to :func:`make_scenario`."""
    if name in _REGISTRY:
        raise ValueError(f"scenario {name!r} is registered twice")
    _REGISTRY[name] = ScenarioKind(name, frozenset(params), build)


def scenarios() -> dict[str, ScenarioKind]:
    """Every registered scenario, by name."""
    import importlib

    for module in EXTRA_SCENARIOS:
        importlib.import_module(module)
    return dict(_REGISTRY)


def _rotation(kind: str) -> Callable[[Mapping[str, Any]], Scenario]:
    def build(w: Mapping[str, Any]) -> Scenario:
        return Rotation(
            _f(w, "duration", 12.0 if kind == "rotation_slow" else 2.0),
            _f(w, "rest", 2.0),
            _v(w, "axis", (0.0, 0.0, 1.0)),  # type: ignore[arg-type]
            _v(w, "position", ZERO),  # type: ignore[arg-type]
        )

    return build


register_scenario(
    "still",
    {"position", "yaw"},
    lambda w: Still(_v(w, "position", ZERO), _f(w, "yaw", 0.0)),  # type: ignore[arg-type]
)
TRAIN_KEYS = frozenset(
    {"center", "radius", "omega", "phase", "height", "out_of_round", "round_phase_deg"}
    | {"rest_phase_deg", "gauge", "tilt_deg", "tilt_axis_deg"}
)
"""World keys of the ``train`` scenario (see :class:`Train`; angles in degrees)."""


def train_from(w: Mapping[str, Any], **defaults: float) -> Train:
    """A :class:`Train` from a world table; ``defaults`` replace the built-in defaults of
    its keys (``round_phase_deg``, ``rest_phase_deg`` in degrees)."""
    d = {"radius": 0.6, "omega": 0.84, "phase": 0.0, "height": 0.0, "out_of_round": 0.0}
    d.update({"round_phase_deg": 0.0, "rest_phase_deg": 0.0, "gauge": 0.045})
    d.update({"tilt_deg": 0.0, "tilt_axis_deg": 0.0})
    d.update(defaults)
    return Train(
        _v(w, "center", (0.0, 0.0)),  # type: ignore[arg-type]
        _f(w, "radius", d["radius"]),
        _f(w, "omega", d["omega"]),
        _f(w, "phase", d["phase"]),
        _f(w, "height", d["height"]),
        _f(w, "out_of_round", d["out_of_round"]),
        math.radians(_f(w, "round_phase_deg", d["round_phase_deg"])),
        math.radians(_f(w, "rest_phase_deg", d["rest_phase_deg"])),
        _f(w, "gauge", d["gauge"]),
        math.radians(_f(w, "tilt_deg", d["tilt_deg"])),
        math.radians(_f(w, "tilt_axis_deg", d["tilt_axis_deg"])),
    )


register_scenario("train", TRAIN_KEYS, train_from)
register_scenario(
    "rail",
    {"start", "axis", "length", "period"},
    lambda w: Rail(
        _v(w, "start", (0.5, 0.0, 0.0)),  # type: ignore[arg-type]
        _v(w, "axis", (1.0, 0.0, 0.0)),  # type: ignore[arg-type]
        _f(w, "length", 1.1),
        _f(w, "period", 8.0),
    ),
)
register_scenario(
    "hand",
    {"center", "period", "amplitude"},
    lambda w: Hand(_v(w, "center", ZERO), _f(w, "period", 1.25), _f(w, "amplitude", 4.0)),  # type: ignore[arg-type]
)
register_scenario(
    "target3d",
    {"center", "amplitude", "period"},
    lambda w: Target3D(
        _v(w, "center", (1.0, 1.0, 1.0)),  # type: ignore[arg-type]
        _f(w, "amplitude", 0.5),
        _f(w, "period", 6.0),
    ),
)
register_scenario(
    "rotation_slow", {"duration", "rest", "axis", "position"}, _rotation("rotation_slow")
)
register_scenario(
    "rotation_fast", {"duration", "rest", "axis", "position"}, _rotation("rotation_fast")
)
register_scenario(
    "shaking",
    {"position", "amplitude", "frequency"},
    lambda w: Shaking(_v(w, "position", ZERO), _f(w, "amplitude", 0.03), _f(w, "frequency", 3.0)),  # type: ignore[arg-type]
)

SCENARIOS = tuple(_REGISTRY)
"""The scenarios of this module (more come from :data:`EXTRA_SCENARIOS`: :func:`scenarios`)."""


def make_scenario(world: Mapping[str, Any]) -> Scenario:
    """Build the scenario a ``[world]`` table describes; ValueError on unknown names/keys."""
    known = scenarios()
    kind = world.get("scenario", "still")
    if kind not in known:
        raise ValueError(f"unknown world scenario {kind!r}; choose one of {tuple(known)}")
    entry = known[kind]
    unknown = set(world) - _COMMON - entry.params
    if unknown:
        raise ValueError(
            f"unknown world keys for scenario {kind!r}: {sorted(unknown)}; "
            f"allowed: {sorted(entry.params | _COMMON)}"
        )
    w = world
    sc = entry.build(w)
    sc.kind = kind
    if "target_radius" in w or "target_length" in w:
        sc.target = Target(
            radius=_f(w, "target_radius", sc.target.radius),
            length=_f(w, "target_length", sc.target.length),
        )
    if "vibration_acc" in w:
        sc.vibration_acc = _f(w, "vibration_acc", 0.0)
    if "vibration_gyro" in w:
        sc.vibration_gyro = _f(w, "vibration_gyro", 0.0)
    return sc


def environment(world: Mapping[str, Any]) -> Environment:
    """The magnetic field and pressure reference of a ``[world]`` table."""
    return Environment(
        mag_horizontal=_f(world, "mag_horizontal", 0.205),
        mag_vertical=_f(world, "mag_vertical", 0.44),
        mag_north=math.radians(_f(world, "mag_north_deg", 90.0)),
        altitude=_f(world, "altitude", 100.0),
        sea_level_hpa=_f(world, "sea_level_hpa", 1013.25),
    )


def epoch_of(world: Mapping[str, Any]) -> float:
    """The shared epoch (epoch seconds) of a world table; 0.0 if absent."""
    return _f(world, "epoch", 0.0)


def world_problems(world: Mapping[str, Any]) -> list[str]:
    """What refuses a ``[world]`` table, one sentence each; [] when the simulator knows its
    scenario, the scenario's keys and values, the environment and the epoch."""
    try:
        make_scenario(world)
        environment(world)
        epoch_of(world)
    except ValueError as e:
        return [str(e)]
    return []


def state_at(scenario: Scenario, epoch: float, t: float) -> State:
    """The :class:`State` of ``scenario`` at epoch time ``t``."""
    m = scenario.motion(t - epoch)
    return State(t, m.position, m.velocity, m.acceleration, m.orientation, m.angular_rate)


def state_of(m: Motion, t: float) -> State:
    """A :class:`State` at epoch time ``t`` from a :class:`Motion`."""
    return State(t, m.position, m.velocity, m.acceleration, m.orientation, m.angular_rate)


def truth_at(world: Mapping[str, Any], t: float) -> State:
    """The true state of the world table's scenario at epoch time ``t`` (pure function).

    Scoring code: ``truth_at(spec.world, sample.t)``; for many calls build the scenario
    once with :func:`make_scenario` and use :func:`state_at`.
    """
    return state_at(make_scenario(world), epoch_of(world), t)
