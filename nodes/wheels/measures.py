"""The ``wheel_encoder`` measure: the balancing robot's wheel travel and whether it balances.

Publishes, every ``period`` (1 / 26 s by default, the IMU's rate), ``[x_wheel [m], balancing]``:
x_wheel the wheels' travel since the counter's zero, counts / ``counts_per_m`` (m; + forward,
the world's +x: the way the robot drives when it leans by theta > 0), and balancing 1.0 while
the robot balances on its wheels, 0.0 on its stand and while it gets up or down. The counts
carry the wheels' scale error (a wheel radius off the nominal one) and a count's
quantisation; a tilt filter differentiating x_wheel twice sees the axle's acceleration a_w.

The board is the simulator (a :class:`~hera.nodes.wheels.sim.SimWheels` on the world's
``balancing`` robot; ``model = {scale_error_sigma = ...}``) unless ``driver =
"package.module:Class"`` names a real :class:`~hera.nodes.wheels.driver.WheelEncoderDriver`,
or one is registered on the node. ``counts_per_m`` defaults to the board's own. Counters:
``dropouts``, ``disconnected`` (:mod:`hera.nodes.board_reads`). ``truth = true`` records the
axle's true travel beside the state (``true x_wheel [m]``).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from hera.measure import MeasureContext, Reading
from hera.nodes import boards
from hera.nodes.board_reads import BoardReads, board_needed
from hera.nodes.boards import BOARD_ARGS, BoardMeasure
from hera.nodes.driver import SimulatedBoard
from hera.nodes.truth import TruthRecorder, want_truth
from hera.nodes.wheels.driver import COUNTS_PER_M, WheelEncoderDriver
from hera.nodes.wheels.sim import SimWheels
from hera.nodes.world import epoch_of, make_scenario
from hera.schema import STR, Setting, Table, number

WHEELS_MODEL = Table(
    "wheels model",
    [
        Setting(
            "scale_error_sigma",
            number(0),
            0.01,
            "relative spread of the wheels' scale error (their radius off the nominal one)",
        ),
    ],
)
"""The simulated board's error model (the measure arg ``model = {...}``)."""

WHEEL_ARGS = Table(
    "wheel_encoder args",
    [
        Setting("board", STR, "wheels", "board name"),
        *BOARD_ARGS,
        Setting(
            "counts_per_m",
            number(above=0),
            None,
            f"counts per metre of travel (default: the board's; the simulator's "
            f"{COUNTS_PER_M:.1f}: 12 CPR x 4, 30:1 gears, 65 mm wheels)",
        ),
    ],
)


def open_wheels(ctx: MeasureContext, args: Mapping[str, Any]) -> Any:
    """The wheel encoders ``args["board"]`` of ``ctx.node``: one registered under that id,
    else the driver the args name, else a simulator built from ``ctx.world`` and the arg
    ``model`` (on the node's clock, when it has one)."""

    def make(bid: str, seed: int) -> SimWheels:
        model = WHEELS_MODEL.parse(args.get("model") or {}, "wheels model")
        clock = ctx.resources.get(boards.CLOCK)
        return SimWheels(
            bid,
            make_scenario(ctx.world),
            epoch_of(ctx.world),
            seed,
            counts_per_m=args.get("counts_per_m") or COUNTS_PER_M,
            scale_error_sigma=model["scale_error_sigma"],
            **({} if clock is None else {"clock": clock}),
        )

    return boards.open_board(
        ctx, args, "wheels", WheelEncoderDriver, "a wheel-encoder driver", make, "wheels"
    )


class WheelEncoder(BoardMeasure):
    """The balancing robot's wheel encoders and whether it balances (see the module
    docstring)."""

    name = "wheel_encoder"
    period = 1.0 / 26.0
    columns = ("x_wheel [m]", "balancing")
    arguments = WHEEL_ARGS

    @classmethod
    def check_args(cls, args: Mapping[str, Any], where: str) -> list[str]:
        problems = super().check_args(args, where)
        model = args.get("model")
        if isinstance(model, Mapping):
            WHEELS_MODEL.parse(model, f"{where}: model", problems)
        return problems

    def init(self, args: Mapping[str, Any], ctx: MeasureContext) -> None:
        problems = self.check_args(args, f"measure {ctx.spec.name!r}")
        if problems:
            raise ValueError("; ".join(problems))
        args = self.prepare_args(args)
        super().init(args, ctx)
        with board_needed():
            self.board = open_wheels(ctx, args)
        given = args["counts_per_m"]
        self.counts_per_m = float(given if given is not None else self.board.counts_per_m)
        self.reads = BoardReads(ctx)
        self._truth: TruthRecorder | None = None
        if want_truth(args, ctx.run_dir) and isinstance(self.board, SimWheels):
            self._truth = TruthRecorder(
                ctx.run_dir,  # type: ignore[arg-type]
                ctx.spec.name,
                ctx.node,
                ("true x_wheel [m]",),
                ctx.world,
            )

    def measure(self) -> Reading | None:
        r = self.reads.read(self.board.read_wheels)
        if r is None:
            return None
        if self._truth is not None and isinstance(self.board, SimulatedBoard):
            self._truth.write(self.board.truth(r.t), (self.board.travel(r.t),))
        return Reading((r.counts / self.counts_per_m, 1.0 if r.balancing else 0.0), r.t)

    def close(self) -> None:
        if self._truth is not None:
            self._truth.close()
            self._truth = None
