"""The slot table of a leader: one slot at a time, first come first served, round-robin.

Pure logic with an injected clock (the Zenoh plumbing is in :mod:`hera.sync.group`).

- A measure (``holder``) waits in a FIFO queue; asking again while queued keeps its place.
  After a slot it must ask again, so it joins the back: round-robin among waiting measures.
- At most one slot is out. It is freed on a release from its holder carrying its epoch and
  token, or when its lease has run out on the leader's clock (``granted_at + duration +
  expiry_margin``), never earlier. The holder's own lease ends no later than
  ``granted_at + duration``.
- Tokens strictly increase, across terms too: ``token = epoch << 32 | n`` (epochs are
  unique for ever, see ``sync/README.md``). They are audit labels: a sonar cannot check one.
"""

from __future__ import annotations

import collections
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

TOKEN_BITS = 32


@dataclass
class Waiting:
    """A queued request: ``duration`` is the slot asked for, ``ticket`` the reply handle,
    ``round_seq`` the number of vote rounds the leader had started when it arrived (a grant
    needs a round started after it: see :class:`hera.sync.core.GroupCore`)."""

    holder: str
    duration: float
    received_at: float
    give_up_at: float
    ticket: Any = None
    queued_since: float | None = None
    round_seq: int = 0

    def __post_init__(self) -> None:
        if self.queued_since is None:
            self.queued_since = self.received_at


@dataclass
class Granted:
    """The slot that is out."""

    holder: str
    epoch: int
    token: int
    granted_at: float
    duration: float
    free_at: float


@dataclass
class _WaitStats:
    count: int = 0
    last: float = 0.0
    total: float = 0.0
    worst: float = 0.0

    def add(self, wait: float) -> None:
        self.count += 1
        self.last = wait
        self.total += wait
        self.worst = max(self.worst, wait)

    def as_dict(self) -> dict[str, float]:
        return {
            "grants": self.count,
            "last_ms": round(self.last * 1e3, 3),
            "mean_ms": round(self.total / self.count * 1e3, 3) if self.count else 0.0,
            "max_ms": round(self.worst * 1e3, 3),
        }


@dataclass
class SlotTable:
    """Queue and current slot of one group's leader for one term."""

    epoch: int
    expiry_margin: float
    queue: collections.OrderedDict[str, Waiting] = field(default_factory=collections.OrderedDict)
    current: Granted | None = None
    issued: int = 0
    grant_times: collections.deque[float] = field(default_factory=collections.deque)
    waits: dict[str, _WaitStats] = field(default_factory=dict)
    released: int = 0
    unused: int = 0
    expired: int = 0

    def enqueue(self, w: Waiting) -> Waiting | None:
        """Queue ``w``; return the request it replaces (same holder), to be finalised."""
        old = self.queue.get(w.holder)
        if old is not None:
            # keeps its place (OrderedDict) and its waiting time, but never the old
            # request's receive time: the lease told to the asker counts from the new one
            w.queued_since = old.queued_since
        self.queue[w.holder] = w
        return old

    def release(self, epoch: int, token: int, holder: str, used: bool) -> bool:
        """Free the slot if it is out to ``holder`` under ``(epoch, token)``; True if it was."""
        cur = self.current
        if cur is None or cur.token != token or cur.epoch != epoch or cur.holder != holder:
            return False
        self.current = None
        self.released += 1
        if not used:
            self.unused += 1
        return True

    def expire(self, now: float) -> list[Waiting]:
        """Free a slot whose lease has run out; return the requests whose askers gave up."""
        if self.current is not None and now >= self.current.free_at:
            self.current = None
            self.expired += 1
        gone = [w for w in self.queue.values() if now >= w.give_up_at]
        for w in gone:
            del self.queue[w.holder]
        return gone

    def grant(
        self,
        now: float,
        may_grant: Callable[[Waiting], bool],
        usable: Callable[[Waiting], bool] = lambda w: True,
    ) -> tuple[Waiting, Granted] | None:
        """Give the slot to the first ``usable`` request if the slot is free and
        ``may_grant(request)``.

        Returns the request and its grant; the caller replies to the request's ticket with
        ``grant_duration(...)``. Requests that are not ``usable`` (too old to be granted,
        waiting to be replaced by their asker's next attempt) keep their place; otherwise
        strict FIFO: a head that may not be granted yet blocks the others (no overtaking).
        """
        if self.current is not None:
            return None
        head = next((w for w in self.queue.values() if usable(w)), None)
        if head is None or not may_grant(head):
            return None
        del self.queue[head.holder]
        self.issued += 1
        token = (self.epoch << TOKEN_BITS) | self.issued
        g = Granted(
            head.holder,
            self.epoch,
            token,
            now,
            head.duration,
            now + head.duration + self.expiry_margin,
        )
        self.current = g
        self.grant_times.append(now)
        self.waits.setdefault(head.holder, _WaitStats()).add(now - (head.queued_since or now))
        return head, g

    @staticmethod
    def grant_duration(w: Waiting, g: Granted) -> float:
        """The lease told to the asker, counted from when it sent its request.

        The request was sent before it was received (``received_at``), so a lease of
        ``(granted_at - received_at) + duration`` counted by the asker from its send time
        ends no later than ``granted_at + duration`` on the leader's clock.
        """
        return (g.granted_at - w.received_at) + g.duration

    def clear(self) -> list[Waiting]:
        """End of term: forget the slot, return every queued request (tickets to drop)."""
        gone = list(self.queue.values())
        self.queue.clear()
        self.current = None
        return gone

    def next_event(self) -> float | None:
        """The next time ``expire`` has something to do, if any."""
        times = [w.give_up_at for w in self.queue.values()]
        if self.current is not None:
            times.append(self.current.free_at)
        return min(times) if times else None

    def rate(self, now: float, window: float = 5.0) -> float:
        """Grants per second over the last ``window`` s."""
        while self.grant_times and self.grant_times[0] < now - window:
            self.grant_times.popleft()
        return len(self.grant_times) / window

    def status(self, now: float) -> dict[str, Any]:
        """JSON-able summary: queue, current slot, rate, waiting time per measure."""
        cur = self.current
        return {
            "queue": list(self.queue),
            "holder": cur.holder if cur else None,
            "token": cur.token if cur else None,
            "grants": self.issued,
            "grants_per_s": round(self.rate(now), 2),
            "released": self.released,
            "unused": self.unused,
            "expired": self.expired,
            "wait": {h: s.as_dict() for h, s in self.waits.items()},
        }
