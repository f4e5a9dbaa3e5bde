"""Leader election for one sync group: the pure state machines, with an injected clock.

Two small classes, no I/O (the Zenoh plumbing is in :mod:`hera.sync.group`):

- :class:`Voter`: what every host of the group promises. Epochs only grow; one candidate
  per epoch; sticky (it refuses to switch while its leader is confirmed fresh and alive);
  silent for a quiet period after start (it may have forgotten a promise by restarting).
- :class:`Term`: what a leader knows about its own term: its epoch, when it was elected,
  until when a majority confirmed it (its lease), and whether it may grant now.

The safety argument and the timing inequalities are in ``sync/README.md``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

from hera.sync.promises import Promises

log = logging.getLogger("hera.sync")


@dataclass(frozen=True)
class Timing:
    """The timing constants of a group, all in seconds of the sync clock.

    - ``lease``: how long a majority confirmation lets a leader grant, counted from
      before it asked for the confirmation (L);
    - ``max_slot``: the longest slot a leader grants (D);
    - ``margin``: the margin m added to the new leader's wait and to every slot's expiry;
    - ``drift``: the largest clock rate error assumed, per clock, against real time (rho);
    - ``renew``: how often a leader asks for a fresh confirmation (L / 6);
    - ``pause``: a gap this long (L / 2) in the leader's own loop makes it demote itself;
    - ``wait``: a new leader grants nothing for this long after its election:
      ``lease + max_slot + margin`` (W);
    - ``quiet``: a starting host neither votes nor runs for this long (Q = W);
    - ``trigger_pause``: the longest pause p between a driver's trigger-time check and its
      trigger that the margin tolerates at this drift (``sync/README.md``, condition C):
      ``2 rho (L + D) / (1 - rho) + (1 + rho) p <= m``.
    """

    lease: float = 0.3
    max_slot: float = 0.15
    margin: float = 0.05
    drift: float = 0.01

    def __post_init__(self) -> None:
        if not self.lease > 0 or not self.max_slot > 0 or not self.margin >= 0:
            raise ValueError("lease and max_slot must be > 0, margin >= 0")
        if self.max_slot > self.lease / 2:
            raise ValueError(
                f"max_slot ({self.max_slot} s) must be <= lease / 2 ({self.lease / 2} s) so a "
                "slot fits in a freshly renewed lease"
            )
        if not 0 <= self.drift < 0.5:
            raise ValueError(f"drift must be in [0, 0.5), got {self.drift!r}")
        if self.trigger_pause < 0:
            raise ValueError(
                f"margin {self.margin} s is too small for a clock drift of {self.drift:.1%} "
                f"over lease + max_slot = {self.lease + self.max_slot} s: it needs at least "
                f"{self.drift_allowance:.4f} s"
            )

    @property
    def renew(self) -> float:
        return self.lease / 6

    @property
    def pause(self) -> float:
        return self.lease / 2

    @property
    def wait(self) -> float:
        return self.lease + self.max_slot + self.margin

    @property
    def quiet(self) -> float:
        return self.wait

    @property
    def drift_allowance(self) -> float:
        """The part of the margin that clock drift takes: ``2 rho (L + D) / (1 - rho)``."""
        return 2 * self.drift * (self.lease + self.max_slot) / (1 - self.drift)

    @property
    def trigger_pause(self) -> float:
        """The longest tolerated pause between trigger check and trigger (p, seconds)."""
        return (self.margin - self.drift_allowance) / (1 + self.drift)


NOBODY = ""


class Voter:
    """The promises of one host for one group.

    Rule (``request``): confirm ``(epoch, candidate)`` if and only if

    1. the quiet period since start is over, and
    2. ``epoch`` is above every epoch this host has promised or seen asked for while quiet,
       or equal to the promised one with the same candidate (a renewal), and
    3. (stickiness, for liveness only) the candidate is the promised one, or the promised
       leader has not been confirmed for ``timing.lease`` s, or it is not alive.

    Rule 2 carries safety; with ``promises`` (durable storage) it holds across restarts:
    a changed promise is saved before the yes is given, and loaded at start. Rule 1 only
    matters when the storage was lost; rule 3 only adds refusals.

    "Confirmed" (rule 3, :meth:`leader`) is refreshed by every yes to the leader while it
    is still fresh here; once it went stale, only when its renewals have been arriving for
    a whole lease with no gap longer than a lease between them. A backlog of renewals held
    up in the network (a link that dropped nothing but delivered nothing for a while, then
    everything at once) arrives after such a gap and all within an instant: the leader that
    sent it has, by its own lease, already lost its term and sends no more, so it must not
    make this voter refuse everyone else again. Without that rule a leader behind a
    flapping link wins the election after each of its cuts (the voters it renewed a moment
    ago refuse the others) and starves the group.
    """

    def __init__(
        self, me: str, timing: Timing, now: float, promises: Promises | None = None
    ) -> None:
        self.me = me
        self.timing = timing
        self.quiet_until = now + timing.quiet
        self.promises = promises
        self.epoch, self.candidate = promises.load() if promises is not None else (0, NOBODY)
        self._saved = (self.epoch, self.candidate)
        self.confirmed_at = float("-inf")
        self.renewed_at = float("-inf")  # the last yes to the promised term
        self.streak_from = float("-inf")  # the first yes of its run without a gap > lease
        self.save_failures = 0

    def request(self, epoch: int, candidate: str, now: float, alive: Callable[[str], bool]) -> bool:
        """Answer a vote request; on yes, promise ``(epoch, candidate)`` from now on (saved
        to ``promises`` first; a failed save answers no)."""
        if now < self.quiet_until:
            # Remember the highest term asked for, so that once quiet is over we never
            # promise below a term that may be live (only adds refusals: safe).
            if epoch > self.epoch:
                self.epoch, self.candidate = epoch, candidate
            return False
        if not self.would(epoch, candidate, now, alive):
            return False
        if self.promises is not None and (epoch, candidate) != self._saved:
            try:
                self.promises.save(epoch, candidate)
            except OSError as e:
                self.save_failures += 1
                log.error("sync voter %s cannot save its promise, answers no: %s", self.me, e)
                return False
            self._saved = (epoch, candidate)
        lease = self.timing.lease
        same = (epoch, candidate) == (self.epoch, self.candidate)
        if not same or now - self.renewed_at > lease:
            self.streak_from = now
        if not same or now - self.confirmed_at < lease or now - self.streak_from >= lease:
            self.confirmed_at = now  # see the class docstring
        self.epoch, self.candidate, self.renewed_at = epoch, candidate, now
        return True

    def would(self, epoch: int, candidate: str, now: float, alive: Callable[[str], bool]) -> bool:
        """Pre-vote: would ``request`` say yes now? Changes nothing.

        A candidate runs a real election only if a majority would vote for it, so a host
        that was cut off or stopped cannot disturb a healthy leader by raising epochs.
        """
        if now < self.quiet_until:
            return False
        if epoch < self.epoch:
            return False
        if epoch == self.epoch and candidate != self.candidate:
            return False
        return not (
            candidate != self.candidate
            and self.candidate != NOBODY
            and now - self.confirmed_at < self.timing.lease
            and alive(self.candidate)
        )  # sticky: refuse to switch while our leader is fresh and alive

    def leader(self, now: float) -> str | None:
        """The leader this host has confirmed within the last lease, if any."""
        if self.candidate and now - self.confirmed_at < self.timing.lease:
            return self.candidate
        return None

    def unstick(self, candidate: str) -> None:
        """Stop being sticky to ``candidate`` (it demoted itself or is gone). Safe: rule 3."""
        if self.candidate == candidate:
            self.confirmed_at = float("-inf")


class Term:
    """One leadership term of this host: epoch, election time and lease.

    The term may grant at ``now`` only if ``now >= elected_at + timing.wait`` and a slot of
    ``duration`` fits in the lease: ``now + duration <= lease_end``. The lease is counted
    from before the confirmation request was sent, so it ends no later than the voters'
    confirmations do.
    """

    def __init__(self, epoch: int, timing: Timing, asked_at: float, now: float) -> None:
        self.epoch = epoch
        self.timing = timing
        self.elected_at = now
        self.lease_end = asked_at + timing.lease
        self.last_tick = now
        self.over = False

    def confirmed(self, asked_at: float, now: float) -> None:
        """A majority confirmed the term for a request sent at ``asked_at``."""
        if self.over:
            return
        if now >= self.lease_end:
            # The lease ran out before the renewal came back: the term is over for good,
            # a new one (new election, new wait) must start.
            self.over = True
            return
        self.lease_end = max(self.lease_end, asked_at + self.timing.lease)

    def tick(self, now: float) -> bool:
        """Check the term at a loop turn; return False if it is over (lease or pause)."""
        if self.over:
            return False
        if now - self.last_tick > self.timing.pause or now >= self.lease_end:
            self.over = True
        self.last_tick = now
        return not self.over

    def may_grant(self, duration: float, now: float) -> bool:
        """True if a slot of ``duration`` s may be granted at ``now`` under this term."""
        return (
            not self.over
            and duration <= self.timing.max_slot
            and now >= self.elected_at + self.timing.wait
            and now + duration <= self.lease_end
        )

    def granting_from(self) -> float:
        return self.elected_at + self.timing.wait
