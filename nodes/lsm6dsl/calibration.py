"""Gyroscope bias calibration with motion detection (seed 003 sec. 4.3: "calibration mode").

The seed's calibration filter: with the sensor still, b_gyro is the mean of the first 100
gyroscope samples (eqs. 22-23: g_Y = b_gyro when d theta / dt = 0). Ours refuses to finish
while the body moves: a sample whose gyroscope differs from the running mean of the samples
collected so far by more than ``gyro_tol_dps`` on any axis, or whose accelerometer differs
from theirs by more than ``acc_tol_g``, restarts the count from that sample (``restarts``
counts it). It finishes with ``n`` consecutive still samples. Pure: no clock, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

COLLECTING, MOVING, DONE = "collecting", "moving", "done"


@dataclass(frozen=True)
class CalibrationStatus:
    """Where a calibration stands: ``state`` (collecting, moving: the last sample showed
    motion, done), samples ``collected`` of ``needed``, ``restarts`` and, once done, the bias
    ``b_gyro_dps`` (deg/s, chip axes)."""

    state: str
    collected: int
    needed: int
    restarts: int
    b_gyro_dps: tuple[float, float, float] | None = None


class GyroCalibration:
    """Mean of ``n`` consecutive still samples (see the module docstring)."""

    def __init__(self, n: int = 100, gyro_tol_dps: float = 1.5, acc_tol_g: float = 0.02) -> None:
        if n < 1:
            raise ValueError(f"calibration needs at least one sample, got n={n}")
        if not (gyro_tol_dps > 0 and acc_tol_g > 0):
            raise ValueError("calibration tolerances must be > 0")
        self.n, self.gyro_tol, self.acc_tol = int(n), float(gyro_tol_dps), float(acc_tol_g)
        self.restarts = 0
        self._moving = False
        self._reset()
        self.result: tuple[float, float, float] | None = None

    def _reset(self) -> None:
        self._count = 0
        self._gyro = [0.0, 0.0, 0.0]
        self._acc = [0.0, 0.0, 0.0]

    def feed(self, acc: Sequence[float], gyro: Sequence[float]) -> bool:
        """Take one sample (acc g, gyro deg/s); True once the calibration is done."""
        if self.result is not None:
            return True
        if not all(math.isfinite(v) for v in (*acc, *gyro)):
            return False
        if self._count:
            k = self._count
            moved = any(abs(gyro[i] - self._gyro[i] / k) > self.gyro_tol for i in range(3)) or any(
                abs(acc[i] - self._acc[i] / k) > self.acc_tol for i in range(3)
            )
            if moved:
                self.restarts += 1
                self._moving = True
                self._reset()
        for i in range(3):
            self._gyro[i] += gyro[i]
            self._acc[i] += acc[i]
        self._count += 1
        if self._count >= self.n:
            k = self._count
            self.result = (self._gyro[0] / k, self._gyro[1] / k, self._gyro[2] / k)
            return True
        if self._count > 1:
            self._moving = False
        return False

    def status(self) -> CalibrationStatus:
        """Where the calibration stands."""
        if self.result is not None:
            return CalibrationStatus(DONE, self.n, self.n, self.restarts, self.result)
        state = MOVING if self._moving else COLLECTING
        return CalibrationStatus(state, self._count, self.n, self.restarts)
