"""Chips behind spidev-like devices, for the real SPI drivers where no board or kernel SPI
device is at hand: a Pmod NAV at register level (``hera.nodes.nav_spi``), an MCP3008 ADC
(``hera.nodes.ir.mcp3008``) and a MAX31855 thermocouple amplifier
(``hera.nodes.ir.max31855``).

Each chip answers a transfer as its data sheet says: the first byte is the address (bit 7
set for a read; the accelerometer/gyroscope advance the address through a burst when
``CTRL_REG8`` IF_ADD_INC is set, the magnetometer and barometer when bit 6 of the address is
set), the bytes after it are read or written. Registers: ``WHO_AM_I``; the control registers
with their power-on values and a software reset that brings them back; outputs that a live
chip refreshes at the rate its control registers set, each sample the signal at that
instant plus the chip's noise, quantised at the full scale set (two's complement, low byte
first). :class:`FakeSpiBus` opens a device by its path as ``periphery.SPI`` does
(``OSError(ENOENT)`` for a path that is not there) and plays an unplugged board (every
byte reads as the MISO line floats: 0xFF or 0x00).
"""

from __future__ import annotations

import errno
import math
import random
import threading
import time
from collections.abc import Callable
from typing import Any

from hera.nodes.ir.max31855 import Max31855
from hera.nodes.ir.mcp3008 import Mcp3008Ir
from hera.nodes.mounting import parse_axes, to_chip
from hera.nodes.nav_spi import (
    ACC_RANGES,
    AG_ID,
    BARO_CTRL_REG1,
    BARO_CTRL_REG2,
    BARO_ID,
    BARO_STATUS,
    CTRL_REG1_G,
    CTRL_REG1_M,
    CTRL_REG2_M,
    CTRL_REG3_M,
    CTRL_REG6_XL,
    CTRL_REG8,
    GYRO_RANGES,
    IF_ADD_INC,
    MAG_ID,
    MAG_ODRS_HZ,
    MAG_RANGES,
    ODRS_HZ,
    OUT_X_G,
    OUT_X_M,
    OUT_X_XL,
    P_DA,
    PRESS_OUT_XL,
    SOFT_RST,
    STATUS_REG_M,
    SW_RESET,
    SWRESET,
    WHO_AM_I,
    ZYXDA,
    SpiPmodNav,
)

Vec = tuple[float, float, float]
Signal = Callable[[float], tuple[Vec, Vec, Vec]]
"""``signal(t)``: (acc g, gyro deg/s, field gauss) in the board frame at monotonic time t."""


def still(
    acc: Vec = (0.0, 0.0, 1.0), gyro: Vec = (0.0, 0.0, 0.0), field: Vec = (0.2, 0.0, -0.4)
) -> Signal:
    """A board at rest: the same specific force, rate and field at every instant."""
    return lambda t: (acc, gyro, field)


def _put(regs: bytearray, at: int, counts: tuple[int, ...]) -> None:
    for i, c in enumerate(counts):
        regs[at + 2 * i : at + 2 * i + 2] = int(c).to_bytes(2, "little", signed=True)


def _count(value: float, lsb: float) -> int:
    return max(-32768, min(32767, round(value / lsb)))


class _Chip:
    """Registers, a software reset and a sample clock; subclasses say what the registers
    mean. ``rate()`` is the sample rate the control registers set (None: not sampling)."""

    chip_id = 0
    reset_reg, reset_bit = 0, 0
    six_bit_address = True  # the magnetometer and barometer: bit 6 asks for a burst

    def __init__(self, clock_error: float = 0.0, seed: int = 0) -> None:
        self.clock_error = clock_error
        self.rng = random.Random(seed)
        self.lock = threading.Lock()
        self.samples = 0
        self.made: list[float] = []  # the monotonic instant of each sample
        self.power_on()

    def power_on(self) -> None:
        self.regs = bytearray(0x80)
        self.regs[WHO_AM_I] = self.chip_id
        self._since: float | None = None  # when the sample clock started
        self._rate: float | None = None
        self._done = 0  # samples made since the clock started

    def rate(self) -> float | None:
        raise NotImplementedError

    def sample(self, t: float) -> None:
        """Refresh the outputs with the sample made at monotonic time ``t``."""
        raise NotImplementedError

    def _tick(self) -> None:
        rate = self.rate()
        now = time.monotonic()
        if rate != self._rate:  # started, stopped or changed: the clock starts again
            self._rate, self._since, self._done = rate, now, 0
        if rate is None or self._since is None:
            return
        period = 1.0 / (rate * (1.0 + self.clock_error))
        due = int((now - self._since) / period)
        if due > self._done:
            t = self._since + due * period
            self._done = due
            self.samples += 1
            self.made.append(t)
            self.sample(t)

    def transfer(self, data: list[int]) -> list[int]:
        with self.lock:
            first = data[0]
            if self.six_bit_address:
                reg, inc = first & 0x3F, bool(first & 0x40)
            else:
                reg, inc = first & 0x7F, bool(self.regs[CTRL_REG8] & IF_ADD_INC)
            n = len(data) - 1
            if first & 0x80:
                self._tick()
                out = [0]
                for i in range(n):
                    out.append(self.regs[(reg + (i if inc else 0)) & 0x7F])
                return out
            for i, value in enumerate(data[1:]):
                self.write((reg + (i if inc else 0)) & 0x7F, value)
            return [0] * len(data)

    def write(self, reg: int, value: int) -> None:
        if reg == WHO_AM_I:
            return  # read only
        if reg == self.reset_reg and value & self.reset_bit:
            self.power_on()
            return
        self.regs[reg] = value


class AccGyroChip(_Chip):
    """The LSM9DS1's accelerometer and gyroscope. ``signal`` in the chip's own axes."""

    chip_id = AG_ID
    reset_reg, reset_bit = CTRL_REG8, SW_RESET
    six_bit_address = False

    def __init__(self, signal: Signal, noise_lsb: float = 4.0, **kw) -> None:
        self.signal, self.noise_lsb = signal, noise_lsb
        super().__init__(**kw)

    def power_on(self) -> None:
        super().power_on()
        self.regs[CTRL_REG8] = IF_ADD_INC

    def rate(self) -> float | None:
        code = self.regs[CTRL_REG1_G] >> 5
        return ODRS_HZ[code - 1] if 1 <= code <= len(ODRS_HZ) else None

    def sample(self, t: float) -> None:
        acc, gyro, _ = self.signal(t)
        fs_g = (self.regs[CTRL_REG1_G] >> 3) & 0b11
        fs_xl = (self.regs[CTRL_REG6_XL] >> 3) & 0b11
        g_lsb = next(lsb for code, lsb in GYRO_RANGES.values() if code == fs_g)
        a_lsb = next(lsb for code, lsb in ACC_RANGES.values() if code == fs_xl)
        noisy = self.rng.gauss
        _put(
            self.regs,
            OUT_X_G,
            tuple(_count(v, g_lsb) + round(noisy(0, self.noise_lsb)) for v in gyro),
        )
        _put(
            self.regs,
            OUT_X_XL,
            tuple(_count(v, a_lsb) + round(noisy(0, self.noise_lsb)) for v in acc),
        )
        _put(self.regs, 0x15, (400 + round(noisy(0, 3.0)),))  # OUT_TEMP: 25 + 400 / 16 deg C


BOARD_MAG_AXES = "-x,y,z"
"""Where the played board's magnetometer die lies in the accelerometer's frame: as the
thesis's ``nav3`` read its Pmod NAV (the driver's default must agree, and is tested so)."""


class MagChip(_Chip):
    """The LSM9DS1's magnetometer, its die's axes lying as ``mag_axes`` says (the driver's
    argument) in the accelerometer's frame, in which ``signal`` gives the field."""

    chip_id = MAG_ID
    reset_reg, reset_bit = CTRL_REG2_M, SOFT_RST

    def __init__(
        self, signal: Signal, noise_lsb: float = 3.0, mag_axes: str = BOARD_MAG_AXES, **kw
    ) -> None:
        self.signal, self.noise_lsb = signal, noise_lsb
        self.die = parse_axes(mag_axes, mirror_ok=True)
        super().__init__(**kw)

    def power_on(self) -> None:
        super().power_on()
        self.regs[CTRL_REG3_M] = 0x03  # power-down

    def rate(self) -> float | None:
        if self.regs[CTRL_REG3_M] & 0x03:
            return None
        return MAG_ODRS_HZ[(self.regs[CTRL_REG1_M] >> 2) & 0b111]

    def sample(self, t: float) -> None:
        field = to_chip(self.die, self.signal(t)[2])
        fs = (self.regs[CTRL_REG2_M] >> 5) & 0b11
        lsb = next(lsb for code, lsb in MAG_RANGES.values() if code == fs)
        counts = tuple(_count(v, lsb) + round(self.rng.gauss(0, self.noise_lsb)) for v in field)
        _put(self.regs, OUT_X_M, counts)
        self.regs[STATUS_REG_M] |= ZYXDA


class BaroChip(_Chip):
    """The LPS25HB: ``hpa(t)`` the pressure; on at 25 Hz when CTRL_REG1's PD bit is set."""

    chip_id = BARO_ID
    reset_reg, reset_bit = BARO_CTRL_REG2, SWRESET

    def __init__(self, hpa: Callable[[float], float] = lambda t: 1013.25, **kw) -> None:
        self.hpa = hpa
        super().__init__(**kw)

    def rate(self) -> float | None:
        return 25.0 if self.regs[BARO_CTRL_REG1] & 0x80 else None

    def sample(self, t: float) -> None:
        raw = round(self.hpa(t) * 4096)
        self.regs[PRESS_OUT_XL : PRESS_OUT_XL + 3] = raw.to_bytes(3, "little", signed=True)
        self.regs[BARO_STATUS] |= P_DA


class FakeSpi:
    """One opened device: a chip select on a bus (see :class:`FakeSpiBus`)."""

    def __init__(self, bus: FakeSpiBus, path: str, mode: int, speed_hz: int) -> None:
        self.bus, self.path, self.mode, self.speed_hz = bus, path, mode, speed_hz
        self.closed = False

    def transfer(self, data: list[int]) -> list[int]:
        if self.closed:
            raise OSError(errno.EBADF, "Bad file descriptor")
        self.bus.transfers += 1
        if self.bus.unplugged is not None:
            return [self.bus.unplugged] * len(data)
        return self.bus.chips[self.path].transfer(list(data))

    def close(self) -> None:
        self.closed = True


class FakeSpiBus:
    """Devices by path, each a chip; ``open`` as ``periphery.SPI(path, mode, max_speed)``.
    ``unplugged``: None, or the byte every read gives with the board gone (MISO floating)."""

    def __init__(self, chips: dict[str, Any]) -> None:
        self.chips = chips
        self.unplugged: int | None = None
        self.opened: list[FakeSpi] = []
        self.transfers = 0

    def open(self, path: str, mode: int, speed_hz: int) -> FakeSpi:
        if path not in self.chips:
            raise OSError(errno.ENOENT, "Opening SPI device: No such file or directory")
        dev = FakeSpi(self, path, mode, speed_hz)
        self.opened.append(dev)
        return dev


def pmod_nav_bus(
    signal: Signal,
    axes: str = "x,y,z",
    clock_error: float = 0.0,
    ag: str = "/dev/spidev0.0",
    mag: str = "/dev/spidev0.1",
    alt: str | None = "/dev/spidev1.0",
    seed: int = 0,
    mag_axes: str = BOARD_MAG_AXES,
) -> FakeSpiBus:
    """A Pmod NAV on a fake bus: ``signal`` in the board frame, the chip mounted as
    ``axes`` says (the driver's argument), so it reads the board's values in its own axes."""
    mount = parse_axes(axes)

    def in_chip(t: float) -> tuple[Vec, Vec, Vec]:
        return tuple(to_chip(mount, v) for v in signal(t))  # type: ignore[return-value]

    chips: dict[str, _Chip] = {
        ag: AccGyroChip(in_chip, clock_error=clock_error, seed=seed),
        mag: MagChip(in_chip, seed=seed + 1, mag_axes=mag_axes),
    }
    if alt is not None:
        chips[alt] = BaroChip(seed=seed + 2)
    return FakeSpiBus(chips)


def turning(start_s: float, rate_dps: float, bias_dps: Vec = (0.5, -0.3, 0.2)) -> Signal:
    """A board lying flat with a gyroscope bias, still until ``start_s`` seconds after it is
    made (monotonic), then turning about z at ``rate_dps``."""
    t0 = time.monotonic()

    def signal(t: float) -> tuple[Vec, Vec, Vec]:
        r = rate_dps if t - t0 >= start_s else 0.0
        heading = math.radians(max(0.0, t - t0 - start_s) * rate_dps)
        field = (0.2 * math.cos(heading), -0.2 * math.sin(heading), -0.4)
        return (0.0, 0.0, 1.0), (bias_dps[0], bias_dps[1], bias_dps[2] + r), field

    return signal


class Turntable:
    """A board a person turns by hand: ``turn(axis, degrees)`` turns it about its own x, y or
    z (as the calibrations ask); :meth:`signal` gives, in its turned frame, gravity's
    specific force, a gyroscope bias, and Earth's field ``earth`` (gauss, in the frame of
    the board's first pose) plus the board's own ``hard_iron`` (gauss, its frame)."""

    def __init__(
        self,
        earth: Vec = (0.2, 0.0, -0.44),
        hard_iron: Vec = (0.12, -0.2, 0.08),
        gyro_bias: Vec = (0.5, -0.3, 0.2),
    ) -> None:
        self.earth, self.hard_iron, self.gyro_bias = earth, hard_iron, gyro_bias
        self.rot = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))  # first pose to board
        self.turns: list[tuple[str, float]] = []

    def turn(self, axis: str, degrees: float) -> None:
        c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
        i = "xyz".index(axis)
        j, k = (i + 1) % 3, (i + 2) % 3
        r = [[0.0] * 3 for _ in range(3)]  # a vector fixed in the world, seen by the board
        r[i][i] = 1.0
        r[j][j], r[j][k], r[k][j], r[k][k] = c, s, -s, c
        self.rot = tuple(
            tuple(sum(r[a][m] * self.rot[m][b] for m in range(3)) for b in range(3))
            for a in range(3)
        )  # type: ignore[assignment]
        self.turns.append((axis, degrees))

    def _seen(self, v: Vec) -> Vec:
        return tuple(sum(self.rot[a][b] * v[b] for b in range(3)) for a in range(3))  # type: ignore[return-value]

    def signal(self, t: float) -> tuple[Vec, Vec, Vec]:
        field = tuple(e + h for e, h in zip(self._seen(self.earth), self.hard_iron, strict=True))
        return self._seen((0.0, 0.0, 1.0)), self.gyro_bias, field  # type: ignore[return-value]


class NavOnFakeSpi(SpiPmodNav):
    """The real driver on a fake bus, for a node's spec (``driver =
    "fake_spi:NavOnFakeSpi"``): a board still for ``start_s`` seconds, then turning about z
    at ``rate_dps`` (:func:`turning`), its chip mounted as the driver's ``axes`` say and its
    clock off by ``clock_error``; other arguments are the driver's."""

    def __init__(
        self, start_s: float = 5.0, rate_dps: float = 30.0, clock_error: float = 0.0, **driver_args
    ) -> None:
        self.fake_bus = pmod_nav_bus(
            turning(start_s, rate_dps),
            axes=driver_args.get("axes", "x,y,z"),
            clock_error=clock_error,
            alt=None,
        )
        super().__init__(**driver_args, spi=self.fake_bus.open)


class AdcChip:
    """An MCP3008: ``volts[channel]`` on its inputs, converted at ``vref`` into 10-bit codes
    (a 3-byte transfer: start bit, single-ended flag and channel, then the null bit and the
    code); ``asked`` keeps each request."""

    def __init__(self, volts: dict[int, float], vref: float = 3.3) -> None:
        self.volts, self.vref = volts, vref
        self.asked: list[list[int]] = []

    def transfer(self, data: list[int]) -> list[int]:
        self.asked.append(list(data))
        assert data[0] == 0x01 and data[1] & 0x80 and len(data) == 3, data
        v = self.volts.get((data[1] >> 4) & 0x07, 0.0)
        code = max(0, min(1023, int(v / self.vref * 1024)))
        return [0x00, code >> 8, code & 0xFF]


class ThermocoupleChip:
    """A MAX31855: ``celsius`` at the junction, ``junction_c`` on the chip, and the fault
    bits ``faults`` (1 open, 2 shorted to GND, 4 to VCC) in its 32-bit frame."""

    def __init__(self, celsius: float, junction_c: float = 24.5, faults: int = 0) -> None:
        self.celsius, self.junction_c, self.faults = celsius, junction_c, faults

    def transfer(self, data: list[int]) -> list[int]:
        hot = round(self.celsius / 0.25) & 0x3FFF
        cold = round(self.junction_c / 0.0625) & 0xFFF
        frame = hot << 18 | cold << 4 | self.faults | (1 << 16 if self.faults else 0)
        return list(frame.to_bytes(4, "big"))[: len(data)]


class IrOnFakeSpi(Mcp3008Ir):
    """The real driver on a fake bus, for a node's spec (``driver = "fake_spi:IrOnFakeSpi"``):
    an MCP3008 whose ``channel`` reads ``volts``; other arguments are the driver's."""

    def __init__(self, volts: float = 1.0, **driver_args) -> None:
        path = driver_args.get("device", "/dev/spidev0.0")
        chip = AdcChip({driver_args.get("channel", 0): volts}, driver_args.get("vref", 3.3))
        self.fake_bus = FakeSpiBus({path: chip})
        super().__init__(**driver_args, spi=self.fake_bus.open)


class ThermocoupleOnFakeSpi(Max31855):
    """The real driver on a fake bus, for a node's spec: a MAX31855 reading ``celsius``."""

    def __init__(self, celsius: float = 21.0, **driver_args) -> None:
        path = driver_args.get("device", "/dev/spidev0.1")
        self.fake_bus = FakeSpiBus({path: ThermocoupleChip(celsius)})
        super().__init__(**driver_args, spi=self.fake_bus.open)
