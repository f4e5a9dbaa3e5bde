"""A chip on a Linux SPI bus (``spidev``, through the ``python-periphery`` package), for the
real drivers that talk SPI (:mod:`hera.nodes.nav_spi`, :mod:`hera.nodes.ir.mcp3008`,
:mod:`hera.nodes.ir.max31855`).

:class:`SpiLink` is one chip select: its device, opened when first needed (so a driver can
be made before its board is plugged in), full-duplex transfers, and every ``OSError`` turned
into :class:`~hera.nodes.driver.BoardDisconnected` naming the device, after which the device
is closed and the next transfer opens it again. SPI has no acknowledge: a chip that is not
there answers whatever the idle MISO line reads (all ones or all zeros); each driver says how
it tells that from a reading.

The drivers' arguments are checked with :func:`path_problems` and :func:`choice_problems`
(one sentence per problem, as :func:`hera.nodes.boards.driver_problems` asks).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from typing import Any

from hera.nodes.driver import BoardDisconnected

MAX_SPEED_HZ = 10_000_000
"""The fastest clock a driver here accepts."""

Opener = Callable[[str, int, int], Any]
"""Opens a device: ``(path, mode, speed_hz) -> object`` with ``transfer(list of bytes) ->
list of bytes`` (as many back as out) and ``close()``: ``periphery.SPI`` or a test's fake."""


def periphery_spi() -> Opener:
    """``periphery.SPI`` (called as ``(path, mode, speed_hz)``); ValueError naming the extra
    to install when python-periphery is missing."""
    try:
        from periphery import SPI
    except ImportError:
        raise ValueError(
            "the SPI drivers need the python-periphery package: pip install 'hera-fusion[spi]'"
        ) from None
    return SPI  # type: ignore[no-any-return]


class SpiLink:
    """One chip select (see the module docstring). ``where`` names it in errors."""

    def __init__(
        self, path: str, where: str, mode: int, speed_hz: int, open_spi: Opener | None = None
    ) -> None:
        self.path, self.where, self.mode, self.speed_hz = path, where, mode, speed_hz
        self._open = open_spi or periphery_spi()  # a missing package refuses the driver now
        self.spi: Any = None

    @property
    def is_open(self) -> bool:
        return self.spi is not None

    def fail(self, e: OSError) -> BoardDisconnected:
        """Close the device after an error and say where it happened."""
        self.close()
        return BoardDisconnected(f"{self.where}: {e.strerror or e}")

    def transfer(self, out: list[int]) -> list[int]:
        """Send ``out`` and return the bytes read meanwhile (BoardDisconnected on an error)."""
        try:
            if self.spi is None:
                self.spi = self._open(self.path, self.mode, self.speed_hz)
            return list(self.spi.transfer(out))
        except OSError as e:
            raise self.fail(e) from None

    def close(self) -> None:
        spi, self.spi = self.spi, None
        if spi is not None:
            with contextlib.suppress(OSError):
                spi.close()


def path_problems(name: str, value: Any, optional: bool = False) -> list[str]:
    """The problem with a device path argument, if any (None allowed when ``optional``)."""
    if value is None and optional:
        return []
    if isinstance(value, str) and value.startswith("/"):
        return []
    what = "a device path (as '/dev/spidev0.1') or none" if optional else "a device path"
    return [f"{name} must be {what}, got {value!r}"]


def choice_problems(name: str, value: Any, options: tuple | dict, unit: str = "") -> list[str]:
    """The problem with an argument that takes one of ``options``, if any."""
    if isinstance(value, bool) or value not in options:
        return [f"{name} must be one of {tuple(options)}{unit}, got {value!r}"]
    return []


def speed_problems(value: Any, most: int = MAX_SPEED_HZ) -> list[str]:
    """The problem with a ``speed_hz`` argument, if any."""
    if isinstance(value, bool) or not (isinstance(value, int) and 0 < value <= most):
        return [f"speed_hz must be an integer in (0, {most}] (Hz), got {value!r}"]
    return []
