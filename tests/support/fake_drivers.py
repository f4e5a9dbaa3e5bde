"""Boards that are not the simulator: minimal drivers written from the driver protocols of
``hera.nodes.driver`` alone (what a real board's driver would implement)."""

from __future__ import annotations

import time

from hera.nodes.driver import ImuSample, RangeSample


class LevelNav:
    """A Pmod NAV lying flat and still: 1 g up, a constant gyro offset, no noise."""

    def __init__(self, gyro_z: float = 3.0) -> None:
        self.gyro_z = gyro_z
        self.reads = 0

    def read_acc(self):
        self.reads += 1
        return (0.0, 0.0, 1.0)

    def read_gyro(self):
        self.reads += 1
        return (0.0, 0.0, self.gyro_z)

    def read_mag(self):
        return (0.2, 0.0, -0.4)

    def read_baro(self):
        return 1000.0

    def read_imu(self, mag: bool = True) -> ImuSample:
        return ImuSample(time.time(), self.read_acc(), self.read_gyro(), self.read_mag())


class FixedSonar:
    """A MaxSonar that always reads ``inches`` and remembers the grants it ran under."""

    def __init__(self, inches: int = 40) -> None:
        self.inches = inches
        self.grants: list[object] = []

    def read_range(self) -> int:
        return self.inches

    def read_sample(self, grant=None) -> RangeSample:
        self.grants.append(grant)
        return RangeSample(time.time(), self.inches)
