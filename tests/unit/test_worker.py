"""The worker's absolute schedule: deadlines k * period, no drift, overruns skipped."""

from __future__ import annotations

import threading
import time

from nodes_helpers import make_ctx

from hera.measure import Measure, Reading
from hera.worker import Worker


def run_worker(cls, period, iterations, args=None):
    ctx = make_ctx("w", period=period, iterations=iterations)
    published, done = [], threading.Event()
    w = Worker(
        cls, args or {}, ctx, lambda name, r, g: published.append(r), lambda w, e: done.set()
    )
    w.start()
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
        time.sleep(0.006 if self.n % 3 == 0 else 0.0)  # 60 % of a period, every third step
        return Reading([time.monotonic()], t=123.0)


def test_schedule_does_not_drift_even_when_steps_take_time():
    period = 0.01
    w, pub = run_worker(SlowEveryThird, period, 60)
    times = [r.values[0] for r in pub]
    assert len(times) == 60 and w.stats.overruns == 0
    # step k starts at start + k * period: the last step is not late by the sum of step times
    span = times[-1] - times[0]
    assert abs(span - 59 * period) < 0.5 * period + 0.006
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
            return [began]

    w, pub = run_worker(Stall, 0.01, 10)
    times = [r.values[0] for r in pub]
    assert w.stats.overruns >= 4
    # after the stall every step is back on the grid start + k * period, one step per slot
    slots = [(t - times[0]) / 0.01 for t in times]
    # (step 2 starts late, whenever the stalled step returns: it realigns the grid)
    assert all(abs(s - round(s)) < 0.35 for s in slots[3:])
    gaps = [b - a for a, b in zip(times, times[1:], strict=False)]
    assert min(gaps) > 0.003  # no burst: the missed deadlines are not run back to back
    assert w.stats.jitter_ms()["max"] < 50


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
