"""StopFlag: the Event semantics a worker's loop relies on, with real threads and real
file descriptors (none left open)."""

from __future__ import annotations

import inspect
import os
import sys
import threading
import time

import pytest
from nodes_helpers import make_ctx

from hera import stopflag
from hera.measure import Measure
from hera.stopflag import StopFlag
from hera.worker import Worker

_WAIT = StopFlag.wait.__code__
_lines, _first = inspect.getsourcelines(StopFlag.wait)
_PAST_CHECK = _first + next(i for i, line in enumerate(_lines) if "if self._set:" in line) + 1


def open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


def _all_waiting(threads: list[threading.Thread], limit: float = 10.0) -> None:
    """Return once every thread is inside StopFlag.wait past its "already set?" check (so
    set() must wake it, not let it through): read from the threads' frames."""
    deadline = time.monotonic() + limit
    while True:
        frames = sys._current_frames()
        if all(
            (fr := frames.get(t.ident)) is not None
            and fr.f_code is _WAIT
            and fr.f_lineno > _PAST_CHECK
            for t in threads
        ):
            return
        assert time.monotonic() < deadline, "the waiters never reached the wait"
        time.sleep(0.001)


def _waiters(f: StopFlag, timeouts: list[float | None]) -> tuple[list[threading.Thread], list]:
    results: list = []
    lock = threading.Lock()

    def run(timeout):
        r = f.wait(timeout)
        with lock:
            results.append(r)

    ts = [threading.Thread(target=run, args=(t,), daemon=True) for t in timeouts]
    for t in ts:
        t.start()
    return ts, results


def test_an_unset_flag_waits_out_its_timeout_and_never_blocks_on_zero():
    f = StopFlag()
    t0 = time.monotonic()
    assert f.wait(0.05) is False
    assert time.monotonic() - t0 >= 0.045
    assert f.wait(0) is False and f.wait(-1.0) is False and not f.is_set()
    f.close()


def test_set_wakes_blocked_waiters_at_once_and_later_waits_return_true():
    f = StopFlag()
    ts, results = _waiters(f, [None, 60.0, 60.0])
    _all_waiting(ts)  # all three are blocked in select
    t0 = time.monotonic()
    f.set()
    for t in ts:
        t.join(10)
    assert results == [True] * 3
    assert time.monotonic() - t0 < 10  # not one of them waited out its 60 s
    assert f.is_set() and f.wait(60.0) is True and f.wait(None) is True and f.wait(0) is True
    f.close()


def test_concurrent_sets_are_one_set():
    for _ in range(30):
        f = StopFlag()
        errors: list[BaseException] = []
        start = threading.Barrier(8)

        def setter(f=f, errors=errors, start=start) -> None:
            start.wait()
            try:
                f.set()
            except BaseException as e:
                errors.append(e)

        ts = [threading.Thread(target=setter) for _ in range(8)]
        for t in ts:
            t.start()
        for t in ts:
            t.join(10)
        assert errors == [] and f.wait(0) is True
        f.close()


def test_close_gives_the_descriptor_back_and_the_flag_still_works():
    before = open_fds()
    flags = [StopFlag() for _ in range(40)]
    assert open_fds() == before + 40  # one eventfd each
    for f in flags:
        f.close()
    assert open_fds() == before
    f = flags[0]
    t0 = time.monotonic()
    assert f.wait(0.05) is False and time.monotonic() - t0 >= 0.045  # still a timed wait
    ts, results = _waiters(f, [60.0])
    time.sleep(0.05)
    f.set()  # after close: no write to a descriptor that may be another file's now
    ts[0].join(10)
    assert results == [True] and f.wait(0) is True


def test_past_selects_limit_it_falls_back_to_an_event(monkeypatch):
    monkeypatch.setattr(stopflag, "FD_LIMIT", 0)  # every descriptor is "too high"
    before = open_fds()
    f = StopFlag()
    assert open_fds() == before  # given back at once
    ts, results = _waiters(f, [60.0])
    f.set()
    ts[0].join(10)
    assert results == [True] and f.wait(0) is True


class Quick(Measure):
    def measure(self):
        return [1.0]


@pytest.mark.parametrize("how", ["stopped", "ran out"])
def test_a_worker_leaves_no_descriptor_open(how):
    before = open_fds()
    done = []
    workers = []
    for _ in range(10):
        ctx = make_ctx("w", period=0.01, iterations=None if how == "stopped" else 3)
        w = Worker(Quick, {}, ctx, lambda name, r, g: None, lambda w, e: done.append(e))
        w.start()
        workers.append(w)
    for w in workers:
        if how == "stopped":
            w.stop()
        w.thread.join(10)
    assert done == [None] * 10
    assert open_fds() == before
