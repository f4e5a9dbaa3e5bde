"""The latest-value store every node keeps (ARCHITECTURE.md part 2, REFERENCE "Core").

It holds the latest sample per (name, node): seq, measurement time, arrival time, values.
A sample is accepted only if its seq is strictly greater than the one held for that
(name, node), so duplicates and stale or reordered deliveries never overwrite fresher data.
Samples are never consumed: readers filter by age, by measurement time, or with a
:class:`Cursor` that remembers the seqs it has already used. All methods are thread-safe.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from hera import wallclock
from hera.wire import Message


@dataclass(frozen=True, slots=True)
class Sample:
    """One stored sample.

    ``t`` is the measurement time (producer's clock, epoch seconds); ``arrival`` is this
    node's monotonic clock (seconds) when the sample was accepted; ``arrival_wall`` is this
    node's wall clock at that moment (epoch seconds).
    """

    name: str
    node: str
    seq: int
    t: float
    arrival: float
    arrival_wall: float
    values: tuple[float, ...]
    grant: tuple[int, int] | None = None

    def age(self, now: float | None = None) -> float:
        """Seconds since arrival on this node's monotonic clock."""
        return (time.monotonic() if now is None else now) - self.arrival


class Store:
    """Thread-safe latest sample per (name, node)."""

    def __init__(self) -> None:
        self._data: dict[str, dict[str, Sample]] = {}
        self._cond = threading.Condition()
        self._version = 0
        self._listeners: tuple = ()
        self.accepted = 0
        self.stale = 0

    def offer(self, name: str, node: str, msg: Message, arrival: float | None = None) -> bool:
        """Store ``msg`` for (name, node) if its seq is newer; return whether it was kept."""
        mono = time.monotonic() if arrival is None else arrival
        wall = wallclock.now()
        sample = Sample(name, node, msg.seq, msg.t, mono, wall, msg.values, msg.grant)
        with self._cond:
            per_name = self._data.setdefault(name, {})
            held = per_name.get(node)
            if held is not None and held.seq >= msg.seq:
                self.stale += 1
                return False
            per_name[node] = sample
            self.accepted += 1
            self._version += 1
            self._cond.notify_all()
            listeners = self._listeners
        for fn in listeners:
            fn(sample)
        return True

    def add_listener(self, fn: Callable[[Sample], None]) -> None:
        """Call ``fn(sample)`` for every sample accepted from now on (on the caller's thread
        of :meth:`offer`; keep it short)."""
        with self._cond:
            self._listeners = (*self._listeners, fn)

    def remove_listener(self, fn: Callable[[Sample], None]) -> None:
        """Stop calling ``fn``."""
        with self._cond:
            self._listeners = tuple(f for f in self._listeners if f != fn)

    def get(self, name: str) -> list[Sample]:
        """All nodes' latest samples of ``name`` (the original's ``get(name)``), by node."""
        with self._cond:
            return sorted(self._data.get(name, {}).values(), key=lambda s: s.node)

    def get_one(self, name: str, node: str) -> Sample | None:
        """The latest sample of ``name`` from ``node``, or None."""
        with self._cond:
            return self._data.get(name, {}).get(node)

    def fresh(
        self,
        name: str,
        max_age: float | None = None,
        newer_than: float | None = None,
        now: float | None = None,
    ) -> list[Sample]:
        """Samples of ``name`` that arrived at most ``max_age`` s ago (monotonic) and whose
        measurement time is strictly later than ``newer_than`` (epoch s), by node."""
        now = time.monotonic() if now is None else now
        return [
            s
            for s in self.get(name)
            if (max_age is None or now - s.arrival <= max_age)
            and (newer_than is None or s.t > newer_than)
        ]

    def latest_seq(self, name: str, node: str) -> int:
        """The seq held for (name, node), 0 if none."""
        s = self.get_one(name, node)
        return 0 if s is None else s.seq

    def seqs_of_node(self, node: str) -> dict[str, int]:
        """Every name this store holds from ``node``, with its seq."""
        with self._cond:
            return {n: per[node].seq for n, per in self._data.items() if node in per}

    def names(self) -> list[str]:
        """The names held, sorted."""
        with self._cond:
            return sorted(self._data)

    def snapshot(self) -> list[Sample]:
        """Every held sample, sorted by (name, node)."""
        with self._cond:
            return sorted(
                (s for per in self._data.values() for s in per.values()),
                key=lambda s: (s.name, s.node),
            )

    @property
    def version(self) -> int:
        """Grows by one at every accepted sample."""
        with self._cond:
            return self._version

    def wait_newer(self, version: int, timeout: float) -> int:
        """Block until a sample is accepted after ``version`` or ``timeout`` s pass;
        return the current version."""
        with self._cond:
            self._cond.wait_for(lambda: self._version > version, timeout)
            return self._version

    def cursor(self, names: Iterable[str]) -> Cursor:
        """A reader that returns each (name, node) sample once (see :class:`Cursor`)."""
        return Cursor(self, names)


class Cursor:
    """Remembers the seq it last returned per (name, node): "newer than what I used last"."""

    def __init__(self, store: Store, names: Iterable[str]) -> None:
        self._store = store
        self._names = tuple(names)
        self._used: dict[tuple[str, str], int] = {}

    def new(self, max_age: float | None = None) -> list[Sample]:
        """Samples not returned before (and at most ``max_age`` s old), marking them used."""
        out = []
        for name in self._names:
            for s in self._store.fresh(name, max_age=max_age):
                if s.seq > self._used.get((name, s.node), 0):
                    self._used[(name, s.node)] = s.seq
                    out.append(s)
        return out
