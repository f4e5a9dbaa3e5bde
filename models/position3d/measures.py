"""The 3-D position models as measures (see :mod:`hera.fusion`): ``position3d`` (ours) and
``position3d_thesis`` (the thesis's e10; entry-point alias ``e10``)."""

from __future__ import annotations

from hera.fusion import FusionMeasure
from hera.models.position3d.thesis import ThesisPosition
from hera.models.position3d.tracker import RangeTracker


class Position3d(FusionMeasure):
    """``position3d``: the target's position from the sonars' raw ranges (our EKF).

    Sonars at any pose; velocity and standard deviations published too."""

    name = "position3d"
    period = 0.05
    model_class = RangeTracker
    columns = RangeTracker.columns


class Position3dThesis(FusionMeasure):
    """``position3d_thesis`` (thesis e10): the position from three axis-aligned sonars.

    The thesis's linear Kalman filter (eq. 7.6)."""

    name = "position3d_thesis"
    period = 0.05
    model_class = ThesisPosition
    columns = ThesisPosition.columns
