"""The worker's absolute schedule: deadlines k * period, no drift, overruns skipped."""

from __future__ import annotations

import threading
import time

from nodes_helpers import make_ctx
from retire_checks import retire_and_check

from hera.measure import Measure, Reading
from hera.worker import Worker, on_grid, wall_grid

_RUNNING: dict[threading.Thread, Worker] = {}


def deadline() -> float:
    """Called in a step: the deadline the worker set for it (monotonic s), read from the
    worker (when the step began less how late that was), free of any delay between the
    worker's clock reading and the measure's."""
    w = _RUNNING[threading.current_thread()]
    return w.step_started - w.stats.lateness[-1]


def start_worker(cls, period, iterations, args=None, phase=None):
    ctx = make_ctx("w", period=period, iterations=iterations)
    published, done = [], threading.Event()
    w = Worker(
        cls,
        args or {},
        ctx,
        lambda name, r, g: published.append(r),
        lambda w, e: done.set(),
        phase=phase,
    )
    _RUNNING[w.thread] = w
    w.start()
    return w, published, done


def run_worker(cls, period, iterations, args=None, phase=None):
    w, published, done = start_worker(cls, period, iterations, args, phase)
    assert done.wait(30)
    return w, published


class Stamp(Measure):
    def measure(self):
        return [time.monotonic()]


class SlowEveryThird(Measure):
    def init(self, args, ctx):
        super().init(args, ctx)
        self.n = 0

    def measure(self):
        self.n += 1
        began = time.monotonic()
        time.sleep(0.006 if self.n % 3 == 0 else 0.0)  # 60 % of a period, every third step
        return Reading([began, deadline()], t=123.0)


def step_slots(pub, period):
    """Each step's deadline as the worker set it (``values[1]``, from :func:`deadline`),
    in periods from the first one."""
    deadlines = [r.values[1] for r in pub]
    return [(t - deadlines[0]) / period for t in deadlines]


def on_the_grid(slots):
    """Every slot a whole number of periods (to float rounding)."""
    return all(abs(s - round(s)) < 1e-6 for s in slots)


def test_schedule_does_not_drift_even_when_steps_take_time():
    period = 0.01
    w, pub = run_worker(SlowEveryThird, period, 60)
    assert len(pub) == 60
    # step k's deadline is start + k * period whatever the steps took: a worker that slept
    # a period after each step would drift by 6 ms every third step, off the grid at once.
    # (Judged on the deadlines, not on overruns == 0: on a loaded machine a 6 ms sleep may
    # overshoot into the next deadline, which is then skipped and counted, as it should.)
    slots = step_slots(pub, period)
    assert on_the_grid(slots)
    k = [round(s) for s in slots]
    assert all(b > a for a, b in zip(k, k[1:], strict=False))  # never two steps on one
    assert w.stats.overruns == k[-1] - (len(k) - 1)  # every skipped deadline counted
    assert all(r.t == 123.0 for r in pub)  # an explicit measurement time is kept


def test_missed_deadlines_are_skipped_and_counted_not_burst():
    class Stall(Measure):
        def init(self, args, ctx):
            super().init(args, ctx)
            self.n = 0

        def measure(self):
            self.n += 1
            began = time.monotonic()
            if self.n == 2:
                time.sleep(0.055)  # misses about 5 deadlines of 10 ms
            return [began, deadline()]

    period = 0.01
    w, pub = run_worker(Stall, period, 10)
    assert len(pub) == 10
    # Judged on the deadlines the worker set (the steps' start times were a CI failure:
    # one was 3.5 ms or more off the grid on a loaded machine).
    slots = step_slots(pub, period)
    late = list(w.stats.lateness)
    assert on_the_grid(slots)  # every deadline on start + k * period
    k = [round(s) for s in slots]
    assert k[:2] == [0, 1]
    assert k[2] - k[1] >= 5  # the deadlines the stall missed are skipped...
    assert all(b > a for a, b in zip(k, k[1:], strict=False))  # ...never two steps on one
    # and every skipped deadline is counted
    assert w.stats.overruns == sum(b - a - 1 for a, b in zip(k, k[1:], strict=False)) >= 4
    assert w.stats.jitter_ms()["max"] == max(late) * 1e3


def test_none_is_not_published_and_iterations_end_normally():
    class Odd(Measure):
        def init(self, args, ctx):
            super().init(args, ctx)
            self.n = 0

        def measure(self):
            self.n += 1
            return [float(self.n)] if self.n % 2 else None

    w, pub = run_worker(Odd, 0.001, 6)
    assert [r.values for r in pub] == [[1.0], [3.0], [5.0]]
    assert (w.stats.steps, w.stats.empty, w.error) == (6, 3, None)


def test_on_grid_gives_the_first_grid_instant_at_or_after_t():
    assert on_grid(10.0, 0.5, 10.0) == 10.0
    assert on_grid(10.0, 0.5, 10.1) == 10.5
    assert on_grid(10.0, 0.5, 9.9) == 10.0
    assert on_grid(10.0, 0.5, 12.25) == 12.5


def grid_offsets(times, phase, period):
    """Where each step began within its period of the grid ``phase + j * period``."""
    return [(t - phase) % period for t in times]


def test_workers_sharing_a_phase_step_together_after_their_first_step():
    """Timer coalescing: two workers started half a period apart, given one phase, run
    their first step at once and every later one on the shared grid."""
    period, phase = 0.1, time.monotonic()
    time.sleep(0.02)
    a, pub_a, done_a = start_worker(Stamp, period, 8, phase=phase)
    time.sleep(period / 2)
    t_start = time.monotonic()
    b, pub_b, done_b = start_worker(Stamp, period, 8, phase=phase)
    assert done_a.wait(30) and done_b.wait(30)
    first_b = pub_b[0].values[0]
    assert first_b - t_start < period / 2  # the first step is not held back to the grid
    for pub in (pub_a, pub_b):
        times = [r.values[0] for r in pub]
        assert times[1] - times[0] >= period / 2  # never two steps within half a period
        # a step begins after its grid instant (late at most by the machine's wake-up)
        assert all(off < period / 2 for off in grid_offsets(times[1:], phase, period)), times


def test_without_a_phase_a_worker_keeps_its_own_grid():
    """The check above must fail for a worker that is not coalesced: started 0.6 period
    off the grid, it stays there."""
    period, phase = 0.1, time.monotonic()
    time.sleep(0.6 * period)
    _, pub = run_worker(Stamp, period, 6)
    offsets = grid_offsets([r.values[0] for r in pub][1:], phase, period)
    assert not all(off < period / 2 for off in offsets), offsets


class WallStamp(Measure):
    def measure(self):
        return [time.time()]


def test_wall_grid_is_the_monotonic_instant_of_the_wall_clocks_offset():
    # wall 1000.25 s at monotonic 50 s: the wall clock read 1000.2 (0.2 s past the 0.5 s
    # multiple 1000.0) 0.05 s before
    assert abs(wall_grid(0.2, 0.5, 1000.25, 50.0) - 49.95) < 1e-9
    assert abs(wall_grid(0.3, 0.5, 1000.25, 50.0) - 49.55) < 1e-9  # 999.8, 0.45 s before


def test_workers_of_one_period_take_turns_at_their_wall_clock_offsets():
    """Two workers (as on two nodes) with offsets 0 and half the period step on the wall
    clock's grid, half a period apart, whenever each was started."""
    period = 0.1
    workers = []
    for offset in (0.0, 0.05):
        workers.append((offset, start_worker(WallStamp, period, 8, phase=_wall_phase(offset))))
        time.sleep(0.013)  # started at unrelated instants
    for offset, (_, pub, done) in workers:
        assert done.wait(30)
        stamps = [r.values[0] for r in pub][1:]  # the first step runs at once
        late = [(t - offset) % period for t in stamps]
        assert all(x < period / 2 for x in late), (offset, late)
        other = [(t - (0.05 - offset)) % period for t in stamps]
        assert not all(x < period / 2 for x in other), other  # the check tells them apart


def _wall_phase(offset):
    return wall_grid(offset, 0.1, time.time(), time.monotonic())


class Batches(Measure):
    def init(self, args, ctx):
        super().init(args, ctx)
        self.n = 0

    def measure(self):
        self.n += 1
        if self.n % 2 == 0:
            return []  # nothing this step
        return [Reading([self.n, k], t=100.0 + self.n + k / 10) for k in range(3)]


def test_a_list_of_readings_is_published_in_order_and_counted():
    w, pub = run_worker(Batches, 0.005, 4)
    assert [(r.t, list(r.values)) for r in pub] == [
        (100.0 + n + k / 10, [n, k]) for n in (1, 3) for k in range(3)
    ]
    assert (w.stats.published, w.stats.empty) == (6, 2)


# -- retire: the old side of a hot reload -------------------------------------------------------
class Journal(Measure):
    """Steps and its close, each with the instant it happened."""

    def init(self, args, ctx):
        super().init(args, ctx)
        self.events = args["events"]

    def measure(self):
        self.events.append(("step", time.monotonic(), deadline()))
        return [1.0]

    def close(self):
        self.events.append(("close", time.monotonic()))


def start_journal(period):
    events: list = []
    w, published, done = start_worker(Journal, period, None, {"events": events})
    return w, events, done


def test_a_retiring_worker_hands_over_at_its_next_deadline_after_closing():
    period = 0.05
    w, events, done = start_journal(period)
    while sum(e[0] == "step" for e in events) < 3:
        time.sleep(0.001)
    retire_and_check(w, events, done, period)


def test_a_retire_taken_back_before_the_deadline_leaves_the_worker_stepping():
    w, events, done = start_journal(0.2)
    while not events:
        time.sleep(0.001)
    handed: list = []
    w.retire(handed.append)
    assert w.cancel_retire()
    while sum(e[0] == "step" for e in events) < 3:
        assert not done.is_set()
        time.sleep(0.01)
    w.stop()
    assert done.wait(5)
    assert handed == [] and events[-1][0] == "close"


def test_retire_now_does_not_wait_for_a_long_period():
    period = 30.0
    w, events, done = start_journal(period)
    while not events:
        time.sleep(0.001)
    handed: list = []
    w.retire(handed.append, now=True)
    assert done.wait(period / 2)  # long before its next deadline
    assert handed == [w] and not w.cancel_retire()  # once handed over, it cannot be taken back


class TwoForThree(Measure):
    columns = ("x [m]", "v [m/s]", "b [m/s^2]")

    def measure(self):
        return [1.0, 2.0]


def test_a_reading_of_another_width_than_the_columns_is_a_crash_that_says_so():
    """A model returning 2 values for its 3 columns was published and logged, and hera eval
    then refused the whole run ("2 values where the rows have 3")."""
    ctx = make_ctx("w", period=0.01, iterations=3)
    published, errors, done = [], [], threading.Event()
    w = Worker(
        TwoForThree,
        {},
        ctx,
        lambda name, r, g: published.append(r),
        lambda w, e: (errors.append(e), done.set()),
    )
    w.start()
    assert done.wait(30)
    assert published == []
    assert str(errors[0]) == (
        "measure w returned 2 values for its 3 columns (x [m], v [m/s], b [m/s^2])"
    )
