"""The tilt filters as measures (seed 003): ``tilt_split`` (the seed's filter, Table 8),
``tilt_ekf``, ``tilt_ukf``, ``tilt_bias`` (b_gyro as a third state) and ``tilt_wheels`` (the
bias filter with the robot's model and its wheel encoders); see :mod:`hera.models.tilt.tilt`."""

from __future__ import annotations

from hera.fusion import FusionMeasure
from hera.models.tilt.tilt import Tilt2D, columns_of


class _Tilt(FusionMeasure):
    model_class = Tilt2D
    period = 1.0 / 26.0


class TiltSplit(_Tilt):
    """``tilt_split``: the seed's split filter (Kalman evolution, EKF correction)."""

    name = "tilt_split"
    model_fixed = {"kind": "split"}
    columns = columns_of("split")


class TiltEkf(_Tilt):
    """``tilt_ekf``: a full EKF on eqs. 25-26."""

    name = "tilt_ekf"
    model_fixed = {"kind": "ekf"}
    columns = columns_of("ekf")


class TiltUkf(_Tilt):
    """``tilt_ukf``: a UKF on eqs. 25-26."""

    name = "tilt_ukf"
    model_fixed = {"kind": "ukf"}
    columns = columns_of("ukf")


class TiltBias(_Tilt):
    """``tilt_bias``: an EKF estimating the gyroscope bias as a third state."""

    name = "tilt_bias"
    model_fixed = {"kind": "bias"}
    columns = columns_of("bias")


class TiltWheels(_Tilt):
    """``tilt_wheels``: the bias EKF with the robot's model and its wheel encoders (inputs
    ``[imu, wheels]``: an ``lsm6dsl`` and a ``wheel_encoder`` measure)."""

    name = "tilt_wheels"
    model_fixed = {"kind": "wheels"}
    columns = columns_of("wheels")
