"""What a wheel-encoder driver answers: the balancing robot's wheel travel and whether it
balances.

A real board answers from a quadrature counter of the two wheels' encoders (the mean of the
left and right counts, so a turn on the spot reads no travel; signed, + when the robot drives
forward, towards the side it leans to when theta > 0) and from its motor controller, whether
it balances (its balance loop runs: the robot up on its wheels) or not (on its stand, or
getting up from it or down onto it). ``counts_per_m`` is
the counter's counts per metre of travel on the ground: the encoder's counts per motor turn
(x 4 for quadrature) times the gearbox ratio over the wheel's circumference.

Errors: :class:`hera.nodes.driver.BoardDisconnected` (bus error),
:class:`hera.nodes.driver.NoReading` (no new count).

Drivers: the simulator (:mod:`hera.nodes.wheels.sim`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

COUNTS_PER_M = 12 * 4 * 30 / (math.pi * 0.065)
"""Counts per metre of a typical small balancing robot (about 7052): a 12 CPR motor encoder
read in quadrature (x 4), a 30:1 gearbox, 65 mm wheels; 0.14 mm of travel per count."""


@dataclass(frozen=True, slots=True)
class WheelReading:
    """One read: ``t`` epoch s, ``counts`` the counter (travel since the counter's zero,
    signed), ``balancing`` the motor controller's state (its balance loop runs)."""

    t: float
    counts: int
    balancing: bool


@runtime_checkable
class WheelEncoderDriver(Protocol):
    """Wheel encoders and the motor controller of a two-wheeled robot."""

    counts_per_m: float
    """Counts per metre of travel (nominal: the wheel radius as specified)."""

    def read_wheels(self) -> WheelReading:
        """The counter now, and whether the robot balances."""
        ...
