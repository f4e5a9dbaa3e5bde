"""The train's models as measures: each runs its fusion model in a node (see :mod:`hera.fusion`).

Published names are descriptive; the thesis names (e4 .. e9) are entry-point aliases of the
same classes.
"""

from __future__ import annotations

from hera.fusion import FusionMeasure
from hera.models.train.bilateration import Bilateration
from hera.models.train.tracker import LADDER, TrainTracker

POSITION = ("x [m]", "y [m]", "theta [rad]", "omega [rad/s]")


class BilaterationMeasure(FusionMeasure):
    """``bilateration``: [x, y] of the target from two sonars (thesis ch. 3.3)."""

    name = "bilateration"
    model_class = Bilateration
    columns = Bilateration.columns


class OmegaAcc(FusionMeasure):
    """``omega_acc`` (thesis e4): angular speed from the centripetal acceleration."""

    name = LADDER["e4"].name
    model_class = TrainTracker
    model_fixed = {"rung": "e4"}
    columns = ("omega [rad/s]",)


class TrackBilat(FusionMeasure):
    """``track_bilat`` (thesis e5): + the bilateration position."""

    name = LADDER["e5"].name
    model_class = TrainTracker
    model_fixed = {"rung": "e5"}
    columns = POSITION


class TrackSonar(FusionMeasure):
    """``track_sonar`` (thesis e6): + each sonar range."""

    name = LADDER["e6"].name
    model_class = TrainTracker
    model_fixed = {"rung": "e6"}
    columns = POSITION


class TrackGyro(FusionMeasure):
    """``track_gyro`` (thesis e7): + the gyroscope."""

    name = LADDER["e7"].name
    model_class = TrainTracker
    model_fixed = {"rung": "e7"}
    columns = POSITION


class TrackRadius(FusionMeasure):
    """``track_radius`` (thesis e8): + the radius as a state."""

    name = LADDER["e8"].name
    model_class = TrainTracker
    model_fixed = {"rung": "e8"}
    columns = (*POSITION, "radius [m]")


class TrackMag(FusionMeasure):
    """``track_mag`` (thesis e9): + the magnetometer heading."""

    name = LADDER["e9"].name
    model_class = TrainTracker
    model_fixed = {"rung": "e9"}
    columns = (*POSITION, "radius [m]")
