"""A real Pmod NAV (LSM9DS1 + LPS25HB) on a Linux SPI bus (``spidev``, through the
``python-periphery`` package).

Give it to the NAV measures (``nav``, ``mag``, ``nav3``): ``driver =
"hera.nodes.nav_spi:SpiPmodNav"``, ``driver_args = { ag = "/dev/spidev0.0", mag =
"/dev/spidev0.1" }`` (``pip install 'hera-fusion[spi]'`` for python-periphery). The Pmod has
one chip-select line per sensor, so each is its own spidev device: CS_AG (Pmod pin 1) the
accelerometer and gyroscope, CS_M (pin 9) the magnetometer, CS_ALT (pin 10) the barometer.
The arguments:

- ``ag``, ``mag``, ``alt``: the three devices' paths (``mag`` None: no magnetometer wired,
  ``alt`` None, the default: no barometer);
- ``speed_hz``: the SPI clock (the chips take up to 10 MHz; 1 MHz by default);
- ``odr_hz``: the accelerometer's and gyroscope's output data rate (14.9, 59.5, 119, 238,
  476, 952 Hz; 119 by default), above the rate of the measures that read it;
- ``acc_range_g`` (2, 4, 8, 16), ``gyro_range_dps`` (245, 500, 2000), ``mag_range_gauss``
  (4, 8, 12, 16): the full scales (the smallest by default, as the GRiSP driver sets);
- ``mag_odr_hz``: the magnetometer's rate (0.625 .. 80 Hz; 80 by default);
- ``axes``: where the chip's accelerometer/gyroscope axes point on the board, as three signed
  chip axes giving the board's x, y and z (:mod:`hera.nodes.mounting`; ``"x,y,z"``, the
  default, for a Pmod lying with its chip's axes as the board's);
- ``timeout_ms``: how long a read waits for a new sample (three periods by default);
- ``mag_axes``: where the magnetometer die's axes lie in the accelerometer's frame (see
  Frames, below).

Wire protocol (LSM9DS1 and LPS25HB data sheets; the GRiSP ``pmod_nav`` driver of the thesis
does the same): SPI mode 3, most significant bit first; the first byte is the register
address, bit 7 set for a read; the accelerometer/gyroscope step the address on by themselves
through a burst (``CTRL_REG8`` IF_ADD_INC), the magnetometer and barometer when bit 6 of the
address asks them to. Outputs are little-endian two's complement (the thesis's appendix E: the
magnetometer read as unsigned put its sphere in four corners).

What the chips are told (each setting read back after it is written): each a software reset,
then block data update (a sample's two bytes always belong together); the accelerometer and
gyroscope at ``odr_hz`` with their full scales (with both on, the accelerometer runs at the
gyroscope's rate); the magnetometer continuous at ``mag_odr_hz``, ultra-high-performance on
all three axes, temperature compensated; the barometer on at 25 Hz.

Frames: the driver returns all three sensors in the accelerometer's frame turned by
``axes``: the board frame of :mod:`hera.nodes.driver`. The magnetometer is a die of its own
whose axes are labelled differently: ``mag_axes`` (default ``"-x,y,z"``) says where they
lie in the accelerometer's frame, here its x negated, as the thesis's ``nav3`` measure read
this board. That is the one source found for this board; other LSM9DS1 code disagrees
(ArduPilot turns its magnetometer a half turn about x on one board, SparkFun's example swaps
x and y), and the data sheet's figure was not at hand. Check it on a board: turned about z,
its heading must turn the same way as the gyroscope's, and lying flat its field's z must be
negative (the field points down, in the northern hemisphere); if not, give ``mag_axes``.

Reads: a read of the accelerometer/gyroscope waits for the next sample the chip makes (so
each read is a sample of its own, as the calibrations average) and stamps it when it was
made: the driver polls the chip (about eight times a period, at most every millisecond) and
takes the middle of the poll that still showed the previous sample and the one that showed
the new (within half a poll of the chip's instant). A new sample is told by its content, not
by the status flags: the gyroscope's and temperature's output bytes change from one sample
to the next on a live chip, its noise alone sees to that (a sample that repeats the last one
to the bit is taken as the next one that does not, stamped as that one). Each poll also
reads ``WHO_AM_I`` and the gyroscope's control register (one burst from 0x0F to 0x1D), so a
chip that is gone or was reset shows at once. ``read_imu`` gives the magnetometer's newest
sample with the accelerometer's (80 Hz, above what the measures read); ``read_mag`` waits
for one it has not given yet (what the magnetometer's calibrations average); the barometer
gives its newest (25 Hz). Scales (data sheets, mechanical characteristics): 0.061 mg/LSB at
2 g .. 0.732 at 16 g, 8.75 mdps/LSB at 245 dps .. 70 at 2000, 0.14 mgauss/LSB at 4 gauss ..
0.58 at 16, pressure 1/4096 hPa/LSB.

Errors, as the driver contract of :mod:`hera.nodes.driver` asks: no new sample within
``timeout_ms`` raises :class:`NoReading` (a dropout); a device that cannot be opened, or a
chip that does not answer (SPI has no acknowledge: an unplugged board reads ``WHO_AM_I`` as
0x00 or 0xFF, never taken for a reading) raises :class:`BoardDisconnected`, and the next read
opens it and sets it up again, so a board plugged back comes back by itself. A chip found
reset (its control registers back to their power-on values: a brown-out) is set up again
and that read is a dropout that says so. A chip that answers with another ``WHO_AM_I`` is a
ValueError: the spec names the wrong device, and waiting will not change it.
"""

from __future__ import annotations

import contextlib
import struct
import threading
import time
from collections.abc import Mapping
from typing import Any

from hera import wallclock
from hera.nodes.driver import BoardDisconnected, ImuSample, NoReading
from hera.nodes.driver_args import checked_args
from hera.nodes.geometry import Vec3
from hera.nodes.mounting import from_chip, parse_axes
from hera.nodes.spi import Opener, SpiLink, choice_problems, path_problems, speed_problems

SPI_MODE = 3
"""Clock idle high, data taken on the rising edge (the chips' data sheets)."""

READ, AUTO_INC = 0x80, 0x40
"""Address bits: read (else write); the magnetometer's and barometer's address increment."""

# LSM9DS1 accelerometer and gyroscope (its data sheet's register map).
WHO_AM_I, CTRL_REG1_G, OUT_X_G, CTRL_REG6_XL, CTRL_REG8, OUT_X_XL = (
    0x0F,
    0x10,
    0x18,
    0x20,
    0x22,
    0x28,
)
AG_ID = 0x68
"""What the accelerometer/gyroscope's ``WHO_AM_I`` reads."""
BDU, IF_ADD_INC, SW_RESET = 0x40, 0x04, 0x01
"""``CTRL_REG8`` bits: block data update, address increment (on at power-on), reset."""

# LSM9DS1 magnetometer.
CTRL_REG1_M, CTRL_REG2_M, CTRL_REG3_M, CTRL_REG4_M, CTRL_REG5_M = 0x20, 0x21, 0x22, 0x23, 0x24
STATUS_REG_M, OUT_X_M = 0x27, 0x28
ZYXDA = 0x08
"""``STATUS_REG_M`` bit: a new sample of all three axes."""
MAG_ID = 0x3D
TEMP_COMP, OM_ULTRA, OMZ_ULTRA, SOFT_RST, MD_POWER_DOWN, BDU_M = 0x80, 0x60, 0x0C, 0x04, 0x03, 0x40

# LPS25HB barometer (its data sheet's register map).
BARO_CTRL_REG1, BARO_CTRL_REG2, BARO_STATUS, PRESS_OUT_XL = 0x20, 0x21, 0x27, 0x28
BARO_ID = 0xBD
PD, ODR_25HZ, BDU_P, SWRESET, P_DA = 0x80, 0x40, 0x04, 0x04, 0x02
BARO_ODR_HZ = 25.0

ODRS_HZ = (14.9, 59.5, 119.0, 238.0, 476.0, 952.0)
"""The accelerometer/gyroscope rates; codes 1..6 in ``CTRL_REG1_G``/``CTRL_REG6_XL`` bits 7:5."""

ACC_RANGES = {2: (0b00, 0.061e-3), 4: (0b10, 0.122e-3), 8: (0b11, 0.244e-3), 16: (0b01, 0.732e-3)}
"""Accelerometer full scale (g): its ``FS_XL`` code (``CTRL_REG6_XL`` bits 4:3) and g/LSB."""

GYRO_RANGES = {245: (0b00, 8.75e-3), 500: (0b01, 17.5e-3), 2000: (0b11, 70e-3)}
"""Gyroscope full scale (deg/s): its ``FS_G`` code (``CTRL_REG1_G`` bits 4:3) and deg/s/LSB."""

MAG_RANGES = {4: (0b00, 0.14e-3), 8: (0b01, 0.29e-3), 12: (0b10, 0.43e-3), 16: (0b11, 0.58e-3)}
"""Magnetometer full scale (gauss): its ``FS`` code (``CTRL_REG2_M`` bits 6:5) and gauss/LSB."""

MAG_ODRS_HZ = (0.625, 1.25, 2.5, 5.0, 10.0, 20.0, 40.0, 80.0)
"""The magnetometer's rates; codes 0..7 in ``CTRL_REG1_M`` bits 4:2."""

MAG_AXES = "-x,y,z"
"""The magnetometer die's axes in the accelerometer's frame, as the thesis's ``nav3`` measure
read this board (its x negated against the accelerometer's); the driver argument
``mag_axes`` overrides it."""

HPA_PER_LSB = 1.0 / 4096.0

POLL_S = 0.001
"""Longest interval between two polls while a read waits for a sample."""

RESET_WAIT_S = 0.02
"""How long the driver waits after a chip's software reset before it writes its settings
(a chip reloads its trimming values then). The settings are read back: a chip that was not
ready is a disconnected board this time and is set up again at the next read."""


class _Device(SpiLink):
    """One chip of the Pmod on its chip select: its register reads and writes
    (``auto_inc``: the chip needs bit 6 of the address for a burst) and its state."""

    def __init__(
        self,
        path: str,
        role: str,
        chip_id: int,
        speed_hz: int,
        auto_inc: bool,
        open_spi: Opener | None,
    ) -> None:
        super().__init__(path, f"SPI {path} ({role})", SPI_MODE, speed_hz, open_spi)
        self.role, self.chip_id = role, chip_id
        self._burst = READ | (AUTO_INC if auto_inc else 0)
        self.set_up = False
        self.fresh = False  # a sample made since the set-up

    def read(self, reg: int, n: int) -> bytes:
        """``n`` registers from ``reg`` on (one burst)."""
        return bytes(self.transfer([(self._burst if n > 1 else READ) | reg] + [0] * n)[1:])

    def write(self, reg: int, value: int) -> None:
        self.transfer([reg, value])

    def check_id(self, who: int) -> None:
        """BoardDisconnected when nothing answers, ValueError when another chip does."""
        if who in (0x00, 0xFF):
            self.set_up = False
            raise BoardDisconnected(
                f"{self.where}: no chip answers (WHO_AM_I reads 0x{who:02x}, "
                f"expected 0x{self.chip_id:02x})"
            )
        if who != self.chip_id:
            raise ValueError(
                f"{self.where} is not a Pmod NAV's chip: WHO_AM_I reads 0x{who:02x}, "
                f"expected 0x{self.chip_id:02x}"
            )

    def set_up_chip(self, reset: tuple[int, int], regs: dict[int, int]) -> None:
        """Check the chip, reset it (``reset``: register and bit), give it time to boot,
        write ``regs`` in order and read them back (BoardDisconnected when they did not
        take: a chip still booting or a bus that garbles)."""
        self.check_id(self.read(WHO_AM_I, 1)[0])
        self.write(*reset)
        self.fresh = False
        time.sleep(RESET_WAIT_S)
        for reg, value in regs.items():
            self.write(reg, value)
        for reg, value in regs.items():
            got = self.read(reg, 1)[0]
            if got != value:
                raise self.fail(
                    OSError(
                        f"register 0x{reg:02x} reads 0x{got:02x} after 0x{value:02x} was written"
                    )
                )
        self.set_up = True

    def await_first(self, status: int, bit: int, within_s: float) -> None:
        """Once after the set-up: wait until the ``status`` register's data-ready ``bit``
        says the outputs hold a sample (NoReading after ``within_s``)."""
        deadline = time.monotonic() + within_s
        while not self.fresh:
            if self.read(status, 1)[0] & bit:
                self.fresh = True
            elif time.monotonic() > deadline:
                raise NoReading(f"{self.where}: no first sample in {within_s * 1e3:g} ms")
            else:
                time.sleep(POLL_S)

    def close(self) -> None:
        self.set_up = False
        super().close()


@checked_args
class SpiPmodNav:
    """A Pmod NAV on SPI (see the module docstring). ``spi`` opens a device (default:
    ``periphery.SPI(path, mode, max_speed)``); anything with ``transfer(list of bytes) ->
    list of bytes`` (full duplex, as many bytes back as out) and ``close()`` will do."""

    kind = "pmod-nav-spi"

    def __init__(
        self,
        ag: str = "/dev/spidev0.0",
        mag: str | None = "/dev/spidev0.1",
        alt: str | None = None,
        speed_hz: int = 1_000_000,
        odr_hz: float = 119.0,
        acc_range_g: int = 2,
        gyro_range_dps: int = 245,
        mag_range_gauss: int = 4,
        mag_odr_hz: float = 80.0,
        axes: str = "x,y,z",
        timeout_ms: float | None = None,
        mag_axes: str = MAG_AXES,
        *,
        spi: Opener | None = None,
    ) -> None:
        self.axes = parse_axes(axes)
        self.mag_axes = parse_axes(mag_axes, "mag_axes", mirror_ok=True)
        self.odr_hz, self.mag_odr_hz = float(odr_hz), float(mag_odr_hz)
        self.period = 1.0 / self.odr_hz
        self.poll = min(POLL_S, self.period / 8)
        self.timeout = 3.0 * self.period if timeout_ms is None else timeout_ms / 1000.0
        code = ODRS_HZ.index(self.odr_hz) + 1
        fs_xl, self._acc_lsb = ACC_RANGES[acc_range_g]
        fs_g, self._gyro_lsb = GYRO_RANGES[gyro_range_dps]
        fs_m, self._mag_lsb = MAG_RANGES[mag_range_gauss]
        self._ag_regs = {CTRL_REG1_G: code << 5 | fs_g << 3, CTRL_REG6_XL: code << 5 | fs_xl << 3}
        self._mag_regs = {
            CTRL_REG1_M: TEMP_COMP | OM_ULTRA | MAG_ODRS_HZ.index(float(mag_odr_hz)) << 2,
            CTRL_REG2_M: fs_m << 5,
            CTRL_REG3_M: 0x00,  # continuous conversion, 4-wire SPI
            CTRL_REG4_M: OMZ_ULTRA,
            CTRL_REG5_M: BDU_M,
        }
        self._baro_regs = {BARO_CTRL_REG2: 0x00, BARO_CTRL_REG1: PD | ODR_25HZ | BDU_P}
        self.ag = _Device(ag, "accelerometer and gyroscope", AG_ID, speed_hz, False, spi)
        self.mag = (
            None if mag is None else _Device(mag, "magnetometer", MAG_ID, speed_hz, True, spi)
        )
        self.alt = None if alt is None else _Device(alt, "barometer", BARO_ID, speed_hz, True, spi)
        self._lock = threading.RLock()
        self._last_field = b""  # the magnetometer's output bytes read_mag returned last
        self.reads = self.setups = self.resets_seen = 0

    @classmethod
    def check_args(cls, args: Mapping[str, Any]) -> list[str]:
        """Every problem with the constructor's arguments ``args`` (all of them, defaults
        filled in), one sentence each (also asked before any node starts:
        :func:`hera.nodes.boards.driver_problems`)."""
        out = path_problems("ag", args["ag"]) + path_problems("mag", args["mag"], True)
        out += path_problems("alt", args["alt"], True) + speed_problems(args["speed_hz"])
        out += choice_problems("odr_hz", args["odr_hz"], ODRS_HZ, " (Hz)")
        out += choice_problems("acc_range_g", args["acc_range_g"], ACC_RANGES)
        out += choice_problems("gyro_range_dps", args["gyro_range_dps"], GYRO_RANGES)
        out += choice_problems("mag_range_gauss", args["mag_range_gauss"], MAG_RANGES)
        out += choice_problems("mag_odr_hz", args["mag_odr_hz"], MAG_ODRS_HZ, " (Hz)")
        timeout_ms = args["timeout_ms"]
        if timeout_ms is not None and (
            isinstance(timeout_ms, bool)
            or not (isinstance(timeout_ms, (int, float)) and 0 < timeout_ms <= 10_000)
        ):
            out.append(f"timeout_ms must be a number of ms in (0, 10000], got {timeout_ms!r}")
        for key in ("axes", "mag_axes"):
            try:
                parse_axes(args[key], key, mirror_ok=key == "mag_axes")
            except ValueError as e:
                out.append(str(e))
        return out

    # -- set-up ----------------------------------------------------------------------------
    def _set_up(self, dev: _Device, reset: tuple[int, int], regs: dict[int, int]) -> None:
        dev.set_up_chip(reset, regs)
        self.setups += 1

    def _ag_ready(self) -> _Device:
        ag = self.ag
        if not ag.set_up:
            self._set_up(ag, (CTRL_REG8, SW_RESET), {CTRL_REG8: BDU | IF_ADD_INC, **self._ag_regs})
        return ag

    def _found_reset(self, dev: _Device) -> NoReading:
        """A chip back at its power-on registers: set it up again on the next read."""
        dev.set_up = False
        self.resets_seen += 1
        return NoReading(f"{dev.where}: the chip had been reset; set up again")

    # -- the accelerometer and gyroscope ---------------------------------------------------
    def _poll(self) -> bytes:
        """One burst from ``WHO_AM_I`` to the gyroscope's outputs, checked: the chip there
        and still set up. Returns the sample's content (temperature and gyroscope bytes)."""
        ag = self._ag_ready()
        head = ag.read(WHO_AM_I, OUT_X_G + 6 - WHO_AM_I)
        ag.check_id(head[0])
        if head[CTRL_REG1_G - WHO_AM_I] != self._ag_regs[CTRL_REG1_G]:
            raise self._found_reset(ag)
        return head[OUT_X_G - WHO_AM_I - 3 : OUT_X_G - WHO_AM_I - 1] + head[OUT_X_G - WHO_AM_I :]

    def _next_sample(self) -> tuple[float, bytes, bytes]:
        """Wait for a sample made after the call began: (its epoch time, its gyroscope and
        accelerometer output bytes)."""
        mono = time.monotonic
        before = mono()
        old = self._poll()  # sets the chip up first if it needs it
        deadline = mono() + self.timeout
        while True:
            time.sleep(self.poll)
            began = mono()
            new = self._poll()
            if new != old:
                made = (before + mono()) / 2.0  # between the poll that saw the old and this
                acc = self.ag.read(OUT_X_XL, 6)
                wall = wallclock.now() - (mono() - made)
                return wall, new[2:], acc
            before, old = began, new
            if began > deadline:  # a poll begun past the deadline saw nothing new (a pause
                # between the poll and this check is not a dropout)
                raise NoReading(f"{self.ag.where}: no new sample in {self.timeout * 1e3:g} ms")

    # -- NavDriver ---------------------------------------------------------------------------
    def read_imu(self, mag: bool = True) -> ImuSample:
        """The next sample of the accelerometer and gyroscope (and the newest of the
        magnetometer if ``mag``), stamped when the chip made it."""
        with self._lock:
            # the magnetometer checked (and set up) first: that does not delay the sample
            mdev = self._mag_ready() if mag else None
            t, gyro, acc = self._next_sample()
            m = None if mdev is None else self._field(mdev.read(OUT_X_M, 6))
            self.reads += 1
        return ImuSample(
            t,
            from_chip(self.axes, struct.unpack("<3h", acc), self._acc_lsb),
            from_chip(self.axes, struct.unpack("<3h", gyro), self._gyro_lsb),
            m,
        )

    def read_acc(self) -> Vec3:
        """Specific force (g) of the next sample, in the board frame."""
        return self.read_imu(mag=False).acc

    def read_gyro(self) -> Vec3:
        """Angular rate (deg/s) of the next sample, in the board frame."""
        return self.read_imu(mag=False).gyro

    def read_mag(self) -> Vec3:
        """A magnetic field sample (gauss, board frame) not returned by ``read_mag`` before,
        waited for up to three magnetometer periods (told by its content, as the
        accelerometer's): a calibration's mean is over samples of their own."""
        with self._lock:
            dev = self._mag_ready()
            deadline = time.monotonic() + 3.0 / self.mag_odr_hz
            while (raw := dev.read(OUT_X_M, 6)) == self._last_field:
                if time.monotonic() > deadline:
                    raise NoReading(f"{dev.where}: no new sample in {3e3 / self.mag_odr_hz:g} ms")
                time.sleep(POLL_S)
            self._last_field = raw
            return self._field(raw)

    def _ready(
        self,
        dev: _Device | None,
        arg: str,
        reset: tuple[int, int],
        regs: dict[int, int],
        status: tuple[int, int],
        rate_hz: float,
    ) -> _Device:
        """The magnetometer or barometer ``dev`` (the driver argument ``arg``), set up
        (``reset``, then ``regs``, a block of consecutive registers), checked (there, not
        reset) and holding a sample (``status``: its data-ready register and bit)."""
        if dev is None:
            raise BoardDisconnected(f"SPI {arg}: not wired (driver_args {arg} not given)")
        if not dev.set_up:
            self._set_up(dev, reset, regs)
        dev.check_id(dev.read(WHO_AM_I, 1)[0])
        if list(dev.read(min(regs), len(regs))) != [regs[r] for r in sorted(regs)]:
            raise self._found_reset(dev)
        dev.await_first(*status, 3.0 / rate_hz)
        return dev

    def _mag_ready(self) -> _Device:
        return self._ready(
            self.mag,
            "mag",
            (CTRL_REG2_M, SOFT_RST),
            self._mag_regs,
            (STATUS_REG_M, ZYXDA),
            self.mag_odr_hz,
        )

    def _field(self, raw: bytes) -> Vec3:
        """The magnetometer's output bytes in gauss, in the board frame."""
        die = struct.unpack("<3h", raw)
        return from_chip(self.axes, from_chip(self.mag_axes, die, self._mag_lsb), 1.0)

    def read_baro(self) -> float:
        """The newest air pressure sample (hPa)."""
        with self._lock:
            dev = self._ready(
                self.alt,
                "alt",
                (BARO_CTRL_REG2, SWRESET),
                self._baro_regs,
                (BARO_STATUS, P_DA),
                BARO_ODR_HZ,
            )
            raw = dev.read(PRESS_OUT_XL, 3)
            return int.from_bytes(raw, "little", signed=True) * HPA_PER_LSB

    def describe(self) -> dict[str, Any]:
        """JSON-able status for the ``board`` verb's listing."""
        devices = [d for d in (self.ag, self.mag, self.alt) if d is not None]
        return {
            "kind": self.kind,
            "devices": {d.role: d.path for d in devices},
            "odr_hz": self.odr_hz,
            "connected": self.ag.set_up,  # the accelerometer/gyroscope, every read's chip
            "set_up": [d.role for d in devices if d.set_up],
            "reads": self.reads,
            "setups": self.setups,
            "resets_seen": self.resets_seen,
            "fault": None,
        }

    def close(self) -> None:
        """Put the chips in power-down (best effort) and close the devices."""
        with self._lock:
            off = (
                (self.ag, {CTRL_REG1_G: 0, CTRL_REG6_XL: 0}),
                (self.mag, {CTRL_REG3_M: MD_POWER_DOWN}),
                (self.alt, {BARO_CTRL_REG1: 0}),
            )
            for dev, regs in off:
                if dev is None:
                    continue
                if dev.set_up:
                    with contextlib.suppress(OSError):
                        for reg, value in regs.items():
                            dev.write(reg, value)
                dev.close()
