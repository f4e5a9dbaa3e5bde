"""The seed-000 rig's board measures: ``sharp_ir`` and ``thermocouple``.

``sharp_ir`` publishes the raw output of a Sharp IR sensor (the seed's EKF works in voltage
space) with the sensor's pose: ``[voltage [V], x [cm], y [cm], heading [deg]]`` (the pose
from the scanner carriage when the board has one, else the args). ``thermocouple``
publishes ``[temperature [degC], x [cm], y [cm]]``. A disconnected channel is a missing
reading, as the seed's firmware marks it invalid: the measure publishes nothing that step
and counts it (``disconnected``), so tracking goes on with the other sensors and this one
is back the step after the channel is.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from hera.measure import MeasureContext, Reading
from hera.nodes.board_reads import BoardReads, board_needed
from hera.nodes.boards import BOARD_ARGS, BoardMeasure
from hera.nodes.ir.boards import open_ir, open_thermocouple, thermocouple_position
from hera.nodes.ir.driver import PosedIr, SimulatedIr, SimulatedThermocouple
from hera.nodes.ir.sharp import VARIANTS, variant
from hera.nodes.truth import TruthRecorder, want_truth
from hera.schema import STR, Setting, Table, list_of, number, text

_XY = list_of(number(), "[x, y] in cm")


def _variant(name: str) -> None:
    try:
        variant(name)
    except ValueError:
        known = ", ".join(f"{p} ({v.alias})" for p, v in VARIANTS.items())
        raise ValueError(f"must be one of {known}") from None


IR_ARGS = Table(
    "sharp_ir args",
    [
        Setting("board", STR, "ir", "board name"),
        *BOARD_ARGS,
        Setting(
            "variant",
            text(_variant, "a Sharp part number or short, medium, long"),
            "GP2Y0A21YK0F",
            f"the sensor: {', '.join(f'{p} ({v.alias})' for p, v in VARIANTS.items())}",
        ),
        Setting("scanner", STR, None, "the plate world's scanner carriage it rides on"),
        Setting("position_cm", _XY, None, "fixed mount [x, y] (cm), default the origin"),
        Setting("heading_deg", number(), 0.0, "fixed mount: where it looks (0 = +x, 90 = +y)"),
    ],
)

TC_ARGS = Table(
    "thermocouple args",
    [
        Setting("board", STR, "tc", "board name"),
        *BOARD_ARGS,
        Setting("position_cm", _XY, None, "[x, y] (cm) on the plate"),
        Setting("index", number(0, integer=True), 0, "else the plate world's thermocouple number"),
    ],
)


class _Board(BoardMeasure):
    """Shared: the truth recorder and the board's reads (:mod:`hera.nodes.board_reads`)."""

    _truth: TruthRecorder | None = None
    reads: BoardReads

    def _open_truth(self, args: Mapping[str, Any], ctx: MeasureContext, column: str) -> None:
        self._truth = None
        if want_truth(args, ctx.run_dir):
            self._truth = TruthRecorder(ctx.run_dir, ctx.spec.name, ctx.node, (column,), ctx.world)  # type: ignore[arg-type]
        elif args.get("truth"):
            ctx.log.warning("truth asked but there is no run directory: not recorded")

    def _read(self) -> Any:
        """The board's sample, or None (counted) when the channel is unreachable."""
        return self.reads.read(self.board.read_sample)

    def close(self) -> None:
        if self._truth is not None:
            self._truth.close()
            self._truth = None


class SharpIr(_Board):
    """A Sharp IR range sensor: ``[voltage [V], x [cm], y [cm], heading [deg]]`` at 50 Hz."""

    name = "sharp_ir"
    period = 0.02
    columns = ("voltage [V]", "x [cm]", "y [cm]", "heading [deg]")
    arguments = IR_ARGS

    def init(self, args: Mapping[str, Any], ctx: MeasureContext) -> None:
        args = self.prepare_args(args)
        super().init(args, ctx)
        with board_needed():
            self.board = open_ir(ctx, args)
        self.reads = BoardReads(ctx)
        pos = args["position_cm"] or (0.0, 0.0)
        self.mount = (float(pos[0]), float(pos[1]), float(args["heading_deg"]))
        self._open_truth(args, ctx, "true distance [cm]")

    def measure(self) -> Reading | None:
        s = self._read()
        if s is None:
            return None
        pose = self.board.pose(s.t) if isinstance(self.board, PosedIr) else self.mount
        if self._truth is not None and isinstance(self.board, SimulatedIr):
            self._truth.write(self.board.truth(s.t), (self.board.true_distance(s.t),))
        return Reading((s.volts, *pose), s.t)


class Thermocouple(_Board):
    """A type-K thermocouple under the plate: ``[temperature [degC], x [cm], y [cm]]``, 5 Hz."""

    name = "thermocouple"
    period = 0.2
    columns = ("temperature [degC]", "x [cm]", "y [cm]")
    arguments = TC_ARGS

    def init(self, args: Mapping[str, Any], ctx: MeasureContext) -> None:
        args = self.prepare_args(args)
        super().init(args, ctx)
        with board_needed():
            self.board = open_thermocouple(ctx, args)
        self.reads = BoardReads(ctx)
        self.position = thermocouple_position(ctx, args)
        self._open_truth(args, ctx, "true temperature [degC]")

    def measure(self) -> Reading | None:
        s = self._read()
        if s is None:
            return None
        if self._truth is not None and isinstance(self.board, SimulatedThermocouple):
            self._truth.write(self.board.truth(s.t), (self.board.true_temperature(s.t),))
        return Reading((s.celsius, *self.position), s.t)
