"""The whole machine's CPU time over a benchmark's measuring window.

A benchmark's own processes are not all that runs: other programs take the cores, and on a
virtual machine the host takes them too. Two figures of the whole machine:

- busy: the CPU time of every process (all its threads, user and system: ``/proc/<pid>/
  stat``) over the window's wall time times the cores. Processes alive at both ends of the
  window count; one that started or ended inside it does not.
- steal: the share the hypervisor took, from ``/proc/stat``'s first line (``man 5 proc``:
  clock ticks since boot per state: user, nice, system, idle, iowait, irq, softirq,
  steal, ...), and, sampling it every ``interval`` seconds through the window, the worst
  steal of one interval: a host that stalls the whole machine for 50 ms shows there even
  when the window's mean is low.

Why busy is not ``/proc/stat``'s: on a kernel with tick-based CPU accounting (here
``CONFIG_TICK_CPU_ACCOUNTING``, 250 Hz) a CPU's state is sampled at each tick, and work
that wakes on a wall-clock grid (every measure of a spec, by default) runs between two
ticks and is counted idle: a process busy 2 ms of every 20 ms, on the grid, shows as 10 %
of a core in its own times and 0.2 % in ``/proc/stat``'s (measured). A process's own times
are its scheduler's exact run time, split by the ticks' ratio of user to system, so their
sum is right. Where ``/proc`` does not exist (not Linux), no figures.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

PROC = Path("/proc")
PROC_STAT = PROC / "stat"
INTERVAL = 0.1
"""Seconds between samples of :class:`MachineWindow` (the worst-steal resolution)."""


@dataclass(frozen=True)
class CpuTimes:
    """Cumulative CPU time of all cores, in clock ticks."""

    steal: int
    total: int


def parse_proc_stat(text: str) -> CpuTimes:
    """The machine's times from ``/proc/stat``'s text; ValueError naming what is wrong."""
    line = text.split("\n", 1)[0]
    fields = line.split()
    if not fields or fields[0] != "cpu":
        raise ValueError(f"/proc/stat: the first line is not the 'cpu' total: {line[:60]!r}")
    try:
        ticks = [int(x) for x in fields[1:9]]
    except ValueError:
        raise ValueError(f"/proc/stat: the 'cpu' line has a non-integer field: {line!r}") from None
    if len(ticks) < 8:
        raise ValueError(f"/proc/stat: the 'cpu' line has {len(ticks)} fields, expected 8+")
    return CpuTimes(steal=ticks[7], total=sum(ticks))


def read_machine() -> CpuTimes | None:
    """The machine's times now, or None where ``/proc/stat`` cannot be read."""
    try:
        return parse_proc_stat(PROC_STAT.read_text())
    except OSError:
        return None


def _times(fields: list[bytes]) -> float:
    """CPU seconds (user + system) from the fields of ``/proc/<pid>/stat`` after the
    command's closing parenthesis."""
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _stat(pid: int | str, proc: Path = PROC) -> list[bytes]:
    """The fields of ``/proc/<pid>/stat`` after the command (which may hold spaces)."""
    with open(os.path.join(proc, str(pid), "stat"), "rb") as f:
        return f.read().rsplit(b")", 1)[1].split()


def cpu_seconds(pid: int) -> float:
    """CPU seconds (user + system, every thread) process ``pid`` has used; 0.0 once it is
    gone."""
    try:
        return _times(_stat(pid))
    except OSError:
        return 0.0


def rss_mb(pid: int) -> float:
    """Resident memory of process ``pid`` in MB; 0.0 once it is gone."""
    try:
        with open(PROC / str(pid) / "statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6
    except OSError:
        return 0.0


def process_times(proc: Path = PROC) -> dict[tuple[int, int], float]:
    """CPU seconds (user + system, every thread) of each process now, keyed by (pid, start
    time in ticks since boot), so a pid used again by another process is another key."""
    out: dict[tuple[int, int], float] = {}
    try:
        entries = os.scandir(proc)
    except OSError:
        return out
    with entries:
        for e in entries:
            if not e.name.isdigit():
                continue
            try:
                fields = _stat(e.name, proc)
                out[(int(e.name), int(fields[19]))] = _times(fields)
            except (OSError, IndexError, ValueError):  # ended meanwhile, or not a process
                continue
    return out


class MachineWindow:
    """Samples the machine through a window (:meth:`sleep`), then :meth:`figures`."""

    def __init__(
        self,
        interval: float = INTERVAL,
        read: Callable[[], CpuTimes | None] = read_machine,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
        processes: Callable[[], dict[tuple[int, int], float]] = process_times,
        cores: int | None = None,
    ) -> None:
        self._interval = interval
        self._read = read
        self._clock = clock
        self._sleep = sleep
        self._processes = processes
        self._cores = cores or os.cpu_count() or 1
        self._samples: list[CpuTimes] = []
        self._busy: float | None = None

    def sleep(self, seconds: float) -> None:
        """Wait ``seconds``, reading the machine at the start, every interval and the end
        (the processes' times at the start and the end)."""
        start = self._clock()
        before = self._processes()
        end = start + seconds
        while True:
            s = self._read()
            if s is None:  # nothing to sample here: just wait
                self._sleep(max(0.0, end - self._clock()))
                return
            self._samples.append(s)
            left = end - self._clock()
            if left <= 0:
                break
            self._sleep(min(self._interval, left))
        after = self._processes()
        elapsed = self._clock() - start
        if before and elapsed > 0:
            used = sum(max(0.0, t - before[k]) for k, t in after.items() if k in before)
            self._busy = 100.0 * used / (elapsed * self._cores)

    def figures(self) -> dict[str, float] | None:
        """``busy_pct`` and ``steal_pct`` of the machine over the window, ``worst_steal_pct``
        of one interval; None without two samples."""
        s = self._samples
        if len(s) < 2 or s[-1].total <= s[0].total or self._busy is None:
            return None
        total = s[-1].total - s[0].total
        worst = max(
            100.0 * (b.steal - a.steal) / (b.total - a.total)
            for a, b in zip(s, s[1:], strict=False)
            if b.total > a.total
        )
        return {
            "busy_pct": self._busy,
            "steal_pct": 100.0 * (s[-1].steal - s[0].steal) / total,
            "worst_steal_pct": worst,
        }
