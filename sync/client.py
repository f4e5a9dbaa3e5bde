"""The measure's side of the sync service: ask for a slot, check it at the trigger, fire,
give it back after the sound.

:class:`SyncClient` implements :class:`hera.measure.SlotClient`; :func:`run_in_slot` is the
whole step of a synchronised worker, and hands the step a :class:`Turn`, whose
:meth:`Turn.check_at_trigger` the driver calls right at its physical trigger.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

import zenoh

from hera.keys import Keys
from hera.spec import longest_slot, slot_lease
from hera.sync import clock as sync_clock
from hera.sync.election import Timing
from hera.sync.protocol import AcquireRequest, GrantReply, ProtocolError, Release

log = logging.getLogger("hera.sync")

RETRY_PAUSE = 0.01
"""Pause before asking again when no host is granting (no leader, or a leader change)."""

Clock = Callable[[], float]
T = TypeVar("T")


@dataclass(frozen=True, slots=True)
class Grant:
    """A slot granted to ``holder`` (implements :class:`hera.measure.SlotGrant`).

    - ``epoch``, ``token``: the term and the token (strictly increasing; an audit label)
      it was granted under; samples taken in the slot carry them;
    - ``duration``: seconds of lease, counted from ``asked_at``;
    - ``asked_at``: this process's :func:`hera.sync.clock.now` just before the request was
      sent.
    """

    group: str
    holder: str
    epoch: int
    token: int
    duration: float
    asked_at: float
    leader: str

    @property
    def deadline(self) -> float:
        """When the lease runs out, on this process's sync clock."""
        return self.asked_at + self.duration

    def fits(self, seconds: float, now: float | None = None) -> bool:
        """True if something lasting ``seconds`` started ``now`` ends within the lease."""
        t = sync_clock.now() if now is None else now
        return t + seconds <= self.deadline


class SlotLost(Exception):
    """Raised by :meth:`Turn.check_at_trigger` when, at the trigger, the sound no longer
    fits the lease (a pause since the grant ate the slack): :func:`run_in_slot` then gives
    the slot back unused."""


@dataclass(frozen=True, slots=True)
class TriggerTime:
    """The clock read by the trigger-time check (``clock``, the sync clock) and, read right
    after it, the wall clock (``wall``, epoch seconds; None if not asked for): the start
    time a driver announces and stamps its sample with."""

    clock: float
    wall: float | None


class Turn:
    """One granted slot as the driver sees it (it also carries ``epoch`` and ``token``, so
    it serves as :class:`hera.measure.SlotGrant`).

    The driver calls :meth:`check_at_trigger` (or :meth:`fire`) right before its physical
    trigger, after taking any lock and preparing everything: the check reads the clock
    once, and the sound starts at that reading. Anything that pauses the process before
    the check (the measure's own code, a lock, a GC pause) is caught; only a pause between
    the check and the trigger instruction is not, and the margin bounds it
    (``Timing.trigger_pause``). One trigger per turn.
    """

    __slots__ = ("grant", "seconds", "clock", "fired_at", "lasts")

    def __init__(self, grant: Grant, seconds: float, clock: Clock = sync_clock.now) -> None:
        self.grant = grant
        self.seconds = seconds
        self.clock = clock
        self.fired_at: float | None = None
        self.lasts = seconds

    @property
    def epoch(self) -> int:
        return self.grant.epoch

    @property
    def token(self) -> int:
        return self.grant.token

    @property
    def duration(self) -> float:
        return self.grant.duration

    @property
    def deadline(self) -> float:
        return self.grant.deadline

    @property
    def ends_at(self) -> float | None:
        """When the sound started at the trigger ends (sync clock), None before it."""
        return None if self.fired_at is None else self.fired_at + self.lasts

    def fits(self, now: float | None = None) -> bool:
        """True if a sound of ``seconds`` started ``now`` ends within the lease."""
        return self.grant.fits(self.seconds, self.clock() if now is None else now)

    def check_at_trigger(
        self, wall: Clock | None = None, lasts: float | None = None
    ) -> TriggerTime:
        """The fit check, at the physical trigger: read the clock once; raise
        :class:`SlotLost` unless a sound of ``seconds`` started now ends within the lease.
        Returns that reading (and ``wall()`` read right after, if given): the start to
        announce. ``lasts``: how long the driver's sound lasts, if shorter than the slot
        (the release goes out when it has ended). ValueError if ``lasts`` exceeds the
        slot; RuntimeError on a second trigger in the same turn."""
        now = self.clock()
        w = wall() if wall is not None else None
        if self.fired_at is not None:
            raise RuntimeError("one trigger per turn: this slot was already used")
        if lasts is not None and not 0 <= lasts <= self.seconds:
            raise ValueError(
                f"a sound of {lasts} s does not fit the {self.seconds} s slot it runs in"
            )
        if now + self.seconds > self.grant.deadline:
            raise SlotLost
        self.fired_at = now
        if lasts is not None:
            self.lasts = lasts
        return TriggerTime(now, w)

    def fire(
        self,
        trigger: Callable[[TriggerTime], T],
        wall: Clock | None = None,
        lasts: float | None = None,
    ) -> T:
        """:meth:`check_at_trigger`, then ``trigger(reading)`` at once (the driver's trigger
        function, which starts the sound and announces ``reading`` as its start)."""
        return trigger(self.check_at_trigger(wall, lasts))


def slot_duration(slot_s: float) -> float:
    """The lease to ask for a step of ``slot_s`` s: the step plus a slack for latency.

    The slack (25 % of the step, at least 5 ms) absorbs the grant's trip back and the
    scheduling delay before firing; a grant that arrives later than that is given back.
    The formula is :func:`hera.spec.slot_lease`, which the spec check uses too.
    """
    return slot_lease(slot_s)


class KnownTerms:
    """The newest term (epoch, leader) a client was granted under, per group.

    A grant of an older term is stale: given back unused. A grant of the same epoch from
    another leader means promises were lost and an epoch reused: also refused. Either way
    the next request tells the leader what the client knows, so that it steps down and is
    re-elected above it (``AcquireRequest.known_epoch``).
    """

    def __init__(self) -> None:
        self._terms: dict[str, tuple[int, str]] = {}

    def get(self, group: str) -> tuple[int, str]:
        return self._terms.get(group, (0, ""))

    def accept(self, group: str, epoch: int, leader: str) -> bool:
        """True (and remember the term) unless a grant of ``(epoch, leader)`` is stale."""
        k_epoch, k_leader = self.get(group)
        if epoch < k_epoch or (epoch == k_epoch and leader != k_leader and k_leader):
            return False
        self._terms[group] = (epoch, leader)
        return True


class SyncClient:
    """Ask the leader of a group for slots (any node, hosting or not)."""

    def __init__(
        self, session: zenoh.Session, keys: Keys, timing: Timing, clock: Clock = sync_clock.now
    ) -> None:
        self.session = session
        self.keys = keys
        self.timing = timing
        self.clock = clock
        self._lock = threading.Lock()
        self._stats: dict[str, dict[str, dict[str, float]]] = {}
        self.known = KnownTerms()

    def _stat(self, group: str, holder: str) -> dict[str, float]:
        return self._stats.setdefault(group, {}).setdefault(
            holder,
            {
                "acquired": 0,
                "timeouts": 0,
                "late": 0,
                "stale": 0,
                "last_wait_ms": 0.0,
                "mean_wait_ms": 0.0,
                "max_wait_ms": 0.0,
            },
        )

    def acquire(self, group: str, holder: str, duration: float, timeout: float) -> Grant | None:
        """Block until a slot of ``duration`` s is granted (a :class:`Grant`) or ``timeout``
        s pass (None). ValueError if ``duration`` exceeds the service's longest slot."""
        if not 0 < duration <= self.timing.max_slot:
            raise ValueError(
                f"sync {group!r}: slot lease {duration:.4f} s is not in (0, "
                f"{self.timing.max_slot:g} s] (half of [cluster] sync_lease_ms), so the longest "
                f"slot is {longest_slot(self.timing.max_slot):g} s; shorten the measure's slot "
                "or raise [cluster] sync_lease_ms"
            )
        start = self.clock()
        end = start + timeout
        key = self.keys.sync(group, "acquire")
        while True:
            asked_at = self.clock()
            left = end - asked_at
            if left <= 0:
                with self._lock:
                    self._stat(group, holder)["timeouts"] += 1
                return None
            # One attempt waits at most a lease: a host that stopped without its link
            # being declared dead yet would otherwise hold the reply stream open.
            grant = self._ask(group, key, holder, duration, min(left, self.timing.lease), asked_at)
            if grant is not None:
                wait = self.clock() - start
                with self._lock:
                    st = self._stat(group, holder)
                    st["acquired"] += 1
                    st["last_wait_ms"] = round(wait * 1e3, 3)
                    st["mean_wait_ms"] += (st["last_wait_ms"] - st["mean_wait_ms"]) / st["acquired"]
                    st["max_wait_ms"] = max(st["max_wait_ms"], st["last_wait_ms"])
                return grant
            time.sleep(min(RETRY_PAUSE, max(0.0, end - self.clock())))

    def _ask(
        self, group: str, key: str, holder: str, duration: float, left: float, asked_at: float
    ) -> Grant | None:
        got: Grant | None = None
        with self._lock:
            k_epoch, k_leader = self.known.get(group)
        try:
            replies = self.session.get(
                key,
                payload=AcquireRequest(holder, duration, left, k_epoch, k_leader).encode(),
                target=zenoh.QueryTarget.ALL,
                consolidation=zenoh.ConsolidationMode.NONE,
                timeout=left,
            )
            for r in replies:
                if not r.ok:
                    continue
                try:
                    rep = GrantReply.decode(r.ok.payload.to_bytes())
                except ProtocolError as e:
                    log.warning("sync %s: bad grant: %s", group, e)
                    continue
                g = Grant(group, holder, rep.epoch, rep.token, rep.duration, asked_at, rep.leader)
                with self._lock:
                    stale = not self.known.accept(group, rep.epoch, rep.leader)
                    if stale:
                        self._stat(group, holder)["stale"] += 1
                if stale:
                    self.release(g, used=False)  # an older term's, or a reused epoch's
                    continue
                got = g
                break
        except Exception as e:  # session closed or cut off: no grant
            log.debug("sync %s: acquire failed: %s", group, e)
        return got

    def release(self, grant: Grant, used: bool) -> None:
        """Give the slot back (best effort: a lost release frees at lease expiry)."""
        msg = Release(grant.epoch, grant.token, grant.holder, bool(used)).encode()
        try:
            self.session.put(
                self.keys.sync(grant.group, "release"),
                msg,
                congestion_control=zenoh.CongestionControl.BLOCK,
                express=True,
            )
        except Exception as e:
            log.debug("sync %s: release failed: %s", grant.group, e)

    def note_late(self, grant: Grant) -> None:
        with self._lock:
            self._stat(grant.group, grant.holder)["late"] += 1

    def status(self) -> dict[str, Any]:
        """Per group and measure: slots acquired, timeouts, late grants given back, waits."""
        with self._lock:
            return {g: {h: dict(s) for h, s in hs.items()} for g, hs in self._stats.items()}


def run_in_slot(
    client: Any,
    group: str,
    holder: str,
    slot_s: float,
    fn: Callable[[Turn], Any],
    timeout: float,
    clock: Clock = sync_clock.now,
    sleep: Callable[[float], None] = time.sleep,
) -> tuple[bool, Any, Grant | None]:
    """One synchronised step: acquire a slot, call ``fn(turn)`` in it, give it back.

    Returns ``(fired, result, grant)``; ``(False, None, None)``: no slot within
    ``timeout``. ``fn`` gets a :class:`Turn` and is expected to hand it to its driver,
    which calls ``turn.check_at_trigger()`` right at the physical trigger; a
    :class:`SlotLost` from that check (the sound no longer fits the lease) means the step
    did not fire: the slot is given back unused and ``(False, None, grant)`` returned. A
    grant that does not fit even before ``fn`` is called is given back the same way.

    The release is sent only after the sound has ended (``turn.ends_at`` on ``clock``),
    also if ``fn`` raises (the exception propagates). A ``fn`` that never calls the check
    is protected only by the check before it is called (weaker: a pause inside ``fn``
    before its trigger is not caught).
    """
    grant = client.acquire(group, holder, slot_duration(slot_s), timeout)
    if grant is None:
        return False, None, None
    turn = Turn(grant, slot_s, clock)
    if turn.fits():
        try:
            result = fn(turn)
        except SlotLost:
            pass
        except BaseException:
            _release_after_sound(client, turn, clock, sleep, used=True)
            raise
        else:
            _release_after_sound(client, turn, clock, sleep, used=True)
            return True, result, grant
    _release_after_sound(client, turn, clock, sleep, used=turn.fired_at is not None)
    if hasattr(client, "note_late"):
        client.note_late(grant)
    return False, None, grant


def _release_after_sound(
    client: Any, turn: Turn, clock: Clock, sleep: Callable[[float], None], used: bool
) -> None:
    """Give the slot back once the sound started at the trigger (if any) has ended."""
    ends = turn.ends_at
    if ends is not None:
        left = ends - clock()
        while left > 0:
            sleep(left)
            left = ends - clock()
    client.release(turn.grant, used)
