"""The 6-DOF IMU as measures (see :mod:`hera.fusion`): ``imu6dof`` (thesis e13, aided by
the sonars' position; entry-point alias ``e13``) and ``imu6dof_inertial`` (the same without
position fixes: pure inertial navigation, to show its drift)."""

from __future__ import annotations

from hera.fusion import FusionMeasure
from hera.models.imu6dof.navigator import Navigator


class Imu6dof(FusionMeasure):
    """``imu6dof`` (thesis e13): position and attitude from ``nav3`` and the sonars.

    Velocity and linear acceleration too; the sonars' position (``position3d``) bounds the
    inertial drift."""

    name = "imu6dof"
    period = 0.05
    model_class = Navigator
    model_fixed = {"aiding": True}
    columns = Navigator.columns


class Imu6dofInertial(FusionMeasure):
    """``imu6dof_inertial``: e13 from ``nav3`` alone (its position drifts)."""

    name = "imu6dof_inertial"
    period = 0.05
    model_class = Navigator
    model_fixed = {"aiding": False}
    columns = Navigator.columns
