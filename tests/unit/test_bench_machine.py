"""hera.bench.machine: the machine's busy and stolen CPU time over a window."""

from __future__ import annotations

import pytest

from hera.bench.machine import CpuTimes, MachineWindow, parse_proc_stat, read_machine

STAT = "cpu  100 5 20 800 10 1 4 30 7 0\ncpu0 50 2 10 400 5 0 2 15 3 0\nintr 12345\n"


def test_the_cpu_line_splits_into_busy_steal_and_total():
    t = parse_proc_stat(STAT)
    # busy: user + nice + system + irq + softirq; guest (7) is inside user already
    assert t == CpuTimes(busy=100 + 5 + 20 + 1 + 4, steal=30, total=130 + 800 + 10 + 30)


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("intr 1 2 3\n", "the first line is not the 'cpu' total: 'intr 1 2 3'"),
        ("cpu 1 2 x 4 5 6 7 8\n", "the 'cpu' line has a non-integer field: 'cpu 1 2 x 4 5 6 7 8'"),
        ("cpu 1 2 3 4\n", "the 'cpu' line has 4 fields, expected 8+"),
        ("", "the first line is not the 'cpu' total: ''"),
    ],
)
def test_a_malformed_proc_stat_is_named(text, says):
    with pytest.raises(ValueError) as e:
        parse_proc_stat(text)
    assert str(e.value) == f"/proc/stat: {says}"


class Fake:
    """A scripted machine: readings in turn, a clock that sleeping advances."""

    def __init__(self, readings):
        self.readings = list(readings)
        self.now = 0.0
        self.slept: list[float] = []

    def read(self):
        return self.readings.pop(0) if self.readings else None

    def sleep(self, s):
        self.slept.append(s)
        self.now += s


def window(fake: Fake, interval=0.1) -> MachineWindow:
    return MachineWindow(interval, read=fake.read, clock=lambda: fake.now, sleep=fake.sleep)


def test_the_window_gives_the_means_and_the_worst_interval():
    # four samples 0.1 s apart on 2 cores (20 ticks an interval); the second interval has
    # 10 ticks stolen: 50 % of it, 10/60 of the window
    readings = [
        CpuTimes(busy=0, steal=0, total=0),
        CpuTimes(busy=10, steal=0, total=20),
        CpuTimes(busy=15, steal=10, total=40),
        CpuTimes(busy=30, steal=10, total=60),
    ]
    fake = Fake(readings)
    w = window(fake)
    w.sleep(0.3)
    assert fake.slept == pytest.approx([0.1, 0.1, 0.1])
    f = w.figures()
    assert f == pytest.approx({"busy_pct": 50.0, "steal_pct": 100 / 6, "worst_steal_pct": 50.0})


def test_without_proc_stat_the_window_still_waits_and_has_no_figures():
    fake = Fake([])
    w = window(fake)
    w.sleep(2.0)
    assert fake.now == pytest.approx(2.0)
    assert w.figures() is None


def test_this_machine_can_be_read():
    t = read_machine()
    assert t is not None and t.total > 0 and 0 <= t.steal <= t.total and t.busy <= t.total
