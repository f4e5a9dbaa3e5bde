"""Opening the seed-000 rig's boards for a node (see :mod:`hera.nodes.boards`).

A board is registered in the node's :class:`~hera.nodes.boards.Boards` under
``"<node>/<board>"``; measures of one node naming the same board share it, and it outlives
a restarted measure (with any fault still on). A real driver replaces the simulator with
the measure arg ``driver = "package.module:Class"`` (built with ``driver_args``); it must
satisfy :class:`~hera.nodes.ir.driver.IrDriver` or
:class:`~hera.nodes.ir.driver.ThermocoupleDriver`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from hera.measure import MeasureContext
from hera.nodes import boards as registry
from hera.nodes.ir.driver import IrDriver, ThermocoupleDriver
from hera.nodes.ir.plate import ThermocoupleModel
from hera.nodes.ir.scenarios import PlateScene
from hera.nodes.ir.sharp import SharpModel, variant
from hera.nodes.ir.sim import SimSharpIr, SimThermocouple
from hera.nodes.world import epoch_of, make_scenario


def open_ir(ctx: MeasureContext, args: Mapping[str, Any]) -> IrDriver:
    """The Sharp IR board ``args["board"]`` (default ``"ir"``) of ``ctx.node``.

    Simulator args: ``variant`` (part number or short/medium/long), ``model`` (a
    :class:`~hera.nodes.ir.sharp.SharpModel` table), ``scanner`` (the plate world's scanner
    it rides on) or a fixed ``position_cm`` [x, y] and ``heading_deg``, ``seed``.
    """

    def make(bid: str, seed: int) -> SimSharpIr:
        pos = args.get("position_cm") or (0.0, 0.0)
        return SimSharpIr(
            bid,
            variant(str(args["variant"])),
            SharpModel.from_args(args.get("model")),
            make_scenario(ctx.world),
            epoch_of(ctx.world),
            seed,
            mount=(float(pos[0]), float(pos[1]), float(args.get("heading_deg") or 0.0)),
            scanner=args.get("scanner"),
        )

    return registry.open_board(ctx, args, "ir", IrDriver, "an IrDriver", make)


def thermocouple_position(ctx: MeasureContext, args: Mapping[str, Any]) -> tuple[float, float]:
    """Where the thermocouple is (cm): the arg ``position_cm``, else the plate world's
    thermocouple number ``index``."""
    pos = args.get("position_cm")
    if pos is not None:
        return (float(pos[0]), float(pos[1]))
    scene = make_scenario(ctx.world)
    if not isinstance(scene, PlateScene):
        raise ValueError("a thermocouple needs 'position_cm' outside the ir_plate world")
    index = int(args.get("index") or 0)
    if not 0 <= index < len(scene.thermocouples):
        raise ValueError(
            f"thermocouple index must be within [0, {len(scene.thermocouples)}), got {index}"
        )
    return scene.thermocouples[index]


def open_thermocouple(ctx: MeasureContext, args: Mapping[str, Any]) -> ThermocoupleDriver:
    """The thermocouple board ``args["board"]`` (default ``"tc"``) of ``ctx.node``.

    Simulator args: ``model`` (a :class:`~hera.nodes.ir.plate.ThermocoupleModel` table),
    ``position_cm`` or ``index`` (see :func:`thermocouple_position`), ``seed``.
    """

    def make(bid: str, seed: int) -> SimThermocouple:
        return SimThermocouple(
            bid,
            ThermocoupleModel.from_args(args.get("model")),
            make_scenario(ctx.world),
            epoch_of(ctx.world),
            seed,
            thermocouple_position(ctx, args),
        )

    return registry.open_board(ctx, args, "tc", ThermocoupleDriver, "a ThermocoupleDriver", make)
