"""The MaxSonar measure of the thesis: ``sonar`` -> ``[range [m], x, y]`` (REFERENCE table).

Publishes nothing ("undefined") when the range exceeds ``max_range``. Synchronised by
default (``sync = true``): the runtime asks the group's sync service for a slot and sets
``ctx.grant`` (the sync turn) while the step runs; the driver checks it at the trigger, and
the ping is announced with that grant. Counters:
``pings``, ``crosstalk`` (readings corrupted by another sonar of the group sounding at the
same time), ``dropouts``, ``disconnected`` (:mod:`hera.nodes.board_reads`).

Its arguments are declared in :data:`SONAR_ARGS` (``hera measures sonar`` lists
them); the board arguments are those of :func:`hera.nodes.boards.open_sonar`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from hera.measure import MeasureContext, Reading
from hera.nodes import boards
from hera.nodes.board_reads import BoardReads, board_needed
from hera.nodes.boards import BOARD_ARGS, BoardMeasure
from hera.nodes.driver import SimulatedSonar
from hera.nodes.sonar_model import INCH
from hera.nodes.truth import TruthRecorder, want_truth
from hera.schema import BOOL, STR, Setting, Table, list_of, number

_NUM = number()
_VEC3 = list_of(_NUM, "[x, y, z]")
SONAR_ARGS = Table(
    "sonar args",
    [
        Setting("board", STR, "sonar", "board name"),
        *BOARD_ARGS,
        Setting("max_range", number(above=0), 6.45, "m; a longer range publishes nothing"),
        Setting("x", _NUM, None, "first number published after the range (default: position x)"),
        Setting("y", _NUM, None, "second one (default: position y)"),
        Setting("position", _VEC3, None, "m (else `world.sonars.<node>`, else `index`)"),
        Setting("direction", _VEC3, None, "pointing direction"),
        Setting("index", number(0, integer=True), 0, "the scenario's default placement number"),
        Setting("ping_ms", number(above=0), None, "ms per reading (simulator: 49)"),
        Setting("half_angle_deg", number(above=0, maximum=89), None, "beam half-angle (20)"),
        Setting(
            "fire_log",
            STR,
            None,
            "audit: append `start end node epoch token deadline` per ping (sync clock s)",
        ),
        Setting("air_group", STR, None, "simulated air shared with (default: the sync group)"),
        Setting("crosstalk", BOOL, True, "simulate cross-talk with the group's other sonars"),
    ],
)


class Sonar(BoardMeasure):
    """A MaxSonar range finder: ``[range [m], x, y]``, range = inches x 0.0254."""

    name = "sonar"
    period = 0.1
    sync = True
    slot = 0.06  # one ping (49 ms) plus margin
    columns = ("range [m]", "x [m]", "y [m]")
    inputs = ()  # reads its board, not the store
    arguments = SONAR_ARGS

    def init(self, args: Mapping[str, Any], ctx: MeasureContext) -> None:
        args = self.prepare_args(args)
        super().init(args, ctx)
        with board_needed():
            self.board = boards.open_sonar(ctx, args)
        self.reads = BoardReads(ctx)
        self.max_range = args["max_range"]
        self.sim = self.board if isinstance(self.board, SimulatedSonar) else None
        pos = boards.sonar_mount(ctx, args).position
        self.x = pos[0] if args["x"] is None else args["x"]
        self.y = pos[1] if args["y"] is None else args["y"]
        self._truth: TruthRecorder | None = None
        if want_truth(args, ctx.run_dir) and self.sim is not None:
            self._truth = TruthRecorder(
                ctx.run_dir,  # type: ignore[arg-type]
                ctx.spec.name,
                ctx.node,
                ("true range [m]", "crosstalk [0/1]"),
                ctx.world,
            )
        elif args.get("truth"):
            ctx.log.warning("truth asked but there is no run directory: not recorded")

    def measure(self) -> Reading | None:
        # the driver checks the sync turn at its trigger (the simulator also announces the
        # grant with its ping)
        s = self.reads.read(self.board.read_sample, self.ctx.grant)
        if s is None:
            return None
        self.ctx.count("pings")
        if s.crosstalk:
            self.ctx.count("crosstalk")
        if self._truth is not None and self.sim is not None:
            b = self.sim
            self._truth.write(b.truth(s.t), (b.true_range(s.t), float(s.crosstalk)))
        r = s.inches * INCH
        if r > self.max_range:
            return None
        return Reading((r, self.x, self.y), s.t)

    def close(self) -> None:
        if self._truth is not None:
            self._truth.close()
            self._truth = None
