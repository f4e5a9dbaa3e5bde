"""One hosted sync group on the Zenoh bus: voter, candidate, leader and slot granting.

A :class:`GroupHost` runs on every node that hosts the service for a group. It declares:

- a liveliness token ``sync/<group>/host/<node>`` and watches the others' tokens;
- the ``vote`` queryable (its :class:`~hera.sync.election.Voter` answers);
- the ``acquire`` queryable: while this host is the leader, requests are queued and
  answered when their slot comes (long poll); otherwise dropped without a reply;
- the ``release`` subscriber;
- one runner thread: renews the leader's lease, runs for election when the group has no
  fresh leader, frees expired slots and hands out the next slot.

Locking: one lock per group guards all state; no Zenoh ``get`` is made while holding it
(the local ``vote`` queryable needs it).
"""

from __future__ import annotations

import logging
import random
import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh
from hera.sync.election import Term, Timing, Voter
from hera.sync.protocol import (
    AcquireRequest,
    GrantReply,
    ProtocolError,
    Release,
    VoteReply,
    VoteRequest,
)
from hera.sync.slots import SlotTable, Waiting

from hera.keys import Keys

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
        clock: Clock = time.monotonic,
    ) -> None:
        if node not in hosts:
            raise ValueError(f"sync group {group!r}: node {node!r} is not among its hosts {hosts}")
        self.session = session
        self.keys = keys
        self.group = group
        self.me = node
        self.hosts = sorted(set(hosts))
        self.majority = len(self.hosts) // 2 + 1
        self.timing = timing
        self.clock = clock
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._stop = False
        now = clock()
        self.voter = Voter(node, timing, now)
        self.term: Term | None = None
        self.table: SlotTable | None = None
        self.alive: set[str] = {node}
        self.seen_epoch = 0
        self.vacant_since: float | None = None
        self.next_try = now
        self.terms = 0
        self.demotions: dict[str, int] = {}
        self.vote_rounds = 0
        self._renew_sent = float("-inf")
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
            gone = self._end_term("closed") if self.term else []
        for w in gone:
            _finish(w.ticket)
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
            if sample.kind == zenoh.SampleKind.PUT:
                self.alive.add(node)
            elif node != self.me:
                self.alive.discard(node)
            self._wake.notify_all()

    def _is_alive(self, node: str) -> bool:
        return node == self.me or node in self.alive

    def _on_vote(self, query: zenoh.Query) -> None:
        with query:
            try:
                req = VoteRequest.decode(query.payload.to_bytes() if query.payload else b"")
            except ProtocolError as e:
                self.bad_messages += 1
                log.warning("sync %s: bad vote request: %s", self.group, e)
                return
            if req.candidate not in self.hosts:
                return
            with self._lock:
                ask = self.voter.would if req.probe else self.voter.request
                ok = ask(req.epoch, req.candidate, self.clock(), self._is_alive)
                reply = VoteReply(self.me, ok, self.voter.epoch, self.voter.candidate)
                if ok:
                    self._wake.notify_all()
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
            too_long = req.duration > self.timing.max_slot
            if self.term is None or self.table is None or self._stop or too_long:
                held = False
            else:
                now = self.clock()
                # a grace after the asker's timeout, so that its next attempt finds and
                # replaces this request, keeping its place in the queue
                give_up = now + req.timeout + self.timing.lease / 2
                w = Waiting(req.holder, req.duration, now, give_up, query)
                old = self.table.enqueue(w)
                if old is not None:
                    _finish(old.ticket)
                self._pump(now)
                held = True
        if not held:
            _finish(query)

    def _on_release(self, sample: zenoh.Sample) -> None:
        try:
            rel = Release.decode(sample.payload.to_bytes())
        except ProtocolError as e:
            self.bad_messages += 1
            log.warning("sync %s: bad release: %s", self.group, e)
            return
        with self._lock:
            if self.table is not None and self.table.release(rel.epoch, rel.token, rel.used):
                self._pump(self.clock())

    # -- leader state (lock held) ---------------------------------------------------------------

    def _pump(self, now: float) -> None:
        """Hand out the slot if it is free and the term may grant (lock held)."""
        term, table = self.term, self.table
        if term is None or table is None:
            return
        for w in table.expire(now):
            _finish(w.ticket)
        res = table.grant(now, lambda d: term.may_grant(d, self.clock()))
        if res is None:
            return
        w, g = res
        reply = GrantReply(g.epoch, g.token, SlotTable.grant_duration(w, g), self.me)
        _finish(w.ticket, reply.encode())

    def _end_term(self, reason: str) -> list[Waiting]:
        """Demote (lock held); return the queued requests, to be finalised by the caller."""
        self.demotions[reason] = self.demotions.get(reason, 0) + 1
        log.info("sync %s: %s ends term %s (%s)", self.group, self.me, self.term, reason)
        gone = self.table.clear() if self.table else []
        self.term, self.table = None, None
        self.voter.unstick(self.me)
        return gone

    # -- runner ---------------------------------------------------------------------------------

    def _run(self) -> None:
        while True:
            action = None
            with self._lock:
                if self._stop:
                    return
                now = self.clock()
                gone: list[Waiting] = []
                if self.term is not None and not self.term.tick(now):
                    gone = self._end_term("lease or pause")
                if self.term is not None:
                    if now - self._renew_sent >= self.timing.renew:
                        action = ("renew", self.term.epoch)
                    else:
                        self._pump(now)
                elif self._may_run(now):
                    action = ("elect", max(self.voter.epoch, self.seen_epoch) + 1)
            for w in gone:
                _finish(w.ticket)
            if action is not None:
                kind, epoch = action
                if kind == "renew" or self._round("probe", epoch):
                    self._round(kind, epoch)
                continue
            with self._lock:
                if not self._stop:
                    self._wake.wait(self._sleep_for(self.clock()))

    def _may_run(self, now: float) -> bool:
        """True if this host should run for election now (lock held)."""
        if now < self.voter.quiet_until:
            return False
        leader = self.voter.leader(now)
        if leader is not None and self._is_alive(leader):
            self.vacant_since = None
            return False
        if self.vacant_since is None:
            self.vacant_since = now
            live = sorted(h for h in self.hosts if self._is_alive(h))
            rank = live.index(self.me)
            self.next_try = max(self.next_try, now + rank * self.timing.lease / 4)
        return now >= self.next_try

    def _sleep_for(self, now: float) -> float:
        times = [now + self.timing.renew]
        if self.term is not None:
            times.append(self._renew_sent + self.timing.renew)
            if self.table is not None:
                ev = self.table.next_event()
                if ev is not None:
                    times.append(ev)
                if now < self.term.granting_from():
                    times.append(self.term.granting_from())
        elif self.vacant_since is not None:
            times.append(self.next_try)
        return max(0.0005, min(times) - now)

    def _round(self, kind: str, epoch: int) -> bool:
        """Ask every host to confirm ``(epoch, me)`` (``kind`` renew, elect, or probe: a
        pre-vote); act on the answer (lock not held). True if a majority said yes."""
        asked_at = self.clock()
        if kind == "renew":
            self._renew_sent = asked_at
        acks: set[str] = set()
        higher = 0
        self.vote_rounds += 1
        try:
            replies = self.session.get(
                self._key("vote"),
                payload=VoteRequest(epoch, self.me, probe=kind == "probe").encode(),
                target=zenoh.QueryTarget.ALL,
                consolidation=zenoh.ConsolidationMode.NONE,
                timeout=self.timing.lease / 6,
            )
            for r in replies:
                if not r.ok:
                    continue
                try:
                    v = VoteReply.decode(r.ok.payload.to_bytes())
                except ProtocolError:
                    self.bad_messages += 1
                    continue
                if v.voter not in self.hosts:
                    continue
                higher = max(higher, v.epoch)
                if v.ok and (kind == "probe" or (v.epoch == epoch and v.candidate == self.me)):
                    acks.add(v.voter)
                if len(acks) >= self.majority:
                    break
        except Exception as e:  # session closed or cut off: the round simply fails
            log.debug("sync %s: vote round failed: %s", self.group, e)
        now = self.clock()
        gone: list[Waiting] = []
        with self._lock:
            self.seen_epoch = max(self.seen_epoch, higher)
            won = len(acks) >= self.majority
            if self._stop or (kind == "probe" and won):
                return won
            if kind == "renew":
                term = self.term
                if term is None or term.epoch != epoch:
                    pass
                elif won:
                    term.confirmed(asked_at, now)
                    if term.over:
                        gone = self._end_term("late confirmation")
                    else:
                        self._pump(now)
                elif higher > epoch:
                    gone = self._end_term("higher epoch")
                # else: no majority this time; the lease runs out unless a renewal succeeds
            elif won and self.term is None:
                self.term = Term(epoch, self.timing, asked_at, now)
                self.table = SlotTable(epoch, expiry_margin=self.timing.margin)
                self.terms += 1
                self._renew_sent = asked_at
                self.vacant_since = None
                log.info("sync %s: %s elected, epoch %d", self.group, self.me, epoch)
            else:
                # Lost (split vote or a fresh leader elsewhere): back off with jitter.
                self.next_try = (
                    now + self.timing.lease / 2 + random.uniform(0, self.timing.lease / 2)
                )
        for w in gone:
            _finish(w.ticket)
        return won

    # -- status ---------------------------------------------------------------------------------

    def status(self) -> dict[str, Any]:
        """JSON-able state of this group on this host."""
        with self._lock:
            now = self.clock()
            term = self.term
            if term is not None:
                role = "leader" if now >= term.granting_from() else "leader-waiting"
                leader: str | None = self.me
                epoch = term.epoch
            else:
                role = "starting" if now < self.voter.quiet_until else "follower"
                leader = self.voter.leader(now)
                epoch = self.voter.epoch
            out: dict[str, Any] = {
                "role": role,
                "leader": leader,
                "epoch": epoch,
                "hosts": self.hosts,
                "alive": sorted(h for h in self.hosts if self._is_alive(h)),
                "terms_won": self.terms,
                "demotions": dict(self.demotions),
                "vote_rounds": self.vote_rounds,
                "bad_messages": self.bad_messages,
                "queue": [],
                "grants_per_s": 0.0,
                "wait": {},
            }
            if self.table is not None:
                out.update(self.table.status(now))
            return out
