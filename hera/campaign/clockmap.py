"""The campaign's map from the sync clock (the fire logs' clock) to the wall clock.

Faults, log events and observed samples are stamped on the wall clock; the fire logs on the
sync clock (:mod:`hera.sync.clock`: ``CLOCK_BOOTTIME``), which a paused virtual machine
stops while its wall clock is set forward on resume, and which NTP's slewing leaves alone.
One offset taken at the start maps a firing after such a step seconds away from the faults
it is checked against (measured: a VM paused 18.7 s mid-campaign, and every firing of the
run's last 150 s placed 18.7 s early: a minority "firing through a cut", streams "never
flowing again"). So the runner samples both clocks together every :data:`PERIOD` s into
``clock.csv`` (``wall,sync`` per line, seconds) and :func:`sync_to_wall` interpolates the
offset between those samples and the journal's own pairs: a step lands within one period.
The same samples show when the machine stood still (:func:`pauses`): the checkers judge
nothing there, as inside a fault (every stream is silent, no node did anything wrong).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from hera.campaign import journal

ANCHORS = "clock.csv"
PERIOD = 0.25
"""s between two samples of the clocks."""


class AnchorWriter:
    """A thread appending ``wall,sync`` to ``folder/clock.csv`` every ``period`` s from
    :meth:`start` to :meth:`stop` (one line at each end too)."""

    def __init__(self, folder: Path, period: float = PERIOD) -> None:
        self.path = Path(folder) / ANCHORS
        self.period = period
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="clock-anchors", daemon=True)

    def start(self) -> AnchorWriter:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5.0)

    def _run(self) -> None:
        with open(self.path, "a", buffering=1) as out:  # line-buffered: a kill leaves lines
            while True:
                wall, sync = journal.now()
                out.write(f"{wall!r},{sync!r}\n")
                if self._stop.wait(self.period):
                    wall, sync = journal.now()
                    out.write(f"{wall!r},{sync!r}\n")
                    return


def read_anchors(folder: Path) -> list[tuple[float, float]]:
    """The (wall, sync) pairs of ``folder/clock.csv`` (none if it is missing; a torn or
    garbled line is skipped)."""
    path = Path(folder) / ANCHORS
    if not path.exists():
        return []
    out = []
    for line in path.read_text().splitlines():
        parts = line.split(",")
        if len(parts) != 2:
            continue
        try:
            out.append((float(parts[0]), float(parts[1])))
        except ValueError:
            continue
    return out


PAUSE_S = 0.2
"""A step of the offset (wall - sync) larger than this between two samples is a pause of the
machine; NTP's slewing moves it by milliseconds a second at most."""


def pauses(
    anchors: Iterable[tuple[float, float]], min_step: float = PAUSE_S
) -> list[tuple[float, float, float]]:
    """(wall from, wall to, seconds stood still) of each pause of the machine between two
    consecutive (wall, sync) samples of ``anchors`` (dense ones: ``clock.csv``'s)."""
    ps = sorted(anchors, key=lambda p: p[1])
    out = []
    for (w0, s0), (w1, s1) in zip(ps, ps[1:], strict=False):
        step = (w1 - s1) - (w0 - s0)
        if step > min_step:
            out.append((w0, w1, step))
    return out


def sync_to_wall(
    pairs: Iterable[tuple[float, float]], fallback_offset: float
) -> Callable[[float], float]:
    """A function from sync-clock seconds to wall-clock seconds: the offset (wall - sync)
    interpolated linearly between the (wall, sync) ``pairs`` read together, held at the
    nearest pair outside them; ``fallback_offset`` throughout when there are none (a
    campaign recorded before the anchors)."""
    ps = sorted((sync, wall - sync) for wall, sync in pairs)
    if not ps:
        return lambda c: c + fallback_offset
    syncs = np.array([p[0] for p in ps])
    offsets = np.array([p[1] for p in ps])

    def to_wall(c: float) -> float:
        return c + float(np.interp(c, syncs, offsets))

    return to_wall
