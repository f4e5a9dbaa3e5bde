"""A real LSM6DSL on an I2C bus (``hera.nodes.lsm6dsl.i2c``), against the chip played at
register level behind an smbus2-like bus (``fake_i2c``): what the chip is told, readings
scaled and turned into the board's axes, one sample per read, dropouts, a chip unplugged,
reset or missing and back, the wrong chip, bad arguments, the ``lsm6dsl`` measure on it,
and smbus2 itself on an adapter that is not there."""

from __future__ import annotations

import math
import statistics
import time
from itertools import pairwise

import pytest
from fake_i2c import ChipOnFakeBus, FakeBus, Lsm6dslChip, leaning
from harness import csv_rows, wait_for
from nodes_helpers import boards_of, make_ctx

from hera.nodes.driver import BoardDisconnected, NoReading
from hera.nodes.lsm6dsl.driver import ImuReading, Lsm6dslDriver
from hera.nodes.lsm6dsl.i2c import (
    ACC_RANGES,
    BDU,
    CTRL1_XL,
    CTRL2_G,
    CTRL3_C,
    GYRO_RANGES,
    IF_INC,
    I2cLsm6dsl,
)
from hera.nodes.lsm6dsl.measures import Lsm6dsl
from hera.nodes.mounting import parse_axes
from hera.nodes.world import G

WHERE = "I2C bus /dev/i2c-1, address 0x6a"


@pytest.fixture
def on_bus():
    """Make the driver on a fake bus (at 104 Hz waiting up to 30 ms unless told otherwise:
    the chip's first sample comes a period after it is set up); closed at the end."""
    made: list[I2cLsm6dsl] = []

    def make(chip: Lsm6dslChip | None = None, **kw) -> tuple[I2cLsm6dsl, FakeBus, Lsm6dslChip]:
        chip = chip or Lsm6dslChip(leaning(5.0, (0.5, -1.25, 2.0)))
        bus = FakeBus({0x6A: chip})
        made.append(I2cLsm6dsl(smbus=bus.open, **{"odr_hz": 104.0, "timeout_ms": 30.0, **kw}))
        return made[-1], bus, chip

    yield make
    for driver in made:
        driver.close()


def read_until_a_sample(driver: I2cLsm6dsl, within: float = 5.0) -> tuple[ImuReading, list]:
    """Read until a sample comes (the errors on the way, in order)."""
    errors: list[Exception] = []
    end = time.monotonic() + within
    while time.monotonic() < end:
        try:
            return driver.read_imu(), errors
        except (NoReading, BoardDisconnected) as e:
            if not errors or str(errors[-1]) != str(e):
                errors.append(e)
            time.sleep(0.005)
    raise AssertionError(f"no sample within {within} s: {errors}")


def test_the_chip_is_reset_and_set_up_as_asked(on_bus):
    driver, bus, chip = on_bus(odr_hz=52.0, acc_range_g=8, gyro_range_dps=1000)
    assert isinstance(driver, Lsm6dslDriver) and bus.opened == 1 and driver.setups == 1
    assert chip.regs[CTRL3_C] == BDU | IF_INC
    assert chip.regs[CTRL1_XL] == 0x3 << 4 | 0b11 << 2  # 52 Hz, 8 g
    assert chip.regs[CTRL2_G] == 0x3 << 4 | 0b1000  # 52 Hz, 1000 dps


@pytest.mark.parametrize("acc_g", sorted(ACC_RANGES))
@pytest.mark.parametrize("gyro_dps", sorted(GYRO_RANGES))
def test_a_reading_is_in_g_and_deg_per_s_to_one_count(on_bus, acc_g, gyro_dps):
    acc, gyro = (-0.0871557, 0.0, 0.9961947), (0.5, -1.25, 2.0)  # 5 deg, the bias
    driver, _, _ = on_bus(acc_range_g=acc_g, gyro_range_dps=gyro_dps)
    r = driver.read_imu()
    assert r.acc == pytest.approx(acc, abs=ACC_RANGES[acc_g][1] / 2 + 1e-12)
    assert r.gyro == pytest.approx(gyro, abs=GYRO_RANGES[gyro_dps][1] / 2 + 1e-12)


def test_the_axes_turn_the_chip_into_the_board(on_bus):
    chip = Lsm6dslChip(lambda t: ((0.1, 0.2, 0.9), (10.0, 20.0, 30.0)))
    r = on_bus(chip, axes="-y, x, z")[0].read_imu()
    assert r.acc == pytest.approx((-0.2, 0.1, 0.9), abs=2e-4)
    assert r.gyro == pytest.approx((-20.0, 10.0, 30.0), abs=0.02)


class Numbered:
    """A chip's signal: sample k reads k deg/s on the gyroscope's x; ``made[k - 1]`` is when
    it was made (monotonic s)."""

    def __init__(self) -> None:
        self.made: list[float] = []

    def __call__(self, t: float):
        self.made.append(t)
        return (0.0, 0.0, 1.0), (float(len(self.made)), 0.0, 0.0)


def test_each_read_is_a_new_sample_waited_for(on_bus):
    driver, _, chip = on_bus(Lsm6dslChip(Numbered()))
    seen = [driver.read_imu().gyro[0] for _ in range(6)]  # read back to back
    assert len(set(seen)) == 6 and seen == sorted(seen)  # each read waited for a new one
    assert driver.reads == 6 and chip.samples >= 6


def test_a_reader_held_up_loses_no_sample(on_bus):
    driver, _, chip = on_bus(Lsm6dslChip(Numbered()))
    first = round(driver.read_imu().gyro[0])
    made, lost = chip.samples, chip.lost
    time.sleep(6 / 104)  # a step held up for six periods: the sampler kept what came
    pending = driver.pending
    # every sample the chip showed is kept (one more may have come since the sampler last
    # looked); the sampler itself held up past a period loses one at the chip, as on a
    # real chip without its FIFO (seen once, under two CI runs at once)
    shown = chip.samples - made - (chip.lost - lost)
    assert shown >= 3 and pending >= shown - 1, (pending, shown)
    got = [round(driver.read_imu().gyro[0]) for _ in range(pending)]
    assert got == list(range(first + 1, first + 1 + len(got)))  # every one, in order
    assert driver.overwritten == 0


@pytest.mark.parametrize("clock_error", [0.03, 0.0, -0.03])
def test_a_sample_is_stamped_when_the_chip_made_it_whatever_its_clock(on_bus, clock_error):
    # Read on the host's schedule at the nominal rate, as the measure does, while the chip's
    # own clock runs 3 % fast or slow: stamped when the data was seen at each read, the
    # samples would be late by up to a period (a 4.8 ms median at 104 Hz when fast); at
    # the middle of the two polls about the data-ready edge, 0.2-0.5 ms off.
    numbered = Numbered()
    driver, _, _ = on_bus(Lsm6dslChip(numbered, clock_error), timeout_ms=9.0)
    read_until_a_sample(driver)
    offset = time.time() - time.monotonic()
    errors, start = [], time.monotonic()
    for i in range(1, 61):
        time.sleep(max(0.0, start + i / 104 - time.monotonic()))
        try:
            r = driver.read_imu()
        except NoReading:
            continue  # a slow chip's sample not there within the timeout: the next read's
        made = numbered.made[round(r.gyro[0]) - 1]
        errors.append(r.t - offset - made)
    assert len(errors) >= 40, errors
    assert statistics.median(abs(e) for e in errors) < 0.2e-3, sorted(errors)
    listed = driver.describe()  # the board listing shows the chip's own period, learnt
    assert listed["period_ms"] == pytest.approx(1000 / (104 * (1 + clock_error)), rel=1e-3)


def test_no_new_sample_in_time_is_a_dropout(on_bus):
    driver, _, _ = on_bus(odr_hz=12.5, timeout_ms=100.0)
    driver.read_imu()
    driver.timeout = 0.005
    with pytest.raises(NoReading, match=f"^{WHERE}: no new sample in 5 ms$"):
        driver.read_imu()


def test_an_unplugged_chip_is_disconnected_and_set_up_again_once_back(on_bus):
    driver, bus, chip = on_bus()
    driver.read_imu()
    bus.unplugged = True
    with pytest.raises(BoardDisconnected, match=f"^{WHERE}: Remote I/O error$"):
        while True:  # a sample made just before may still come first
            driver.read_imu()
    assert bus.closed == 1
    bus.unplugged = False
    chip.power_on()  # it lost power while out: back in power-down
    r, errors = read_until_a_sample(driver)
    assert r.acc[2] == pytest.approx(math.cos(math.radians(5)), abs=1e-3)
    assert driver.setups == 2 and bus.opened == 2
    assert all(isinstance(e, (BoardDisconnected, NoReading)) for e in errors)


def test_a_chip_reset_while_running_is_set_up_again_and_said(on_bus):
    driver, _, chip = on_bus()
    driver.read_imu()
    chip.power_on()  # a brown-out: registers back to power-down, no more samples
    r, errors = read_until_a_sample(driver)
    assert r.gyro[1] == pytest.approx(-1.25, abs=0.02)
    assert driver.resets_seen == 1 and driver.setups == 2
    assert any("the chip had been reset; set up again" in str(e) for e in errors), errors


def test_an_adapter_not_there_yet_is_disconnected_until_it_is():
    chip = Lsm6dslChip()
    bus = FakeBus({0x6A: chip})
    bus.present = False
    driver = I2cLsm6dsl(odr_hz=104.0, timeout_ms=30.0, smbus=bus.open)  # made: it retries
    try:
        with pytest.raises(BoardDisconnected, match=f"^{WHERE}: No such file or directory$"):
            driver.read_imu()
        bus.present = True
        assert read_until_a_sample(driver)[0].acc[2] == pytest.approx(1.0, abs=1e-3)
    finally:
        driver.close()


def test_another_chip_at_the_address_is_refused():
    bus = FakeBus({0x6B: Lsm6dslChip(who_am_i=0x6C)})  # an LSM6DSO
    with pytest.raises(ValueError) as e:
        I2cLsm6dsl(address=0x6B, smbus=bus.open)
    assert str(e.value) == (
        "I2C bus /dev/i2c-1, address 0x6b is not an LSM6DSL: WHO_AM_I reads 0x6c, "
        "an LSM6DSL reads 0x6a"
    )


def test_closing_stops_the_sampler_and_puts_the_chip_in_power_down(on_bus):
    driver, bus, chip = on_bus()
    driver.read_imu()
    driver.close()
    assert not driver._thread.is_alive()
    assert chip.regs[CTRL1_XL] == chip.regs[CTRL2_G] == 0 and bus.closed == 1


@pytest.mark.parametrize(
    ("kw", "says"),
    [
        ({"bus": -1}, "bus must be an adapter number or a device path, got -1"),
        ({"bus": "i2c-1"}, "bus must be an adapter number or a device path, got 'i2c-1'"),
        ({"address": 0x6C}, "address must be 0x6a or 0x6b (the chip's two), got 108"),
        ({"odr_hz": 25}, "odr_hz must be one of (12.5, 26.0, 52.0, 104.0, 208.0, 416.0, "
         "833.0, 1666.0, 3332.0, 6664.0) (Hz), got 25"),
        ({"acc_range_g": 3}, "acc_range_g must be one of (2, 4, 8, 16), got 3"),
        ({"gyro_range_dps": 250}, "gyro_range_dps must be one of (125, 245, 500, 1000, 2000), "
         "got 250"),
        ({"timeout_ms": 0}, "timeout_ms must be a number of ms in (0, 384.615] (ten periods), "
         "got 0"),
        ({"axes": "x,y"}, "axes must name each chip axis once with an optional sign, as "
         "'-y,x,z', got 'x,y'"),
        ({"axes": "x,x,z"}, "axes must name each chip axis once with an optional sign, as "
         "'-y,x,z', got 'x,x,z'"),
        ({"axes": "--x,y,z"}, "axes must name each chip axis once with an optional sign, as "
         "'-y,x,z', got '--x,y,z'"),
        ({"axes": "-x,y,z"}, "axes '-x,y,z' is a mirror image of the chip's frame (no chip "
         "can be mounted so): turn the sign of one more axis"),
        ({"axes": "y,x,z"}, "axes 'y,x,z' is a mirror image of the chip's frame (no chip "
         "can be mounted so): turn the sign of one more axis"),
    ],
)  # fmt: skip
def test_bad_arguments_are_refused_in_one_sentence(kw, says):
    bus = FakeBus({0x6A: Lsm6dslChip()})
    with pytest.raises(ValueError) as e:
        I2cLsm6dsl(**kw, smbus=bus.open)
    assert str(e.value) == says


def test_the_turns_allowed_are_the_rotations():
    assert parse_axes("x,y,z") == ((0, 1.0), (1, 1.0), (2, 1.0))
    assert parse_axes("-x,-y,z") == ((0, -1.0), (1, -1.0), (2, 1.0))  # turned about z
    assert parse_axes("z,x,y") == ((2, 1.0), (0, 1.0), (1, 1.0))  # a cyclic permutation


WORLD = {"scenario": "balancing", "epoch": 0.0}
DRIVER = "fake_i2c:ChipOnFakeBus"


@pytest.fixture
def ctx_of():
    """Measure contexts whose boards are closed at the end (their samplers stopped)."""
    made = []

    def make(period: float):
        made.append(make_ctx("lsm6dsl", WORLD, period=period))
        return made[-1]

    yield make
    for ctx in made:
        boards_of(ctx).close()


def test_the_measure_runs_on_the_chip_and_calibrates_on_it(ctx_of):
    ctx = ctx_of(1 / 104)
    m = Lsm6dsl()
    drv = {"theta_deg": 5.0, "bias_dps": [0.5, -1.25, 2.0], "odr_hz": 104.0}
    m.init({"odr_hz": 104.0, "calib_samples": 5, "driver": DRIVER, "driver_args": drv}, ctx)
    board = boards_of(ctx).get("n1/imu")
    assert isinstance(board, ChipOnFakeBus) and board.reads == 0
    readings = (m.measure() for _ in range(50))
    values = [r.values for r in readings if r is not None][:6]  # the first may be a dropout
    assert len(values) == 6
    a_x, a_z, g_y, b, state = values[-1]
    th = math.radians(5.0)
    assert a_x == pytest.approx(G * math.sin(th), abs=2e-3)  # the seed's sign: leaning forward
    assert a_z == pytest.approx(G * math.cos(th), abs=2e-3)
    assert g_y == pytest.approx(math.radians(-1.25), abs=1e-3)  # published raw
    assert b == pytest.approx(math.radians(-1.25), abs=1e-3) and state == 2  # calibrated
    assert ctx.counters["calibrations"] == 1


def test_a_late_step_publishes_every_sample_the_chip_made_since(ctx_of):
    ctx = ctx_of(1 / 104)
    m = Lsm6dsl()
    drv = {"theta_deg": 5.0, "odr_hz": 104.0}
    m.init({"odr_hz": 104.0, "calib_samples": 5, "driver": DRIVER, "driver_args": drv}, ctx)
    while m.measure() is None:  # the chip's first sample
        pass
    time.sleep(5 / 104)
    late = m.measure()
    assert isinstance(late, list) and len(late) >= 4, late
    steps = [y.t - x.t for x, y in pairwise(late)]
    assert all(0.5 / 104 < dt < 1.5 / 104 for dt in steps), steps  # consecutive samples


def test_a_board_at_another_rate_than_the_measure_is_refused(ctx_of):
    ctx = ctx_of(1 / 26)
    with pytest.raises(ValueError) as e:
        Lsm6dsl().init({"driver": DRIVER, "driver_args": {"odr_hz": 52.0}}, ctx)
    assert str(e.value) == (
        "measure 'lsm6dsl': its board runs at 52 Hz, the measure's odr_hz is 26: "
        "give both the same rate"
    )


def test_smbus2_on_an_adapter_that_is_not_there_is_a_disconnected_board():
    driver = I2cLsm6dsl(bus="/dev/i2c-hera-test-none")
    with pytest.raises(BoardDisconnected) as e:
        driver.read_imu()
    driver.close()
    assert str(e.value) == (
        "I2C bus /dev/i2c-hera-test-none, address 0x6a: No such file or directory"
    )


SPEC = """
[cluster]
name = "i2c"
[world]
scenario = "balancing"
[logging]
node = "robot"
[[nodes]]
name = "robot"
[[nodes.measures]]
use = "lsm6dsl"
name = "imu"
period = 0.0096154
args = {{ odr_hz = 104.0, calib_samples = 20, driver = "fake_i2c:ChipOnFakeBus", driver_args = {{ odr_hz = 104.0, theta_deg = -4.0, bias_dps = [0.0, 2.5, 0.0], axes = "{axes}", clock_error = 0.03 }} }}
[[nodes.measures]]
use = "lsm6dsl"
name = "imu_b"
period = 0.0384615
args = {{ board = "imu_b", driver = "hera.nodes.lsm6dsl.i2c:I2cLsm6dsl", driver_args = {{ bus = "/dev/i2c-hera-test-none" }} }}
"""  # noqa: E501


def test_a_node_publishes_its_chip_and_waits_for_an_adapter_not_there(cluster):
    # The chip mounted a half turn about z (its x and y point the other way on the robot)
    # and ``axes`` saying so: the robot's values come out as if it were the right way round.
    # Its clock runs 3 % fast: its samples are stamped on its clock, not the node's.
    c = cluster(SPEC.format(axes="-x,-y,z"))
    log = c.run_dir / "measures" / "imu_robot.csv"  # seq, time, a_X, a_Z, g_Y, b, calibration

    def rows() -> list[list[float]]:
        return [[float(v) for v in row[1:]] for row in csv_rows(log)]

    def calibrated() -> list[float] | None:
        last = rows()[-1:]
        return last[0][1:] if last and last[0][-1] == 2.0 else None

    a_x, a_z, g_y, b, _ = wait_for(calibrated, 20, "the chip's samples, calibrated")
    stamps = wait_for(lambda: (r := rows()) and len(r) > 300 and [x[0] for x in r], 20, "300")
    steps = [y - x for x, y in pairwise(stamps[-200:])]  # ms
    chip_ms = 1000 / (104 * 1.03)
    periods = [round(s / chip_ms) for s in steps]  # 2 where the node lost one: none should
    assert sum(steps) / sum(periods) == pytest.approx(chip_ms, abs=0.02), steps
    # each stamp on the chip's clock: raw edge midpoints would be off by up to half a poll
    # (0.5 ms) either way, their intervals by up to a poll
    off = [abs(s - n * chip_ms) for s, n in zip(steps, periods, strict=True)]
    assert statistics.median(off) < 0.3, steps
    th = math.radians(-4.0)
    assert a_x == pytest.approx(G * math.sin(th), abs=0.01)  # leaning back: a_X < 0
    assert a_z == pytest.approx(G * math.cos(th), abs=0.01)
    assert g_y == pytest.approx(math.radians(2.5), abs=1e-3)  # raw, the bias alone
    assert b == pytest.approx(math.radians(2.5), abs=1e-3)  # calibrated on the chip
    m = c.status("robot")["measures"]
    assert m["imu"]["trouble"] is None and m["imu"]["crashes"] == 0, m["imu"]
    b_ = m["imu_b"]
    assert b_["state"] == "running" and b_["crashes"] == 0 and b_["restarts"] == 0, b_
    assert b_["trouble"] == (
        "board not answering (I2C bus /dev/i2c-hera-test-none, address 0x6a: "
        "No such file or directory)"
    ), b_
