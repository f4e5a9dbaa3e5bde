"""A real MaxSonar on a serial port: the MaxBotix LV-MaxSonar-EZ's serial output (the
Pmod MAXSONAR's UART pins, or any USB-serial adapter), read with the standard library.

Give it to the ``sonar`` measure: ``driver = "hera.nodes.serial_sonar:SerialMaxSonar"``,
``driver_args = { port = "/dev/ttyUSB0" }`` (and ``trigger``, below).

The sensor sends each reading as ``R``, three ASCII digits (the range in whole inches)
and a carriage return, at 9600 baud, 8 data bits, no parity, one stop bit. Its
data sheet calls the levels "RS232 format": inverted against a plain TTL UART, which some
adapters (and the Pmod) undo; a port that shows only garbage needs that inversion.

How a reading is taken (``trigger``):

- ``"free"`` (the default): the sensor's RX pin left open, it ranges every 49 ms on its own.
  A read drops what came before it and returns the next complete reading, stamped one
  ranging cycle (``cycle_ms``) before it arrived. The sonars of a sync group cannot take
  turns this way (each pings on its own clock): wire their RX pins for a trigger.
- ``"rts"`` or ``"dtr"``: that modem line of the port drives the sensor's RX pin, the
  asserted line holding it high (the adapter's wiring must make it so). A read asserts the
  line for ``pulse_ms`` (the data sheet asks for 20 us or more), releases it, and returns
  the reading that follows; the ping starts at the trigger, so a sync group's turns hold.
  A port without that line is refused when the driver is made.

Errors: no complete reading within ``timeout_ms`` raises :class:`NoReading` (a dropout); a
port that cannot be opened or fails (an unplugged adapter) raises
:class:`BoardDisconnected`, and the next read opens it again (the adapter plugged back in).
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import re
import select
import struct
import termios
import time
import tty
from typing import Any

from hera import wallclock
from hera.nodes.driver import (
    BoardDisconnected,
    DriverError,
    NoReading,
    RangeSample,
    SonarDriverBase,
)

FRAME = re.compile(rb"R(\d{3})\r")
"""One reading on the wire: ``R``, the range in inches as three digits, a carriage return."""

LINES = {"rts": termios.TIOCM_RTS, "dtr": termios.TIOCM_DTR}
"""The modem lines a trigger can use, by name."""

_KEEP = 8  # bytes kept when no reading is complete (a reading is 5 bytes long)


class SerialMaxSonar(SonarDriverBase):
    """A MaxSonar read on serial port ``port`` (see the module docstring)."""

    def __init__(
        self,
        port: str,
        trigger: str = "free",
        baud: int = 9600,
        timeout_ms: float = 200.0,
        pulse_ms: float = 1.0,
        cycle_ms: float = 49.0,
    ) -> None:
        if trigger != "free" and trigger not in LINES:
            raise ValueError(f"trigger must be free, rts or dtr, got {trigger!r}")
        speed = getattr(termios, f"B{baud}", None) if isinstance(baud, int) else None
        if speed is None:
            raise ValueError(f"baud {baud!r} is not a serial speed of this system")
        for name, value in (("timeout_ms", timeout_ms), ("pulse_ms", pulse_ms)):
            if not 0 < value < 60_000:
                raise ValueError(f"{name} must be a number of ms in (0, 60000), got {value!r}")
        if not 0 <= cycle_ms < 1000:
            raise ValueError(f"cycle_ms must be a number of ms in [0, 1000), got {cycle_ms!r}")
        self.port, self.trigger, self._speed = str(port), trigger, speed
        self.timeout, self.pulse, self.cycle = timeout_ms / 1000, pulse_ms / 1000, cycle_ms / 1000
        self._fd: int | None = None
        self._buf = bytearray()
        self._arrived = 0.0
        with contextlib.suppress(BoardDisconnected):  # not plugged in yet: reads retry
            self._open()

    # -- the port ---------------------------------------------------------------------------
    def _open(self) -> int:
        """Open and configure the port (raw, 8N1, the speed; the trigger line released);
        BoardDisconnected when it cannot be opened, ValueError when it is no serial port or
        has no trigger line."""
        try:
            fd = os.open(self.port, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        except OSError as e:
            raise BoardDisconnected(f"serial port {self.port}: {e.strerror}") from None
        try:
            if not os.isatty(fd):
                raise ValueError(f"{self.port} is not a serial port")
            tty.setraw(fd)
            attrs = termios.tcgetattr(fd)
            attrs[2] = (attrs[2] & ~(termios.PARENB | termios.CSTOPB | termios.CSIZE)) | (
                termios.CS8 | termios.CLOCAL | termios.CREAD
            )
            attrs[4] = attrs[5] = self._speed
            termios.tcsetattr(fd, termios.TCSANOW, attrs)
            if self.trigger != "free":
                try:
                    self._line(fd, on=False)  # the sensor waits for its trigger
                except OSError as e:
                    raise ValueError(
                        f"serial port {self.port} cannot drive its {self.trigger.upper()} line "
                        f"({e.strerror}): use a port that has it, or trigger = 'free'"
                    ) from None
        except termios.error as e:  # the port failed while being set up: as if unplugged
            os.close(fd)
            raise BoardDisconnected(f"serial port {self.port}: {e.args[-1]}") from None
        except BaseException:
            os.close(fd)
            raise
        self._fd = fd
        self._buf.clear()
        return fd

    def _line(self, fd: int, on: bool) -> None:
        """Assert (``on``) or release the trigger's modem line."""
        request = termios.TIOCMBIS if on else termios.TIOCMBIC
        fcntl.ioctl(fd, request, struct.pack("I", LINES[self.trigger]))

    def close(self) -> None:
        """Close the port (the node is stopping); a later read opens it again."""
        fd, self._fd = self._fd, None
        if fd is not None:
            os.close(fd)

    # -- reading ----------------------------------------------------------------------------
    def read_range(self) -> int:
        """Take one reading (see the module docstring): the range in whole inches."""
        try:
            fd = self._fd if self._fd is not None else self._open()
            termios.tcflush(fd, termios.TCIFLUSH)  # only what comes after this read counts
            self._buf.clear()
            if self.trigger != "free":
                self._line(fd, on=True)
                time.sleep(self.pulse)
                self._line(fd, on=False)
            return self._next_reading(fd, time.monotonic() + self.timeout)
        except (OSError, termios.error) as e:  # termios.error is (errno, text), no OSError
            if isinstance(e, DriverError):  # NoReading, BoardDisconnected: as they are
                raise
            self.close()
            why = e.strerror if isinstance(e, OSError) else e.args[-1]
            raise BoardDisconnected(f"serial port {self.port}: {why or e}") from None

    def _next_reading(self, fd: int, deadline: float) -> int:
        """The first complete reading from the port before ``deadline`` (monotonic s);
        NoReading if none comes, BoardDisconnected if the port closes."""
        while True:
            found = FRAME.search(self._buf)
            if found is not None:
                self._arrived = wallclock.now()
                inches = int(found.group(1))  # before the buffer the match reads changes
                del self._buf[: found.end()]
                return inches
            del self._buf[:-_KEEP]  # noise: keep only what may start a reading
            left = deadline - time.monotonic()
            if left <= 0:
                raise NoReading(f"no reading from {self.port} in {self.timeout * 1000:.0f} ms")
            if select.select([fd], [], [], left)[0]:
                chunk = os.read(fd, 256)
                if not chunk:  # the other end hung up
                    self.close()
                    raise BoardDisconnected(f"serial port {self.port}: hung up")
                self._buf += chunk

    def read_sample(self, grant: Any = None) -> RangeSample:
        """Ping once (see the module docstring for when the ping happens and its stamp)."""
        if self.trigger != "free":
            return super().read_sample(grant)
        if grant is not None:
            grant.check_at_trigger(wallclock.now)  # SlotLost: no reading in a lost slot
        inches = self.read_range()
        return RangeSample(self._arrived - self.cycle, inches)
