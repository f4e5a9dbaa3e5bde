"""The models as measures: each runs its fusion model in a node (see :mod:`hera.fusion`).

Published names are descriptive; the thesis names (e4 .. e9) are entry-point aliases.
"""

from __future__ import annotations

from hera.models.bilateration import Bilateration
from hera.models.train import LADDER, TrainTracker

from hera.fusion import FusionMeasure


def _rung_model(rung: str) -> type[TrainTracker]:
    """A TrainTracker class fixed to one rung (the measure's ``model`` args tune it)."""

    class RungTracker(TrainTracker):
        def __init__(self, **params):
            if params.setdefault("rung", rung) != rung:
                raise ValueError(f"this measure is rung {rung}; drop 'rung' from its args")
            super().__init__(**params)

    RungTracker.__name__ = f"TrainTracker_{rung}"
    return RungTracker


class BilaterationMeasure(FusionMeasure):
    """``bilateration``: [x, y] of the target from two sonars (thesis ch. 3.3)."""

    name = "bilateration"
    model_class = Bilateration
    columns = Bilateration.columns


class OmegaAcc(FusionMeasure):
    """``omega_acc`` (thesis e4): angular speed from the centripetal acceleration."""

    name = LADDER["e4"].name
    model_class = _rung_model("e4")
    columns = ("omega [rad/s]",)


class TrackBilat(FusionMeasure):
    """``track_bilat`` (thesis e5): + the bilateration position."""

    name = LADDER["e5"].name
    model_class = _rung_model("e5")
    columns = ("x [m]", "y [m]", "theta [rad]", "omega [rad/s]")


class TrackSonar(FusionMeasure):
    """``track_sonar`` (thesis e6): + each sonar range."""

    name = LADDER["e6"].name
    model_class = _rung_model("e6")
    columns = TrackBilat.columns


class TrackGyro(FusionMeasure):
    """``track_gyro`` (thesis e7): + the gyroscope."""

    name = LADDER["e7"].name
    model_class = _rung_model("e7")
    columns = TrackBilat.columns


class TrackRadius(FusionMeasure):
    """``track_radius`` (thesis e8): + the radius as a state."""

    name = LADDER["e8"].name
    model_class = _rung_model("e8")
    columns = (*TrackBilat.columns, "radius [m]")


class TrackMag(FusionMeasure):
    """``track_mag`` (thesis e9): + the magnetometer heading."""

    name = LADDER["e9"].name
    model_class = _rung_model("e9")
    columns = TrackRadius.columns


MEASURES = {
    "bilateration": BilaterationMeasure,
    "e4": OmegaAcc,
    "e5": TrackBilat,
    "e6": TrackSonar,
    "e7": TrackGyro,
    "e8": TrackRadius,
    "e9": TrackMag,
}
"""Model measures by thesis name (used by ``hera replay`` and ``hera eval``)."""
