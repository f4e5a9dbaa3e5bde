"""A real Sharp IR sensor on a Linux host: its analog output through an MCP3008 ADC on SPI
(``spidev``, through python-periphery: ``pip install 'hera-fusion[spi]'``).

The seed's rig reads the sensor with the STM32's own 12-bit ADC; a Raspberry Pi has none,
and the MCP3008 (10 bits, 8 channels) is the usual one to add. Give it to the ``sharp_ir``
measure: ``driver = "hera.nodes.ir.mcp3008:Mcp3008Ir"``, ``driver_args = { device =
"/dev/spidev0.0", channel = 0 }``. The arguments:

- ``device``: the spidev device of the ADC's chip select;
- ``channel``: the ADC input the sensor's output is wired to (0-7, single-ended);
- ``vref``: the ADC's reference voltage (its VREF pin; 3.3 V by default, as on a Pi's
  3.3 V rail): the full scale of a conversion. A Sharp sensor's output stays under about
  3.2 V, so a 3.3 V reference keeps all of it;
- ``speed_hz``: the SPI clock (1 MHz by default; the data sheet allows 3.6 MHz at 5 V and
  1.35 MHz at 2.7 V).

A conversion (MCP3008 data sheet): the host sends a start bit, then the
single-ended flag and the channel's three bits; the ADC samples the input, sends a null bit
(0) and the ten bits of the code, most significant first. One 3-byte transfer does it, in
SPI mode 0: the code is the low two bits of the second byte and the third byte, and the
voltage is code * vref / 1024. The null bit tells a chip that answers from a MISO line left
pulled up (no chip: every bit reads 1), which is a disconnected board (see
:mod:`hera.nodes.driver`), not a reading at full scale. A line pulled down reads as 0 V,
which a Sharp sensor with nothing in range also gives: a missing chip then shows as a sensor
that sees nothing.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from hera.nodes.driver import BoardDisconnected
from hera.nodes.driver_args import checked_args
from hera.nodes.ir.driver import IrDriverBase
from hera.nodes.spi import Opener, SpiLink, path_problems, speed_problems

CODES = 1024
"""Codes of a 10-bit conversion: VIN = code * VREF / 1024."""

START, SINGLE = 0x01, 0x80
"""The first byte (its last bit the start bit); the second byte's single-ended flag."""

NULL_BIT = 0x04
"""In the second byte answered: the null bit before the code's two high bits (always 0)."""

MAX_SPEED_HZ = 3_600_000


@checked_args
class Mcp3008Ir(IrDriverBase):
    """A Sharp IR sensor on one channel of an MCP3008 (see the module docstring). ``spi``
    opens the device (default ``periphery.SPI``; see :data:`hera.nodes.spi.Opener`)."""

    kind = "sharp-ir-mcp3008"

    def __init__(
        self,
        device: str = "/dev/spidev0.0",
        channel: int = 0,
        vref: float = 3.3,
        speed_hz: int = 1_000_000,
        *,
        spi: Opener | None = None,
    ) -> None:
        self.channel, self.vref = channel, float(vref)
        self.link = SpiLink(device, f"SPI {device} (MCP3008 channel {channel})", 0, speed_hz, spi)
        self._ask = [START, SINGLE | channel << 4, 0x00]
        self.reads = 0

    @classmethod
    def check_args(cls, args: Mapping[str, Any]) -> list[str]:
        """Every problem with the constructor's arguments, one sentence each."""
        out = path_problems("device", args["device"])
        channel, vref = args["channel"], args["vref"]
        if isinstance(channel, bool) or channel not in range(8):
            out.append(f"channel must be an ADC input 0-7, got {channel!r}")
        if isinstance(vref, bool) or not (isinstance(vref, (int, float)) and 0 < vref <= 5.5):
            out.append(f"vref must be the ADC's reference in (0, 5.5] V, got {vref!r}")
        return out + speed_problems(args["speed_hz"], MAX_SPEED_HZ)

    def read_volts(self) -> float:
        """Convert once: the sensor's output (V)."""
        _, high, low = self.link.transfer(self._ask)
        if high & NULL_BIT:
            raise BoardDisconnected(
                f"{self.link.where}: no chip answers (its null bit reads 1: MISO pulled up)"
            )
        self.reads += 1
        return ((high & 0x03) << 8 | low) * self.vref / CODES

    def describe(self) -> dict[str, Any]:
        """JSON-able status for the ``board`` verb's listing."""
        return {
            "kind": self.kind,
            "device": self.link.path,
            "channel": self.channel,
            "vref": self.vref,
            "connected": self.link.is_open,
            "reads": self.reads,
            "fault": None,
        }

    def close(self) -> None:
        self.link.close()
