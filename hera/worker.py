"""A measure worker: one thread that runs one measure on an absolute schedule.

Deadline k is ``start + k * period`` on the monotonic clock, so the loop never drifts (the
original slept a relative ``timeout`` and drifted). A step that starts late is counted in
the jitter figures; deadlines missed entirely are skipped and counted as overruns, never
run in a burst.

Timer coalescing: a worker given a ``phase`` (a monotonic instant) runs its first step at
once, as any worker, and its later steps on the grid ``phase + j * period``, the first of
them at least half a period after that first step. Nodes give the phase of a wall-clock
grid (:func:`wall_grid`): a measure's steps fall its spec's ``offset`` (default 0) past each
multiple of its period in epoch time, on every node alike. The measures that share a period
then wake together, on a node and across the nodes of a cluster whose clocks are in step,
and their samples leave in batches: the 5-node observer cluster (``hera bench bus``) cost
6.0-10.0 % of a core, against 7.8-13.4 % with a grid per node. Different offsets take
turns: three 10 Hz range sensors at offsets 0, 1/30 and 2/30 s give a fusion a reading
every 33 ms rather than three at once every 100 ms.

A worker given a :class:`~hera.beat.Beat` (a measure declared ``thread = "shared"``) runs
its first step at once in its own thread, then has the beat's thread run its later steps
(:meth:`Worker.beat_step`) while its own thread waits for the end; everything else is the
same.

A measure whose ``init`` raises :class:`~hera.measure.NotReady` waits: its ``trouble`` says
why, and ``init`` is tried again every :data:`NOT_READY_RETRY_S` until it starts or the
worker is stopped (no crash, no restart).

The worker publishes what the measure returns through the node's ``publish`` function and
reports its exit (normal or with the exception) to its supervisor.
"""

from __future__ import annotations

import itertools
import logging
import math
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable, Mapping
from typing import Any

from hera import wallclock
from hera.beat import Beat
from hera.measure import Measure, MeasureContext, NotReady, Reading, own_keys, readings_of
from hera.stopflag import StopFlag

log = logging.getLogger("hera.worker")

NOT_READY_RETRY_S = 2.0
"""Seconds between two tries of a measure's ``init`` that raised NotReady."""


class InjectedFault(RuntimeError):
    """A crash injected through the control plane (fault campaigns)."""


class WorkerStats:
    """Counters and recent timing of one worker; read by the status query."""

    WINDOW = 512

    def __init__(self) -> None:
        self.steps = 0
        self.published = 0
        self.empty = 0
        self.overruns = 0
        self.skipped_slots = 0
        self.lateness = deque(maxlen=self.WINDOW)  # seconds after the deadline a step began
        self.publish_times = deque(maxlen=64)  # monotonic times of recent publications

    def rate(self, now: float | None = None) -> float:
        """Publications per second over the recent window (0 if idle for 3 periods)."""
        t = self.publish_times
        if len(t) < 2:
            return 0.0
        now = time.monotonic() if now is None else now
        span = t[-1] - t[0]
        if span <= 0 or now - t[-1] > 3 * span / (len(t) - 1) + 1.0:
            return 0.0
        return (len(t) - 1) / span

    def jitter_ms(self) -> dict[str, float]:
        """p50, p99 and max lateness of recent steps, in milliseconds."""
        if not self.lateness:
            return {"p50": 0.0, "p99": 0.0, "max": 0.0}
        xs = sorted(self.lateness)
        pick = lambda q: xs[min(len(xs) - 1, int(q * len(xs)))]  # noqa: E731
        return {"p50": pick(0.5) * 1e3, "p99": pick(0.99) * 1e3, "max": xs[-1] * 1e3}


def on_grid(phase: float, period: float, t: float) -> float:
    """The first instant ``phase + j * period`` (integer j) at or after ``t`` (seconds)."""
    return phase + math.ceil((t - phase) / period) * period


def wall_grid(offset: float, period: float, wall: float, mono: float) -> float:
    """A monotonic instant at which the wall clock reads ``offset`` past a multiple of
    ``period`` (seconds), from one reading of both clocks (``wall`` epoch, ``mono``
    monotonic): the ``phase`` of a grid that workers of other processes and hosts share."""
    return mono - (wall - offset) % period


PublishFn = Callable[[str, Reading, Any], None]
SlotRunner = Callable[[Callable[[], Any]], "tuple[bool, Any, Any]"]


class Worker:
    """Runs ``measure_cls`` with ``args`` in a thread until its iterations end or it stops.

    ``on_exit(worker, error)`` is called exactly once from the worker thread when it ends:
    ``error`` is None for a normal end, else the exception. A worker marked
    :attr:`abandoned` (reported hung and replaced) never publishes again.
    """

    _ids = itertools.count(1)

    def __init__(
        self,
        measure_cls: type[Measure],
        args: Mapping[str, Any],
        ctx: MeasureContext,
        publish: PublishFn,
        on_exit: Callable[[Worker, BaseException | None], None],
        slot_runner: SlotRunner | None = None,
        halt: threading.Event | None = None,
        args_source: Callable[[], Mapping[str, Any]] | None = None,
        gate: threading.Event | None = None,
        phase: float | None = None,
        beat: Beat | None = None,
    ) -> None:
        """``phase``: the monotonic instant of its node's shared grid (timer coalescing, see
        the module docstring); None: deadlines count from the worker's own start. ``beat``:
        the beat that runs its steps after the first (``thread = "shared"``), or None."""
        self.id = next(self._ids)
        self.measure_cls = measure_cls
        self.args = args
        self.ctx = ctx
        self.spec = ctx.spec
        self.stats = WorkerStats()
        self.step_started: float | None = None
        self.started_at = time.monotonic()
        self.first_step_at: float | None = None
        self.ended_at: float | None = None
        self.abandoned = False
        self.error: str | None = None
        self._publish = publish
        self._on_exit = on_exit
        self._slot_runner = slot_runner
        self._stop = StopFlag()  # waited on once a step: cheaper than an Event
        self._halt = halt or threading.Event()
        self._fault: str | None = None
        self._args_source = args_source
        self._gate = gate
        self._phase = phase
        self._beat = beat
        self._beat_error: BaseException | None = None
        self._remaining: int | None = None
        self._not_before = 0.0
        self._stepper: int | None = None  # ident of the thread running a beat's step
        self._not_stepping = threading.Event()
        self._not_stepping.set()
        self._beat_lock = threading.Lock()  # a beat's step begins, or the worker left: not both
        self._left = False
        self._changes: dict[str, Any] = {}
        self._changes_lock = threading.Lock()
        self.measure: Measure | None = None
        self.ready = threading.Event()
        """Set once ``init`` has returned (a gated worker then waits for its gate)."""
        self.handover: tuple[str, Mapping[str, Any]] | None = None
        """(old version, old state) for :meth:`Measure.code_change`, set before the gate."""
        self._retire: Callable[[Worker], None] | None = None
        self._retire_lock = threading.Lock()
        self._retiring = False
        self.retired_deadline: float | None = None
        """The deadline (monotonic) whose step this worker gave up to its replacement (hot
        reload), and ``retired_at`` when it did (woken for that deadline, as late as any
        step may be)."""
        self.retired_at: float | None = None
        self.thread = threading.Thread(
            target=self._run, name=f"measure-{self.spec.name}-{self.id}", daemon=True
        )

    def start(self) -> None:
        self.started_at = time.monotonic()
        self.thread.start()

    def stop(self) -> None:
        """Ask the loop to end after the current step."""
        self._stop.set()

    def retire(self, hand: Callable[[Worker], None], now: bool = False) -> None:
        """The old side of a hot reload: end at the next deadline instead of stepping (at
        once if ``now``) and, the measure closed, call ``hand(self)`` in this worker's
        thread before reporting the end, so that the replacement steps on this worker's
        schedule. Not called if the worker crashes first; :meth:`cancel_retire` takes it
        back."""
        with self._retire_lock:
            self._retire = hand
        if now:
            self._stop.set()

    def cancel_retire(self) -> bool:
        """Take back :meth:`retire`; False if ``hand`` has already been called."""
        with self._retire_lock:
            if self._retiring:
                return False
            self._retire = None
            return True

    def inject(self, fault: str) -> None:
        """Make the next step ``crash`` (raise InjectedFault) or ``hang`` (block until the node
        halts)."""
        if fault not in ("crash", "hang"):
            raise ValueError(f"unknown worker fault {fault!r}: use 'crash' or 'hang'")
        self._fault = fault

    def _run(self) -> None:
        error: BaseException | None = None
        unfollow = None
        try:
            if not self._init_when_ready():
                return
            unfollow = self._follow_args()
            self.ready.set()
            if self._gate is not None and not self._wait_gate():
                return
            if self.handover is not None:
                self.measure.code_change(*self.handover)
            if self._beat is None:
                self._loop()
            else:
                self._loop_on_beat(self._beat)
        except BaseException as e:  # reported to the supervisor, which decides
            error = e
            self.error = f"{type(e).__name__}: {e}"
            if not self.abandoned:
                log.warning(
                    "measure %s crashed: %s\n%s",
                    self.spec.name,
                    self.error,
                    "".join(traceback.format_exception(e)),
                )
        finally:
            if unfollow is not None:
                unfollow()
            if self.measure is not None:
                try:
                    self.measure.close()
                except Exception as e:
                    log.warning("measure %s close() failed: %s", self.spec.name, e)
            self.step_started = None
            self.ended_at = time.monotonic()
            self._stop.close()  # this thread waits on it no more
            if error is None:
                self._hand_over()
            self._on_exit(self, error)

    def _init_when_ready(self) -> bool:
        """Create and init the measure; while ``init`` raises NotReady, say why and try again
        every NOT_READY_RETRY_S. False if the worker was stopped while waiting."""
        waiting_since: float | None = None
        while True:
            self.measure = self.measure_cls()
            try:
                self.measure.init(self.args, self.ctx)
            except NotReady as e:
                failed, self.measure = self.measure, None
                try:
                    failed.close()
                except Exception as ce:  # what init opened, half done
                    log.warning("measure %s close() failed: %s", self.spec.name, ce)
                self.ctx.trouble = f"waiting to start: {e}"
                if waiting_since is None:
                    waiting_since = time.monotonic()
                    log.warning(
                        "measure %s waits to start: %s (trying again every %g s)",
                        self.spec.name,
                        e,
                        NOT_READY_RETRY_S,
                    )
                if self._stop.wait(NOT_READY_RETRY_S) or self.abandoned:
                    return False
                continue
            if waiting_since is not None:
                self.ctx.trouble = None
                log.info(
                    "measure %s started after waiting %.1f s",
                    self.spec.name,
                    time.monotonic() - waiting_since,
                )
            return True

    def _hand_over(self) -> None:
        with self._retire_lock:
            hand = self._retire
            self._retiring = hand is not None
        if hand is not None:
            try:
                hand(self)
            except Exception:
                log.exception("measure %s: handing over to its new code failed", self.spec.name)

    def _wait_gate(self) -> bool:
        """Wait for the gate; False if the worker was stopped first."""
        while not self._gate.wait(0.02):
            if self._stop.is_set() or self.abandoned:
                return False
        return not (self._stop.is_set() or self.abandoned)

    def _follow_args(self) -> Callable[[], None] | None:
        """Collect changes of the measure's own args keys for its next step; return the
        function that stops collecting."""
        store = self.ctx.args
        if store is None or not hasattr(store, "add_listener"):
            return None
        calib, prefix = own_keys(self.ctx.node, self.spec.name)

        def on_change(key: str, value: Any, deleted: bool) -> None:
            if threading.current_thread() is self.thread or threading.get_ident() == self._stepper:
                return  # the measure's own write
            if key == calib or key.startswith(prefix):
                with self._changes_lock:
                    self._changes[key] = None if deleted else value

        store.add_listener(on_change)
        return lambda: store.remove_listener(on_change)

    def _apply_changes(self) -> None:
        """Tell the measure about changed keys; re-create it unless it applied them."""
        with self._changes_lock:
            changes, self._changes = self._changes, {}
        if self.measure.args_changed(changes):
            return
        log.info("measure %s: %s changed; re-creating it", self.spec.name, ", ".join(changes))
        args = self._args_source() if self._args_source is not None else self.args
        old, self.measure = self.measure, None
        old.close()
        self.measure = self.measure_cls()
        self.measure.init(args, self.ctx)

    def _loop(self) -> None:
        period = self.spec.period
        remaining = self.spec.steps
        start = time.monotonic()
        k = 0
        while not self._stop.is_set() and not self.abandoned:
            deadline = start + k * period
            now = time.monotonic()
            if now < deadline:
                if self._stop.wait(deadline - now):
                    break
                now = time.monotonic()
            elif now - deadline >= period:  # missed whole deadlines: skip, never burst
                missed = math.floor((now - deadline) / period)
                self.stats.overruns += missed
                k += missed
                deadline = start + k * period
            if self._retire is not None:  # a hot reload: the new code steps at this deadline
                self.retired_deadline, self.retired_at = deadline, now
                break
            if self._changes:
                self._apply_changes()
                now = time.monotonic()
            self.stats.lateness.append(now - deadline)
            self._step(self.measure, now)
            if k == 0 and self._phase is not None:  # later deadlines on the node's grid
                start = on_grid(self._phase, period, start + period / 2) - period
            k += 1
            if remaining is not None:
                remaining -= 1
                if remaining <= 0:
                    break

    def _loop_on_beat(self, beat: Beat) -> None:
        """The first step at once, as :meth:`_loop`'s; the later ones on ``beat``, this
        thread waiting for the end (stop, retirement, the last iteration or an error of a
        step, which is raised here as if this thread had run it)."""
        now = time.monotonic()
        if self._retire is not None or self._stop.is_set() or self.abandoned:
            return
        if self._changes:
            self._apply_changes()
            now = time.monotonic()
        self.stats.lateness.append(0.0)
        self._step(self.measure, now)
        self._remaining = None if self.spec.steps is None else self.spec.steps - 1
        if self._remaining is not None and self._remaining <= 0:
            return
        self._not_before = now + self.spec.period / 2
        beat.join(self)
        try:
            self._stop.wait()
        finally:
            beat.leave(self)
            with self._beat_lock:
                self._left = True  # no step begins from now on
            self._not_stepping.wait()  # and none runs: the measure is closed after
        if self._beat_error is not None:
            raise self._beat_error

    def beat_step(self, deadline: float) -> None:
        """The step due at ``deadline`` (monotonic), run by the beat's thread; ends the
        worker (sets its stop flag) on retirement, its last iteration or an error, which
        its own thread then raises. Never raises."""
        with self._beat_lock:
            if self._left or self._stop.is_set() or self.abandoned or deadline < self._not_before:
                return
            if self._retire is not None:  # a hot reload: the new code steps at this deadline
                self.retired_deadline, self.retired_at = deadline, time.monotonic()
                self._stop.set()
                return
            self._not_stepping.clear()
        self._stepper = threading.get_ident()
        try:
            now = time.monotonic()
            if self._changes:
                self._apply_changes()
                now = time.monotonic()
            self.stats.lateness.append(now - deadline)
            self._step(self.measure, now)
            if self._remaining is not None:
                self._remaining -= 1
                if self._remaining <= 0:
                    self._stop.set()
        except BaseException as e:  # this worker's crash, raised in its own thread
            self._beat_error = e
            self._stop.set()
        finally:
            self._stepper = None
            self._not_stepping.set()

    def overran(self, missed: int) -> None:
        """``missed`` deadlines went by without a step (its beat was late)."""
        self.stats.overruns += missed

    def _step(self, measure: Measure, started: float) -> None:
        """One step, begun at ``started`` (monotonic; its lateness was taken from it, so
        ``step_started - lateness[-1]`` is the step's deadline, exactly)."""
        self.step_started = started
        if self.first_step_at is None:
            self.first_step_at = self.step_started
        t_wall = wallclock.now()
        fault, self._fault = self._fault, None
        if fault == "crash":
            raise InjectedFault(f"crash injected into {self.spec.name}")
        if fault == "hang":
            self._halt.wait()
            raise InjectedFault(f"hang injected into {self.spec.name} ended by shutdown")
        grant = None
        if self._slot_runner is not None:
            fired, result, grant = self._slot_runner(measure.measure)
            if not fired:
                self.stats.skipped_slots += 1
                result = None
        else:
            result = measure.measure()
        self.step_started = None
        self.stats.steps += 1
        if self.abandoned:
            return
        batch = readings_of(result, t_wall)  # a plain sequence: stamped t_wall at once
        if not batch:
            self.stats.empty += 1
            return
        width = len(getattr(measure, "columns", ()) or ())
        for reading in batch:
            if width and hasattr(reading.values, "__len__") and len(reading.values) != width:
                # a programming error: logged rows of another width made the whole run
                # unreadable for hera eval; better a crash that names it
                raise ValueError(
                    f"measure {self.spec.name} returned {len(reading.values)} values for its "
                    f"{width} columns ({', '.join(measure.columns)})"
                )
            if reading.t is None:
                reading = Reading(reading.values, t_wall)
            self._publish(self.spec.name, reading, grant)
            self.stats.published += 1
            self.stats.publish_times.append(time.monotonic())
