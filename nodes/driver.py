"""The board driver interface: what a Pmod NAV and a Pmod MAXSONAR driver answer.

Measures talk only to these protocols, in the drivers' own units, so a real board driver
can replace the simulator without touching any measure:

- Pmod NAV (LSM9DS1 + LPS25HB): accelerometer in g, gyroscope in deg/s, magnetometer in
  gauss (the units of the GRiSP ``pmod_nav`` driver, REFERENCE "Measures and models"),
  barometer in hPa;
- Pmod MAXSONAR (MaxBotix LV-MaxSonar-EZ1): range in whole inches.

Frame contract: the three NAV sensors report in one right-handed **board frame** (x forward,
y left, z up; a board lying flat and still reads about (0, 0, +1) g). A real LSM9DS1 has its
magnetometer axes turned relative to the accelerometer/gyroscope (the original code flipped
some signs for it); an adapter for a real board maps the chip axes into the board frame.

Optional protocols, for what only a simulated board has: :class:`SimulatedBoard` (the true
state of what it senses, for recording ground truth) and :class:`SimulatedSonar` (+ the true
range). Measures use them when the board offers them and work without them.

Times: a driver stamps its readings with the node's wall clock (:mod:`hera.wallclock`,
``time.time()`` unless a clock skew is injected).

Errors: a disconnected board raises :class:`BoardDisconnected` (an ``OSError``, as an I2C or
UART error would); a reading that is simply missing this time raises :class:`NoReading`
(measures answer "nothing this step"). The measures take any other ``OSError`` a driver lets
through (an I2C read of an unplugged chip: ``EREMOTEIO``) as the board not answering, as
:class:`BoardDisconnected` (:mod:`hera.nodes.board_reads`).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

from hera import wallclock
from hera.nodes.geometry import Vec3

if TYPE_CHECKING:  # pragma: no cover
    from hera.nodes.world import State


class DriverError(OSError):
    """A board did not answer as it should."""


class BoardDisconnected(DriverError):
    """The board is not reachable (unplugged, bus error)."""


class NoReading(DriverError):
    """The board answered but has no reading this time (a dropout)."""


@dataclass(frozen=True, slots=True)
class ImuSample:
    """One coherent read of a Pmod NAV: ``t`` epoch s (when it was taken), ``acc`` g,
    ``gyro`` deg/s, ``mag`` gauss or None when not read."""

    t: float
    acc: Vec3
    gyro: Vec3
    mag: Vec3 | None = None


@dataclass(frozen=True, slots=True)
class RangeSample:
    """One MaxSonar reading: ``t`` epoch s at the start of the ping, ``inches`` the range.

    ``crosstalk`` is known only to the simulator (True when another sonar of the group
    sounded during this ping, so the range is corrupted); a real driver leaves it False.
    """

    t: float
    inches: int
    crosstalk: bool = False


@runtime_checkable
class NavDriver(Protocol):
    """A Pmod NAV: 3-axis accelerometer, gyroscope, magnetometer and a barometer."""

    def read_acc(self) -> Vec3:
        """Specific force (g) in the board frame."""
        ...

    def read_gyro(self) -> Vec3:
        """Angular rate (deg/s) in the board frame."""
        ...

    def read_mag(self) -> Vec3:
        """Magnetic field (gauss) in the board frame."""
        ...

    def read_baro(self) -> float:
        """Air pressure (hPa)."""
        ...

    def read_imu(self, mag: bool = True) -> ImuSample:
        """Accelerometer, gyroscope and (if ``mag``) magnetometer read together, with the
        time they were taken."""
        ...


@runtime_checkable
class SonarDriver(Protocol):
    """A MaxSonar range finder."""

    def read_range(self) -> int:
        """The range to the nearest object in the beam (whole inches)."""
        ...

    def read_sample(self, grant: Any = None) -> RangeSample:
        """Ping once: the range with the time of the ping.

        ``grant``: in a synchronised step, the sync turn (``hera.sync.client.Turn``): call
        ``grant.check_at_trigger(time.time)`` right before triggering the ping (after any
        lock) and stamp the sample with its ``wall`` reading; it raises ``SlotLost`` when
        the ping no longer fits its slot: then do not ping. None when not synchronised.
        """
        ...


@runtime_checkable
class SimulatedBoard(Protocol):
    """Optional: a simulated board knows the true motion of the body it senses."""

    def truth(self, t: float) -> State:
        """The true state at epoch time ``t`` (s)."""
        ...

    def rest_truth(self) -> State:
        """The true state in the scenario's rest ("0 deg") pose."""
        ...


@runtime_checkable
class SimulatedSonar(SimulatedBoard, Protocol):
    """Optional: a simulated sonar also knows the true range it should read."""

    def true_range(self, t: float) -> float | None:
        """The noise-free range (m) at epoch time ``t``, None when nothing is in the beam."""
        ...


class NavDriverBase(ABC):
    """Convenience base for real NAV drivers: implement the four reads, get ``read_imu``."""

    @abstractmethod
    def read_acc(self) -> Vec3: ...

    @abstractmethod
    def read_gyro(self) -> Vec3: ...

    @abstractmethod
    def read_mag(self) -> Vec3: ...

    @abstractmethod
    def read_baro(self) -> float: ...

    def read_imu(self, mag: bool = True) -> ImuSample:
        t = wallclock.now()
        return ImuSample(t, self.read_acc(), self.read_gyro(), self.read_mag() if mag else None)


class SonarDriverBase(ABC):
    """Convenience base for real sonar drivers: implement ``read_range``."""

    @abstractmethod
    def read_range(self) -> int: ...

    def read_sample(self, grant: Any = None) -> RangeSample:
        t = wallclock.now() if grant is None else grant.check_at_trigger(wallclock.now).wall
        return RangeSample(t, self.read_range())  # read_range triggers the ping
