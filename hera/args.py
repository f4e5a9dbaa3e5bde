"""The replicated args store: calibrations and shared arguments on every node.

The original kept a table replicated by multicall, lost when the whole cluster stopped. Ours:

- ``put(key, value)`` on any node publishes on ``hera/<cluster>/args/<key>``; every node
  subscribes and keeps the entry with the latest ``(stamp, origin)`` (last writer wins,
  ties broken by origin node name, so all replicas agree);
- stamps are hybrid logical clocks in ns: a write is stamped ``max(wall clock, the largest
  stamp seen + 1)``, so a write always wins over what its writer has seen, even when its
  clock is behind; a stamp further than ``max_skew_ns`` ahead of the receiver's wall clock
  is refused and counted (``future``), from the bus, from peers and from the state file, so
  no write from the far future can win forever;
- every node answers queries on ``hera/<cluster>/args/**`` with all entries it holds, and a
  starting node asks all live peers before it starts its measures (:meth:`recover`); it
  asks again each time a peer comes up (:meth:`on_peer_up`): a write made while the link
  to that peer did not exist yet (two nodes starting together) reaches it then;
- writes go out with blocking congestion control: Zenoh's default drops a put when a
  link's queue is full, and a dropped write would be missing on that replica until the
  next peer-up;
- each node persists its entries to ``<state_dir>/args.msgpack`` (written atomically), so a
  restart of the whole cluster keeps them;
- ``delete(key)`` writes a tombstone that wins like any later write (so a node that was down
  during the delete does not bring the value back); a deleted key reads as absent;
- ``add_listener(fn)``: ``fn(key, value, deleted)`` after every change an entry takes, from
  this node or a peer (the worker uses it to tell a measure at its next step).

Values are anything msgpack carries (numbers, strings, lists, maps).
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgpack
import zenoh

from hera import wallclock
from hera.bus import query_all
from hera.keys import Keys, check_chunk

log = logging.getLogger("hera.args")


class ArgsStore:
    """Last-writer-wins replicated key/value store (local only when ``session`` is None)."""

    FILE = "args.msgpack"

    def __init__(
        self,
        node: str,
        session: Any = None,
        keys: Keys | None = None,
        state_dir: str | os.PathLike | None = None,
        max_skew_ns: int = 1_000_000_000,
    ) -> None:
        self.node = node
        self.max_skew_ns = int(max_skew_ns)
        self._clock = 0
        self._session = session
        self._keys = keys
        self._path = Path(state_dir) / self.FILE if state_dir is not None else None
        self._lock = threading.Lock()
        self._save_lock = threading.Lock()  # one save at a time: the last one is the newest
        self._pull_lock = threading.Lock()
        self._pull_wanted = self._pulling = False  # see on_peer_up
        self._entries: dict[str, tuple[int, str, Any, bool]] = {}  # stamp, origin, value, deleted
        self._listeners: tuple[Callable[[str, Any, bool], None], ...] = ()
        self.rejected: dict[str, int] = {}
        self._sub = self._queryable = None
        if self._path is not None:
            self._load()
        if session is not None:
            if keys is None:
                raise ValueError("ArgsStore needs keys when it has a session")
            self._sub = session.declare_subscriber(keys.args("**"), self._on_sample)
            self._queryable = session.declare_queryable(
                keys.args("**"), self._on_query, complete=True
            )

    # -- reading -------------------------------------------------------------------------
    def get(self, key: str, default: Any = None) -> Any:
        """The current value of ``key``, or ``default`` (also when it was deleted)."""
        with self._lock:
            entry = self._entries.get(key)
        return default if entry is None or entry[3] else entry[2]

    def entry(self, key: str) -> tuple[int, str, Any] | None:
        """``(stamp ns, origin node, value)`` of ``key``, None if absent or deleted."""
        with self._lock:
            entry = self._entries.get(key)
        return None if entry is None or entry[3] else entry[:3]

    def items(self) -> dict[str, Any]:
        """A copy of every key and value (deleted keys left out)."""
        with self._lock:
            return {k: e[2] for k, e in self._entries.items() if not e[3]}

    def __contains__(self, key: str) -> bool:
        with self._lock:
            entry = self._entries.get(key)
        return entry is not None and not entry[3]

    def add_listener(self, fn: Callable[[str, Any, bool], None]) -> None:
        """Call ``fn(key, value, deleted)`` after every change of an entry (keep it short:
        it runs on the thread that merged the change)."""
        with self._lock:
            self._listeners = (*self._listeners, fn)

    def remove_listener(self, fn: Callable[[str, Any, bool], None]) -> None:
        """Stop calling ``fn``."""
        with self._lock:
            self._listeners = tuple(f for f in self._listeners if f != fn)

    # -- writing -------------------------------------------------------------------------
    def put(self, key: str, value: Any) -> None:
        """Set ``key`` on every node (last writer wins); raises ValueError on a bad key or a
        value msgpack cannot carry."""
        self._write(key, value, False)

    def delete(self, key: str) -> None:
        """Delete ``key`` on every node (a tombstone, last writer wins like a put)."""
        self._write(key, None, True)

    def _write(self, key: str, value: Any, deleted: bool) -> None:
        for chunk in key.split("/"):
            check_chunk(chunk, "args key element")
        with self._lock:
            stamp = self._clock = max(wallclock.now_ns(), self._clock + 1)
        payload = _pack(stamp, self.node, value, deleted)  # fails early on unpackable values
        self._merge(key, stamp, self.node, value, deleted)
        if self._session is not None:
            self._session.put(
                self._keys.args(key), payload, congestion_control=zenoh.CongestionControl.BLOCK
            )

    def recover(self, timeout: float = 1.0) -> int:
        """Ask every live peer for all entries and merge them; return how many were new."""
        if self._session is None:
            return 0
        merged = 0
        for sample in query_all(self._session, self._keys.args("**"), timeout):
            key = self._key_of(str(sample.key_expr))
            entry = _unpack(sample.payload.to_bytes())
            if key is None or entry is None:
                self._refuse("malformed")
                continue
            merged += self._merge(key, *entry)
        return merged

    def on_peer_up(self, node: str) -> None:
        """A peer ``node`` came up (its liveliness token): ask every live peer for all
        entries again, on a thread of its own (never on the bus's callback thread), so what
        either side wrote before their link existed is merged on both. Peers that come up
        together share pulls: one runs at a time, and one more after it if a peer came up
        meanwhile (every peer-up is followed by a pull that starts after it)."""
        if node == self.node or self._session is None:
            return
        with self._pull_lock:
            self._pull_wanted = True
            if self._pulling:
                return
            self._pulling = True
        threading.Thread(target=self._pull, name="args-pull", daemon=True).start()

    def _pull(self) -> None:
        while True:
            with self._pull_lock:
                if not self._pull_wanted:
                    self._pulling = False
                    return
                self._pull_wanted = False
            try:
                got = self.recover(timeout=1.0)
                if got:
                    log.info("took %d args entries when a peer came up", got)
            except Exception as e:  # a closing session: the next start recovers anyway
                log.debug("args pull after a peer came up failed: %s", e)

    @property
    def clock(self) -> int:
        """The largest stamp written or accepted (ns): the next write is stamped above."""
        with self._lock:
            return self._clock

    def close(self) -> None:
        """Undeclare the subscriber and queryable (the session stays open)."""
        for handle in (self._sub, self._queryable):
            if handle is not None:
                with contextlib.suppress(Exception):
                    handle.undeclare()
        self._sub = self._queryable = None

    # -- internals -----------------------------------------------------------------------
    def _key_of(self, key_expr: str) -> str | None:
        head = self._keys.args("")
        return key_expr[len(head) :] if key_expr.startswith(head) else None

    def _refuse(self, why: str) -> None:
        with self._lock:
            self.rejected[why] = self.rejected.get(why, 0) + 1

    def _future(self, stamp: int) -> bool:
        return stamp > wallclock.now_ns() + self.max_skew_ns

    def _merge(self, key: str, stamp: int, origin: str, value: Any, deleted: bool = False) -> int:
        if self._future(stamp):
            self._refuse("future")
            log.warning("refused args write %s from %s stamped in the future", key, origin)
            return 0
        with self._lock:
            self._clock = max(self._clock, stamp)
            held = self._entries.get(key)
            if held is not None and (held[0], held[1]) >= (stamp, origin):
                return 0
            self._entries[key] = (stamp, origin, value, deleted)
            listeners = self._listeners
        self._save()
        for fn in listeners:
            try:
                fn(key, value, deleted)
            except Exception:  # a listener's bug must not lose the write
                log.exception("args listener failed on %s", key)
        return 1

    def _on_sample(self, sample: Any) -> None:
        key = self._key_of(str(sample.key_expr))
        entry = _unpack(sample.payload.to_bytes())
        if key is None or entry is None:
            self._refuse("malformed")
            log.warning("rejected malformed args sample on %s", str(sample.key_expr)[:200])
            return
        self._merge(key, *entry)

    def _on_query(self, query: Any) -> None:
        with query:
            with self._lock:
                entries = list(self._entries.items())
            for key, (stamp, origin, value, deleted) in entries:
                query.reply(self._keys.args(key), _pack(stamp, origin, value, deleted))

    def _load(self) -> None:
        try:
            raw = self._path.read_bytes()
        except FileNotFoundError:
            return
        try:
            data = msgpack.unpackb(raw, raw=False)
            for key, (stamp, origin, value, *deleted) in data.items():
                if self._future(int(stamp)):
                    self._refuse("future")
                    log.error(
                        "dropping args entry %s of the state file: stamped in the future", key
                    )
                    continue
                self._entries[key] = (int(stamp), str(origin), value, bool(deleted and deleted[0]))
                self._clock = max(self._clock, int(stamp))
        except Exception as e:  # a damaged file must not stop the node: peers still have it
            log.error("ignoring unreadable args file %s: %s", self._path, e)

    def _save(self) -> None:
        """Write every entry to the state file (atomically). Saves are serialised and each
        takes its snapshot inside the save: two threads saving at once used to let the
        older snapshot replace the newer file (a calibration stored by one measure while
        another measure's was being written was lost on disk)."""
        if self._path is None:
            return
        with self._save_lock:
            with self._lock:
                data = {k: list(e) for k, e in self._entries.items()}
            self._path.parent.mkdir(parents=True, exist_ok=True)
            tmp = self._path.with_suffix(".tmp")
            tmp.write_bytes(msgpack.packb(data, use_bin_type=True))
            os.replace(tmp, self._path)


def _pack(stamp: int, origin: str, value: Any, deleted: bool = False) -> bytes:
    msg = {"ts": stamp, "origin": origin, "value": value}
    if deleted:
        msg["deleted"] = True
    try:
        return msgpack.packb(msg, use_bin_type=True)
    except (TypeError, ValueError) as e:
        raise ValueError(f"args value cannot be stored: {e}") from None


def _unpack(payload: bytes) -> tuple[int, str, Any, bool] | None:
    try:
        msg = msgpack.unpackb(payload, raw=False)
        stamp, origin = msg["ts"], msg["origin"]
        if not isinstance(stamp, int) or isinstance(stamp, bool) or not isinstance(origin, str):
            return None
        if stamp < 0 or len(origin) > 64:
            return None
        return stamp, origin, msg["value"], msg.get("deleted") is True
    except Exception:
        return None
