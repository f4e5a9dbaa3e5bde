"""The seed-000 models as fusion measures (see :mod:`hera.fusion`).

- ``ir_track``: the lab-2 EKF (:class:`~hera.models.ir.tracker.IrTracker`), 50 Hz;
- ``occupancy_grid``: the lab-3 map fusing IR and thermocouples
  (:class:`~hera.models.ir.grid.OccupancyGrid`, ``use = "both"``), and the same map from
  one modality alone: ``occupancy_ir`` and ``occupancy_thermal`` (the seed's figures 2-7
  against 8-13). Each map is published as tiles (:mod:`hera.models.ir.tiles`).
"""

from __future__ import annotations

from hera.fusion import FusionMeasure
from hera.models.ir.grid import OccupancyGrid
from hera.models.ir.tiles import COLUMNS
from hera.models.ir.tracker import IrTracker


class IrTrack(FusionMeasure):
    """``ir_track``: [distance cm, velocity cm/s, sigma cm, gated] from raw IR voltages."""

    name = "ir_track"
    period = 0.02
    model_class = IrTracker
    columns = IrTracker.columns


class OccupancyFused(FusionMeasure):
    """``occupancy_grid``: the plate's occupancy from IR and thermocouples (Bayes)."""

    name = "occupancy_grid"
    model_class = OccupancyGrid
    model_fixed = {"use": "both"}
    columns = COLUMNS


class OccupancyIr(FusionMeasure):
    """``occupancy_ir``: the plate's occupancy from the IR scanners alone."""

    name = "occupancy_ir"
    model_class = OccupancyGrid
    model_fixed = {"use": "ir"}
    columns = COLUMNS


class OccupancyThermal(FusionMeasure):
    """``occupancy_thermal``: the plate's occupancy from the thermocouples alone."""

    name = "occupancy_thermal"
    model_class = OccupancyGrid
    model_fixed = {"use": "thermal"}
    columns = COLUMNS
