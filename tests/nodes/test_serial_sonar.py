"""A real MaxSonar on a serial port (``hera.nodes.serial_sonar``), against a sensor played
on the other side of a pseudo-terminal: readings, noise on the line, dropouts, an adapter
unplugged and plugged back, the trigger, and a real node publishing what its port says."""

from __future__ import annotations

import contextlib
import os
import threading
import time
from pathlib import Path

import pytest
from harness import csv_rows, wait_for

from hera.nodes.driver import BoardDisconnected, NoReading, SonarDriver
from hera.nodes.serial_sonar import SerialMaxSonar
from hera.nodes.sonar_model import INCH


class Sensor:
    """A MaxSonar's serial output played on a pty's master side; ``path`` is the port.
    ``start(every)`` sends ``R<inches>\\r`` every ``every`` s from a thread (free-running)."""

    def __init__(self, inches: int = 40) -> None:
        self.master, self.slave = os.openpty()
        os.set_blocking(self.master, False)  # a reader that stopped reading blocks nobody
        self.path = os.ttyname(self.slave)
        self.inches = inches
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def write(self, data: bytes) -> None:
        with contextlib.suppress(BlockingIOError):
            os.write(self.master, data)

    def start(self, every: float = 0.02) -> Sensor:
        def run() -> None:
            while not self._stop.wait(every):
                self.write(b"R%03d\r" % self.inches)

        self._thread = threading.Thread(target=run, daemon=True)
        self._thread.start()
        return self

    def unplug(self) -> None:
        """The adapter pulled out: the master side closes, readers see a hang-up."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        for fd in (self.master, self.slave):
            with contextlib.suppress(OSError):
                os.close(fd)


@pytest.fixture
def sensor():
    s = Sensor()
    yield s
    s.unplug()


class Fed(SerialMaxSonar):
    """The driver with ``chunks`` written to the line once a read waits for its reading
    (after the read dropped what came before it), the last after ``late`` s."""

    def __init__(self, sensor: Sensor, chunks: list[bytes], late: float = 0.0, **kw) -> None:
        self.sensor, self.chunks, self.late = sensor, chunks, late
        super().__init__(sensor.path, **kw)

    def _next_reading(self, fd: int, deadline: float) -> int:
        *first, last = self.chunks or [b""]
        for chunk in first:
            self.sensor.write(chunk)
        threading.Timer(self.late, self.sensor.write, (last,)).start()
        return super()._next_reading(fd, deadline)


def test_a_free_running_sensor_gives_its_next_reading_stamped_a_cycle_before(sensor):
    driver = SerialMaxSonar(sensor.path)
    assert isinstance(driver, SonarDriver)
    sensor.start(every=0.02)
    before = time.time()
    sample = driver.read_sample()
    assert sample.inches == 40 and not sample.crosstalk
    assert before - 0.049 <= sample.t <= time.time() - 0.049 + 0.005  # arrival - 49 ms
    sensor.inches = 41
    wait_for(lambda: driver.read_range() == 41, 2, "the new range (older readings dropped)")
    driver.close()


def test_noise_and_a_reading_split_across_writes_are_read_through(sensor):
    driver = Fed(sensor, [b"\x00\xffzzR0", b"7", b"2\rR9"], late=0.03)
    assert driver.read_range() == 72
    driver = Fed(sensor, [b"R1x2\r" * 3, b"R15", b"6\r"], late=0.02)  # bad digits: skipped
    assert driver.read_range() == 156


def test_no_reading_in_time_is_a_dropout(sensor):
    driver = SerialMaxSonar(sensor.path, timeout_ms=60)
    t0 = time.monotonic()
    with pytest.raises(NoReading, match=f"no reading from {sensor.path} in 60 ms"):
        driver.read_range()
    assert 0.06 <= time.monotonic() - t0 < 1.0


def test_an_unplugged_adapter_is_disconnected_and_read_again_once_plugged_back(tmp_path):
    first, port = Sensor(inches=30), tmp_path / "ttyUSB0"  # a stable name, as udev gives
    port.symlink_to(first.path)
    driver = SerialMaxSonar(str(port))
    first.start()
    assert driver.read_range() == 30
    first.unplug()
    with pytest.raises(BoardDisconnected, match=f"serial port {port}"):
        driver.read_range()
    port.unlink()
    with pytest.raises(BoardDisconnected, match="No such file or directory"):
        driver.read_range()  # still out
    second = Sensor(inches=31)
    try:
        port.symlink_to(second.path)
        second.start()
        assert driver.read_range() == 31  # opened again on this read
    finally:
        second.unplug()


def test_a_trigger_pulses_its_line_and_reads_what_follows(sensor):
    with pytest.raises(ValueError) as e:  # a pty has no modem lines
        SerialMaxSonar(sensor.path, trigger="rts")
    assert str(e.value) == (
        f"serial port {sensor.path} cannot drive its RTS line (Inappropriate ioctl for "
        "device): use a port that has it, or trigger = 'free'"
    )

    class Wired(SerialMaxSonar):  # the line's effect: the sensor pings once, when raised
        lines: list[bool] = []

        def _line(self, fd: int, on: bool) -> None:
            self.lines.append(on)
            if on:
                sensor.write(b"R088\r")

    driver = Wired(sensor.path, trigger="dtr", pulse_ms=2)
    sensor.write(b"R001\r")  # a reading from before the trigger does not count
    before = time.time()
    sample = driver.read_sample()
    assert sample.inches == 88 and Wired.lines == [False, True, False]
    assert before <= sample.t <= time.time()  # stamped at the trigger


@pytest.mark.parametrize(
    ("kw", "says"),
    [
        ({"trigger": "gpio"}, "trigger must be free, rts or dtr, got 'gpio'"),
        ({"baud": 9601}, "baud 9601 is not a serial speed of this system"),
        ({"timeout_ms": 0}, "timeout_ms must be a number of ms in (0, 60000), got 0"),
        ({"port": "/dev/null"}, "/dev/null is not a serial port"),
    ],
)
def test_bad_arguments_are_refused_in_one_sentence(sensor, kw, says):
    with pytest.raises(ValueError) as e:
        SerialMaxSonar(**{"port": sensor.path, **kw})
    assert str(e.value) == says


SPEC = """
[cluster]
name = "serial"
[logging]
node = "s1"
[[nodes]]
name = "s1"
[[nodes.measures]]
use = "sonar"
sync = false
period = 0.1
args = {{ driver = "hera.nodes.serial_sonar:SerialMaxSonar", driver_args = {{ port = "{port}" }}, position = [0.5, 1.5, 0.0], direction = [0.0, 1.0, 0.0] }}
"""  # noqa: E501


def test_a_node_publishes_what_its_serial_port_says(cluster, sensor, tmp_path: Path):
    sensor.inches = 57
    sensor.start(every=0.049)
    c = cluster(SPEC.format(port=sensor.path))

    log = c.run_dir / "measures" / "sonar_s1.csv"  # seq, time, range, x, y per sample

    def latest() -> list[float] | None:
        rows = csv_rows(log)
        return [float(v) for v in rows[-1][2:]] if rows else None

    values = wait_for(latest, 20, "a sonar sample from the serial port")
    assert values == pytest.approx([57 * INCH, 0.5, 1.5])
    sensor.inches = 58
    wait_for(lambda: latest()[0] == pytest.approx(58 * INCH), 10, "the new range published")
    counters = c.status("s1")["measures"]["sonar"]["counters"]
    assert counters.get("pings", 0) >= 2 and not counters.get("dropouts")
