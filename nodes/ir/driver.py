"""The driver interface of the seed-000 rig: what a Sharp IR channel and a thermocouple
amplifier answer, in their own units.

- :class:`IrDriver`: one Sharp IR sensor on an ADC channel: its output in volts (0 - 3.3 V,
  12-bit on the seed's STM32F407) with the time it was converted;
- :class:`ThermocoupleDriver`: one type-K thermocouple behind its amplifier: degC.

Optional, for what only a simulator or a scanning rig has: :class:`PosedIr` (the sensor's
pose at a time: a carriage's encoder, or the simulated scanner) and :class:`SimulatedIr` /
:class:`SimulatedThermocouple` (the true distance or temperature, for recording truth).

Errors are those of :mod:`hera.nodes.driver`: :class:`~hera.nodes.driver.BoardDisconnected`
when the channel is unreachable, :class:`~hera.nodes.driver.NoReading` for a missing reading.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from hera import wallclock


@dataclass(frozen=True, slots=True)
class VoltageSample:
    """One conversion: ``t`` epoch s, ``volts`` the sensor's output."""

    t: float
    volts: float


@dataclass(frozen=True, slots=True)
class TemperatureSample:
    """One thermocouple reading: ``t`` epoch s, ``celsius``."""

    t: float
    celsius: float


@runtime_checkable
class IrDriver(Protocol):
    """A Sharp IR range sensor on an ADC channel."""

    def read_volts(self) -> float:
        """Convert once: the output (V)."""
        ...

    def read_sample(self) -> VoltageSample:
        """Convert once: the output (V) and the time of the conversion."""
        ...


@runtime_checkable
class ThermocoupleDriver(Protocol):
    """A type-K thermocouple behind a cold-junction-compensating amplifier."""

    def read_celsius(self) -> float:
        """Read once: the temperature (degC)."""
        ...

    def read_sample(self) -> TemperatureSample:
        """Read once: the temperature (degC) and the time of the reading."""
        ...


@runtime_checkable
class PosedIr(Protocol):
    """Optional: an IR sensor that knows where it is (a scanner's carriage)."""

    def pose(self, t: float) -> tuple[float, float, float]:
        """(x cm, y cm, heading deg) of the sensor at epoch time ``t``."""
        ...


@runtime_checkable
class SimulatedIr(Protocol):
    """Optional: a simulated sensor knows the true distance it should read."""

    def true_distance(self, t: float) -> float:
        """The distance (cm) to what its beam meets at epoch time ``t``."""
        ...


@runtime_checkable
class SimulatedThermocouple(Protocol):
    """Optional: a simulated thermocouple knows the true temperature at its spot."""

    def true_temperature(self, t: float) -> float:
        """The plate's temperature (degC) under it at epoch time ``t``."""
        ...


class IrDriverBase(ABC):
    """Convenience base for a real IR channel: implement ``read_volts``."""

    @abstractmethod
    def read_volts(self) -> float: ...

    def read_sample(self) -> VoltageSample:
        t = wallclock.now()
        return VoltageSample(t, self.read_volts())


class ThermocoupleDriverBase(ABC):
    """Convenience base for a real thermocouple amplifier: implement ``read_celsius``."""

    @abstractmethod
    def read_celsius(self) -> float: ...

    def read_sample(self) -> TemperatureSample:
        t = wallclock.now()
        return TemperatureSample(t, self.read_celsius())
