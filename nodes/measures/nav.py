"""The Pmod NAV measures of the thesis: ``nav``, ``mag`` and ``nav3`` (REFERENCE table).

All read a board through :class:`hera.nodes.driver.NavDriver` (the simulator by default, a
real driver with the arg ``driver``) and calibrate once: the result is stored in the
replicated args store under ``calib/<node>/<measure>`` and read back first, so a restarted
measure does not recalibrate. Measures of one node naming the same ``board`` share one board.
Counters: ``dropouts``, ``disconnected`` (:mod:`hera.nodes.board_reads`).

Their arguments are declared (:data:`NAV_ARGS`, ``arguments`` of each class): unknown or
ill-typed ones are refused before a node starts.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any, ClassVar

from hera.measure import MeasureContext, Reading
from hera.nodes import boards
from hera.nodes import geometry as gm
from hera.nodes.board_reads import BoardReads, board_needed
from hera.nodes.boards import BOARD_ARGS, BoardMeasure
from hera.nodes.calibration import (
    calibrate_mag,
    calibrate_nav,
    calibrate_nav3,
    heading,
    is_vec,
    rotate_y,
    stored_or_run,
)
from hera.nodes.driver import ImuSample, NavDriver, SimulatedBoard
from hera.nodes.truth import TruthRecorder, want_truth
from hera.nodes.world import G, State
from hera.schema import BOOL, STR, Setting, Table, choice, number


def nav_args(calib_samples: int, *extra: Setting) -> Table:
    """The arguments of a NAV measure: the board and its calibration (+ ``extra``)."""
    return Table(
        "nav args",
        [
            Setting("board", STR, "nav", "board name (measures naming one board share it)"),
            *BOARD_ARGS,
            Setting(
                "calib_samples", number(1, integer=True), calib_samples, "samples to calibrate on"
            ),
            *extra,
        ],
    )


def _yaw(q: gm.Quat) -> float:
    w, x, y, z = q
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


class _NavMeasure(BoardMeasure):
    """Shared set-up: the board, the truth recorder."""

    truth_columns: ClassVar[tuple[str, ...]] = ()
    inputs = ()  # reads its board, not the store

    board: NavDriver
    _truth: TruthRecorder | None = None

    def _setup(self, args: Mapping[str, Any], ctx: MeasureContext) -> Mapping[str, Any]:
        """Open the board and the truth recorder; return the args with their defaults."""
        args = self.prepare_args(args)
        super().init(args, ctx)
        with board_needed():
            self.board = boards.open_nav(ctx, args)
        self.reads = BoardReads(ctx)
        self._truth = None
        if want_truth(args, ctx.run_dir):
            self._truth = TruthRecorder(
                ctx.run_dir,  # type: ignore[arg-type]
                ctx.spec.name,
                ctx.node,
                self.truth_columns,
                ctx.world,
            )
        elif args.get("truth"):
            ctx.log.warning("truth asked but there is no run directory: not recorded")
        return args

    def _calibration(
        self, run: Callable[[], dict[str, Any]], check: Callable[[Any], bool]
    ) -> dict[str, Any]:
        """The stored calibration, else one made on the board now (``stored_or_run``); a
        board that does not answer makes the measure wait for it (NotReady)."""
        with board_needed():
            return stored_or_run(self.ctx, run, check)

    def _state(self, t: float) -> State | None:
        b = self.board
        return b.truth(t) if isinstance(b, SimulatedBoard) else None

    def close(self) -> None:
        if self._truth is not None:
            self._truth.close()
            self._truth = None


class Nav(_NavMeasure):
    """The train IMU: ``[a_y [m/s^2], g_z [rad/s]]``.

    Bias removal and tilt correction as thesis ch. 3.2.1: subtract the still means (acc
    including gravity, gyro), rotate about y by the tilt found from gravity (eqs. 3.7-3.11),
    then a_y * 9.81 and g_z * pi / 180. Calibration: mean of ``calib_samples`` (500) still
    samples. In the train scenario a_y is the centripetal acceleration r omega^2 and g_z the
    angular rate omega (thesis eqs. 6.1, 6.4).
    """

    name = "nav"
    period = 0.05
    columns = ("a_y [m/s^2]", "g_z [rad/s]")
    truth_columns = ("true a_y [m/s^2]", "true g_z [rad/s]")
    arguments = nav_args(500)

    def init(self, args: Mapping[str, Any], ctx: MeasureContext) -> None:
        args = self._setup(args, ctx)
        n = args["calib_samples"]
        cal = self._calibration(
            lambda: calibrate_nav(self.board, n),
            lambda c: (
                isinstance(c, Mapping)
                and is_vec(c.get("acc"))
                and is_vec(c.get("gyro"))
                and is_vec([c.get("sin_tilt")], 1)
            ),
        )
        self.acc0: gm.Vec3 = tuple(cal["acc"])  # type: ignore[assignment]
        self.gyro0: gm.Vec3 = tuple(cal["gyro"])  # type: ignore[assignment]
        self.sin_tilt = float(cal["sin_tilt"])

    def measure(self) -> Reading | None:
        s = self.reads.read(self.board.read_imu, mag=False)
        if s is None:
            return None
        a = rotate_y(gm.sub(s.acc, self.acc0), self.sin_tilt)
        w = rotate_y(gm.sub(s.gyro, self.gyro0), self.sin_tilt)
        if self._truth is not None:
            st = self._state(s.t)
            if st is not None:
                lin = gm.unrotate(st.orientation, st.acceleration)
                self._truth.write(st, (lin[1], st.angular_rate[2]))
        return Reading((a[1] * G, w[2] * math.pi / 180.0), s.t)


class Mag(_NavMeasure):
    """Heading from the magnetometer: ``[heading [rad]]`` in [-pi, pi).

    heading = -wrap(atan2(m_y - b_y, m_x - b_x) - offset) (thesis eq. 6.6), counter-clockwise
    like the train's theta and the gyro's g_z in our z-up board frame: in the train scenario it
    equals theta. Arg ``clockwise = true`` gives the original formula's sign (a compass
    heading). Calibration (thesis ch. 6.6): hard-iron (b_x, b_y) from two means of
    ``calib_samples`` (10) readings 180 deg apart, then ``offset`` = the raw angle in the
    scenario's "0 deg" pose.
    """

    name = "mag"
    period = 0.3
    columns = ("heading [rad]",)
    truth_columns = ("true heading [rad]",)
    arguments = nav_args(
        10, Setting("clockwise", BOOL, False, "the original formula's sign (a compass heading)")
    )

    def init(self, args: Mapping[str, Any], ctx: MeasureContext) -> None:
        args = self._setup(args, ctx)
        self.sign = 1.0 if args["clockwise"] else -1.0
        n = args["calib_samples"]
        cal = self._calibration(
            lambda: calibrate_mag(self.board, n=n),
            lambda c: (
                isinstance(c, Mapping) and is_vec(c.get("bias"), 2) and is_vec([c.get("offset")], 1)
            ),
        )
        self.bias = (float(cal["bias"][0]), float(cal["bias"][1]))
        self.offset = float(cal["offset"])
        b = self.board
        self._yaw0 = _yaw(b.rest_truth().orientation) if isinstance(b, SimulatedBoard) else 0.0

    def measure(self) -> Reading | None:
        s = self.reads.read(self.board.read_imu, mag=True)
        if s is None:
            return None
        m = s.mag
        assert m is not None
        h = gm.wrap_angle(self.sign * heading(m[0], m[1], self.bias, self.offset))
        if self._truth is not None:
            st = self._state(s.t)
            if st is not None:
                true_h = gm.wrap_angle(_yaw(st.orientation) - self._yaw0)
                self._truth.write(st, (true_h if self.sign < 0 else gm.wrap_angle(-true_h),))
        return Reading((h,), s.t)


def is_matrix(value: Any) -> bool:
    """True if ``value`` is a 3x3 matrix of finite numbers (a list of 3 rows)."""
    return isinstance(value, (list, tuple)) and len(value) == 3 and all(is_vec(r) for r in value)


def nav3_values(s: ImuSample, cal: Mapping[str, Any]) -> tuple[float, ...]:
    """The 9 values ``nav3`` publishes for one board reading, given its calibration ``cal``
    (:func:`~hera.nodes.calibration.calibrate_nav3`): acc (m/s^2), gyro less its bias
    (rad/s), magnetometer less its hard iron (gauss). A ``full`` calibration also corrects
    the accelerometer's bias and scale and the magnetometer's soft iron, then turns all
    three into the body frame (``mount``)."""
    m = s.mag
    if m is None:
        raise ValueError("nav3 needs a magnetometer reading")
    k = math.pi / 180.0
    g0, b = cal["gyro"], cal["mag"]
    a = s.acc
    gyro = ((s.gyro[0] - g0[0]) * k, (s.gyro[1] - g0[1]) * k, (s.gyro[2] - g0[2]) * k)
    mag = (m[0] - b[0], m[1] - b[1], m[2] - b[2])
    mount = cal.get("mount")
    if mount is not None:
        ab = cal["acc_bias"]
        a = gm.mat_vec(cal["acc_scale"], (a[0] - ab[0], a[1] - ab[1], a[2] - ab[2]))
        mag = gm.mat_vec(cal["soft_iron"], mag)
        a, gyro, mag = gm.mat_vec(mount, a), gm.mat_vec(mount, gyro), gm.mat_vec(mount, mag)
    return (a[0] * G, a[1] * G, a[2] * G, *gyro, *mag)


class Nav3(_NavMeasure):
    """The 9-axis IMU: acc (m/s^2, specific force), gyro (rad/s, bias removed), mag (gauss,
    hard-iron removed), all in the right-handed board frame (x forward, y left, z up; flat and
    still reads acc (0, 0, +9.81)): down is -acc. Calibration (thesis ch. 7.1.1): gyro mean of
    ``calib_samples`` (300) still samples; 3-D hard iron by turns of 180 deg about z then x.

    Beyond the thesis, ``calibration = "full"`` (default ``"thesis"``): the board is turned
    through 48 poses and ellipsoid fits give the accelerometer's bias and scale and the
    magnetometer's hard and soft iron (thesis ch. 7.1.1 left soft iron out); all three
    vectors are then published in the body frame, the body being level in the calibration
    pose (the mounting tilt taken out, see :func:`~hera.nodes.calibration.calibrate_nav3`).
    :func:`nav3_values` says exactly what is published.
    """

    name = "nav3"
    period = 0.1
    columns = (
        "acc_x [m/s^2]",
        "acc_y [m/s^2]",
        "acc_z [m/s^2]",
        "gyro_x [rad/s]",
        "gyro_y [rad/s]",
        "gyro_z [rad/s]",
        "mag_x [gauss]",
        "mag_y [gauss]",
        "mag_z [gauss]",
    )

    arguments = nav_args(
        300,
        Setting(
            "calibration",
            choice("thesis", "full"),
            "thesis",
            "`thesis`: gyro bias, hard iron (ch. 7.1.1); `full`: + accelerometer bias and "
            "scale, soft iron, body frame",
        ),
    )

    def init(self, args: Mapping[str, Any], ctx: MeasureContext) -> None:
        args = self._setup(args, ctx)
        n = args["calib_samples"]
        full = args["calibration"] == "full"
        self.cal = self._calibration(
            lambda: calibrate_nav3(self.board, n_gyro=n, full=full),
            lambda c: (
                isinstance(c, Mapping)
                and is_vec(c.get("gyro"))
                and is_vec(c.get("mag"))
                and (
                    not full
                    or (
                        is_vec(c.get("acc_bias"))
                        and all(is_matrix(c.get(k)) for k in ("acc_scale", "soft_iron", "mount"))
                    )
                )
            ),
        )
        if not full:  # a full calibration stored earlier: use only its thesis part
            self.cal.pop("mount", None)
        self.gyro0: gm.Vec3 = tuple(self.cal["gyro"])  # type: ignore[assignment]
        self.mag0: gm.Vec3 = tuple(self.cal["mag"])  # type: ignore[assignment]

    def measure(self) -> Reading | None:
        s = self.reads.read(self.board.read_imu, mag=True)
        if s is None:
            return None
        values = nav3_values(s, self.cal)
        if self._truth is not None:
            st = self._state(s.t)
            if st is not None:
                self._truth.write(st)
        return Reading(values, s.t)
