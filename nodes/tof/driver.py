"""What a VL53L1 time-of-flight sensor driver answers (seed 001: "[distance, ambient,
signal, status]").

A reading is the four values the ST driver reports for one ranging: the distance (m; the
chip reports whole millimetres), the ambient and signal return rates (Mcps, mega counts per
second; the chip reports them in 9.7 fixed point) and the range status. Only status
:data:`RANGE_VALID` carries a distance to trust; the other codes (ST's ``VL53L1_RANGESTATUS_*``)
say why not. The measurement time ``t`` is the middle of the ranging (its timing budget).

Errors: :class:`hera.nodes.driver.BoardDisconnected` for an I2C error,
:class:`hera.nodes.driver.NoReading` when no ranging completed this time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

RANGE_VALID = 0
SIGMA_FAIL = 1
SIGNAL_FAIL = 2
MIN_RANGE_CLIPPED = 3
OUT_OF_BOUNDS = 4
HARDWARE_FAIL = 5
WRAP_TARGET_FAIL = 7

STATUS_NAMES = {
    RANGE_VALID: "range valid",
    SIGMA_FAIL: "sigma fail (estimated noise above the limit)",
    SIGNAL_FAIL: "signal fail (return signal too weak)",
    MIN_RANGE_CLIPPED: "valid but clipped at the minimum range",
    OUT_OF_BOUNDS: "out of bounds (phase outside the valid range)",
    HARDWARE_FAIL: "hardware fail",
    WRAP_TARGET_FAIL: "wrap-around (a target beyond the ambiguity range)",
}
"""Range status codes of the ST VL53L1 API (``vl53l1_def.h``) that the simulator produces."""


@dataclass(frozen=True, slots=True)
class TofReading:
    """One ranging: ``t`` epoch s (middle of the ranging), ``distance`` m, ``ambient`` and
    ``signal`` Mcps, ``status`` (a range status code)."""

    t: float
    distance: float
    ambient: float
    signal: float
    status: int

    def values(self) -> tuple[float, float, float, float]:
        """The seed's four-value vector [distance, ambient, signal, status]."""
        return (self.distance, self.ambient, self.signal, float(self.status))

    @property
    def valid(self) -> bool:
        return self.status == RANGE_VALID and math.isfinite(self.distance)


@runtime_checkable
class TofDriver(Protocol):
    """A VL53L1 sensor."""

    def read_ranging(self) -> TofReading:
        """The latest completed ranging (blocks until one is ready)."""
        ...
