"""A real LSM6DSL on an I2C bus (Linux ``i2c-dev``, through the ``smbus2`` package).

Give it to the ``lsm6dsl`` measure: ``driver = "hera.nodes.lsm6dsl.i2c:I2cLsm6dsl"``,
``driver_args = { bus = 1 }`` (``pip install 'hera-fusion[i2c]'`` for smbus2; on a
Raspberry Pi, bus 1 is the header's SDA/SCL pins). The arguments:

- ``bus``: the adapter's number (``/dev/i2c-<bus>``) or the device's path;
- ``address``: 0x6A (the chip's SA0 pin low, the default) or 0x6B (high);
- ``odr_hz``: the output data rate of both sensors (12.5 .. 6664 Hz; the measure's own
  ``odr_hz`` must be the same, and its period 1 / ``odr_hz``);
- ``acc_range_g`` (2, 4, 8, 16; 4 by default) and ``gyro_range_dps`` (125, 245, 500, 1000,
  2000; 500 by default): the full scales, as the simulator's defaults;
- ``axes``: where the chip's axes point on the robot, as three signed chip axes giving the
  board's x, y and z (``"x,y,z"`` by default: the chip's frame is the board's; ``"-y,x,z"``:
  the board's x is the chip's -y, its y the chip's x). The measure expects the seed's robot
  frame from its board (see :mod:`hera.nodes.lsm6dsl.measures`); a mirror image (one axis
  turned alone) is refused, as no chip can be mounted that way;
- ``timeout_ms``: how long a read waits for a new sample (half a period by default).

What the chip is told (data sheet registers): a software reset (``CTRL3_C`` SW_RESET), then
block data update and address auto-increment (``CTRL3_C`` = BDU | IF_INC), the rate and full
scale of the accelerometer (``CTRL1_XL``) and of the gyroscope (``CTRL2_G``). A sampler
thread polls ``STATUS_REG`` and, once both XLDA and GDA say a new sample is there, reads the
twelve output bytes ``OUTX_L_G`` .. ``OUTZ_H_XL`` in one block (a repeated-start read). It
stamps each sample with when the chip made it, from the edges of the data-ready flags
(:class:`hera.nodes.data_ready.DataReadyClock` tracks the chip's clock from them: about
0.1 ms from the chip's own instant, whatever the chip's clock and the host's do to each
other), and polls little between samples. It keeps every sample until it is read
(up to :data:`QUEUE`; ``overwritten`` in the board listing counts what went), so a read
held up by a busy node, or a chip a little faster than the reads, loses none: a read
returns the oldest sample not read yet (``pending`` says how many more there are; the
``lsm6dsl`` measure takes them all each step), scaled (data sheet, mechanical
characteristics: 0.061 mg/LSB at 2 g .. 70 mdps/LSB at 2000 dps), waiting up to
``timeout_ms`` for one. A sample lost during a push cost the tilt filters half a degree
for many seconds: the gyroscope's rotation over its interval is gone.

Errors, as the driver contract of :mod:`hera.nodes.driver` asks: no new sample within
``timeout_ms`` raises :class:`NoReading` (a dropout); a bus that cannot be opened or a chip
that does not answer (``EREMOTEIO``: unplugged, no power) raises :class:`BoardDisconnected`,
and the sampler opens the bus and sets the chip up again every :data:`RETRY_S`, so a chip
plugged back or powered again comes back by itself. A chip found reset while running (no
sample for three periods, its rate register back to power-down: a brown-out) is set up
again, and the next dropout says so. A device at the
address that is not an LSM6DSL (``WHO_AM_I`` other than 0x6A) is a ValueError: the spec
names the wrong chip, and waiting will not change it.
"""

from __future__ import annotations

import contextlib
import struct
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from typing import Any

from hera import wallclock
from hera.nodes.data_ready import DataReadyClock
from hera.nodes.driver import BoardDisconnected, NoReading
from hera.nodes.driver_args import checked_args
from hera.nodes.lsm6dsl.driver import ODRS_HZ, ImuReading
from hera.nodes.mounting import from_chip, parse_axes

WHO_AM_I, CTRL1_XL, CTRL2_G, CTRL3_C, STATUS_REG, OUTX_L_G = 0x0F, 0x10, 0x11, 0x12, 0x1E, 0x22
"""Register addresses (data sheet section 9)."""

CHIP_ID = 0x6A
"""What ``WHO_AM_I`` reads on an LSM6DSL."""

ADDRESSES = (0x6A, 0x6B)
"""The chip's two I2C addresses (SA0 low, high)."""

BDU, IF_INC, SW_RESET = 0x40, 0x04, 0x01
"""``CTRL3_C`` bits: block data update, register address auto-increment, software reset."""

XLDA, GDA = 0x01, 0x02
"""``STATUS_REG`` bits: a new accelerometer sample, a new gyroscope sample."""

ACC_RANGES = {2: (0b00, 0.061e-3), 4: (0b10, 0.122e-3), 8: (0b11, 0.244e-3), 16: (0b01, 0.488e-3)}
"""Accelerometer full scale (g): its ``FS_XL`` code (``CTRL1_XL`` bits 3:2) and g per LSB."""

GYRO_RANGES = {
    125: (0b0010, 4.375e-3),
    245: (0b0000, 8.75e-3),
    500: (0b0100, 17.5e-3),
    1000: (0b1000, 35e-3),
    2000: (0b1100, 70e-3),
}
"""Gyroscope full scale (deg/s): ``CTRL2_G`` bits 3:0 (FS_G, FS_125) and deg/s per LSB."""

RESET_WAIT_S = 0.05
"""How long a software reset may take before the chip is taken as not answering."""

POLL_S = 0.001
"""Longest interval between two polls of ``STATUS_REG`` near a sample's edge (a tenth of a
period at the fastest rates)."""

QUEUE = 32
"""Samples kept for the reads (1.2 s at 26 Hz); the oldest goes when one more comes."""

RETRY_S = 0.25
"""Seconds between two tries to set the bus and chip up again after an error."""


def odr_code(odr_hz: float) -> int:
    """The ``ODR_XL``/``ODR_G`` code (bits 7:4) of an output data rate (Hz)."""
    return ODRS_HZ.index(odr_hz) + 1


def _open_smbus(bus: int | str) -> Any:
    try:
        from smbus2 import SMBus
    except ImportError:
        raise ValueError(
            "the I2C driver needs the smbus2 package: pip install 'hera-fusion[i2c]'"
        ) from None
    return SMBus(bus)


@checked_args
class I2cLsm6dsl:
    """An LSM6DSL on an I2C bus (see the module docstring). ``smbus`` opens the bus (default:
    ``smbus2.SMBus``); anything answering ``read_byte_data``, ``write_byte_data``,
    ``read_i2c_block_data`` and ``close`` as smbus2 does will do."""

    kind = "lsm6dsl-i2c"

    def __init__(
        self,
        bus: int | str = 1,
        address: int = 0x6A,
        odr_hz: float = 26.0,
        acc_range_g: int = 4,
        gyro_range_dps: int = 500,
        axes: str = "x,y,z",
        timeout_ms: float | None = None,
        *,
        smbus: Callable[[int | str], Any] | None = None,
    ) -> None:
        if timeout_ms is None:
            timeout_ms = 500.0 / odr_hz
        self.axes = parse_axes(axes)
        self.bus_name = bus if isinstance(bus, str) else f"/dev/i2c-{bus}"
        self.bus, self.address, self.odr_hz = bus, int(address), float(odr_hz)
        self.timeout = timeout_ms / 1000.0
        fs_xl, self._acc_lsb = ACC_RANGES[acc_range_g]
        fs_g, self._gyro_lsb = GYRO_RANGES[gyro_range_dps]
        code = odr_code(self.odr_hz) << 4
        self._ctrl = {CTRL1_XL: code | fs_xl << 2, CTRL2_G: code | fs_g}
        self._smbus = smbus or _open_smbus
        self._dev: Any = None
        self.reads = self.setups = self.resets_seen = self.overwritten = 0
        self._where = f"I2C bus {self.bus_name}, address 0x{self.address:02x}"
        period = 1.0 / self.odr_hz
        self.clock = DataReadyClock(period, min(POLL_S, period / 10))
        self._cond = threading.Condition()
        self._queue: deque[tuple[float, bytes]] = deque()  # (epoch s, the twelve bytes)
        self._trouble: BoardDisconnected | None = None
        self._fatal: ValueError | None = None
        self._note = ""  # said by the next dropout (a reset seen)
        self._stop = threading.Event()
        try:
            self._setup()
        except BoardDisconnected as e:  # not plugged in yet: the sampler tries again
            self._trouble = e
        self._thread = threading.Thread(
            target=self._sample_loop, name=f"lsm6dsl {self._where}", daemon=True
        )
        self._thread.start()

    @classmethod
    def check_args(cls, args: Mapping[str, Any]) -> list[str]:
        """Every problem with the constructor's arguments ``args`` (all of them, defaults
        filled in), one sentence each: what the constructor refuses, and what a spec check
        asks before any node starts (:func:`hera.nodes.boards.driver_problems`)."""
        bus, address, odr_hz = args["bus"], args["address"], args["odr_hz"]
        acc, gyro = args["acc_range_g"], args["gyro_range_dps"]
        timeout_ms = args["timeout_ms"]
        out = []
        if isinstance(bus, bool) or not (
            (isinstance(bus, int) and bus >= 0) or (isinstance(bus, str) and bus.startswith("/"))
        ):
            out.append(f"bus must be an adapter number or a device path, got {bus!r}")
        if address not in ADDRESSES:
            out.append(f"address must be 0x6a or 0x6b (the chip's two), got {address!r}")
        if odr_hz not in ODRS_HZ:
            out.append(f"odr_hz must be one of {ODRS_HZ} (Hz), got {odr_hz!r}")
        if acc not in ACC_RANGES:
            out.append(f"acc_range_g must be one of {tuple(ACC_RANGES)}, got {acc!r}")
        if gyro not in GYRO_RANGES:
            out.append(f"gyro_range_dps must be one of {tuple(GYRO_RANGES)}, got {gyro!r}")
        if timeout_ms is not None and odr_hz in ODRS_HZ:
            most = 10_000.0 / odr_hz
            if isinstance(timeout_ms, bool) or not (
                isinstance(timeout_ms, (int, float)) and 0 < timeout_ms <= most
            ):
                out.append(
                    f"timeout_ms must be a number of ms in (0, {most:g}] (ten periods), "
                    f"got {timeout_ms!r}"
                )
        try:
            parse_axes(args["axes"])
        except ValueError as e:
            out.append(str(e))
        return out

    # -- the bus ----------------------------------------------------------------------------
    def _fail(self, e: OSError) -> BoardDisconnected:
        """Close the bus after an error and say where it happened."""
        self._close_bus()
        return BoardDisconnected(f"{self._where}: {e.strerror or e}")

    def _close_bus(self) -> None:
        dev, self._dev = self._dev, None
        if dev is not None:
            with contextlib.suppress(OSError):
                dev.close()

    def _setup(self) -> Any:
        """Open the bus if needed, check the chip and set it up (reset, BDU | IF_INC, the two
        control registers); BoardDisconnected when the bus or chip does not answer."""
        a = self.address
        try:
            if self._dev is None:
                self._dev = self._smbus(self.bus)
            dev = self._dev
            who = dev.read_byte_data(a, WHO_AM_I)
            if who != CHIP_ID:
                self._close_bus()
                raise ValueError(
                    f"{self._where} is not an LSM6DSL: WHO_AM_I reads 0x{who:02x}, "
                    f"an LSM6DSL reads 0x{CHIP_ID:02x}"
                )
            dev.write_byte_data(a, CTRL3_C, SW_RESET)
            deadline = time.monotonic() + RESET_WAIT_S
            while dev.read_byte_data(a, CTRL3_C) & SW_RESET:
                if time.monotonic() > deadline:
                    raise OSError(f"the chip did not finish its reset in {RESET_WAIT_S:g} s")
                time.sleep(POLL_S)
            dev.write_byte_data(a, CTRL3_C, BDU | IF_INC)
            for reg, value in self._ctrl.items():
                dev.write_byte_data(a, reg, value)
        except OSError as e:
            raise self._fail(e) from None
        self.setups += 1
        return dev

    def _still_set_up(self, dev: Any) -> bool:
        """Whether the control registers still hold what :meth:`_setup` wrote."""
        return all(dev.read_byte_data(self.address, r) == v for r, v in self._ctrl.items())

    # -- the sampler thread -----------------------------------------------------------------
    def _sample_loop(self) -> None:
        """Poll the data-ready flags on the :class:`DataReadyClock`'s schedule, keep the
        newest sample with its stamp, set the bus up again after an error (every
        :data:`RETRY_S`) or a reset, until :meth:`close`."""
        clock, mono = self.clock, time.monotonic
        quiet = 3.0 * clock.nominal  # no sample this long: was the chip reset?
        last = mono()
        while not self._stop.is_set():
            try:
                dev = self._dev if self._dev is not None else self._setup()
                if self._trouble is not None:
                    with self._cond:
                        self._trouble = None
                    last = mono()
                began = mono()
                status = dev.read_byte_data(self.address, STATUS_REG)
                now = mono()
                if status & (XLDA | GDA) == XLDA | GDA:
                    made = clock.ready(now)
                    raw = bytes(dev.read_i2c_block_data(self.address, OUTX_L_G, 12))
                    wall = wallclock.now() - (mono() - made)
                    with self._cond:
                        if len(self._queue) == QUEUE:
                            self._queue.popleft()
                            self.overwritten += 1
                        self._queue.append((wall, raw))
                        self._cond.notify_all()
                    last = now
                else:
                    clock.not_ready(began)
                    if now - last > quiet:
                        last = now  # looked: look again after another quiet spell
                        if not self._still_set_up(dev):  # a brown-out: back in power-down
                            self.resets_seen += 1
                            self._setup()
                            with self._cond:
                                self._note = "the chip had been reset; set up again"
                wait = clock.next_poll(mono()) - mono()
            except BoardDisconnected as e:
                self._set_trouble(e)
                wait = RETRY_S
            except OSError as e:
                self._set_trouble(self._fail(e))
                wait = RETRY_S
            except ValueError as e:  # another chip at the address: for good
                with self._cond:
                    self._fatal = e
                    self._cond.notify_all()
                return
            if wait > 0:
                self._stop.wait(wait)

    def _set_trouble(self, e: BoardDisconnected) -> None:
        with self._cond:
            self._trouble = e
            self._queue.clear()
            self._cond.notify_all()

    # -- Lsm6dslDriver ----------------------------------------------------------------------
    @property
    def pending(self) -> int:
        """Samples made and not read yet (the ``lsm6dsl`` measure reads them all each step)."""
        with self._cond:
            return len(self._queue)

    def read_imu(self) -> ImuReading:
        """The oldest sample not read yet, stamped when the chip made it; waits up to
        ``timeout_ms`` for one (see the module docstring for the errors)."""
        deadline = time.monotonic() + self.timeout
        with self._cond:
            while True:
                if self._fatal is not None:
                    raise self._fatal
                if self._queue:
                    t, raw = self._queue.popleft()
                    break
                if self._trouble is not None:
                    raise self._trouble
                left = deadline - time.monotonic()
                if left <= 0:
                    note, self._note = self._note, ""
                    why = note or f"no new sample in {self.timeout * 1e3:g} ms"
                    raise NoReading(f"{self._where}: {why}")
                self._cond.wait(left)
        gx, gy, gz, ax, ay, az = struct.unpack("<6h", raw)
        self.reads += 1
        return ImuReading(
            t,
            from_chip(self.axes, (ax, ay, az), self._acc_lsb),
            from_chip(self.axes, (gx, gy, gz), self._gyro_lsb),
        )

    def describe(self) -> dict[str, Any]:
        """JSON-able status for the ``board`` verb's listing."""
        return {
            "kind": self.kind,
            "bus": self.bus_name,
            "address": f"0x{self.address:02x}",
            "odr_hz": self.odr_hz,
            "connected": self._dev is not None,
            "reads": self.reads,
            "setups": self.setups,
            "resets_seen": self.resets_seen,
            "overwritten": self.overwritten,
            "period_ms": round(self.clock.period * 1e3, 4),
            "relocks": self.clock.relocks,
            "fault": None,
        }

    def close(self) -> None:
        """Stop the sampler, put the chip in power-down (best effort) and close the bus."""
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join()
        dev = self._dev
        if dev is not None:
            with contextlib.suppress(OSError):
                for reg in self._ctrl:
                    dev.write_byte_data(self.address, reg, 0)
        self._close_bus()
