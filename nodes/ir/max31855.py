"""A real type-K thermocouple on a Linux host: a MAX31855 amplifier on SPI (``spidev``,
through python-periphery: ``pip install 'hera-fusion[spi]'``).

Give it to the ``thermocouple`` measure: ``driver = "hera.nodes.ir.max31855:Max31855"``,
``driver_args = { device = "/dev/spidev0.1" }`` (``speed_hz``: 1 MHz by default, the data
sheet allows 5 MHz). The chip converts on its own (about ten times a second) and cold-
junction compensates; a read takes its last conversion.

A read (MAX31855 data sheet, memory map): 32 bits clocked out in SPI mode 0, most
significant first: bits 31-18 the thermocouple's temperature (14-bit two's complement,
0.25 degC), bit 17 reserved (0), bit 16 a fault, bits 15-4 the chip's own (cold-junction)
temperature (12-bit, 0.0625 degC), bit 3 reserved (0), bits 2-0 which fault: short to VCC,
short to GND, open (no thermocouple). A fault is a disconnected board that says which (see
:mod:`hera.nodes.driver`): the measure counts it and shows it until the thermocouple is
back. A frame with a reserved bit set (a MISO line pulled up: no chip, every bit 1) or with
every bit 0 (pulled down: 0.00 degC at the junction and the chip, which a live chip on a
bench does not read) is a chip that does not answer, never a reading.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from hera.nodes.driver import BoardDisconnected
from hera.nodes.driver_args import checked_args
from hera.nodes.ir.driver import ThermocoupleDriverBase
from hera.nodes.spi import Opener, SpiLink, path_problems, speed_problems

FAULT, RESERVED = 1 << 16, (1 << 17) | (1 << 3)
FAULTS = ((1 << 0, "open: no thermocouple"), (1 << 1, "shorted to GND"), (1 << 2, "shorted to VCC"))
"""The fault bits and what each says."""

THERMO_LSB, JUNCTION_LSB = 0.25, 0.0625
"""degC per count of the thermocouple's and the chip's own temperature."""

MAX_SPEED_HZ = 5_000_000


def decode(frame: int) -> tuple[float, float]:
    """(thermocouple degC, chip degC) of a fault-free 32-bit frame."""
    hot = frame >> 18
    cold = (frame >> 4) & 0xFFF
    return (
        (hot - (1 << 14) if hot & (1 << 13) else hot) * THERMO_LSB,
        (cold - (1 << 12) if cold & (1 << 11) else cold) * JUNCTION_LSB,
    )


@checked_args
class Max31855(ThermocoupleDriverBase):
    """A thermocouple behind a MAX31855 (see the module docstring). ``spi`` opens the device
    (default ``periphery.SPI``; see :data:`hera.nodes.spi.Opener`)."""

    kind = "thermocouple-max31855"

    def __init__(
        self,
        device: str = "/dev/spidev0.1",
        speed_hz: int = 1_000_000,
        *,
        spi: Opener | None = None,
    ) -> None:
        self.link = SpiLink(device, f"SPI {device} (MAX31855)", 0, speed_hz, spi)
        self.reads = 0
        self.junction: float | None = None  # the chip's own temperature at the last read

    @classmethod
    def check_args(cls, args: Mapping[str, Any]) -> list[str]:
        """Every problem with the constructor's arguments, one sentence each."""
        return path_problems("device", args["device"]) + speed_problems(
            args["speed_hz"], MAX_SPEED_HZ
        )

    def read_celsius(self) -> float:
        """The thermocouple's temperature (degC) of the chip's last conversion."""
        frame = int.from_bytes(bytes(self.link.transfer([0, 0, 0, 0])), "big")
        where = self.link.where
        if frame & RESERVED or frame == 0:
            raise BoardDisconnected(f"{where}: no chip answers (the frame reads 0x{frame:08x})")
        if frame & FAULT:
            said = [what for bit, what in FAULTS if frame & bit] or ["a fault"]
            raise BoardDisconnected(f"{where}: thermocouple {', '.join(said)}")
        hot, self.junction = decode(frame)
        self.reads += 1
        return hot

    def describe(self) -> dict[str, Any]:
        """JSON-able status for the ``board`` verb's listing."""
        return {
            "kind": self.kind,
            "device": self.link.path,
            "connected": self.link.is_open,
            "junction_c": self.junction,
            "reads": self.reads,
            "fault": None,
        }

    def close(self) -> None:
        self.link.close()
