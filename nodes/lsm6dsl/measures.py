"""The ``lsm6dsl`` measure: a 6-axis IMU on a self-balancing robot, and its gyro calibration.

Publishes, at the output data rate (``odr_hz``, the seed's 26 Hz by default; the spec's
``period`` must be 1 / ``odr_hz``), ``[a_X [m/s^2], a_Z [m/s^2], g_Y [rad/s], b_gyro [rad/s],
calibration]`` in the seed's sensor convention (eqs. 20a-c: a robot leaning forward by theta
reads a_X = |g| sin theta, a_Z = |g| cos theta, g_Y = d theta / dt + b_gyro; the seed's X axis
points backward, so a_X is minus the chip's x). The gyroscope is published raw: ``b_gyro`` is
the calibrated bias (0 before any calibration), which the tilt models take as their control
input (seed eq. 25a), and ``calibration`` says where that stands: 0 none, 1 calibrating,
2 calibrated.

Calibration (seed sec. 4.3, "calibration mode"; :mod:`hera.nodes.lsm6dsl.calibration`): the
mean of ``calib_samples`` (100) still gyroscope samples, restarted while the robot moves. It
runs at the start when ``calibration = "at_start"`` (the default) and no bias is stored yet,
and whenever an operator asks with the ``gyro_calibration`` control verb. The result goes to
the replicated args store under ``calib/<node>/<measure>`` (``b_gyro_dps``, chip axes), so a
restarted measure or node keeps it and never recalibrates by itself. Counters:
``calibrations``, ``calib_restarts`` (motion seen during a calibration), ``dropouts``,
``disconnected`` (:mod:`hera.nodes.board_reads`).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Mapping
from typing import Any

from hera.measure import MeasureContext, Reading
from hera.nodes import boards
from hera.nodes.board_reads import BoardReads, board_needed
from hera.nodes.boards import BOARD_ARGS, BoardMeasure
from hera.nodes.calibration import calib_key, is_vec
from hera.nodes.lsm6dsl.calibration import GyroCalibration
from hera.nodes.lsm6dsl.driver import ODRS_HZ, ImuReading, Lsm6dslDriver
from hera.nodes.lsm6dsl.model import IMU_MODEL, ImuModel
from hera.nodes.lsm6dsl.sim import SimLsm6dsl
from hera.nodes.world import G, epoch_of, make_scenario
from hera.resources import Resources
from hera.schema import STR, Setting, Table, choice, number

NONE, CALIBRATING, CALIBRATED = 0, 1, 2

LSM6DSL_ARGS = Table(
    "lsm6dsl args",
    [
        Setting("board", STR, "imu", "board name"),
        *BOARD_ARGS,
        Setting("odr_hz", number(above=0), 26.0, "output data rate (Hz), one of the chip's"),
        Setting(
            "calibration",
            choice("at_start", "on_request"),
            "at_start",
            "`at_start`: calibrate when no bias is stored; `on_request`: only when asked",
        ),
        Setting("calib_samples", number(1, integer=True), 100, "still samples averaged"),
        Setting("still_gyro_dps", number(above=0), 1.5, "deg/s a still gyro stays within"),
        Setting("still_acc_g", number(above=0), 0.02, "g a still accelerometer stays within"),
    ],
)


class CalibrationDesk:
    """The gyro calibrations of one node's ``lsm6dsl`` measures: requests from the control
    verb and the states the measures report (kept in the node's resources, so a request
    survives a measure restart). Thread-safe."""

    RESOURCE = "hera.nodes.lsm6dsl.calibrations"

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._pending: set[str] = set()
        self._states: dict[str, dict[str, Any]] = {}

    @classmethod
    def of(cls, resources: Resources) -> CalibrationDesk:
        return resources.get_or_create(cls.RESOURCE, cls)

    def request(self, measure: str) -> dict[str, Any]:
        """Ask measure ``measure`` to calibrate at its next step; ValueError if this node
        runs no such measure."""
        with self._lock:
            if measure not in self._states:
                known = ", ".join(sorted(self._states)) or "none"
                raise ValueError(
                    f"no lsm6dsl measure {measure!r} on this node; lsm6dsl measures: {known}"
                )
            self._pending.add(measure)
            return {"measure": measure, "requested": True, **self._states[measure]}

    def take(self, measure: str) -> bool:
        """Whether a calibration of ``measure`` was asked for (the request is consumed)."""
        with self._lock:
            if measure in self._pending:
                self._pending.discard(measure)
                return True
            return False

    def report(self, measure: str, state: Mapping[str, Any]) -> None:
        with self._lock:
            self._states[measure] = dict(state)

    def states(self) -> dict[str, dict[str, Any]]:
        with self._lock:
            return {
                m: {**s, "requested": m in self._pending} for m, s in sorted(self._states.items())
            }


def open_imu(ctx: MeasureContext, args: Mapping[str, Any]) -> Any:
    """The LSM6DSL ``args["board"]`` of ``ctx.node``: one registered under that id, else the
    driver the args name, else a simulator built from ``ctx.world`` and the arg ``model``,
    sampling on its own clock (``stamps = "chip"``: a node's timing does not change the
    samples; on a node's virtual clock it makes a sample at each read)."""

    def make(bid: str, seed: int) -> SimLsm6dsl:
        clock = ctx.resources.get(boards.CLOCK)
        timing = {"clock": clock} if clock is not None else {"stamps": "chip", "sleep": time.sleep}
        return SimLsm6dsl(
            bid,
            make_scenario(ctx.world),
            epoch_of(ctx.world),
            ImuModel.from_args(args.get("model")),
            seed,
            odr_hz=float(args.get("odr_hz", 26.0)),
            **timing,
        )

    return boards.open_board(ctx, args, "imu", Lsm6dslDriver, "an LSM6DSL driver", make, "lsm6dsl")


def stored_bias(value: Any) -> tuple[float, float, float] | None:
    """The gyro bias (deg/s) of a stored calibration, or None if it is not a valid one."""
    if isinstance(value, Mapping) and is_vec(value.get("b_gyro_dps")):
        return tuple(float(v) for v in value["b_gyro_dps"])  # type: ignore[return-value]
    return None


class Lsm6dsl(BoardMeasure):
    """An LSM6DSL accelerometer + gyroscope (see the module docstring)."""

    name = "lsm6dsl"
    period = 1.0 / 26.0
    columns = ("a_X [m/s^2]", "a_Z [m/s^2]", "g_Y [rad/s]", "b_gyro [rad/s]", "calibration")
    arguments = LSM6DSL_ARGS

    @classmethod
    def check_args(cls, args: Mapping[str, Any], where: str) -> list[str]:
        problems = super().check_args(args, where)
        model = args.get("model")
        if isinstance(model, Mapping):
            IMU_MODEL.parse(model, f"{where}: model", problems)
        odr = args.get("odr_hz", 26.0)
        if isinstance(odr, (int, float)) and odr not in ODRS_HZ:
            problems.append(f"{where}: odr_hz must be one of {ODRS_HZ} (Hz), got {odr!r}")
        return problems

    def init(self, args: Mapping[str, Any], ctx: MeasureContext) -> None:
        problems = self.check_args(args, f"measure {ctx.spec.name!r}")
        if problems:
            raise ValueError("; ".join(problems))
        args = self.prepare_args(args)
        super().init(args, ctx)
        odr = args["odr_hz"]
        period = ctx.spec.period
        if period is not None and abs(period * odr - 1.0) > 0.05:
            raise ValueError(
                f"measure {ctx.spec.name!r}: period {period:g} s does not match odr_hz {odr:g}; "
                f"give period = {1.0 / odr:.6g} (1 / odr_hz)"
            )
        with board_needed():
            self.board = open_imu(ctx, args)
        if self.board.odr_hz != odr:
            raise ValueError(
                f"measure {ctx.spec.name!r}: its board runs at {self.board.odr_hz:g} Hz, the "
                f"measure's odr_hz is {odr:g}: give both the same rate"
            )
        self.reads = BoardReads(ctx)
        self.key = calib_key(ctx)
        self.desk = CalibrationDesk.of(ctx.resources)
        self._calib_args = (args["calib_samples"], args["still_gyro_dps"], args["still_acc_g"])
        self.calib: GyroCalibration | None = None
        held = ctx.args.get(self.key)
        self.bias = stored_bias(held)
        if held is not None and self.bias is None:
            ctx.log.warning("ignoring malformed calibration %s = %r", self.key, held)
        if self.bias is None and args["calibration"] == "at_start":
            self._start_calibration()
        self._report()

    def _start_calibration(self) -> None:
        n, tol_g, tol_a = self._calib_args
        self.calib = GyroCalibration(n, tol_g, tol_a)

    def _state(self) -> int:
        if self.calib is not None:
            return CALIBRATING
        return CALIBRATED if self.bias is not None else NONE

    def _report(self) -> None:
        st: dict[str, Any] = {
            "state": ("none", "calibrating", "calibrated")[self._state()],
            "b_gyro_dps": None if self.bias is None else list(self.bias),
        }
        if self.calib is not None:
            s = self.calib.status()
            st.update(progress=s.state, collected=s.collected, needed=s.needed, restarts=s.restarts)
        self.desk.report(self.ctx.spec.name or self.name, st)

    def measure(self) -> Reading | list[Reading] | None:
        if self.desk.take(self.ctx.spec.name or self.name):
            self._start_calibration()
        r = self.reads.read(self.board.read_imu)
        if r is None:
            return None
        out = [self._reading(r)]
        # A driver that keeps its samples (``pending``) may hold more than one: all of them,
        # in order, so no gyroscope interval is lost to a late step.
        while getattr(self.board, "pending", 0) > 0:
            r = self.reads.read(self.board.read_imu)
            if r is None:
                break
            out.append(self._reading(r))
        return out[0] if len(out) == 1 else out

    def _reading(self, r: ImuReading) -> Reading:
        """One sample in the seed's convention, fed to a calibration under way."""
        if self.calib is not None:
            restarts = self.calib.restarts
            done = self.calib.feed(r.acc, r.gyro)
            self.ctx.count("calib_restarts", self.calib.restarts - restarts)
            if done:
                self.bias = self.calib.result
                self.calib = None
                self.ctx.args.put(self.key, {"b_gyro_dps": list(self.bias), "t": r.t})
                self.ctx.count("calibrations")
            self._report()
        b = 0.0 if self.bias is None else math.radians(self.bias[1])
        return Reading(
            (-r.acc[0] * G, r.acc[2] * G, math.radians(r.gyro[1]), b, float(self._state())),
            r.t,
        )
