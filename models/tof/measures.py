"""The ToF height models as measures (seed 001): ``tof_cv``, ``tof_ca``, ``tof_fused`` and
``tof_plane`` (see :mod:`hera.models.tof.height`).

Besides the fusion arguments (:data:`hera.fusion.FUSION_ARGS`), ``forecast = true`` makes the
measure publish, at every step, the filter's state predicted to the step's time (the seed's
100 Hz output: a predict every 0.01 s, an update when a reading arrives) instead of the
estimate at each reading's time. The filter itself never reads a clock: the forecast is
computed from its state and thrown away, so ``hera replay`` of the readings gives the same
filter (it writes the estimates at the readings' times).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

from hera.fusion import FUSION_ARGS, FusionMeasure
from hera.measure import MeasureContext, Reading
from hera.models.tof.height import TofHeight, columns_of
from hera.schema import BOOL, Setting, Table

TOF_FUSION_ARGS = Table(
    "tof fusion args",
    [
        *FUSION_ARGS.settings,
        Setting(
            "forecast",
            BOOL,
            False,
            "publish the state predicted to each step's time (the seed's 100 Hz output)",
        ),
    ],
)


class _TofMeasure(FusionMeasure):
    model_class = TofHeight
    period = 0.01
    arguments = TOF_FUSION_ARGS

    def init(self, args: Mapping[str, Any], ctx: MeasureContext) -> None:
        self.forecasting = bool(self.prepare_args(args)["forecast"])
        super().init(args, ctx)
        self._forecast_t = float("-inf")  # the newest forecast's time (FusionMeasure's
        # _last_t is the newest sample's: a forecast is later than every sample it follows)

    def measure(self) -> list[Reading] | Reading | None:
        out = super().measure()
        if not self.forecasting:
            return out
        est = self.model.forecast(time.time())
        if est is None or est[0] <= self._forecast_t:
            return None
        self._forecast_t = est[0]
        return Reading(est[1], est[0])


class TofCv(_TofMeasure):
    """``tof_cv`` (seed 001 task 2): constant velocity [v, x], the centre sensor."""

    name = "tof_cv"
    model_fixed = {"kind": "cv"}
    columns = columns_of("cv")


class TofCa(_TofMeasure):
    """``tof_ca`` (seed 001 task 3): constant acceleration [a, v, x], the centre sensor."""

    name = "tof_ca"
    model_fixed = {"kind": "ca"}
    columns = columns_of("ca")


class TofFused(_TofMeasure):
    """``tof_fused`` (seed 001 task 4): constant acceleration, the three sensors."""

    name = "tof_fused"
    model_fixed = {"kind": "fused"}
    columns = columns_of("fused")


class TofPlane(_TofMeasure):
    """``tof_plane``: height, pitch and roll of the board from the three ranges."""

    name = "tof_plane"
    model_fixed = {"kind": "plane"}
    columns = columns_of("plane")
