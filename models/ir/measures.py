"""The seed-000 models as fusion measures (see :mod:`hera.fusion`).

- ``ir_track``: the lab-2 EKF (:class:`~hera.models.ir.tracker.IrTracker`), 50 Hz;
- ``occupancy_grid``: the lab-3 map fusing IR and thermocouples
  (:class:`~hera.models.ir.grid.OccupancyGrid`, ``use = "both"``), and the same map from
  one modality alone: ``occupancy_ir`` and ``occupancy_thermal`` (the seed's figures 2-7
  against 8-13). Each map is published as tiles (:mod:`hera.models.ir.tiles`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from hera.fusion import FusionMeasure
from hera.models.ir.grid import OccupancyGrid
from hera.models.ir.tiles import COLUMNS
from hera.models.ir.tracker import IrTracker


class _Checked(FusionMeasure):
    """A fusion measure whose model settings are checked before a node starts: the model
    is built from them, and what it refuses is reported with the spec's other problems."""

    @classmethod
    def check_args(cls, args: Mapping[str, Any], where: str) -> list[str]:
        problems = super().check_args(args, where)
        model = args.get("model", {})
        if not problems and isinstance(model, Mapping):
            try:
                cls.model_class(**{**model, **cls.model_fixed})
            except (TypeError, ValueError) as e:
                problems.append(f"{where}: model: {e}")
        return problems


class IrTrack(_Checked):
    """``ir_track``: [distance cm, velocity cm/s, sigma cm, gated] from raw IR voltages."""

    name = "ir_track"
    period = 0.02
    model_class = IrTracker
    columns = IrTracker.columns


class OccupancyFused(_Checked):
    """``occupancy_grid``: the plate's occupancy from IR and thermocouples (Bayes)."""

    name = "occupancy_grid"
    model_class = OccupancyGrid
    model_fixed = {"use": "both"}
    columns = COLUMNS


class OccupancyIr(_Checked):
    """``occupancy_ir``: the plate's occupancy from the IR scanners alone."""

    name = "occupancy_ir"
    model_class = OccupancyGrid
    model_fixed = {"use": "ir"}
    columns = COLUMNS


class OccupancyThermal(_Checked):
    """``occupancy_thermal``: the plate's occupancy from the thermocouples alone."""

    name = "occupancy_thermal"
    model_class = OccupancyGrid
    model_fixed = {"use": "thermal"}
    columns = COLUMNS
