"""OTP-style supervision of measure workers.

Semantics follow OTP's supervisor (REFERENCE "Core framework"):

- strategies ``one_for_one`` (default: restart only the child that ended),
  ``one_for_all`` (restart every child) and ``rest_for_one`` (the child and those declared
  after it);
- restart types ``permanent`` (always restarted), ``transient`` (restarted only after an
  abnormal end) and ``temporary`` (never restarted);
- restart intensity: at most ``intensity`` restarts within any sliding ``period`` seconds;
  one more and the supervisor gives up and escalates (the node process exits non-zero and
  the launcher restarts it);
- a child whose step runs longer than ``hang_factor * period`` (at least ``hang_min`` s) is
  reported hung, abandoned (it can never publish again) and replaced, which counts as a
  restart;
- backoff (not in OTP): a child that crashes again less than ``FAST_CRASH_S`` after it was
  started waits before its next start, 50 ms doubling up to 2 s, so a measure whose sensor
  is unplugged does not burn the whole restart intensity within milliseconds. Its first
  restart is always immediate.

A restarted child is re-created from its original arguments (the ``start`` callable of its
:class:`Child` is fixed when the child is added), so a calibration is never redone.
Reaction is event driven: a worker's end wakes the supervisor at once.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from hera.worker import Worker

log = logging.getLogger("hera.supervisor")

STRATEGIES = ("one_for_one", "one_for_all", "rest_for_one")
FAST_CRASH_S = 1.0
BACKOFF_FIRST_S = 0.05
BACKOFF_MAX_S = 2.0


def backoff_delay(fast_crashes: int) -> float:
    """Seconds to wait before restarting a child after its ``fast_crashes``-th consecutive
    crash within FAST_CRASH_S of its start: 0 for the first, then 50 ms doubling to 2 s."""
    if fast_crashes <= 1:
        return 0.0
    return min(BACKOFF_FIRST_S * 2 ** (fast_crashes - 2), BACKOFF_MAX_S)


@dataclass
class Child:
    """One supervised child: how to start it and what has happened to it."""

    id: str
    start: Callable[[Callable[[Worker, BaseException | None], None]], Worker]
    restart: str = "permanent"
    worker: Worker | None = None
    state: str = "stopped"  # running | restarting | stopped | done | failed
    restarts: int = 0
    hangs: int = 0
    crashes: int = 0
    last_error: str | None = None
    last_restart_ms: float | None = None
    last_exit_at: float | None = None  # monotonic time the previous worker ended or hung
    fast_crashes: int = 0  # consecutive crashes within FAST_CRASH_S of a start
    stopped_by_request: bool = field(default=False, repr=False)

    @property
    def restart_ms(self) -> float | None:
        """Milliseconds from the last crash or hang to the replacement's first step."""
        w = self.worker
        if self.last_exit_at is None or w is None or w.first_step_at is None:
            return None
        return round((w.first_step_at - self.last_exit_at) * 1e3, 3)


IDLE_WAKE = 1.0
"""The longest the supervisor's watcher sleeps when no hang can come sooner."""


class Supervisor:
    """Starts, watches and restarts :class:`Child` workers; see the module docstring.

    ``hang_check``: the shortest the watcher sleeps between two looks for hung steps (it
    sleeps until the next step could have hung, at most :data:`IDLE_WAKE` s).
    """

    def __init__(
        self,
        intensity: int = 10,
        period: float = 60.0,
        strategy: str = "one_for_one",
        on_escalate: Callable[[str], None] | None = None,
        hang_check: float = 0.005,
    ) -> None:
        if strategy not in STRATEGIES:
            raise ValueError(f"strategy must be one of {STRATEGIES}, got {strategy!r}")
        if intensity < 0 or period <= 0:
            raise ValueError("intensity must be >= 0 and period > 0")
        self.intensity = intensity
        self.period = period
        self.strategy = strategy
        self.children: dict[str, Child] = {}
        self.escalated: str | None = None
        self._on_escalate = on_escalate
        self._restarts: deque[float] = deque()
        self._pending: list[tuple[float, Child, str]] = []  # delayed restarts (backoff)
        self._events: queue.Queue[tuple[Worker, BaseException | None] | None] = queue.Queue()
        self._lock = threading.RLock()
        self._hang_check = hang_check
        self._closing = False
        self._thread = threading.Thread(target=self._watch, name="supervisor", daemon=True)
        self._thread.start()

    # -- public API ---------------------------------------------------------------------
    def add(self, child: Child, start: bool = True) -> Child:
        """Register ``child`` (ids are unique) and start it unless ``start`` is False."""
        with self._lock:
            if child.id in self.children:
                raise ValueError(f"a child called {child.id!r} is already supervised")
            self.children[child.id] = child
            if start:
                self._start(child)
        return child

    def start_child(self, child_id: str) -> None:
        """(Re)start a stopped or finished child; it keeps its original arguments."""
        with self._lock:
            child = self._get(child_id)
            if child.state in ("running", "restarting"):
                raise ValueError(f"measure {child_id!r} is already {child.state}")
            child.fast_crashes = 0
            self._start(child)

    def stop_child(self, child_id: str) -> None:
        """Stop a child; it is not restarted until :meth:`start_child`."""
        with self._lock:
            child = self._get(child_id)
            child.stopped_by_request = True
            self._pending = [p for p in self._pending if p[1] is not child]
            if child.worker is not None:
                child.worker.stop()
            child.state = "stopped"

    def remove(self, child_id: str) -> Child:
        """Stop a child and forget it (a measure added at run time, stopped for good)."""
        with self._lock:
            self.stop_child(child_id)
            return self.children.pop(child_id)

    def replace(
        self,
        child_id: str,
        worker: Worker,
        start: Callable[[Callable[[Worker, BaseException | None], None]], Worker],
    ) -> Worker | None:
        """Hand a child to ``worker`` (already started; its ends must be reported to
        :meth:`exited`) and make ``start`` its factory for later restarts. The previous
        worker is abandoned (it never publishes again), asked to stop and returned."""
        with self._lock:
            child = self._get(child_id)
            old, child.worker, child.start = child.worker, worker, start
            child.state = "running"
            child.stopped_by_request = False
            self._pending = [p for p in self._pending if p[1] is not child]
            if old is not None:
                old.abandoned = True
                old.stop()
            return old

    def exited(self, worker: Worker, error: BaseException | None) -> None:
        """Report the end of one of the children's workers (the ``on_exit`` of workers)."""
        self._events.put((worker, error))

    def worker(self, child_id: str) -> Worker:
        """The running worker of a child (for fault injection)."""
        with self._lock:
            child = self._get(child_id)
            if child.worker is None or child.state != "running":
                raise ValueError(f"measure {child_id!r} is not running")
            return child.worker

    def shutdown(self, timeout: float = 2.0) -> None:
        """Stop every child and wait up to ``timeout`` s in total for their threads."""
        with self._lock:
            self._closing = True
            workers = [c.worker for c in self.children.values() if c.worker is not None]
            for w in workers:
                w.stop()
        deadline = time.monotonic() + timeout
        for w in workers:
            w.thread.join(max(0.0, deadline - time.monotonic()))
        self._events.put(None)
        self._thread.join(1.0)

    # -- internals ----------------------------------------------------------------------
    def _get(self, child_id: str) -> Child:
        try:
            return self.children[child_id]
        except KeyError:
            known = ", ".join(sorted(self.children)) or "none"
            raise ValueError(f"no measure {child_id!r} on this node (measures: {known})") from None

    def _start(self, child: Child) -> None:
        child.stopped_by_request = False
        child.worker = child.start(self.exited)
        child.state = "running"
        child.worker.start()

    def _watch(self) -> None:
        timeout = self._hang_check
        while True:
            if self._pending:
                due = min(p[0] for p in self._pending) - time.monotonic()
                timeout = max(0.0, min(timeout, due))
            try:
                event = self._events.get(timeout=timeout)
            except queue.Empty:
                event = False
            if event is None:
                return
            with self._lock:
                if self._closing or self.escalated:
                    continue
                if event:
                    self._handle_exit(*event)
                self._start_due()
                timeout = max(self._hang_check, self._check_hangs())

    def _start_due(self) -> None:
        now = time.monotonic()
        due = [p for p in self._pending if p[0] <= now]
        self._pending = [p for p in self._pending if p[0] > now]
        for _, child, reason in due:
            self._restart_group(child, reason)

    def _child_of(self, worker: Worker) -> Child | None:
        for c in self.children.values():
            if c.worker is worker:
                return c
        return None

    def _handle_exit(self, worker: Worker, error: BaseException | None) -> None:
        child = self._child_of(worker)
        if child is None or worker.abandoned:
            return  # a replaced (hung) worker finally ended: already handled
        child.last_exit_at = worker.ended_at
        if error is None:
            child.state = "stopped" if child.stopped_by_request else "done"
            if child.restart != "permanent" or child.stopped_by_request:
                return
            reason = "ended normally (permanent)"
        else:
            child.crashes += 1
            child.last_error = worker.error
            lived = worker.ended_at - worker.started_at  # ended_at is set before the report
            child.fast_crashes = child.fast_crashes + 1 if lived < FAST_CRASH_S else 0
            if child.restart == "temporary":
                child.state = "failed"
                return
            reason = f"crashed: {worker.error}"
        self._restart(child, reason)

    def _check_hangs(self) -> float:
        """Replace the workers whose step has run longer than its limit; return how long
        until the next one could (a step starting now, or the running ones), at most
        :data:`IDLE_WAKE` s: the watcher sleeps that long, not a fixed short tick."""
        now = time.monotonic()
        wake = IDLE_WAKE
        for child in list(self.children.values()):
            w = child.worker
            if w is None or child.state != "running" or w.abandoned:
                continue
            started = w.step_started
            limit = max(w.spec.hang_factor * w.spec.period, w.spec.hang_min)
            wake = min(wake, limit if started is None else limit - (now - started))
            if started is not None and now - started > limit:
                w.abandoned = True
                w.stop()
                child.last_exit_at = now
                child.hangs += 1
                child.last_error = f"hung: step running for {now - started:.2f} s > {limit:.2f} s"
                log.warning("measure %s %s; replacing it", child.id, child.last_error)
                self._restart(child, child.last_error)
        return max(0.0, wake)

    def _restart(self, child: Child, reason: str) -> None:
        now = time.monotonic()
        self._restarts.append(now)
        while self._restarts and now - self._restarts[0] > self.period:
            self._restarts.popleft()
        if len(self._restarts) > self.intensity:
            self.escalated = (
                f"restart intensity exceeded: {len(self._restarts)} restarts within "
                f"{self.period:g} s > {self.intensity} (last: {child.id} {reason})"
            )
            log.error("%s; escalating", self.escalated)
            child.state = "failed"
            if self._on_escalate is not None:
                self._on_escalate(self.escalated)
            return
        delay = backoff_delay(child.fast_crashes)
        if delay > 0:
            child.state = "restarting"
            self._pending.append((now + delay, child, reason))
            return
        self._restart_group(child, reason)

    def _restart_group(self, child: Child, reason: str) -> None:
        ids = list(self.children)
        if self.strategy == "one_for_one":
            group = [child]
        elif self.strategy == "one_for_all":
            group = [self.children[i] for i in ids]
        else:
            group = [self.children[i] for i in ids[ids.index(child.id) :]]
        for c in group:
            if c is not child and c.worker is not None and c.state == "running":
                c.worker.abandoned = True
                c.worker.stop()
            if c is child or c.state in ("running", "restarting"):
                c.restarts += 1
                c.last_restart_ms = round(time.time() * 1e3)
                self._start(c)
        log.info("restarted %s (%s)", child.id, reason)
