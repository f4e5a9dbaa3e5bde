"""hera.bench.machine: the machine's busy and stolen CPU time over a window."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest

from hera.bench.machine import (
    CpuTimes,
    MachineWindow,
    parse_proc_stat,
    process_times,
    read_machine,
)

STAT = "cpu  100 5 20 800 10 1 4 30 7 0\ncpu0 50 2 10 400 5 0 2 15 3 0\nintr 12345\n"


def test_the_cpu_line_gives_steal_and_total():
    t = parse_proc_stat(STAT)
    # total: user .. steal; guest (7) is inside user already
    assert t == CpuTimes(steal=30, total=100 + 5 + 20 + 800 + 10 + 1 + 4 + 30)


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
    """A scripted machine: /proc/stat readings and process tables in turn, a clock that
    sleeping advances."""

    def __init__(self, readings, processes=()):
        self.readings = list(readings)
        self.tables = list(processes)
        self.now = 0.0
        self.slept: list[float] = []

    def read(self):
        return self.readings.pop(0) if self.readings else None

    def processes(self):
        return self.tables.pop(0) if self.tables else {}

    def sleep(self, s):
        self.slept.append(s)
        self.now += s


def window(fake: Fake, interval=0.1) -> MachineWindow:
    return MachineWindow(
        interval,
        read=fake.read,
        clock=lambda: fake.now,
        sleep=fake.sleep,
        processes=fake.processes,
        cores=2,
    )


def test_the_window_gives_the_means_and_the_worst_interval():
    # four samples 0.1 s apart on 2 cores (20 ticks an interval); the second interval has
    # 10 ticks stolen: 50 % of it, 10/60 of the window. The processes used 0.3 s of the
    # 0.6 s the two cores had: 50 % busy
    readings = [
        CpuTimes(steal=0, total=0),
        CpuTimes(steal=0, total=20),
        CpuTimes(steal=10, total=40),
        CpuTimes(steal=10, total=60),
    ]
    fake = Fake(readings, [{(1, 5): 1.0, (2, 7): 0.5}, {(1, 5): 1.2, (2, 7): 0.6}])
    w = window(fake)
    w.sleep(0.3)
    assert fake.slept == pytest.approx([0.1, 0.1, 0.1])
    f = w.figures()
    assert f == pytest.approx({"busy_pct": 50.0, "steal_pct": 100 / 6, "worst_steal_pct": 50.0})


def test_busy_counts_only_processes_alive_at_both_ends():
    # pid 2 ended, pid 3 started, pid 4 is another process by the end (a new start time):
    # none of them counts; pid 1 used 0.5 s of the 2 x 1 s
    before = {(1, 5): 1.0, (2, 7): 3.0, (4, 9): 8.0}
    after = {(1, 5): 1.5, (3, 11): 4.0, (4, 20): 0.1}
    fake = Fake([CpuTimes(0, 0), CpuTimes(0, 200)], [before, after])
    w = window(fake, interval=1.0)
    w.sleep(1.0)
    assert w.figures()["busy_pct"] == pytest.approx(25.0)


def test_without_proc_stat_the_window_still_waits_and_has_no_figures():
    fake = Fake([])
    w = window(fake)
    w.sleep(2.0)
    assert fake.now == pytest.approx(2.0)
    assert w.figures() is None


def test_this_machine_can_be_read():
    t = read_machine()
    assert t is not None and t.total > 0 and 0 <= t.steal <= t.total
    mine = process_times()
    assert any(pid == os.getpid() and cpu > 0 for (pid, _), cpu in mine.items()), len(mine)


GRID_BURNER = """
import time
end = time.time() + {seconds}
while time.time() < end:
    time.sleep((0 - time.time()) % 0.02)  # on the 20 ms wall-clock grid, as measures are
    t = time.perf_counter()
    while time.perf_counter() - t < 0.002:
        pass
"""


def test_busy_sees_work_that_wakes_on_the_wall_clock_grid():
    # 2 ms of every 20 ms on the grid: about 10 % of a core, which a tick-sampled
    # /proc/stat counts as nearly idle on this kernel; the processes' own times see it
    child = subprocess.Popen([sys.executable, "-c", GRID_BURNER.format(seconds=4)])
    try:
        time.sleep(1.0)  # started and on the grid
        mine = next(k for k in process_times() if k[0] == child.pid)
        before = process_times()[mine]
        w = MachineWindow()
        w.sleep(2.0)
        used = process_times()[mine] - before
    finally:
        child.wait(10)
    assert used > 0.1, used  # it ran: about 0.2 s of CPU in the 2 s
    cores = os.cpu_count() or 1
    assert w.figures()["busy_pct"] * cores / 100 * 2.0 >= 0.9 * used, (w.figures(), used)
