"""The AHRS models as measures (see :mod:`hera.fusion`): ``ahrs`` (ours) and
``ahrs_thesis`` (the thesis's e11; entry-point alias ``e11``)."""

from __future__ import annotations

from hera.fusion import FusionMeasure
from hera.models.ahrs.model import AhrsModel, ThesisAhrsModel


class Ahrs(FusionMeasure):
    """``ahrs``: attitude and heading from ``nav3``, our multiplicative EKF."""

    name = "ahrs"
    period = 0.05
    model_class = AhrsModel
    columns = AhrsModel.columns


class AhrsThesis(FusionMeasure):
    """``ahrs_thesis`` (thesis e11): attitude and heading from ``nav3``, the thesis's
    quaternion Kalman filter."""

    name = "ahrs_thesis"
    period = 0.05
    model_class = ThesisAhrsModel
    columns = ThesisAhrsModel.columns
