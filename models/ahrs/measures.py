"""The AHRS models as measures (see :mod:`hera.fusion`): ``attitude`` (ours) and
``attitude_thesis`` (the thesis's e11; entry-point alias ``e11``)."""

from __future__ import annotations

from hera.fusion import FusionMeasure
from hera.models.ahrs.model import AhrsModel, ThesisAhrsModel


class Ahrs(FusionMeasure):
    """``attitude_mekf``: attitude and heading from ``nav3``, our multiplicative EKF."""

    name = "attitude_mekf"
    period = 0.05
    model_class = AhrsModel
    columns = AhrsModel.columns


class AhrsThesis(FusionMeasure):
    """``attitude_thesis`` (thesis e11): attitude and heading from ``nav3``.

    The thesis's quaternion Kalman filter (eqs. 7.1-7.5)."""

    name = "attitude_thesis"
    period = 0.05
    model_class = ThesisAhrsModel
    columns = ThesisAhrsModel.columns
