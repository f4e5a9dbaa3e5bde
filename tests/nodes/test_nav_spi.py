"""A real Pmod NAV on SPI (``hera.nodes.nav_spi``), against its three chips played at register
level behind spidev-like devices (``fake_spi``): what the chips are told, readings scaled,
signed and turned into the board frame (the magnetometer's own x axis), one new sample per
read stamped when the chip made it, a board unplugged, a chip reset or stuck, the wrong chip,
bad arguments, the ``nav`` measure on it in a node, and python-periphery on a device that is
not there."""

from __future__ import annotations

import math
import statistics
import time
from itertools import pairwise

import pytest
from fake_spi import AccGyroChip, MagChip, Turntable, pmod_nav_bus, still
from harness import csv_rows, wait_for

from hera.nodes.calibration import calibrate_mag, calibrate_nav, calibrate_nav3
from hera.nodes.driver import BoardDisconnected, NavDriver, NoReading
from hera.nodes.nav_spi import (
    ACC_RANGES,
    AG_ID,
    BARO_CTRL_REG1,
    BARO_CTRL_REG2,
    BDU,
    CTRL_REG1_G,
    CTRL_REG1_M,
    CTRL_REG2_M,
    CTRL_REG3_M,
    CTRL_REG4_M,
    CTRL_REG5_M,
    CTRL_REG6_XL,
    CTRL_REG8,
    GYRO_RANGES,
    IF_ADD_INC,
    MAG_RANGES,
    SpiPmodNav,
)

AG, MAG, ALT = "/dev/spidev0.0", "/dev/spidev0.1", "/dev/spidev1.0"
AG_WHERE = f"SPI {AG} (accelerometer and gyroscope)"

# A board tilted about x and y, turning, in a field with a negative x: every sign shows.
ACC, GYRO, FIELD = (0.1, -0.2, 0.97), (1.5, -2.0, 30.0), (-0.25, 0.1, -0.45)


@pytest.fixture
def on_bus():
    """Make the driver on a fake Pmod NAV (barometer wired); closed at the end."""
    made: list[SpiPmodNav] = []

    def make(signal=None, axes: str = "x,y,z", clock_error: float = 0.0, **kw):
        bus = pmod_nav_bus(signal or still(ACC, GYRO, FIELD), axes, clock_error)
        made.append(SpiPmodNav(alt=ALT, axes=axes, spi=bus.open, **kw))
        return made[-1], bus

    yield make
    for driver in made:
        driver.close()


def mean_reading(driver: SpiPmodNav, n: int = 20):
    samples = [driver.read_imu() for _ in range(n)]
    return [
        tuple(statistics.fmean(s[k] for s in col) for k in range(3))
        for col in (
            [s.acc for s in samples],
            [s.gyro for s in samples],
            [s.mag for s in samples],
        )
    ]


def test_the_chips_are_told_what_the_data_sheets_ask(on_bus):
    driver, bus = on_bus(
        odr_hz=952.0,
        acc_range_g=16,
        gyro_range_dps=2000,
        mag_range_gauss=8,
        mag_odr_hz=40.0,
        speed_hz=2_000_000,
    )
    assert isinstance(driver, NavDriver)
    driver.read_imu()
    driver.read_baro()
    ag, mag, alt = (bus.chips[p].regs for p in (AG, MAG, ALT))
    assert ag[CTRL_REG8] == BDU | IF_ADD_INC
    assert ag[CTRL_REG1_G] == 6 << 5 | 0b11 << 3  # 952 Hz, 2000 dps
    assert ag[CTRL_REG6_XL] == 6 << 5 | 0b01 << 3  # 952 Hz, 16 g
    # temperature compensated, ultra-high performance, 40 Hz; 8 gauss; continuous; BDU
    assert ag[CTRL_REG8] == 0x44
    assert [mag[r] for r in (CTRL_REG1_M, CTRL_REG2_M, CTRL_REG3_M, CTRL_REG4_M, CTRL_REG5_M)] == [
        0x80 | 0x60 | 6 << 2,
        0b01 << 5,
        0x00,
        0x0C,
        0x40,
    ]
    assert alt[BARO_CTRL_REG1] == 0x80 | 0x40 | 0x04 and alt[BARO_CTRL_REG2] == 0  # on, 25 Hz
    assert {(d.path, d.mode, d.speed_hz) for d in bus.opened} == {
        (p, 3, 2_000_000) for p in (AG, MAG, ALT)
    }
    assert driver.setups == 3


@pytest.mark.parametrize("acc_g", sorted(ACC_RANGES))
@pytest.mark.parametrize("gyro_dps", sorted(GYRO_RANGES))
def test_readings_are_scaled_and_signed(on_bus, acc_g, gyro_dps):
    driver, _ = on_bus(acc_range_g=acc_g, gyro_range_dps=gyro_dps, odr_hz=952.0)
    acc, gyro, _ = mean_reading(driver)
    # the fake chip adds 4 counts of noise: the mean of 20 is within 3 counts
    assert acc == pytest.approx(ACC, abs=3 * ACC_RANGES[acc_g][1])
    assert gyro == pytest.approx(GYRO, abs=3 * GYRO_RANGES[gyro_dps][1])


@pytest.mark.parametrize("gauss", sorted(MAG_RANGES))
def test_the_magnetometer_reads_in_the_board_frame(on_bus, gauss):
    # its die's x points the other way: read as the chip's own x, FIELD's x would come out
    # +0.25; read unsigned (the thesis's appendix E), the negative axes near 2^16 counts
    driver, _ = on_bus(mag_range_gauss=gauss)
    assert mean_reading(driver)[2] == pytest.approx(FIELD, abs=2 * MAG_RANGES[gauss][1])
    assert driver.read_mag() == pytest.approx(FIELD, abs=4 * MAG_RANGES[gauss][1] + 1e-3)


def test_the_magnetometer_die_lies_as_mag_axes_says():
    # a board whose magnetometer is turned a half turn about x against the accelerometer
    bus = pmod_nav_bus(still(ACC, GYRO, FIELD), mag_axes="x,-y,-z")
    driver = SpiPmodNav(mag_axes="x,-y,-z", spi=bus.open)
    assert driver.read_mag() == pytest.approx(FIELD, abs=2e-3)
    driver.close()
    wrong = SpiPmodNav(spi=pmod_nav_bus(still(ACC, GYRO, FIELD), mag_axes="x,-y,-z").open)
    assert wrong.read_mag() == pytest.approx((0.25, -0.1, 0.45), abs=2e-3)  # every axis off
    wrong.close()


def test_the_axes_turn_the_chip_into_the_board(on_bus):
    driver, bus = on_bus(axes="-y,x,z", odr_hz=952.0)
    acc, gyro, mag = mean_reading(driver)
    assert acc == pytest.approx(ACC, abs=3e-4)
    assert gyro == pytest.approx(GYRO, abs=0.03)
    assert mag == pytest.approx(FIELD, abs=1e-3)
    chip = bus.chips[AG].regs  # the chip's own x is the board's y: it reads ACC's y there
    assert int.from_bytes(chip[0x28:0x2A], "little", signed=True) == pytest.approx(
        -0.2 / 0.061e-3, abs=20
    )


def test_the_barometer_reads_hpa(on_bus):
    driver, _ = on_bus()
    assert driver.read_baro() == pytest.approx(1013.25, abs=1 / 4096)


@pytest.mark.parametrize("clock_error", [0.0, 0.03, -0.03])
def test_each_read_is_a_new_sample_stamped_when_the_chip_made_it(on_bus, clock_error):
    driver, bus = on_bus(clock_error=clock_error)
    chip = bus.chips[AG]
    offset = time.time() - time.monotonic()
    stamps = []
    for _ in range(30):
        stamps.append(driver.read_imu(mag=False).t)
        time.sleep(0.003)  # a reader slower than the chip now and then
    made = [m + offset for m in chip.made]
    nearest = [min(made, key=lambda m, s=s: abs(s - m)) for s in stamps]
    errors = [s - m for s, m in zip(stamps, nearest, strict=True)]
    # within half a poll (1 ms) either way, not late on average (stamped when seen: 0.5 ms)
    assert statistics.median(map(abs, errors)) < 0.7e-3, errors
    assert abs(statistics.fmean(errors)) < 0.25e-3, errors
    # each read a sample of its own: one chip instant per stamp, all different
    assert len(set(nearest)) == len(stamps)
    assert all(b - a > 0.5 / 119 for a, b in pairwise(stamps))


def test_calibration_averages_samples_of_their_own(on_bus):
    driver, bus = on_bus()
    before = bus.chips[AG].samples
    cal = calibrate_nav(driver, 30)
    assert bus.chips[AG].samples - before >= 60  # 30 for the accelerometer, 30 for the gyro
    assert cal["acc"] == pytest.approx(ACC, abs=1e-4)
    assert cal["gyro"] == pytest.approx(GYRO, abs=0.01)


def test_a_person_turning_the_board_calibrates_its_magnetometer():
    # A real board cannot turn itself: the calibrations take turn=<a function asking a
    # person> (README), here a turntable; each mean is over magnetometer samples of their own.
    table = Turntable()
    bus = pmod_nav_bus(table.signal)
    driver = SpiPmodNav(spi=bus.open)
    before = bus.chips[MAG].samples
    cal = calibrate_mag(driver, turn=table.turn, n=10)
    assert bus.chips[MAG].samples - before >= 30  # three means of ten samples each
    assert cal["bias"] == pytest.approx(table.hard_iron[:2], abs=1e-3)
    assert cal["offset"] == pytest.approx(math.atan2(0.0, 0.2), abs=0.01)
    cal3 = calibrate_nav3(driver, turn=table.turn, n_gyro=20, n_mag=10)
    assert cal3["mag"] == pytest.approx(table.hard_iron, abs=1e-3)
    assert cal3["gyro"] == pytest.approx(table.gyro_bias, abs=0.02)
    assert table.turns == [("z", 180.0), ("z", -180.0)] + [
        ("z", 180.0),
        ("x", 180.0),
        ("x", -180.0),
        ("z", -180.0),
    ]
    driver.close()


@pytest.mark.parametrize("floats", [0xFF, 0x00])
def test_a_board_unplugged_is_never_a_reading_and_comes_back(on_bus, floats):
    driver, bus = on_bus()
    driver.read_imu()
    bus.unplugged = floats  # MISO pulled up or down: every byte reads the same
    for read in (driver.read_imu, driver.read_mag, driver.read_baro):
        with pytest.raises(BoardDisconnected) as e:
            read()
        assert f"no chip answers (WHO_AM_I reads 0x{floats:02x}" in str(e.value)
    with pytest.raises(BoardDisconnected) as e:
        driver.read_acc()
    assert str(e.value) == (
        f"{AG_WHERE}: no chip answers (WHO_AM_I reads 0x{floats:02x}, expected 0x{AG_ID:02x})"
    )
    bus.unplugged = None  # plugged back: the chips power up again
    for chip in bus.chips.values():
        chip.power_on()
    setups = driver.setups
    sample = driver.read_imu()
    assert sample.acc == pytest.approx(ACC, abs=1e-3) and sample.mag is not None
    assert driver.read_baro() == pytest.approx(1013.25, abs=1e-3)
    assert driver.setups == setups + 3


def test_a_chip_reset_while_running_is_set_up_again(on_bus):
    driver, bus = on_bus()
    driver.read_imu()
    bus.chips[AG].power_on()  # a brown-out: back in power-down
    with pytest.raises(NoReading) as e:
        driver.read_imu()
    assert str(e.value) == f"{AG_WHERE}: the chip had been reset; set up again"
    assert driver.read_imu().gyro == pytest.approx(GYRO, abs=0.05)
    bus.chips[MAG].power_on()
    with pytest.raises(NoReading, match="magnetometer\\): the chip had been reset"):
        driver.read_mag()
    assert driver.read_mag() == pytest.approx(FIELD, abs=2e-3)
    assert driver.resets_seen == 2 and driver.describe()["resets_seen"] == 2


def test_a_chip_that_makes_no_new_sample_is_a_dropout(on_bus):
    driver, bus = on_bus(timeout_ms=30)
    driver.read_imu()
    bus.chips[AG].rate = lambda: None  # its registers intact, its clock stopped
    t0 = time.monotonic()
    with pytest.raises(NoReading) as e:
        driver.read_imu()
    assert str(e.value) == f"{AG_WHERE}: no new sample in 30 ms"
    assert 0.03 <= time.monotonic() - t0 < 0.5


def test_another_chip_is_refused_for_good():
    bus = pmod_nav_bus(still())
    bus.chips[AG] = MagChip(still())  # the spec swapped the two chip selects
    bus.chips[MAG] = AccGyroChip(still())
    driver = SpiPmodNav(spi=bus.open)
    with pytest.raises(ValueError) as e:
        driver.read_imu(mag=False)
    assert (
        str(e.value) == f"{AG_WHERE} is not a Pmod NAV's chip: WHO_AM_I reads 0x3d, expected 0x68"
    )
    driver.close()


def test_sensors_not_wired_say_so():
    bus = pmod_nav_bus(still(ACC, GYRO, FIELD))
    driver = SpiPmodNav(mag=None, spi=bus.open)
    assert driver.read_imu(mag=False).acc == pytest.approx(ACC, abs=1e-3)
    with pytest.raises(BoardDisconnected) as e:
        driver.read_mag()
    assert str(e.value) == "SPI mag: not wired (driver_args mag not given)"
    with pytest.raises(BoardDisconnected) as e:
        driver.read_baro()
    assert str(e.value) == "SPI alt: not wired (driver_args alt not given)"
    driver.close()


def test_a_device_not_there_is_disconnected_and_close_powers_down():
    bus = pmod_nav_bus(still(ACC, GYRO, FIELD))
    driver = SpiPmodNav(ag="/dev/spidev5.0", spi=bus.open)
    with pytest.raises(BoardDisconnected) as e:
        driver.read_imu()
    assert str(e.value) == (
        "SPI /dev/spidev5.0 (accelerometer and gyroscope): Opening SPI device: "
        "No such file or directory"
    )
    driver.close()
    driver = SpiPmodNav(spi=bus.open)
    driver.read_imu()
    driver.close()
    assert bus.chips[AG].regs[CTRL_REG1_G] == 0 and bus.chips[AG].regs[CTRL_REG6_XL] == 0
    assert bus.chips[MAG].regs[CTRL_REG3_M] == 0x03  # power-down
    assert all(d.closed for d in bus.opened)


def test_periphery_on_a_device_that_is_not_there_is_a_disconnected_board():
    driver = SpiPmodNav(ag="/dev/spidev-hera-test-none")
    with pytest.raises(BoardDisconnected) as e:
        driver.read_imu(mag=False)
    driver.close()
    assert str(e.value) == (
        "SPI /dev/spidev-hera-test-none (accelerometer and gyroscope): Opening SPI device: "
        "No such file or directory"
    )


@pytest.mark.parametrize(
    ("kw", "says"),
    [
        ({"ag": "spidev0.0"}, "ag must be a device path, got 'spidev0.0'"),
        ({"mag": 1}, "mag must be a device path (as '/dev/spidev0.1') or none, got 1"),
        (
            {"speed_hz": 20_000_000},
            "speed_hz must be an integer in (0, 10000000] (Hz), got 20000000",
        ),
        (
            {"odr_hz": 100},
            "odr_hz must be one of (14.9, 59.5, 119.0, 238.0, 476.0, 952.0) (Hz), got 100",
        ),
        ({"acc_range_g": 6}, "acc_range_g must be one of (2, 4, 8, 16), got 6"),
        ({"gyro_range_dps": True}, "gyro_range_dps must be one of (245, 500, 2000), got True"),
        ({"mag_range_gauss": 2}, "mag_range_gauss must be one of (4, 8, 12, 16), got 2"),
        ({"timeout_ms": 0}, "timeout_ms must be a number of ms in (0, 10000], got 0"),
        (
            {"axes": "x,-y,z"},
            "axes 'x,-y,z' is a mirror image of the chip's frame (no chip can be mounted so): "
            "turn the sign of one more axis",
        ),
        (
            {"mag_axes": "x,y"},
            "mag_axes must name each chip axis once with an optional sign, as '-y,x,z', got 'x,y'",
        ),
        (
            {"odr_hz": 50, "mag_odr_hz": 100},
            "odr_hz must be one of (14.9, 59.5, 119.0, 238.0, 476.0, 952.0) (Hz), got 50; "
            "mag_odr_hz must be one of (0.625, 1.25, 2.5, 5.0, 10.0, 20.0, 40.0, 80.0) (Hz), "
            "got 100",
        ),
    ],
)
def test_bad_arguments_are_refused_in_one_sentence(kw, says):
    with pytest.raises(ValueError) as e:
        SpiPmodNav(**kw, spi=pmod_nav_bus(still()).open)
    assert str(e.value) == says


SPEC = """
[cluster]
name = "spi"
[logging]
node = "train"
[[nodes]]
name = "train"
[[nodes.measures]]
use = "nav"
name = "nav"
period = 0.05
args = { calib_samples = 20, driver = "fake_spi:NavOnFakeSpi", driver_args = { odr_hz = 59.5, start_s = 4.0, rate_dps = 30.0, clock_error = 0.02 } }
[[nodes.measures]]
use = "mag"
name = "mag"
period = 0.1
args = { driver = "fake_spi:NavOnFakeSpi" }
[[nodes.measures]]
use = "nav"
name = "nav_b"
period = 0.1
args = { board = "nav_b", driver = "hera.nodes.nav_spi:SpiPmodNav", driver_args = { ag = "/dev/spidev-hera-test-none" } }
"""  # noqa: E501


def test_a_node_publishes_its_pmod_nav_and_waits_for_a_device_not_there(cluster):
    c = cluster(SPEC)
    log = c.run_dir / "measures" / "nav_train.csv"  # seq, time, a_y, g_z

    def rows() -> list[list[float]]:
        return [[float(v) for v in row[1:]] for row in csv_rows(log)]

    turning = wait_for(
        lambda: len(t := [r for r in rows() if r[2] > 0.3]) >= 20 and t, 30, "20 turning"
    )
    still_rows = [r for r in rows() if abs(r[2]) < 0.05]
    assert len(still_rows) >= 10 and len(turning) >= 20
    # calibrated on the chip's still samples: the bias is gone, the turn is 30 deg/s
    assert statistics.fmean(r[2] for r in still_rows) == pytest.approx(0.0, abs=5e-3)
    assert statistics.fmean(r[2] for r in turning) == pytest.approx(math.radians(30), abs=5e-3)
    assert all(abs(r[1]) < 0.02 for r in rows())  # lying flat: no a_y
    # each stamp on the chip's clock (2 % fast): a whole number of its periods apart
    chip_ms = 1000 / (59.5 * 1.02)
    steps = [b - a for a, b in pairwise(r[0] for r in rows()[-60:])]  # ms
    off = [abs(s - round(s / chip_ms) * chip_ms) for s in steps]
    assert statistics.median(off) < 0.7, steps
    listing = {b["board"]: b for b in c.control("train", "board", {})["boards"]}
    nav = listing["train/nav"]
    assert nav["kind"] == "pmod-nav-spi" and nav["connected"] and nav["reads"] >= 60, nav
    assert nav["set_up"] == ["accelerometer and gyroscope"]  # nav reads no magnetometer
    assert not listing["train/nav_b"]["connected"]
    m = c.status("train")["measures"]
    assert m["nav"]["trouble"] is None and m["nav"]["crashes"] == 0, m["nav"]
    # mag's calibration turns the board: on a real one it waits for one stored by hand
    assert m["mag"]["trouble"].startswith(
        "waiting to start: no calibration stored at calib/train/mag, and this board cannot "
        "turn itself"
    ), m["mag"]
    calibration = {"bias": [0.0, 0.0], "offset": 0.0, "n": 10}
    assert c.control(
        "train", "args", {"op": "set", "key": "calib/train/mag", "value": calibration}
    )["ok"]
    headings = c.run_dir / "measures" / "mag_train.csv"
    wait_for(lambda: len(csv_rows(headings)) >= 5, 20, "mag started on the stored calibration")
    assert c.status("train")["measures"]["mag"]["trouble"] is None
    b = m["nav_b"]
    assert b["state"] == "running" and b["crashes"] == 0 and b["restarts"] == 0, b
    assert b["trouble"] == (  # its calibration waits for the board before it starts
        "waiting to start: board not answering (SPI /dev/spidev-hera-test-none "
        "(accelerometer and gyroscope): Opening SPI device: No such file or directory)"
    ), b
