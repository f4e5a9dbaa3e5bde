"""A node's data path: publishing its samples, taking everyone's into the store.

- :meth:`DataPath.publish` gives each sample of this node's measures the next seq of its
  (name, node) and puts it on ``data/<name>/<node>``;
- :meth:`DataPath.on_data` decodes every sample it subscribed to (:mod:`hera.wire`), offers
  it to the store (which keeps it only if its seq is newer), records the publish-to-store
  transit and writes the CSV log when this node logs;
- :meth:`DataPath.want` subscribes by interest: a node takes only the names its measures
  read (``"prefix*"`` for a prefix), or everything (a full mirror) when one of them may
  read anything or the node logs every sender; a store does not grow with the cluster.
- :meth:`DataPath.on_seq_query` answers ``seq/<name>/<node>`` queries with the
  (incarnation, seq) it holds of each name, so a restarted node continues its seqs
  (REFERENCE "Core framework"); :meth:`DataPath.recover_seqs` takes only the answers of the
  node's own previous incarnation, so no forged seq can be adopted.

Every sample carries this process's incarnation (a random id drawn at start). Bad input
(malformed payloads, bad keys, names longer than :data:`hera.keys.MAX_CHUNK`, senders that
are not nodes of the cluster, more names from one node than the store takes, unpublishable
values) is rejected, counted by kind and never reaches the store. A declared source whose
samples are all refused (at least :data:`REFUSED_ALARM` in a row) is reported in the status.
The CSV log writes only the sources the spec's ``[logging]`` asks for.
"""

from __future__ import annotations

import logging
import secrets
import threading
from collections import deque
from collections.abc import Iterable, Mapping
from typing import Any

import msgpack
import zenoh

from hera import wire
from hera.csvlog import CsvLog
from hera.keys import Keys
from hera.measure import Reading
from hera.store import Store

log = logging.getLogger("hera.datapath")

MAX_RATE_HZ = 100_000
"""No measure publishes faster: a recovered seq above what the node's previous incarnation
could have published since it started is not its own (a forgery) and is not adopted."""
REFUSED_ALARM = 10
"""A declared source refused this many times in a row, with nothing accepted in between,
is reported in the status (``refused_sources``)."""


def new_incarnation() -> int:
    """A random incarnation id in [1, 2**63)."""
    return secrets.randbits(63) or 1


class DataPath:
    """Publishes this node's samples and stores everyone's (see module docstring)."""

    TRANSIT_WINDOW = 4096
    SOURCES_CACHED = 4096
    """Parsed data keys kept (key -> (name, node)); past that many, keys are parsed anew."""

    def __init__(
        self,
        node: str,
        keys: Keys,
        store: Store,
        csv: CsvLog | None = None,
        log_names: tuple[str, ...] = (),
        declared: frozenset[tuple[str, str]] | None = None,
        incarnation: int | None = None,
    ) -> None:
        """``declared``: the (name, node) sources of the spec: the CSV log writes only these
        (and only ``log_names`` among them when given), and their refusals are tracked."""
        self.node = node
        self.keys = keys
        self.store = store
        self.csv = csv
        self.log_names = frozenset(log_names)
        self.declared = declared
        self.incarnation = new_incarnation() if incarnation is None else incarnation
        self.previous_incarnation: int | None = None
        self.previous_start: float | None = None
        """Wall-clock start (epoch s) of the previous incarnation, when known."""
        self._streaks: dict[tuple[str, str], tuple[int, str]] = {}
        self._sources: dict[str, tuple[str, str]] = {}
        self.rejected: dict[str, int] = {}
        self.last_rejection: str | None = None
        self.transit: dict[str, deque[float]] = {}
        self._seq: dict[str, int] = {}
        self._seq_lock = threading.Lock()
        self._publishers: dict[str, Any] = {}
        self._session: zenoh.Session | None = None
        self._handles: list[Any] = []
        self._subs: dict[str, Any] = {}
        self._wanted: set[str] = set()
        self._mirror: Any = None

    def attach(self, session: zenoh.Session) -> None:
        """Answer seq queries; samples come in through :meth:`want`."""
        self._session = session
        self._handles.append(
            session.declare_queryable(self.keys.seq("*", "*"), self.on_seq_query, complete=True)
        )

    def want(self, names: Iterable[str] | None) -> None:
        """Take the samples of ``names`` from now on: ``name``, ``prefix*`` (every name
        starting with it) or ``name/node`` (one sender only); None: every sample of the
        cluster (a full mirror, which replaces the rest)."""
        names = None if names is None else tuple(n for n in dict.fromkeys(names))
        with self._seq_lock:
            if self._mirror is not None:
                return
            if names is None:
                self._mirror = self._session.declare_subscriber(
                    f"{self.keys.prefix}/data/**", self.on_data
                )
                for sub in self._subs.values():
                    sub.undeclare()
                self._subs.clear()
                return
            for n in names:
                if n not in self._wanted:
                    key = self.keys.data_read(n)
                    self._subs[n] = self._session.declare_subscriber(key, self.on_data)
                    self._wanted.add(n)

    @property
    def interest(self) -> list[str] | None:
        """The names this node takes (None: every one)."""
        return None if self._mirror is not None else sorted(self._wanted)

    def close(self) -> None:
        """Undeclare subscriptions and publishers (before the session closes)."""
        subs = [*self._subs.values(), *([self._mirror] if self._mirror is not None else [])]
        for h in (*subs, *reversed(self._handles), *self._publishers.values()):
            try:
                h.undeclare()
            except Exception as e:  # a closing session may already have dropped them
                log.debug("undeclare failed: %s", e)
        self._handles.clear()
        self._publishers.clear()
        self._subs.clear()
        self._mirror = None

    # -- seqs ---------------------------------------------------------------------------
    def seq(self, name: str) -> int:
        """The last seq this node published (or recovered) for its measure ``name``."""
        with self._seq_lock:
            return self._seq.get(name, 0)

    def adopt_seqs(self, seqs: Mapping[str, Any]) -> None:
        """Continue after the given seqs (recovered from peers): keep the larger of each."""
        with self._seq_lock:
            for name, seq in seqs.items():
                if (
                    isinstance(seq, int)
                    and not isinstance(seq, bool)
                    and seq > self._seq.get(name, 0)
                ):
                    self._seq[name] = seq

    # -- publishing ---------------------------------------------------------------------
    def publish(self, name: str, reading: Reading, grant: Any = None) -> None:
        """Publish one sample of this node's measure ``name`` with the next seq."""
        with self._seq_lock:
            seq = self._seq.get(name, 0) + 1
            if seq > wire.MAX_SEQ:  # the end of the range: go on as a new incarnation
                self.incarnation, seq = new_incarnation(), 1
                self._seq.clear()
            try:
                payload = wire.encode(
                    seq,
                    reading.t,
                    reading.values,
                    (grant.epoch, grant.token) if grant else None,
                    self.incarnation,
                )
            except (wire.WireError, TypeError, ValueError) as e:
                self.reject("invalid_output", f"measure {name} returned unpublishable values: {e}")
                return
            self._seq[name] = seq
            pub = self._publishers.get(name)
            if pub is None:
                pub = self._session.declare_publisher(self.keys.data(name, self.node))
                self._publishers[name] = pub
        pub.put(payload)

    # -- receiving ----------------------------------------------------------------------
    def on_data(self, sample: zenoh.Sample) -> None:
        """Decode, check and store one sample from the bus."""
        key = str(sample.key_expr)
        try:
            source = self._sources.get(key)
            if source is None:
                source = self.keys.parse_data(key)
                if len(self._sources) < self.SOURCES_CACHED:
                    self._sources[key] = source
            name, node = source
            msg = wire.decode(sample.payload.to_bytes())
        except wire.WireError as e:
            self.reject("oversized" if "too large" in str(e) else "malformed", f"{key}: {e}")
            return
        except ValueError as e:
            self.reject("bad_key", str(e))
            return
        why, held = self.store.offer_sample(name, node, msg)
        tracked = self.declared is not None and source in self.declared
        if why is not None:
            if why != "stale":
                self.reject(why, f"{key}: {why.replace('_', ' ')}")
            if tracked:
                n, _ = self._streaks.get(source, (0, why))
                self._streaks[source] = (n + 1, why)
            return
        if tracked and source in self._streaks:
            del self._streaks[source]
        # publish-to-store transit on the wall clock (exact on one host; needs NTP across)
        window = self.transit.get(node)
        if window is None:
            window = self.transit[node] = deque(maxlen=self.TRANSIT_WINDOW)
        window.append(held.arrival_wall - held.t)
        if self.csv is not None and self.logs(name, node):
            self.csv.write(held)

    def logs(self, name: str, node: str) -> bool:
        """Whether the CSV log writes (name, node): a declared source, of ``log_names``."""
        if self.log_names and name not in self.log_names:
            return False
        return self.declared is None or (name, node) in self.declared

    def refused_sources(self) -> dict[str, dict[str, Any]]:
        """Sources refused at least :data:`REFUSED_ALARM` times in a row, by
        ``name/node``, with the count and the last reason."""
        return {
            f"{name}/{node}": {"refused": n, "reason": why}
            for (name, node), (n, why) in list(self._streaks.items())
            if n >= REFUSED_ALARM
        }

    def reject(self, kind: str, message: str, count: int = 1) -> None:
        """Count ``count`` rejected inputs of ``kind`` (logged the first times, then every
        1000)."""
        self.rejected[kind] = self.rejected.get(kind, 0) + count
        self.last_rejection = message
        if self.rejected[kind] <= 3 or self.rejected[kind] % 1000 == 0:
            log.warning("rejected input (%s, %d so far): %s", kind, self.rejected[kind], message)

    def on_seq_query(self, query: zenoh.Query) -> None:
        """Answer ``seq/<any>/<node>`` with ``{name: [incarnation, seq]}``: every source of
        ``<node>`` this node holds (its own published seqs for itself)."""
        with query:
            head = self.keys.seq("", "")
            parts = str(query.key_expr)[len(head) - 1 :].split("/")
            node = parts[-1] if len(parts) == 2 else None
            if node is None or "*" in node:
                return
            seqs = {k: list(v) for k, v in self.store.seqs_of_node(node).items()}
            if node == self.node:
                with self._seq_lock:
                    for k, v in self._seq.items():
                        seqs[k] = [self.incarnation, v]
            query.reply(self.keys.seq("all", node), msgpack.packb(seqs))

    def recover_seqs(self, session: zenoh.Session, timeout: float) -> int:
        """Ask live peers for the latest seqs of this node's measures and adopt those of
        its previous incarnation (:attr:`previous_incarnation`; none when it is unknown);
        return how many answers were refused as not of that incarnation."""
        import time

        from hera.bus import query_all

        refused = 0
        start = self.previous_start
        ceiling = None if start is None else (time.time() - start) * MAX_RATE_HZ + 1000
        for sample in query_all(session, self.keys.seq("*", self.node), timeout):
            try:
                seqs = msgpack.unpackb(sample.payload.to_bytes(), raw=False)
                if not isinstance(seqs, dict):
                    raise ValueError(f"expected a map, got {type(seqs).__name__}")
                mine = {}
                for name, entry in seqs.items():
                    if isinstance(entry, list) and entry[:1] == [self.incarnation]:
                        # its own queryable's answer to this very query, holding what it
                        # adopted from an earlier answer: no peer had it (nothing published)
                        continue
                    if (
                        isinstance(entry, list)
                        and len(entry) == 2
                        and self.previous_incarnation is not None
                        and entry[0] == self.previous_incarnation
                        and isinstance(entry[1], int)
                        and (ceiling is None or entry[1] <= ceiling)
                    ):
                        mine[name] = entry[1]
                    elif self.previous_incarnation is not None:
                        refused += 1
                self.adopt_seqs(mine)
            except Exception as e:  # a peer's bad reply must not stop this node's start
                log.warning("ignoring malformed seq reply: %s", e)
        if refused:
            self.reject(
                "foreign_seq", f"{refused} seq answers not of incarnation of this node", refused
            )
        return refused

    def percentiles(self) -> dict[str, dict[str, float]]:
        """Publish-to-store transit per sender (ms): p50, p99, max, n."""
        return {n: _percentiles(w) for n, w in list(self.transit.items())}


def _percentiles(window: deque[float]) -> dict[str, float]:
    xs = sorted(window)
    if not xs:
        return {}
    pick = lambda q: round(xs[min(len(xs) - 1, int(q * len(xs)))] * 1e3, 4)  # noqa: E731
    return {"p50": pick(0.5), "p99": pick(0.99), "max": round(xs[-1] * 1e3, 4), "n": len(xs)}
