"""The whole machine's CPU time over a benchmark's measuring window, from ``/proc/stat``.

A benchmark's own processes are not all that runs: other programs take the cores, and on a
virtual machine the host takes them too. ``/proc/stat``'s first line counts, in clock
ticks since boot, the time all CPUs spent per state (``man 5 proc``): user, nice, system,
idle, iowait, irq, softirq, steal (a virtual CPU ready to run while the hypervisor ran
something else), then guest time (already inside user and nice). From two readings:

- busy: the share of the machine's CPU time that was neither idle nor iowait nor steal;
- steal: the share the hypervisor took;

and, sampling every ``interval`` seconds through the window, the worst steal of one
interval: a host that stalls the whole machine for 50 ms shows there even when the
window's mean is low. Where ``/proc/stat`` does not exist (not Linux), no figures.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

PROC_STAT = Path("/proc/stat")
INTERVAL = 0.1
"""Seconds between samples of :class:`MachineWindow` (the worst-steal resolution)."""


@dataclass(frozen=True)
class CpuTimes:
    """Cumulative CPU time of all cores, in clock ticks."""

    busy: int
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
    user, nice, system, idle, iowait, irq, softirq, steal = ticks
    busy = user + nice + system + irq + softirq
    return CpuTimes(busy=busy, steal=steal, total=busy + idle + iowait + steal)


def read_machine() -> CpuTimes | None:
    """The machine's times now, or None where ``/proc/stat`` cannot be read."""
    try:
        return parse_proc_stat(PROC_STAT.read_text())
    except OSError:
        return None


class MachineWindow:
    """Samples the machine through a window (:meth:`sleep`), then :meth:`figures`."""

    def __init__(
        self,
        interval: float = INTERVAL,
        read: Callable[[], CpuTimes | None] = read_machine,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        self._interval = interval
        self._read = read
        self._clock = clock
        self._sleep = sleep
        self._samples: list[CpuTimes] = []

    def sleep(self, seconds: float) -> None:
        """Wait ``seconds``, reading the machine at the start, every interval and the end."""
        end = self._clock() + seconds
        while True:
            s = self._read()
            if s is None:  # nothing to sample here: just wait
                self._sleep(max(0.0, end - self._clock()))
                return
            self._samples.append(s)
            left = end - self._clock()
            if left <= 0:
                return
            self._sleep(min(self._interval, left))

    def figures(self) -> dict[str, float] | None:
        """``busy_pct`` and ``steal_pct`` of the machine over the window, ``worst_steal_pct``
        of one interval; None without two samples."""
        s = self._samples
        if len(s) < 2 or s[-1].total <= s[0].total:
            return None
        total = s[-1].total - s[0].total
        worst = max(
            100.0 * (b.steal - a.steal) / (b.total - a.total)
            for a, b in zip(s, s[1:], strict=False)
            if b.total > a.total
        )
        return {
            "busy_pct": 100.0 * (s[-1].busy - s[0].busy) / total,
            "steal_pct": 100.0 * (s[-1].steal - s[0].steal) / total,
            "worst_steal_pct": worst,
        }
