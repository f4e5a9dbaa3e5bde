"""A beat: one thread that steps, at each deadline, the measures that share it.

By default every measure worker has a thread of its own that wakes at each of its deadlines
(:mod:`hera.worker`). The measures of one node with the same period and offset wake at the
same instants anyway (timer coalescing), so a measure declared ``thread = "shared"`` is
stepped instead by its node's beat of that period and offset: one wake for all of them, in
the order they joined, each step still its own worker's (its lateness, publication,
counters, faults and restarts). Four streams at 50 Hz then cost one wake, not four.

What sharing costs: a step that blocks holds up the steps after it on that deadline (their
lateness shows it), and a step that hangs stops the beat until the supervisor has reported
its worker hung (after ``hang_factor`` periods, as any hang): the hung worker's thread then
leaves the beat, which goes on in a new thread, and the old one ends when (if ever) that
step returns. A worker's first step runs in its own thread at once, as any worker's; it
joins the beat for the next deadline at least half a period later.

A beat's thread runs while it has members: the first to join starts it, the last to leave
ends it. :class:`Beat` knows workers through :class:`Member` only: ``beat_step(deadline)``,
``overran(n)``, ``abandoned``.
"""

from __future__ import annotations

import math
import threading
import time
from typing import Protocol

from hera.stopflag import StopFlag


class Member(Protocol):
    """What a beat needs of a worker it steps."""

    abandoned: bool

    def beat_step(self, deadline: float) -> None:
        """Run the member's step due at ``deadline`` (monotonic), or nothing when it is not
        due or has stopped; never raises (the member reports its own errors)."""

    def overran(self, missed: int) -> None:
        """``missed`` deadlines passed without a step (the beat was late past them)."""


class Beat:
    """Steps its members at ``phase + j * period`` (monotonic seconds); see the module
    docstring."""

    def __init__(self, period: float, phase: float, name: str = "beat") -> None:
        if not period > 0:
            raise ValueError(f"a beat's period must be > 0 s, got {period!r}")
        self.period = period
        self.phase = phase
        self.name = name
        self._lock = threading.Lock()
        self._members: list[Member] = []
        self._generation = 0
        self._wake: StopFlag | None = None  # set when the current thread must end
        self.thread: threading.Thread | None = None
        self.stepping: Member | None = None
        """The member whose step the beat's thread is running, or None."""

    @property
    def members(self) -> list[Member]:
        """The members, in stepping order."""
        with self._lock:
            return list(self._members)

    def join(self, member: Member) -> None:
        """Step ``member`` from the next deadline on; starts the thread if none runs."""
        with self._lock:
            self._members.append(member)
            if self.thread is None:
                self._spawn()

    def leave(self, member: Member) -> None:
        """Step ``member`` no more. When the beat's thread is inside an abandoned member's
        step (a hang), the others go on in a new thread; the thread ends with the last
        member."""
        with self._lock:
            if member in self._members:
                self._members.remove(member)
            if not self._members:
                self._end()
            elif self.stepping is member and member.abandoned:
                self._end()
                self._spawn()

    def _spawn(self) -> None:
        """A new thread for the current members (the lock held)."""
        self._generation += 1
        self._wake = StopFlag()
        self.thread = threading.Thread(
            target=self._run,
            args=(self._generation, self._wake),
            name=f"{self.name}-{self._generation}",
            daemon=True,
        )
        self.thread.start()

    def _end(self) -> None:
        """End the current thread after its step (the lock held)."""
        if self._wake is not None:
            self._wake.set()
        self._generation += 1
        self._wake = None
        self.thread = None
        self.stepping = None

    def _run(self, generation: int, wake: StopFlag) -> None:
        period = self.period
        try:
            deadline = self.phase + math.ceil((time.monotonic() - self.phase) / period) * period
            while True:
                now = time.monotonic()
                if now < deadline and wake.wait(deadline - now):
                    return
                missed = math.floor((time.monotonic() - deadline) / period)
                deadline += max(0, missed) * period  # never a burst of late steps
                with self._lock:
                    if generation != self._generation:
                        return
                    members = list(self._members)
                for m in members:
                    if missed > 0:
                        m.overran(missed)
                    with self._lock:
                        if generation != self._generation:
                            return
                        self.stepping = m
                    m.beat_step(deadline)
                    with self._lock:
                        if generation != self._generation:
                            return
                        self.stepping = None
                deadline += period
        finally:
            wake.close()
