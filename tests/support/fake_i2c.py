"""An LSM6DSL at register level behind an smbus2-like bus, for the real I2C driver
(``hera.nodes.lsm6dsl.i2c``) where no chip or kernel I2C adapter is at hand.

:class:`Lsm6dslChip` keeps the registers the driver touches as the data sheet describes
them: ``WHO_AM_I``; ``CTRL3_C`` with IF_INC set at power-on and a SW_RESET that clears the
registers and itself; ``CTRL1_XL``/``CTRL2_G`` whose rate codes start the chip's own sample
clock (``clock_error``: its oscillator off by that fraction); ``STATUS_REG`` whose XLDA/GDA
rise with each sample and fall when the sensor's output registers are read; the output
registers with the signal quantised at the full scale set. :class:`FakeBus` answers
``read_byte_data``, ``write_byte_data``, ``read_i2c_block_data`` and ``close`` as smbus2's
``SMBus`` does, and ``OSError(EREMOTEIO)`` when no chip acknowledges (unplugged).
"""

from __future__ import annotations

import errno
import json
import math
import struct
import threading
import time
from collections.abc import Callable
from pathlib import Path

from hera import wallclock
from hera.nodes.lsm6dsl.driver import ODRS_HZ, ImuReading
from hera.nodes.lsm6dsl.i2c import (
    ACC_RANGES,
    CTRL1_XL,
    CTRL2_G,
    CTRL3_C,
    GDA,
    GYRO_RANGES,
    IF_INC,
    OUTX_L_G,
    STATUS_REG,
    SW_RESET,
    WHO_AM_I,
    XLDA,
    I2cLsm6dsl,
)
from hera.nodes.lsm6dsl.model import ImuModel
from hera.nodes.lsm6dsl.sim import SimLsm6dsl
from hera.nodes.mounting import parse_axes, to_chip
from hera.nodes.world import epoch_of, make_scenario

Vec = tuple[float, float, float]


Signal = Callable[[float], tuple[Vec, Vec]]


def leaning(theta_deg: float, bias_dps: Vec = (0.0, 0.0, 0.0)) -> Signal:
    """A still robot leaning forward by ``theta_deg`` in the seed's frame (its X axis points
    backward: the chip's x reads -sin theta), its gyroscope off by ``bias_dps``."""
    th = math.radians(theta_deg)
    return lambda t: ((-math.sin(th), 0.0, math.cos(th)), bias_dps)


class Lsm6dslChip:
    """The chip (see the module docstring); ``signal(t)`` gives (acc g, gyro deg/s) in the
    chip's axes for the sample made at monotonic time ``t``."""

    def __init__(
        self,
        signal: Signal | None = None,
        clock_error: float = 0.0,
        who_am_i: int = 0x6A,
    ) -> None:
        self.signal = signal or leaning(0.0)
        self.clock_error, self.who_am_i = clock_error, who_am_i
        self.lock = threading.Lock()
        self.samples = self.lost = 0  # made; lost before a read took them
        self.power_on()

    def power_on(self) -> None:
        """Registers at their power-on values: both sensors in power-down."""
        self.regs = bytearray(0x80)
        self.regs[WHO_AM_I] = self.who_am_i
        self.regs[CTRL3_C] = IF_INC
        self._since: float | None = None
        self._made = 0

    def _period(self) -> float | None:
        code = self.regs[CTRL1_XL] >> 4
        if not code or code != self.regs[CTRL2_G] >> 4:
            return None
        return 1.0 / ODRS_HZ[code - 1] / (1.0 + self.clock_error)

    def _tick(self) -> None:
        """Make the samples the chip's clock has reached since the last access (the output
        registers keep the newest)."""
        period = self._period()
        if period is None or self._since is None:
            return
        now = time.monotonic()
        made = math.floor((now - self._since) / period)
        if made <= self._made:
            return
        # the output registers keep the newest: the samples made before it since the last
        # access never showed, and one made before and still unread is overwritten
        self.lost += made - self._made - 1 + (1 if self.regs[STATUS_REG] & XLDA else 0)
        self.samples += made - self._made
        self._made = made
        acc, gyro = self.signal(self._since + made * period)  # at the sample's own instant
        fs_xl = next(g for g, (c, _) in ACC_RANGES.items() if c == (self.regs[CTRL1_XL] >> 2) & 3)
        fs_g = next(d for d, (c, _) in GYRO_RANGES.items() if c == self.regs[CTRL2_G] & 0x0F)
        counts = [_count(v, ACC_RANGES[fs_xl][1]) for v in acc]
        rates = [_count(v, GYRO_RANGES[fs_g][1]) for v in gyro]
        self.regs[OUTX_L_G : OUTX_L_G + 12] = struct.pack("<6h", *rates, *counts)
        self.regs[STATUS_REG] |= XLDA | GDA

    def read(self, reg: int, n: int) -> list[int]:
        with self.lock:
            self._tick()
            out = []
            for i in range(n):
                r = reg + i if self.regs[CTRL3_C] & IF_INC else reg
                out.append(self.regs[r])
                if OUTX_L_G <= r < OUTX_L_G + 6:
                    self.regs[STATUS_REG] &= ~GDA & 0xFF
                elif OUTX_L_G + 6 <= r < OUTX_L_G + 12:
                    self.regs[STATUS_REG] &= ~XLDA & 0xFF
            return out

    def write(self, reg: int, value: int) -> None:
        with self.lock:
            if reg == CTRL3_C and value & SW_RESET:
                self.power_on()  # the reset is over by the next access
                return
            self.regs[reg] = value & 0xFF
            if reg in (CTRL1_XL, CTRL2_G):
                self._since, self._made = time.monotonic(), 0


def _count(value: float, lsb: float) -> int:
    return max(-32768, min(32767, round(value / lsb)))


def _nack() -> OSError:
    return OSError(errno.EREMOTEIO, "Remote I/O error")


class FakeBus:
    """An I2C adapter with ``chips`` by address; ``unplugged`` makes every transfer fail as
    an unanswered address does; ``opened``/``closed`` count what the driver did."""

    def __init__(self, chips: dict[int, Lsm6dslChip]) -> None:
        self.chips = chips
        self.unplugged = False
        self.present = True  # the adapter itself (/dev/i2c-N) exists
        self.opened = self.closed = 0

    def open(self, bus: int | str) -> FakeBus:
        """The ``smbus`` argument of the driver: open this adapter."""
        if not self.present:
            raise FileNotFoundError(errno.ENOENT, "No such file or directory", f"/dev/i2c-{bus}")
        self.opened += 1
        return self

    def _chip(self, address: int) -> Lsm6dslChip:
        chip = self.chips.get(address)
        if chip is None or self.unplugged:
            raise _nack()
        return chip

    def read_byte_data(self, address: int, register: int) -> int:
        return self._chip(address).read(register, 1)[0]

    def read_i2c_block_data(self, address: int, register: int, length: int) -> list[int]:
        return self._chip(address).read(register, length)

    def write_byte_data(self, address: int, register: int, value: int) -> None:
        self._chip(address).write(register, value)

    def close(self) -> None:
        self.closed += 1


class _OnFakeBus(I2cLsm6dsl):
    """The real driver on a fake bus holding one chip of ``signal`` and ``clock_error``, at
    the driver's address (other arguments are the driver's)."""

    def __init__(self, signal: Signal, clock_error: float, driver_args: dict) -> None:
        chip = Lsm6dslChip(signal, clock_error)
        self.fake_bus = FakeBus({driver_args.get("address", 0x6A): chip})
        super().__init__(**driver_args, smbus=self.fake_bus.open)


class ChipOnFakeBus(_OnFakeBus):
    """The real driver on a fake bus, for a node's spec (``driver = "fake_i2c:ChipOnFakeBus"``):
    a still robot leaning ``theta_deg`` with gyroscope bias ``bias_dps`` (the board's axes),
    the chip mounted as the driver's ``axes`` say (so it reads the board's values turned
    into its own axes), its clock off by ``clock_error``; other arguments are the driver's."""

    def __init__(
        self,
        theta_deg: float = 0.0,
        bias_dps: list[float] | None = None,
        clock_error: float = 0.0,
        **driver_args,
    ) -> None:
        board = leaning(theta_deg, tuple(bias_dps or (0.0, 0.0, 0.0)))  # type: ignore[arg-type]
        mount = parse_axes(driver_args.get("axes", "x,y,z"))

        def signal(t: float) -> tuple[Vec, Vec]:
            acc, gyro = board(t)
            return to_chip(mount, acc), to_chip(mount, gyro)

        super().__init__(signal, clock_error, driver_args)


class SimChipOnFakeBus(_OnFakeBus):
    """The real driver on a fake bus whose chip plays the simulated LSM6DSL of a run's world
    (``world_file``: the run's ``cluster.json``, read at the first sample, for the world and
    its epoch): each sample is the simulator's reading at the instant the chip's clock (off
    by ``clock_error``) makes it, taken and stamped by the driver as a real chip's would be.
    ``seed`` and ``model`` are the simulator's; other arguments are the driver's."""

    def __init__(
        self,
        world_file: str,
        clock_error: float = 0.0,
        seed: int = 0,
        model: dict | None = None,
        **driver_args,
    ) -> None:
        self.world_file, self.sim_seed, self.model = world_file, seed, model
        self.sim: SimLsm6dsl | None = None
        self._at = 0.0
        super().__init__(self._sample, clock_error, driver_args)

    def _sample(self, t_mono: float) -> tuple[Vec, Vec]:
        if self.sim is None:
            world = json.loads(Path(self.world_file).read_text())["resolved_spec"]["world"]
            self.sim = SimLsm6dsl(
                "sim/imu",
                make_scenario(world),
                epoch_of(world),
                ImuModel.from_args(self.model),
                self.sim_seed,
                odr_hz=self.odr_hz,
                clock=lambda: self._at,
            )
        self._at = time.time() - (time.monotonic() - t_mono)  # the sample's epoch time
        r = self.sim.read_imu()
        return r.acc, r.gyro


class StampedWhenRead(SimChipOnFakeBus):
    """The same chip read the naive way, for comparison: each read takes the newest sample
    (the others are lost) and stamps it when it is read."""

    def read_imu(self) -> ImuReading:
        r = super().read_imu()
        while self.pending:
            r = super().read_imu()
        return ImuReading(wallclock.now(), r.acc, r.gyro)
