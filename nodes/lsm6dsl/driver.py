"""What an LSM6DSL accelerometer + gyroscope driver answers.

Units are the drivers' (ST's API reports mg and mdps): acceleration in g, angular rate in
deg/s, in the chip's right-handed frame (lying flat and still it reads about (0, 0, +1) g).
The output data rate (ODR) is chosen when the driver is made (12.5 .. 6664 Hz; the seed's
robot used 26 Hz); a read returns the latest output sample with the time it stands for.

Errors: :class:`hera.nodes.driver.BoardDisconnected` (bus error),
:class:`hera.nodes.driver.NoReading` (no new sample).

Drivers: the simulator (:mod:`hera.nodes.lsm6dsl.sim`) and a real chip on an I2C bus
(:mod:`hera.nodes.lsm6dsl.i2c`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from hera.nodes.geometry import Vec3

ODRS_HZ = (12.5, 26.0, 52.0, 104.0, 208.0, 416.0, 833.0, 1666.0, 3332.0, 6664.0)
"""Output data rates of the LSM6DSL (data sheet)."""


@dataclass(frozen=True, slots=True)
class ImuReading:
    """One output sample: ``t`` epoch s, ``acc`` g, ``gyro`` deg/s (chip frame)."""

    t: float
    acc: Vec3
    gyro: Vec3


@runtime_checkable
class Lsm6dslDriver(Protocol):
    """An LSM6DSL (or any 6-axis IMU answering the same)."""

    odr_hz: float

    def read_imu(self) -> ImuReading:
        """The latest accelerometer and gyroscope sample (a driver that keeps its samples
        may give the oldest one not read yet, and say with an ``int`` attribute ``pending``
        how many more it holds: the ``lsm6dsl`` measure then reads them all each step)."""
        ...
