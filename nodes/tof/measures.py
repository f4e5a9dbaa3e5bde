"""The ``vl53l1`` measure: one VL53L1 sensor of a carrier board (seed 001).

Publishes every ranging, valid or not, as ``[distance [m], ambient [Mcps], signal [Mcps],
status, x [m], y [m]]``: the seed's four-value vector, then where the sensor sits on the
carrier board (so the geometry travels with the data, as the sonar's position does). The
fusion models decide what to trust from the status. Counters: ``rangings``, ``invalid``
(status other than 0), ``dropouts``, ``disconnected`` (:mod:`hera.nodes.board_reads`).

Where the sensor sits: ``position = [x, y]`` (m, carrier frame: x right, y forward, origin at
the centre sensor), else the default of ``sensor`` (``left``, ``centre``, ``right``: the
X-NUCLEO-53L1A1 layout, see :data:`MOUNTS`). The board is the simulator (a
:class:`~hera.nodes.tof.sim.SimVl53l1` built from the world and the arg ``model``, a
:data:`~hera.nodes.tof.model.TOF_MODEL` table) unless ``driver = "package.module:Class"``
names a real :class:`~hera.nodes.tof.driver.TofDriver`, or one is registered on the node.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from hera.measure import MeasureContext, Reading
from hera.nodes import boards
from hera.nodes.board_reads import BoardReads, board_needed
from hera.nodes.boards import BOARD_ARGS, BoardMeasure
from hera.nodes.driver import SimulatedBoard
from hera.nodes.tof.driver import TofDriver
from hera.nodes.tof.model import TOF_MODEL, TofModel
from hera.nodes.tof.sim import SimVl53l1
from hera.nodes.truth import TruthRecorder, want_truth
from hera.nodes.world import epoch_of, make_scenario
from hera.schema import STR, Setting, Table, choice, list_of, number

MOUNTS = {"left": (-0.03, -0.02), "centre": (0.0, 0.0), "right": (0.03, -0.02)}
"""Default sensor positions (m) on the carrier: the X-NUCLEO-53L1A1's centre sensor and its
two satellites on the left and right edges, about 3 cm aside and 2 cm behind it (our reading
of the board's photos: an assumption, give ``position`` for your board)."""

VL53L1_ARGS = Table(
    "vl53l1 args",
    [
        Setting("board", STR, "tof", "board name (one sensor per board)"),
        *BOARD_ARGS,
        Setting("sensor", choice(*MOUNTS), "centre", "which sensor of the X-NUCLEO-53L1A1"),
        Setting("position", list_of(number(-1, 1), "[x, y]"), None, "m on the carrier board"),
    ],
)


def open_tof(ctx: MeasureContext, args: Mapping[str, Any], mount: tuple[float, float]) -> Any:
    """The VL53L1 ``args["board"]`` of ``ctx.node``: one registered under that id, else the
    driver the args name, else a simulator built from ``ctx.world`` (see the module
    docstring). The board is registered in the node's board registry (faults, listing)."""

    def make(bid: str, seed: int) -> SimVl53l1:
        return SimVl53l1(
            bid,
            make_scenario(ctx.world),
            epoch_of(ctx.world),
            TofModel.from_args(args.get("model")),
            mount,
            seed,
        )

    return boards.open_board(ctx, args, "tof", TofDriver, "a VL53L1 driver", make, "vl53l1")


class Vl53l1(BoardMeasure):
    """One VL53L1 time-of-flight sensor (see the module docstring)."""

    name = "vl53l1"
    period = 0.1  # the seed's 10 Hz
    columns = (
        "distance [m]",
        "ambient [Mcps]",
        "signal [Mcps]",
        "status",
        "x [m]",
        "y [m]",
    )
    arguments = VL53L1_ARGS

    @classmethod
    def check_args(cls, args: Mapping[str, Any], where: str) -> list[str]:
        problems = super().check_args(args, where)
        model = args.get("model")
        if isinstance(model, Mapping):
            TOF_MODEL.parse(model, f"{where}: model", problems)
        pos = args.get("position")
        if isinstance(pos, (list, tuple)) and len(pos) != 2:
            problems.append(f"{where}: position must be [x, y] (m), got {list(pos)!r}")
        return problems

    def init(self, args: Mapping[str, Any], ctx: MeasureContext) -> None:
        problems = self.check_args(args, f"measure {ctx.spec.name!r}")
        if problems:
            raise ValueError("; ".join(problems))
        args = self.prepare_args(args)
        super().init(args, ctx)
        pos = args["position"]
        self.mount = (float(pos[0]), float(pos[1])) if pos else MOUNTS[args["sensor"]]
        with board_needed():
            self.board = open_tof(ctx, args, self.mount)
        self.reads = BoardReads(ctx)
        self._truth: TruthRecorder | None = None
        if want_truth(args, ctx.run_dir) and isinstance(self.board, SimVl53l1):
            self._truth = TruthRecorder(
                ctx.run_dir,  # type: ignore[arg-type]
                ctx.spec.name,
                ctx.node,
                ("true range [m]",),
                ctx.world,
            )

    def measure(self) -> Reading | None:
        r = self.reads.read(self.board.read_ranging)
        if r is None:
            return None
        self.ctx.count("rangings")
        if r.status != 0:
            self.ctx.count("invalid")
        if self._truth is not None and isinstance(self.board, SimulatedBoard):
            self._truth.write(self.board.truth(r.t), (self.board.true_range(r.t),))
        return Reading((*r.values(), *self.mount), r.t)

    def close(self) -> None:
        if self._truth is not None:
            self._truth.close()
            self._truth = None
