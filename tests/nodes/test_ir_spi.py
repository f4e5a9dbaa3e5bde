"""The seed-000 rig's sensors on a Linux host: a Sharp IR sensor through an MCP3008 ADC
(``hera.nodes.ir.mcp3008``) and a thermocouple behind a MAX31855 (``hera.nodes.ir.max31855``),
against the chips played behind spidev-like devices (``fake_spi``): conversions, faults, a
chip that is not there never taken for a reading, bad arguments, the shared SPI link, and
both in a node's measures."""

from __future__ import annotations

import sys

import pytest
from fake_spi import AdcChip, FakeSpiBus, ThermocoupleChip
from harness import csv_rows, wait_for

from hera.nodes.driver import BoardDisconnected
from hera.nodes.ir.driver import IrDriver, ThermocoupleDriver
from hera.nodes.ir.max31855 import Max31855
from hera.nodes.ir.mcp3008 import Mcp3008Ir
from hera.nodes.spi import SpiLink

ADC, TC = "/dev/spidev0.0", "/dev/spidev0.1"


@pytest.mark.parametrize("channel", [0, 5, 7])
@pytest.mark.parametrize("volts", [0.0, 0.4, 1.71, 3.1])
def test_a_conversion_is_the_channels_volts_to_one_code(channel, volts):
    chip = AdcChip({channel: volts, (channel + 1) % 8: 2.5})
    bus = FakeSpiBus({ADC: chip})
    adc = Mcp3008Ir(channel=channel, spi=bus.open)
    assert isinstance(adc, IrDriver)
    sample = adc.read_sample()
    assert sample.volts == pytest.approx(volts, abs=3.3 / 1024)
    assert chip.asked == [[0x01, 0x80 | channel << 4, 0x00]]  # start, single-ended, channel
    assert [(d.mode, d.speed_hz) for d in bus.opened] == [(0, 1_000_000)]
    adc.close()


def test_the_reference_sets_the_full_scale():
    bus = FakeSpiBus({ADC: AdcChip({0: 4.0}, vref=5.0)})
    assert Mcp3008Ir(vref=5.0, spi=bus.open).read_volts() == pytest.approx(4.0, abs=5 / 1024)


def test_an_adc_not_there_is_disconnected_or_reads_nothing_in_range():
    bus = FakeSpiBus({ADC: AdcChip({0: 1.0})})
    adc = Mcp3008Ir(spi=bus.open)
    bus.unplugged = 0xFF  # MISO pulled up: the null bit reads 1
    with pytest.raises(BoardDisconnected) as e:
        adc.read_volts()
    assert str(e.value) == (
        "SPI /dev/spidev0.0 (MCP3008 channel 0): no chip answers (its null bit reads 1: "
        "MISO pulled up)"
    )
    bus.unplugged = 0x00  # pulled down: 0 V, what a Sharp sensor with nothing in range gives
    assert adc.read_volts() == 0.0
    bus.unplugged = None
    assert adc.read_volts() == pytest.approx(1.0, abs=3.3 / 1024)
    with pytest.raises(BoardDisconnected) as e:
        Mcp3008Ir(device="/dev/spidev3.0", spi=bus.open).read_volts()
    assert str(e.value) == (
        "SPI /dev/spidev3.0 (MCP3008 channel 0): Opening SPI device: No such file or directory"
    )


@pytest.mark.parametrize(
    ("celsius", "junction"), [(21.0, 24.5), (-12.25, 3.0), (1023.75, 60.0625), (-200.0, -8.5)]
)
def test_a_thermocouple_reads_its_signed_temperatures(celsius, junction):
    bus = FakeSpiBus({TC: ThermocoupleChip(celsius, junction)})
    tc = Max31855(spi=bus.open)
    assert isinstance(tc, ThermocoupleDriver)
    assert tc.read_sample().celsius == celsius  # quarter degrees: exact
    assert tc.junction == junction and tc.describe()["junction_c"] == junction
    assert [(d.mode, d.speed_hz) for d in bus.opened] == [(0, 1_000_000)]


@pytest.mark.parametrize(
    ("faults", "says"),
    [(1, "open: no thermocouple"), (2, "shorted to GND"), (4, "shorted to VCC")],
)
def test_a_thermocouple_fault_is_named_and_clears(faults, says):
    chip = ThermocoupleChip(80.0, faults=faults)
    tc = Max31855(spi=FakeSpiBus({TC: chip}).open)
    with pytest.raises(BoardDisconnected) as e:
        tc.read_celsius()
    assert str(e.value) == f"SPI /dev/spidev0.1 (MAX31855): thermocouple {says}"
    chip.faults = 0
    assert tc.read_celsius() == 80.0


@pytest.mark.parametrize(("floats", "frame"), [(0xFF, "ffffffff"), (0x00, "00000000")])
def test_a_thermocouple_amplifier_not_there_is_never_a_reading(floats, frame):
    bus = FakeSpiBus({TC: ThermocoupleChip(21.0)})
    bus.unplugged = floats
    with pytest.raises(BoardDisconnected) as e:
        Max31855(spi=bus.open).read_celsius()
    assert (
        str(e.value)
        == f"SPI /dev/spidev0.1 (MAX31855): no chip answers (the frame reads 0x{frame})"
    )


@pytest.mark.parametrize(
    ("make", "says"),
    [
        (lambda: Mcp3008Ir(channel=8), "channel must be an ADC input 0-7, got 8"),
        (lambda: Mcp3008Ir(vref=0), "vref must be the ADC's reference in (0, 5.5] V, got 0"),
        (
            lambda: Mcp3008Ir(device="spidev0.0", speed_hz=4_000_000),
            "device must be a device path, got 'spidev0.0'; speed_hz must be an integer in "
            "(0, 3600000] (Hz), got 4000000",
        ),
        (
            lambda: Max31855(speed_hz=True),
            "speed_hz must be an integer in (0, 5000000] (Hz), got True",
        ),
    ],
)
def test_bad_arguments_are_refused_in_one_sentence(make, says):
    with pytest.raises(ValueError) as e:
        make()
    assert str(e.value) == says


def test_without_python_periphery_the_link_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "periphery", None)  # import fails
    with pytest.raises(ValueError) as e:  # when the driver is made, not at its first read
        SpiLink(ADC, "SPI /dev/spidev0.0 (test)", 0, 1_000_000)
    assert str(e.value) == (
        "the SPI drivers need the python-periphery package: pip install 'hera-fusion[spi]'"
    )


SPEC = """
[cluster]
name = "plate"
[logging]
node = "plate"
[[nodes]]
name = "plate"
[[nodes.measures]]
use = "sharp_ir"
name = "ir"
args = { position_cm = [10.0, 20.0], heading_deg = 90.0, driver = "fake_spi:IrOnFakeSpi", driver_args = { volts = 1.25, channel = 3 } }
[[nodes.measures]]
use = "thermocouple"
name = "tc"
args = { position_cm = [5.0, 5.0], driver = "fake_spi:ThermocoupleOnFakeSpi", driver_args = { celsius = 31.5 } }
[[nodes.measures]]
use = "thermocouple"
name = "tc_b"
args = { board = "tc_b", position_cm = [5.0, 5.0], driver = "hera.nodes.ir.max31855:Max31855", driver_args = { device = "/dev/spidev-hera-test-none" } }
"""  # noqa: E501


def test_a_node_publishes_its_adc_and_thermocouple_and_waits_for_a_device_not_there(cluster):
    c = cluster(SPEC)
    ir = c.run_dir / "measures" / "ir_plate.csv"  # seq, time, V, x, y, heading
    tc = c.run_dir / "measures" / "tc_plate.csv"  # seq, time, degC, x, y
    ir_rows = wait_for(lambda: len(r := csv_rows(ir)) >= 20 and r, 20, "20 IR samples")
    tc_rows = wait_for(lambda: len(r := csv_rows(tc)) >= 3 and r, 20, "3 temperatures")
    for row in ir_rows:
        assert [float(v) for v in row[2:]] == pytest.approx([1.25, 10.0, 20.0, 90.0], abs=4e-3)
    assert all([float(v) for v in row[2:]] == [31.5, 5.0, 5.0] for row in tc_rows)
    listing = {b["board"]: b for b in c.control("plate", "board", {})["boards"]}
    adc, amp = listing["plate/ir"], listing["plate/tc"]
    assert adc["kind"] == "sharp-ir-mcp3008" and adc["channel"] == 3 and adc["connected"], adc
    assert amp["kind"] == "thermocouple-max31855" and amp["junction_c"] == 24.5, amp
    assert not listing["plate/tc_b"]["connected"]
    m = c.status("plate")["measures"]
    assert m["ir"]["trouble"] is None and m["tc"]["trouble"] is None, m
    b = m["tc_b"]
    assert b["state"] == "running" and b["crashes"] == 0 and b["restarts"] == 0, b
    assert b["trouble"] == (
        "board not answering (SPI /dev/spidev-hera-test-none (MAX31855): Opening SPI device: "
        "No such file or directory)"
    ), b
