"""The latest-value store every node keeps (ARCHITECTURE.md part 2, REFERENCE "Core").

It holds the latest sample per (name, node): seq, measurement time, arrival time, values.
Within one incarnation of its producer (a random id drawn at each start of its process,
:mod:`hera.wire`), a sample is accepted only if its seq is strictly greater than the one
held for that (name, node), so duplicates and stale or reordered deliveries never overwrite
fresher data. A sample of another incarnation is taken as the producer's restart and
accepted: neither a restart nor a forged huge seq can freeze a source (a forger's sample is
replaced by the real producer's next one; access control keeps forgers off the bus).

A store may be bounded: it takes samples only from the cluster's ``nodes`` and at most
``max_names_per_node`` names from each; every refusal is counted with its reason
(``stale``, ``unknown_node``, ``too_many_names``).
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
    inc: int = 0

    def age(self, now: float | None = None) -> float:
        """Seconds since arrival on this node's monotonic clock."""
        return (time.monotonic() if now is None else now) - self.arrival


class Store:
    """Thread-safe latest sample per (name, node), optionally bounded (module docstring)."""

    def __init__(
        self, nodes: Iterable[str] | None = None, max_names_per_node: int | None = None
    ) -> None:
        self._data: dict[str, dict[str, Sample]] = {}
        self._cond = threading.Condition()
        self._version = 0
        self._listeners: tuple = ()
        self._waiting = 0  # threads in wait_newer (guarded by _cond)
        self._nodes = None if nodes is None else frozenset(nodes)
        self._max_names = max_names_per_node
        self._names_of: dict[str, int] = {}
        self.accepted = 0
        self.stale = 0
        self.incarnations = 0
        self.refused: dict[str, int] = {}

    def offer(self, name: str, node: str, msg: Message, arrival: float | None = None) -> bool:
        """Store ``msg`` for (name, node) if it is newer; return whether it was kept."""
        return self.offer_why(name, node, msg, arrival) is None

    def offer_why(
        self, name: str, node: str, msg: Message, arrival: float | None = None
    ) -> str | None:
        """Store ``msg`` for (name, node) if it is newer; None when kept, else the reason
        it was refused: ``stale`` (not newer within its incarnation), ``unknown_node`` (not
        a node of the cluster) or ``too_many_names`` (its node's quota of names is full)."""
        return self.offer_sample(name, node, msg, arrival)[0]

    def offer_sample(
        self, name: str, node: str, msg: Message, arrival: float | None = None
    ) -> tuple[str | None, Sample]:
        """:meth:`offer_why` that also returns the :class:`Sample` made of ``msg``, the one
        now held when it was kept (a later read may find a newer one)."""
        mono = time.monotonic() if arrival is None else arrival
        sample = Sample(
            name, node, msg.seq, msg.t, mono, wallclock.now(), msg.values, msg.grant, msg.inc
        )
        with self._cond:
            per_name = self._data.get(name)
            held = per_name.get(node) if per_name is not None else None
            if held is None:
                why = self._admit(node)
                if why is not None:
                    self.refused[why] = self.refused.get(why, 0) + 1
                    return why, sample
                if per_name is None:
                    per_name = self._data[name] = {}
                self._names_of[node] = self._names_of.get(node, 0) + 1
            elif held.inc == msg.inc:
                if held.seq >= msg.seq:
                    self.stale += 1
                    self.refused["stale"] = self.refused.get("stale", 0) + 1
                    return "stale", sample
            else:
                self.incarnations += 1
            per_name[node] = sample
            self.accepted += 1
            self._version += 1
            if self._waiting:  # notify_all is a Python call layer: only when one waits
                self._cond.notify_all()
            listeners = self._listeners
        for fn in listeners:
            fn(sample)
        return None, sample

    def _admit(self, node: str) -> str | None:
        """Why a new source of ``node`` cannot be taken, or None (lock held)."""
        if self._nodes is not None and node not in self._nodes:
            return "unknown_node"
        if self._max_names is not None and self._names_of.get(node, 0) >= self._max_names:
            return "too_many_names"
        return None

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

    def seqs_of_node(self, node: str) -> dict[str, tuple[int, int]]:
        """Every name this store holds from ``node``, with its (incarnation, seq)."""
        with self._cond:
            return {
                n: (per[node].inc, per[node].seq) for n, per in self._data.items() if node in per
            }

    def names(self) -> list[str]:
        """The names held, sorted."""
        with self._cond:
            return sorted(self._data)

    def snapshot(self) -> list[Sample]:
        """Every held sample, sorted by (name, node)."""
        return sorted(self.samples(), key=lambda s: (s.name, s.node))

    def samples(self) -> list[Sample]:
        """Every held sample, in no particular order (:meth:`snapshot` without its sort)."""
        with self._cond:
            return [s for per in self._data.values() for s in per.values()]

    @property
    def version(self) -> int:
        """Grows by one at every accepted sample."""
        with self._cond:
            return self._version

    def wait_newer(self, version: int, timeout: float) -> int:
        """Block until a sample is accepted after ``version`` or ``timeout`` s pass;
        return the current version."""
        with self._cond:
            self._waiting += 1
            try:
                self._cond.wait_for(lambda: self._version > version, timeout)
            finally:
                self._waiting -= 1
            return self._version

    def cursor(self, names: Iterable[str]) -> Cursor:
        """A reader that returns each (name, node) sample once (see :class:`Cursor`)."""
        return Cursor(self, names)


class Cursor:
    """Remembers the (incarnation, seq) it last returned per (name, node): "newer than what
    I used last" (a sample of a new incarnation is new)."""

    def __init__(self, store: Store, names: Iterable[str]) -> None:
        self._store = store
        self._names = tuple(names)
        self._used: dict[tuple[str, str], tuple[int, int]] = {}

    def new(self, max_age: float | None = None) -> list[Sample]:
        """Samples not returned before (and at most ``max_age`` s old), marking them used."""
        out = []
        for name in self._names:
            for s in self._store.fresh(name, max_age=max_age):
                inc, seq = self._used.get((name, s.node), (s.inc, 0))
                if inc != s.inc or s.seq > seq:
                    self._used[(name, s.node)] = (s.inc, s.seq)
                    out.append(s)
        return out
