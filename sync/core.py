"""One host's part of one sync group, as a pure state machine with an injected clock.

:class:`GroupCore` is everything a host decides: how its voter answers, when it runs for
election or renews, which queued request gets the slot and what the grant says. It does no
I/O and reads no clock: every input carries ``now``, and it answers with what to send.
:class:`hera.sync.group.GroupHost` feeds it from Zenoh; the tests drive it through a
simulated network with clocks that can freeze.

Held requests are opaque ``ticket`` objects; the core answers ``(ticket, payload)`` pairs
(``payload`` None: drop the request without a reply) for the caller to send.

A leader grants a queued request only after a vote round *started after the request
arrived* came back confirmed by a majority at its epoch (as Raft's ReadIndex): so a leader
that was paused, or whose clock stopped, grants nothing once a majority has moved on to a
higher epoch, whatever its clock says. Requests arriving while no such round is under way
start one; under load one round backs every request that arrived before it. A request is
granted at most L after it arrived (its asker asks again by then), so a grant's duration
is at most L + D.
"""

from __future__ import annotations

import random
import secrets
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from hera.sync.election import Term, Timing, Voter
from hera.sync.promises import Promises
from hera.sync.protocol import AcquireRequest, GrantReply, Release, VoteReply, VoteRequest
from hera.sync.slots import SlotTable, Waiting

Reply = tuple[Any, bytes | None]
"""What to do with a held request: answer ``ticket`` with ``payload``, or drop it (None)."""


@dataclass(frozen=True, slots=True)
class Round:
    """A vote round to run: ask every host to confirm ``(epoch, me)``.

    ``kind``: ``probe`` (pre-vote), ``elect`` or ``renew``; ``asked_at``: this host's clock
    just before the requests go out; ``seq``: rounds started by this host, this one included.
    """

    kind: str
    epoch: int
    asked_at: float
    seq: int = 0

    def request(self, me: str) -> VoteRequest:
        return VoteRequest(self.epoch, me, probe=self.kind == "probe")


class GroupCore:
    """The sync service of one group on one host (see the module docstring)."""

    def __init__(
        self,
        me: str,
        hosts: list[str],
        timing: Timing,
        now: float,
        rng: random.Random | None = None,
        promises: Promises | None = None,
        incarnation: str | None = None,
    ) -> None:
        """``incarnation``: this process's id (random by default): with ``me`` it names the
        terms it leads (``term_id``), so a host restarted with its promises lost that is
        elected at an epoch it led before is not taken for its old term by a client."""
        if me not in hosts:
            raise ValueError(f"node {me!r} is not among the hosts {hosts}")
        self.me = me
        self.term_id = f"{me}#{incarnation or secrets.token_hex(4)}"
        self.hosts = sorted(set(hosts))
        self.majority = len(self.hosts) // 2 + 1
        self.timing = timing
        self.rng = rng or random.Random()
        self.voter = Voter(me, timing, now, promises)
        self.term: Term | None = None
        self.table: SlotTable | None = None
        self.alive: set[str] = {me}
        self.seen_epoch = 0
        self.vacant_since: float | None = None
        self.next_try = now
        self.terms = 0
        self.demotions: dict[str, int] = {}
        self.vote_rounds = 0
        self.renew_sent = float("-inf")
        self.rounds_started = 0
        self.backed_seq = 0  # the latest round confirmed by a majority in the current term
        self.closed = False

    # -- liveliness -----------------------------------------------------------------------

    def on_alive(self, node: str, present: bool) -> None:
        """A host's liveliness token appeared (``present``) or vanished."""
        if present:
            self.alive.add(node)
        elif node != self.me:
            self.alive.discard(node)

    def is_alive(self, node: str) -> bool:
        return node == self.me or node in self.alive

    # -- voter ------------------------------------------------------------------------------

    def on_vote(self, req: VoteRequest, now: float) -> VoteReply | None:
        """Answer a vote request (None: the candidate is not a host of the group)."""
        if req.candidate not in self.hosts:
            return None
        ask = self.voter.would if req.probe else self.voter.request
        ok = ask(req.epoch, req.candidate, now, self.is_alive)
        return VoteReply(self.me, ok, self.voter.epoch, self.voter.candidate)

    # -- slot requests ------------------------------------------------------------------------

    def on_acquire(self, req: AcquireRequest, now: float, ticket: Any) -> list[Reply]:
        """A measure asks for a slot: queue it while leader (long poll), else drop it.

        An asker that knows a newer term than ours (a higher epoch, or ours under another
        leader: promises were lost) makes us step down, to be re-elected above it."""
        term = self.term
        if term is None or self.table is None or self.closed:
            return [(ticket, None)]
        if req.known_epoch > term.epoch or (
            req.known_epoch == term.epoch and req.known_leader not in ("", self.term_id)
        ):
            self.seen_epoch = max(self.seen_epoch, req.known_epoch)
            return [(ticket, None), *self.end_term("a client knows a newer term")]
        if req.duration > self.timing.max_slot:
            return [(ticket, None)]
        # a grace after the asker's timeout, so that its next attempt finds and replaces
        # this request, keeping its place in the queue
        give_up = now + req.timeout + self.timing.lease / 2
        w = Waiting(req.holder, req.duration, now, give_up, ticket, round_seq=self.rounds_started)
        out: list[Reply] = []
        old = self.table.enqueue(w)
        if old is not None:
            out.append((old.ticket, None))
        out += self.pump(now)
        return out

    def on_release(self, rel: Release, now: float) -> list[Reply]:
        """A holder gives its slot back (only the holder, for the slot it holds)."""
        if self.table is not None and self.table.release(
            rel.epoch, rel.token, rel.holder, rel.used
        ):
            return self.pump(now)
        return []

    def _backed(self, w: Waiting) -> bool:
        """A majority confirmed this term in a round started after ``w`` arrived."""
        return w.round_seq < self.backed_seq

    def _fresh(self, w: Waiting, now: float) -> bool:
        """``w`` arrived at most L ago, so its grant's duration is at most L + D."""
        return now - w.received_at <= self.timing.lease

    def _unbacked(self) -> bool:
        """A queued request arrived after the last round started: it needs a new round."""
        return self.table is not None and any(
            w.round_seq >= self.rounds_started for w in self.table.queue.values()
        )

    def pump(self, now: float) -> list[Reply]:
        """Free an expired slot, drop given-up requests, hand out the slot if it may."""
        term, table = self.term, self.table
        if term is None or table is None:
            return []
        out: list[Reply] = [(w.ticket, None) for w in table.expire(now)]
        res = table.grant(
            now,
            lambda w: self._backed(w) and term.may_grant(w.duration, now),
            lambda w: self._fresh(w, now),
        )
        if res is not None:
            w, g = res
            reply = GrantReply(g.epoch, g.token, SlotTable.grant_duration(w, g), self.term_id)
            out.append((w.ticket, reply.encode()))
        return out

    # -- terms ----------------------------------------------------------------------------------

    def end_term(self, reason: str, lost_at: float | None = None) -> list[Reply]:
        """Demote: forget the slot table; every queued request is dropped.

        ``lost_at``: the term ended because no majority confirmed it in time (its lease
        ran out, or the confirmation came back too late) at this time; this host then
        stands back for one lease before it runs again, whatever its rank. It is the one
        host known to have just failed to reach a majority (cut off, stopped, its link
        flapping): the hosts that kept in touch elect one of theirs meanwhile, where it
        would otherwise be first to run again and, if its link came back for a moment,
        win the group back only to lose it again at its next cut (liveness only).
        """
        self.demotions[reason] = self.demotions.get(reason, 0) + 1
        gone = self.table.clear() if self.table else []
        self.term, self.table = None, None
        self.voter.unstick(self.me)
        if lost_at is not None and len(self.hosts) > 1:
            self.next_try = max(self.next_try, lost_at + self.timing.lease)
        return [(w.ticket, None) for w in gone]

    def close(self) -> list[Reply]:
        """The host is going away: end the term (if any); nothing more is granted."""
        self.closed = True
        return self.end_term("closed") if self.term is not None else []

    def step(self, now: float) -> tuple[list[Reply], Round | None]:
        """A turn of the runner: check the term, then either a vote round to run now (the
        caller runs it and calls :meth:`round_done`) or grants to send."""
        out: list[Reply] = []
        if self.closed:
            return out, None
        if self.term is not None and not self.term.tick(now):
            out += self.end_term("lease or pause", lost_at=now)
        if self.term is not None:
            if now - self.renew_sent >= self.timing.renew or self._unbacked():
                self.renew_sent = now
                return out, self._round("renew", self.term.epoch, now)
            out += self.pump(now)
            return out, None
        if self._may_run(now):
            return out, self._round("probe", max(self.voter.epoch, self.seen_epoch) + 1, now)
        return out, None

    def _round(self, kind: str, epoch: int, now: float) -> Round:
        self.vote_rounds += 1
        self.rounds_started += 1
        return Round(kind, epoch, now, self.rounds_started)

    def _may_run(self, now: float) -> bool:
        """True if this host should run for election now."""
        if now < self.voter.quiet_until:
            return False
        leader = self.voter.leader(now)
        if leader is not None and self.is_alive(leader):
            self.vacant_since = None
            return False
        if self.vacant_since is None:
            self.vacant_since = now
            live = sorted(h for h in self.hosts if self.is_alive(h))
            rank = live.index(self.me)
            self.next_try = max(self.next_try, now + rank * self.timing.lease / 4)
        return now >= self.next_try

    def tally(self, rnd: Round, replies: Iterable[VoteReply]) -> tuple[bool, int]:
        """Did ``replies`` win ``rnd``, and the highest epoch they show.

        Won: a majority of the hosts said yes; for an election, this host's own voter among
        them, so that the epoch is saved here before the term starts (a restarted process
        never runs a term of its previous life again)."""
        acks: set[str] = set()
        higher = 0
        for v in replies:
            if v.voter not in self.hosts:
                continue
            higher = max(higher, v.epoch)
            if v.ok and (rnd.kind == "probe" or (v.epoch == rnd.epoch and v.candidate == self.me)):
                acks.add(v.voter)
        won = len(acks) >= self.majority and (rnd.kind != "elect" or self.me in acks)
        return won, higher

    def round_done(
        self, rnd: Round, replies: Iterable[VoteReply], now: float
    ) -> tuple[list[Reply], Round | None]:
        """Act on the answers to ``rnd``; return grants to send and, after a won pre-vote,
        the election round to run next."""
        won, higher = self.tally(rnd, replies)
        self.seen_epoch = max(self.seen_epoch, higher)
        out: list[Reply] = []
        if self.closed:
            return out, None
        if rnd.kind == "probe":
            if won:
                return out, self._round("elect", rnd.epoch, now)
            self._back_off(now)
        elif rnd.kind == "renew":
            term = self.term
            if term is None or term.epoch != rnd.epoch:
                pass
            elif won:
                term.confirmed(rnd.asked_at, now)
                if term.over:
                    out += self.end_term("late confirmation", lost_at=now)
                else:
                    self.backed_seq = max(self.backed_seq, rnd.seq)
                    out += self.pump(now)
            elif higher > rnd.epoch:
                out += self.end_term("higher epoch")
            # else: no majority this time; the lease runs out unless a renewal succeeds
        elif won and self.term is None:
            self.term = Term(rnd.epoch, self.timing, rnd.asked_at, now)
            self.table = SlotTable(rnd.epoch, expiry_margin=self.timing.margin)
            self.terms += 1
            self.renew_sent = rnd.asked_at
            self.backed_seq = rnd.seq
            self.vacant_since = None
        else:
            self._back_off(now)
        return out, None

    def _back_off(self, now: float) -> None:
        """Lost (split vote or a fresh leader elsewhere): try again later, with jitter."""
        self.next_try = now + self.timing.lease / 2 + self.rng.uniform(0, self.timing.lease / 2)

    # -- timing and status ----------------------------------------------------------------------

    def sleep_for(self, now: float) -> float:
        """How long the runner may sleep before :meth:`step` has something to do."""
        times = [now + self.timing.renew]
        if self.term is not None:
            times.append(self.renew_sent + self.timing.renew)
            if self.table is not None:
                ev = self.table.next_event()
                if ev is not None:
                    times.append(ev)
                if now < self.term.granting_from():
                    times.append(self.term.granting_from())
        elif self.vacant_since is not None:
            times.append(self.next_try)
        return max(0.0005, min(times) - now)

    def role(self, now: float) -> str:
        if self.term is not None:
            return "leader" if now >= self.term.granting_from() else "leader-waiting"
        return "starting" if now < self.voter.quiet_until else "follower"

    def status(self, now: float) -> dict[str, Any]:
        """JSON-able state of this group on this host."""
        term = self.term
        out: dict[str, Any] = {
            "role": self.role(now),
            "leader": self.me if term is not None else self.voter.leader(now),
            "epoch": term.epoch if term is not None else self.voter.epoch,
            "hosts": self.hosts,
            "alive": sorted(h for h in self.hosts if self.is_alive(h)),
            "terms_won": self.terms,
            "demotions": dict(self.demotions),
            "vote_rounds": self.vote_rounds,
            "queue": [],
            "grants_per_s": 0.0,
            "wait": {},
        }
        if self.table is not None:
            out.update(self.table.status(now))
        return out
