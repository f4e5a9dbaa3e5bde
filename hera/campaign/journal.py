"""The fault journal: what was done to the cluster, when, one JSON line per event.

``<campaign dir>/faults.jsonl``; every line ``{"event", "index", "name", "kind", "nodes",
"t", "clock", ...}`` with ``event`` one of ``start`` (the fault struck), ``end`` (it was
undone), ``error`` (it could not be done: ``error`` says why), ``note`` (``extra``: what
else is worth knowing, e.g. who held the slot when the leader was killed). ``t`` is the wall
clock (epoch s) and ``clock`` the sync clock (:mod:`hera.sync.clock`, the fire logs' clock)
read at the same moment; an ``end`` (and a flap's ``healed``) is stamped when the undoing
began, since the fault is no longer whole from then on (healing the links of several
namespaces takes tens of ms). Faults injected by hand (``hera inject`` on a campaign's cluster)
are journaled too, with ``index`` -1.

Each line is appended with one ``write`` on an ``O_APPEND`` file, so two writers (the
campaign and a person's ``hera inject``) never interleave within a line.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hera.sync import clock as sync_clock

FILE = "faults.jsonl"


TRIES = 3
"""Reads of the two clocks per pair (:func:`now` keeps the tightest)."""


def now(
    tries: int = TRIES,
    wall: Callable[[], float] = time.time,
    sync: Callable[[], float] = sync_clock.now,
) -> tuple[float, float]:
    """(wall clock, sync clock) read together: the sync clock read between two reads of the
    wall clock, ``tries`` times, and the try whose two wall reads lie closest kept (the
    wall time its midpoint). A process descheduled between two reads (milliseconds under
    load) pairs the clocks that far apart, and a map between them built on such a pair is
    off by as much; a deschedule in every try of a few microseconds is unlikely."""
    reads = []
    for _ in range(max(1, tries)):
        w0 = wall()
        c = sync()
        w1 = wall()
        reads.append((w1 - w0, (w0 + w1) / 2.0, c))
    _, w, c = min(reads)
    return w, c


def append(
    folder: Path, event: str, at: tuple[float, float] | None = None, **fields: Any
) -> dict[str, Any]:
    """Append one event to ``folder/faults.jsonl``; return it. ``at``: the (wall, sync)
    clocks it happened at (:func:`now` read then), default now."""
    t, clock = at if at is not None else now()
    entry = {"event": event, "t": t, "clock": clock, **fields}
    line = (json.dumps(entry, default=str) + "\n").encode()
    fd = os.open(Path(folder) / FILE, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, line)
    finally:
        os.close(fd)
    return entry


def read(folder: Path) -> list[dict[str, Any]]:
    """Every event of the journal in order (a torn last line is skipped)."""
    path = Path(folder) / FILE
    if not path.exists():
        return []
    out = []
    for line in path.read_text().splitlines():
        try:
            out.append(json.loads(line))
        except ValueError:
            continue
    return out
