"""One hosted sync group on the Zenoh bus: voter, candidate, leader and slot granting.

A :class:`GroupHost` runs on every node that hosts the service for a group. It declares:

- a liveliness token ``sync/<group>/host/<node>`` and watches the others' tokens;
- the ``vote`` queryable (its :class:`~hera.sync.election.Voter` answers);
- the ``acquire`` queryable: while this host is the leader, requests are queued and
  answered when their slot comes (long poll); otherwise dropped without a reply;
- the ``release`` subscriber;
- one runner thread: runs the vote rounds the core asks for (renewals, the rounds that
  back grants, pre-votes and elections), frees expired slots and hands out the next slot.

All decisions are :class:`~hera.sync.core.GroupCore`'s; this class only moves messages.
With a ``state_dir`` the voter's promise is kept in ``sync-<group>.promise.json`` there
(:mod:`hera.sync.promises`). Locking: one lock per group guards the core; no Zenoh
``get`` is made and no reply is sent while holding it (the local ``vote`` queryable
needs it).
"""

from __future__ import annotations

import logging
import os
import threading
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import zenoh

from hera.keys import Keys
from hera.sync import clock as sync_clock
from hera.sync.core import GroupCore, Reply, Round
from hera.sync.election import Timing
from hera.sync.promises import PromiseFile
from hera.sync.protocol import AcquireRequest, ProtocolError, Release, VoteReply, VoteRequest

log = logging.getLogger("hera.sync")

Clock = Callable[[], float]


def _finish(query: Any, payload: bytes | None = None) -> None:
    """Reply (if ``payload``, on the query's own key) and finalise a held query; never raises."""
    try:
        if payload is not None:
            query.reply(query.key_expr, payload)
    except Exception as e:  # the asker or our session may be gone: nothing to do
        log.debug("reply failed: %s", e)
    finally:
        try:
            query.drop()
        except Exception as e:
            log.debug("query drop failed: %s", e)


class GroupHost:
    """The sync service of one group on one host node (see the module docstring)."""

    def __init__(
        self,
        session: zenoh.Session,
        keys: Keys,
        group: str,
        node: str,
        hosts: list[str],
        timing: Timing,
        clock: Clock = sync_clock.now,
        state_dir: str | os.PathLike[str] | None = None,
    ) -> None:
        if node not in hosts:
            raise ValueError(f"sync group {group!r}: node {node!r} is not among its hosts {hosts}")
        self.session = session
        self.keys = keys
        self.group = group
        self.me = node
        self.timing = timing
        self.clock = clock
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._stop = False
        promises = (
            PromiseFile(Path(state_dir) / f"sync-{group}.promise.json", group)
            if state_dir is not None
            else None
        )
        self.core = GroupCore(node, hosts, timing, clock(), promises=promises)
        self.hosts = self.core.hosts
        self.bad_messages = 0
        self._decl: list[Any] = []
        self._thread: threading.Thread | None = None

    # -- keys -------------------------------------------------------------------------------

    def _key(self, rest: str) -> str:
        return self.keys.sync(self.group, rest)

    # -- lifecycle --------------------------------------------------------------------------

    def start(self) -> None:
        """Declare the tokens, queryables and subscriber, and start the runner thread."""
        s = self.session
        self._decl.append(
            s.liveliness().declare_subscriber(self._key("host/*"), self._on_alive, history=True)
        )
        self._decl.append(s.liveliness().declare_token(self._key(f"host/{self.me}")))
        self._decl.append(s.declare_queryable(self._key("vote"), self._on_vote, complete=True))
        self._decl.append(
            s.declare_queryable(self._key("acquire"), self._on_acquire, complete=True)
        )
        self._decl.append(s.declare_subscriber(self._key("release"), self._on_release))
        self._thread = threading.Thread(
            target=self._run, name=f"hera-sync-{self.group}", daemon=True
        )
        self._thread.start()

    def close(self) -> None:
        """Stop the runner, drop held requests and undeclare everything (idempotent)."""
        with self._lock:
            self._stop = True
            self._wake.notify_all()
            out = self.core.close()
        _send(out)
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        for d in reversed(self._decl):
            try:
                d.undeclare()
            except Exception as e:  # session already closed
                log.debug("undeclare failed: %s", e)
        self._decl.clear()

    # -- callbacks (Zenoh threads) ------------------------------------------------------------

    def _on_alive(self, sample: zenoh.Sample) -> None:
        node = str(sample.key_expr).rsplit("/", 1)[-1]
        with self._lock:
            self.core.on_alive(node, sample.kind == zenoh.SampleKind.PUT)
            self._wake.notify_all()

    def _on_vote(self, query: zenoh.Query) -> None:
        with query:
            try:
                req = VoteRequest.decode(query.payload.to_bytes() if query.payload else b"")
            except ProtocolError as e:
                self.bad_messages += 1
                log.warning("sync %s: bad vote request: %s", self.group, e)
                return
            with self._lock:
                reply = self.core.on_vote(req, self.clock())
                if reply is not None and reply.ok:
                    self._wake.notify_all()
            if reply is not None:
                query.reply(query.key_expr, reply.encode())

    def _on_acquire(self, query: zenoh.Query) -> None:
        try:
            req = AcquireRequest.decode(query.payload.to_bytes() if query.payload else b"")
        except ProtocolError as e:
            self.bad_messages += 1
            log.warning("sync %s: bad acquire request: %s", self.group, e)
            _finish(query)
            return
        with self._lock:
            out = self.core.on_acquire(req, self.clock(), query)
            self._wake.notify_all()
        _send(out)

    def _on_release(self, sample: zenoh.Sample) -> None:
        try:
            rel = Release.decode(sample.payload.to_bytes())
        except ProtocolError as e:
            self.bad_messages += 1
            log.warning("sync %s: bad release: %s", self.group, e)
            return
        with self._lock:
            out = self.core.on_release(rel, self.clock())
        _send(out)

    # -- runner ---------------------------------------------------------------------------------

    def _run(self) -> None:
        while True:
            with self._lock:
                if self._stop:
                    return
                out, rnd = self.core.step(self.clock())
            _send(out)
            if rnd is not None:
                while rnd is not None:
                    replies = self._ask(rnd)
                    with self._lock:
                        out, rnd = self.core.round_done(rnd, replies, self.clock())
                        if self._stop:
                            rnd = None
                    _send(out)
                continue
            with self._lock:
                if not self._stop:
                    self._wake.wait(self.core.sleep_for(self.clock()))

    def _ask(self, rnd: Round) -> list[VoteReply]:
        """Run a vote round (lock not held): the answers received until a majority said yes,
        every host answered, or L/6 passed."""
        got: list[VoteReply] = []
        try:
            replies = self.session.get(
                self._key("vote"),
                payload=rnd.request(self.me).encode(),
                target=zenoh.QueryTarget.ALL,
                consolidation=zenoh.ConsolidationMode.NONE,
                timeout=self.timing.lease / 6,
            )
            for r in replies:
                if not r.ok:
                    continue
                try:
                    got.append(VoteReply.decode(r.ok.payload.to_bytes()))
                except ProtocolError:
                    self.bad_messages += 1
                    continue
                if self.core.tally(rnd, got)[0]:
                    break
        except Exception as e:  # session closed or cut off: the round simply fails
            log.debug("sync %s: vote round failed: %s", self.group, e)
        return got

    # -- status ---------------------------------------------------------------------------------

    def status(self) -> dict[str, Any]:
        """JSON-able state of this group on this host."""
        with self._lock:
            out = self.core.status(self.clock())
        out["bad_messages"] = self.bad_messages
        return out


def _send(out: Iterable[Reply]) -> None:
    """Answer or drop held requests, as the core said (lock not held)."""
    for ticket, payload in out:
        _finish(ticket, payload)
