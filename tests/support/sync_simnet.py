"""A simulated sync group: real :class:`GroupCore` hosts and slot clients on a fake network.

Everything runs on one simulated real-time axis (an event queue). Each process has its own
:class:`SimClock` (rate error, offset, and it can freeze, as ``CLOCK_MONOTONIC`` does over
a system suspend and every guest clock does over a VM pause). Hosts are driven exactly as
:class:`hera.sync.group.GroupHost` drives its core: a runner that steps, runs one vote round
at a time (answers until a majority said yes or L/6 passed on its own clock) and sleeps,
and callbacks for vote requests, slot requests, releases and liveliness.

Clients follow :class:`hera.sync.client.SyncClient` and :func:`~hera.sync.client.run_in_slot`:
ask every host, take the first grant of a term they do not know to be stale, check at the
trigger on their own clock, sound for ``slot`` s of real time, release after the sound
ended, ask again. Every emission is recorded in real time, so :func:`overlaps` is the
ground truth, whatever the processes believed.

The network delays, loses, reorders and partitions; a test can also hold messages and
deliver them when it likes (an adversarial network).
"""

from __future__ import annotations

import heapq
import random
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from hera.sync.client import Grant, KnownTerms, SlotLost, Turn
from hera.sync.core import GroupCore, Reply, Round
from hera.sync.election import Timing
from hera.sync.protocol import AcquireRequest, GrantReply, Release, VoteReply, VoteRequest


class SimClock:
    """A process clock as a function of real time: ``offset + rate * t``, and it can freeze."""

    def __init__(self, rate: float = 1.0, offset: float = 0.0) -> None:
        self.rate = rate
        self._real = 0.0
        self._local = offset
        self.frozen = False

    def read(self, real: float) -> float:
        if self.frozen:
            return self._local
        return self._local + self.rate * (real - self._real)

    def freeze(self, real: float) -> None:
        self._local, self._real, self.frozen = self.read(real), real, True

    def thaw(self, real: float) -> None:
        self._real, self.frozen = real, False

    def real_after(self, real: float, local_delay: float) -> float:
        """The real time at which this clock will have advanced by ``local_delay``."""
        return real + max(0.0, local_delay) / self.rate


@dataclass
class Emission:
    """One sound, in real time, and the grant it was made under."""

    start: float
    end: float
    holder: str
    epoch: int
    token: int
    leader: str
    checked_at: float  # the client's clock at the trigger check


class Sim:
    """The event queue and the network."""

    def __init__(self, timing: Timing, seed: int = 0) -> None:
        self.timing = timing
        self.rnd = random.Random(seed)
        self.now = 0.0
        self._events: list[tuple[float, int, Callable[[], None]]] = []
        self._seq = 0
        self.procs: dict[str, Proc] = {}
        self.emissions: list[Emission] = []
        self.loss = 0.0
        self.delay: Callable[[], float] = lambda: 0.0005
        self.cut: set[frozenset[str]] = set()
        self.holds: list[tuple[Callable[[str, str, Any], bool], list]] = []

    # -- events -----------------------------------------------------------------------------

    def at(self, t: float, fn: Callable[[], None]) -> None:
        self._seq += 1
        heapq.heappush(self._events, (max(t, self.now), self._seq, fn))

    def run(self, until: float) -> None:
        while self._events and self._events[0][0] <= until:
            t, _, fn = heapq.heappop(self._events)
            self.now = t
            fn()
        self.now = max(self.now, until)

    def run_until(self, cond: Callable[[], bool], limit: float, step: float = 0.005) -> bool:
        """Run until ``cond()`` (checked every ``step`` s of real time) or ``limit``."""
        while self.now < limit:
            if cond():
                return True
            self.run(self.now + step)
        return cond()

    # -- network ----------------------------------------------------------------------------

    def send(self, src: str, dst: str, msg: Any, deliver: Callable[[], None]) -> None:
        """Carry ``msg`` from ``src`` to ``dst``: lost, cut, held or delivered after a delay."""
        if frozenset((src, dst)) in self.cut and src != dst:
            return
        if src != dst and self.rnd.random() < self.loss:
            return
        for pred, box in self.holds:
            if pred(src, dst, msg):
                box.append((dst, deliver))
                return
        d = 0.0001 if src == dst else self.delay()
        self.at(self.now + d, lambda: self.procs[dst].deliver(deliver))

    def hold(self, pred: Callable[[str, str, Any], bool]) -> list:
        """Hold back every message matching ``pred``; returns the box of held messages."""
        box: list = []
        self.holds.append((pred, box))
        return box

    def unhold(self, box: list) -> None:
        """Stop holding, and deliver what was held (after the usual delay)."""
        self.holds = [(p, b) for p, b in self.holds if b is not box]
        for dst, deliver in box:
            self.at(self.now + self.delay(), lambda d=dst, f=deliver: self.procs[d].deliver(f))
        box.clear()

    def cut_off(self, who: str, others: list[str]) -> None:
        """Cut the links between ``who`` and each of ``others``."""
        self.cut |= {frozenset((who, o)) for o in others}

    def partition(self, *groups: set[str]) -> None:
        """Cut every link between different groups (a missing process is alone)."""
        names = list(self.procs)
        where = {n: i for i, g in enumerate(groups) for n in g}
        self.cut = {
            frozenset((a, b))
            for a in names
            for b in names
            if a != b and where.get(a, -1 - names.index(a)) != where.get(b, -1 - names.index(b))
        }

    def heal(self) -> None:
        self.cut = set()

    # -- the oracle -------------------------------------------------------------------------

    def hosts(self) -> list[SimHost]:
        return [p for p in self.procs.values() if isinstance(p, SimHost)]


def overlaps(emissions: list[Emission]) -> list[tuple[Emission, Emission]]:
    """Pairs of emissions that overlap in real time (each with the latest-ending earlier one)."""
    out = []
    latest: Emission | None = None
    for e in sorted(emissions, key=lambda e: e.start):
        if latest is not None and e.start < latest.end:
            out.append((latest, e))
        if latest is None or e.end > latest.end:
            latest = e
    return out


class Proc:
    """A process: a clock, and it can be paused (nothing runs; work queues up)."""

    def __init__(self, sim: Sim, name: str, clock: SimClock) -> None:
        self.sim = sim
        self.name = name
        self.clock = clock
        self.paused = False
        self.dead = False
        self.incarnation = 0
        self._backlog: list[Callable[[], None]] = []
        sim.procs[name] = self

    def local(self) -> float:
        return self.clock.read(self.sim.now)

    def deliver(self, fn: Callable[[], None]) -> None:
        if self.dead:
            return
        if self.paused:
            self._backlog.append(fn)
        else:
            fn()

    def after(self, local_delay: float, fn: Callable[[], None]) -> None:
        """Run ``fn`` when this process's clock has advanced ``local_delay`` (a timer)."""
        self._arm(self.local() + max(0.0, local_delay), fn, self.incarnation)

    def _arm(self, target: float, fn: Callable[[], None], inc: int) -> None:
        def fire() -> None:
            if self.incarnation != inc or self.dead:
                return
            if self.clock.frozen:  # a frozen clock's timers wait for it to thaw
                self._backlog.append(lambda: self._arm(target, fn, inc))
            elif self.local() < target - 1e-12:
                self._arm(target, fn, inc)
            else:
                self.deliver(fn)

        left = target - self.local()
        self.sim.at(self.clock.real_after(self.sim.now, left) if left > 0 else self.sim.now, fire)

    def pause(self, freeze_clock: bool = False) -> None:
        """Stop the process (SIGSTOP); ``freeze_clock``: its clock stops too (VM pause, or a
        system suspend under ``CLOCK_MONOTONIC``)."""
        self.paused = True
        if freeze_clock:
            self.clock.freeze(self.sim.now)

    def resume(self) -> None:
        if self.clock.frozen:
            self.clock.thaw(self.sim.now)
        self.paused = False
        todo, self._backlog = self._backlog, []
        for fn in todo:
            if not self.paused and not self.dead:
                fn()
            else:
                self._backlog.append(fn)


class SimDisk:
    """A voter's promise storage that survives a restart (``hera.sync.promises.Promises``)."""

    def __init__(self) -> None:
        self.promise = (0, "")

    def load(self) -> tuple[int, str]:
        return self.promise

    def save(self, epoch: int, candidate: str) -> None:
        self.promise = (epoch, candidate)


class SimHost(Proc):
    """A host of the group: a :class:`GroupCore`, driven as ``GroupHost`` drives it.

    ``durable``: its voter keeps its promise on a :class:`SimDisk` across restarts.
    """

    durable = True

    def __init__(self, sim: Sim, name: str, hosts: list[str], clock: SimClock) -> None:
        super().__init__(sim, name, clock)
        self.hosts = hosts
        self.disk = SimDisk()  # what survives a restart (unless wiped)
        self.core = self._new_core()
        self._round: Round | None = None
        self._round_id = 0
        self._replies: list[VoteReply] = []
        self._sleeping = False
        self._wake_id = 0
        # (epoch, token, holder, incarnation) of each grant
        self.granted: list[tuple[int, int, str, int]] = []
        self.after(0.0, self._runner)

    def _new_core(self) -> GroupCore:
        return GroupCore(
            self.name,
            self.hosts,
            self.sim.timing,
            self.local(),
            rng=random.Random(self.sim.rnd.random()),
            promises=self.disk if self.durable else None,
        )

    # -- lifecycle ----------------------------------------------------------------------------

    def restart(self, wipe: bool = False) -> None:
        """Kill and start again: memory lost (``wipe``: the disk too); tokens go and come."""
        self.incarnation += 1
        if wipe:
            self.disk = SimDisk()
        self.paused = False
        self._backlog = []
        if self.clock.frozen:
            self.clock.thaw(self.sim.now)
        self._round = None
        self._sleeping = False
        self.core = self._new_core()
        self.learn_alive()
        for p in self.sim.hosts():
            if p is not self:
                self.sim.send(self.name, p.name, "alive-", lambda p=p: p.on_alive(self.name, False))
                self.sim.send(self.name, p.name, "alive+", lambda p=p: p.on_alive(self.name, True))
        self.after(0.0, self._runner)

    def learn_alive(self) -> None:
        """The liveliness history at start: every host not dead is there."""
        for p in self.sim.hosts():
            if p is not self and not p.dead:
                self.core.on_alive(p.name, True)

    def on_alive(self, node: str, present: bool) -> None:
        self.core.on_alive(node, present)
        self._notify()

    # -- runner -------------------------------------------------------------------------------

    def _notify(self) -> None:
        if self._sleeping:
            self._sleeping = False
            self._wake_id += 1
            self.after(0.0, self._runner)

    def _runner(self) -> None:
        if self._round is not None:
            return
        out, rnd = self.core.step(self.local())
        self._send_replies(out)
        if rnd is not None:
            self._start_round(rnd)
            return
        self._sleeping = True
        self._wake_id += 1
        wid = self._wake_id

        def wake() -> None:
            if self._sleeping and self._wake_id == wid:
                self._sleeping = False
                self._runner()

        self.after(self.core.sleep_for(self.local()), wake)

    def _start_round(self, rnd: Round) -> None:
        self._round = rnd
        self._round_id += 1
        rid = self._round_id
        self._replies = []
        req = rnd.request(self.name)
        for h in self.sim.hosts():
            self.sim.send(self.name, h.name, req, lambda h=h, rid=rid: h.on_vote(self, req, rid))
        self.after(self.sim.timing.lease / 6, lambda: self._round_over(rid))

    def on_vote(self, asker: SimHost, req: VoteRequest, rid: int) -> None:
        reply = self.core.on_vote(req, self.local())
        if reply is None:
            return
        if reply.ok:
            self._notify()
        inc = asker.incarnation
        self.sim.send(self.name, asker.name, reply, lambda: asker.on_vote_reply(reply, rid, inc))

    def on_vote_reply(self, reply: VoteReply, rid: int, inc: int) -> None:
        if inc != self.incarnation or rid != self._round_id or self._round is None:
            return
        self._replies.append(reply)
        if self.core.tally(self._round, self._replies)[0]:
            self._round_over(rid)

    def _round_over(self, rid: int) -> None:
        if rid != self._round_id or self._round is None:
            return
        rnd, self._round = self._round, None
        out, nxt = self.core.round_done(rnd, list(self._replies), self.local())
        self._send_replies(out)
        if nxt is not None:
            self._start_round(nxt)
        else:
            self._runner()

    # -- slots --------------------------------------------------------------------------------

    def on_acquire(self, client: SimClient, req: AcquireRequest, attempt: int) -> None:
        out = self.core.on_acquire(req, self.local(), (client, attempt))
        self._notify()
        self._send_replies(out)

    def on_release(self, rel: Release) -> None:
        self._send_replies(self.core.on_release(rel, self.local()))

    def _send_replies(self, out: list[Reply]) -> None:
        for (client, attempt), payload in out:
            if payload is None:
                continue
            rep = GrantReply.decode(payload)
            self.granted.append((rep.epoch, rep.token, client.name, self.incarnation))
            self.sim.send(
                self.name, client.name, rep, lambda c=client, a=attempt, r=rep: c.on_grant(r, a)
            )


class SimClient(Proc):
    """A measure asking for slots of ``slot`` s and sounding in them, over and over.

    ``pause_after_check``: real seconds between the trigger check and the start of the
    sound (a callable, drawn per firing); ``think``: real seconds before asking again.
    """

    def __init__(
        self,
        sim: Sim,
        name: str,
        slot: float,
        clock: SimClock,
        duration: float | None = None,
        pause_after_check: Callable[[], float] = lambda: 0.0,
        think: Callable[[], float] = lambda: 0.0,
        start: float = 0.0,
    ) -> None:
        super().__init__(sim, name, clock)
        self.slot = slot
        self.duration = duration if duration is not None else slot + max(0.005, 0.25 * slot)
        self.pause_after_check = pause_after_check
        self.think = think
        self.known = KnownTerms()
        self.attempt = 0
        self.asked_at = 0.0
        self.busy = False
        self.fired = 0
        self.late = 0
        self.stale = 0
        self.stopped = False
        sim.at(start, lambda: self.deliver(self._ask))

    def _ask(self) -> None:
        if self.stopped or self.busy:
            return
        self.attempt += 1
        attempt = self.attempt
        self.asked_at = self.local()
        timeout = self.sim.timing.lease
        req = AcquireRequest(self.name, self.duration, timeout, *self.known.get("g"))
        for h in self.sim.hosts():
            self.sim.send(self.name, h.name, req, lambda h=h: h.on_acquire(self, req, attempt))
        self.after(timeout, lambda: self._timeout(attempt))

    def _timeout(self, attempt: int) -> None:
        if attempt == self.attempt and not self.busy:
            self.after(0.01, self._ask)

    def on_grant(self, rep: GrantReply, attempt: int) -> None:
        g = Grant("g", self.name, rep.epoch, rep.token, rep.duration, self.asked_at, rep.leader)
        if attempt != self.attempt or self.busy:
            self._release(g, used=False)  # a second grant, or one for a request given up
            return
        if not self.known.accept("g", rep.epoch, rep.leader):
            self.stale += 1
            self._release(g, used=False)
            return
        self.busy = True
        self.attempt += 1  # this attempt is answered
        turn = Turn(g, self.slot, self.local)
        if not turn.fits():
            self.late += 1
            self._release(g, used=False)
            self._done()
            return
        self._trigger(turn)

    def _trigger(self, turn: Turn) -> None:
        """The trigger-time check, then the sound after ``pause_after_check``."""
        g = turn.grant
        try:
            checked = turn.check_at_trigger().clock
        except SlotLost:
            self.late += 1
            self._release(g, used=False)
            self._done()
            return
        pause = self.pause_after_check()

        def sound() -> None:
            start = self.sim.now
            self.sim.emissions.append(
                Emission(start, start + self.slot, self.name, g.epoch, g.token, g.leader, checked)
            )
            self.fired += 1
            self.sim.at(start + self.slot, lambda: self.deliver(lambda: self._finish(g)))

        if pause > 0:
            self.sim.at(self.sim.now + pause, sound)  # the sound starts whatever the process does
        else:
            sound()

    def _finish(self, g: Grant) -> None:
        self._release(g, used=True)
        self._done()

    def _done(self) -> None:
        self.busy = False
        self.after(self.think(), self._ask)

    def _release(self, g: Grant, used: bool) -> None:
        rel = Release(g.epoch, g.token, g.holder, used)
        for h in self.sim.hosts():
            self.sim.send(self.name, h.name, rel, lambda h=h: h.on_release(rel))


@dataclass
class Group:
    """A group of hosts and clients on one :class:`Sim`."""

    sim: Sim
    hosts: list[SimHost] = field(default_factory=list)
    clients: list[SimClient] = field(default_factory=list)

    def host(self, name: str) -> SimHost:
        return next(h for h in self.hosts if h.name == name)

    def leader(self) -> SimHost | None:
        """The host with the highest epoch that thinks it may grant now."""
        live = [
            h
            for h in self.hosts
            if h.core.term is not None and not h.paused and h.core.role(h.local()) == "leader"
        ]
        return max(live, key=lambda h: h.core.term.epoch, default=None)


def make_group(
    timing: Timing,
    hosts: int = 3,
    clients: int = 3,
    slot: float = 0.005,
    seed: int = 0,
    rates: Callable[[random.Random], float] = lambda r: 1.0,
) -> Group:
    """``hosts`` hosts h0..; ``clients`` clients c0.. with slot ``slot`` s; clock rates from
    ``rates`` (per process); a 0.5 ms network."""
    sim = Sim(timing, seed)
    names = [f"h{i}" for i in range(hosts)]
    g = Group(sim)
    for n in names:
        g.hosts.append(SimHost(sim, n, names, SimClock(rates(sim.rnd), sim.rnd.uniform(0, 100))))
    for h in g.hosts:
        h.learn_alive()
    for i in range(clients):
        g.clients.append(
            SimClient(sim, f"c{i}", slot, SimClock(rates(sim.rnd), sim.rnd.uniform(0, 100)))
        )
    return g
