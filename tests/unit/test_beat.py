"""Shared stepping (hera.beat): the measures of one period and offset on one thread, each
still its own worker for its schedule, errors, stop, iterations and hangs (real threads,
no bus)."""

from __future__ import annotations

import threading
import time

import pytest
from harness import wait_for
from nodes_helpers import make_ctx
from retire_checks import retire_and_check

from hera.beat import Beat
from hera.measure import Measure, MeasureSpecError
from hera.supervisor import Child, Supervisor
from hera.worker import Worker

PERIOD = 0.01


class Ident(Measure):
    """Publishes the thread that ran each step and the deadline its worker set for it;
    raises at step ``crash_at``, blocks from step ``block_at`` until ``release`` is set."""

    def init(self, args, ctx):
        super().init(args, ctx)
        self.args = args
        self.n = 0
        self.closed = False
        args.setdefault("inits", []).append(self)

    def measure(self):
        self.n += 1
        if self.n == self.args.get("crash_at"):
            raise ValueError("boom")
        if self.n == self.args.get("block_at") and len(self.args["inits"]) == 1:
            self.args["release"].wait(10)
        w = self.args["worker"]()
        assert not self.closed, "a step ran on a closed measure"
        return [float(threading.get_ident()), w.step_started - w.stats.lateness[-1]]

    def close(self):
        self.closed = True


def shared(beat, name, args, published, ended, iterations=None, halt=None):
    """A worker of ``Ident`` on ``beat``; ``published[name]``: its readings."""
    ctx = make_ctx(name, period=PERIOD, iterations=iterations, thread="shared")
    holder = {}
    args = {**args, "worker": lambda: holder["w"]}
    w = Worker(
        Ident,
        args,
        ctx,
        lambda n, r, g: published.setdefault(n, []).append(r.values),
        lambda w, e: ended.setdefault(name, []).append(e),
        halt=halt,
        beat=beat,
    )
    holder["w"] = w
    return w


def test_measures_on_one_beat_step_on_its_thread_at_each_deadline_together():
    beat = Beat(PERIOD, time.monotonic())
    pub, ended = {}, {}
    ws = [shared(beat, f"m{i}", {}, pub, ended) for i in range(3)]
    for w in ws:
        w.start()
    try:
        wait_for(lambda: all(len(pub.get(f"m{i}", ())) >= 20 for i in range(3)), 10, "steps")
    finally:
        for w in ws:
            w.stop()
        for w in ws:
            w.thread.join(5)
    threads = {i: {v[0] for v in pub[f"m{i}"][1:]} for i in range(3)}
    # after its first step (in its own thread), every step of each ran on the beat's thread
    assert threads[0] == threads[1] == threads[2] and len(threads[0]) == 1, threads
    assert all(pub[f"m{i}"][0][0] != next(iter(threads[0])) for i in range(3))
    # all on the beat's grid, and the three share their deadlines
    deadlines = [
        {round((v[1] - beat.phase) / PERIOD, 6) for v in pub[f"m{i}"][1:]} for i in range(3)
    ]
    for d in deadlines:
        assert all(x == int(x) for x in d), d
    common = deadlines[0] & deadlines[1] & deadlines[2]
    assert len(common) >= 10, deadlines
    assert all(ended[f"m{i}"] == [None] for i in range(3))  # stopped: a normal end
    wait_for(lambda: beat.thread is None, 5, "the beat's thread to end with its last member")


def test_a_crash_in_a_shared_step_is_its_workers_alone():
    beat = Beat(PERIOD, time.monotonic())
    pub, ended = {}, {}
    bad = shared(beat, "bad", {"crash_at": 4}, pub, ended)
    good = shared(beat, "good", {}, pub, ended)
    bad.start()
    good.start()
    try:
        wait_for(lambda: "bad" in ended, 10, "the crash reported")
        (error,) = ended["bad"]
        assert isinstance(error, ValueError) and str(error) == "boom"
        assert bad.error == "ValueError: boom" and bad.measure.closed
        n = len(pub["good"])
        wait_for(lambda: len(pub["good"]) >= n + 10, 10, "the other member stepping on")
        assert beat.members == [good]
    finally:
        good.stop()
        good.thread.join(5)
    assert ended["good"] == [None]


def test_a_shared_worker_ends_after_its_iterations():
    beat = Beat(PERIOD, time.monotonic())
    pub, ended = {}, {}
    w = shared(beat, "three", {}, pub, ended, iterations=3)
    w.start()
    w.thread.join(10)
    assert not w.thread.is_alive()
    assert len(pub["three"]) == 3 and ended["three"] == [None]
    assert w.stats.steps == 3 and beat.members == []


def test_a_stopped_shared_worker_is_closed_only_after_its_running_step():
    beat = Beat(PERIOD, time.monotonic())
    pub, ended = {}, {}
    release = threading.Event()
    w = shared(beat, "slow", {"block_at": 3, "release": release}, pub, ended)
    w.start()
    try:
        wait_for(lambda: w.step_started is not None and w.measure.n == 3, 10, "step 3 running")
        w.stop()
        time.sleep(0.05)
        assert not w.measure.closed and w.thread.is_alive()  # waits for the step
    finally:
        release.set()
    w.thread.join(5)
    assert not w.thread.is_alive() and w.measure.closed and ended["slow"] == [None]


def test_a_hung_shared_step_is_replaced_and_the_others_go_on_in_a_new_thread():
    beat = Beat(PERIOD, time.monotonic())
    pub, ended = {}, {}
    release = threading.Event()
    halt = threading.Event()
    args = {"block_at": 5, "release": release, "inits": []}  # blocks in its first life only

    def start_hang(on_exit):
        ctx = make_ctx("hang", period=PERIOD, hang_factor=5, hang_min=0.1, thread="shared")
        holder = {}
        w = Worker(
            Ident,
            {**args, "worker": lambda: holder["w"]},
            ctx,
            lambda n, r, g: pub.setdefault("hang", []).append(r.values),
            on_exit,
            halt=halt,
            beat=beat,
        )
        holder["w"] = w
        return w

    other = shared(beat, "other", {}, pub, ended)
    other.start()
    sup = Supervisor()
    try:
        wait_for(lambda: len(pub.get("other", ())) >= 3, 10, "the other member on the beat")
        beat_thread = pub["other"][-1][0]  # the beat's first thread, before any hang
        sup.add(Child("hang", start_hang))
        wait_for(lambda: sup.children["hang"].hangs == 1, 10, "hang detection")
        n = len(pub["other"])
        wait_for(lambda: len(pub["other"]) >= n + 10, 10, "the other member stepping again")
        assert pub["other"][-1][0] != beat_thread  # on a new beat thread
        wait_for(lambda: len(pub.get("hang", ())) >= 8, 10, "the replacement stepping")
        assert sup.children["hang"].state == "running"
    finally:
        release.set()  # the hung step returns: it must not publish, the old thread ends
        time.sleep(0.05)
        other.stop()
        halt.set()
        sup.shutdown()
        other.thread.join(5)
    assert len(args["inits"]) == 2  # the hung measure and its replacement


def test_shared_is_refused_for_synchronised_measures():
    with pytest.raises(MeasureSpecError, match='thread = "shared" is for unsynchronised'):
        make_ctx("s", thread="shared", sync=True)


class Journal(Measure):
    """Its steps (with the deadline its worker set) and its close, each with its instant."""

    def init(self, args, ctx):
        super().init(args, ctx)
        self.events = args["events"]
        self.worker = args["worker"]

    def measure(self):
        w = self.worker()
        self.events.append(("step", time.monotonic(), w.step_started - w.stats.lateness[-1]))
        return [1.0]

    def close(self):
        self.events.append(("close", time.monotonic()))


def test_a_retiring_shared_worker_hands_over_at_its_next_deadline_after_closing():
    period = 0.05
    beat = Beat(period, time.monotonic())
    events: list = []
    holder: dict = {}
    done = threading.Event()
    ctx = make_ctx("j", period=period, thread="shared")
    w = Worker(
        Journal,
        {"events": events, "worker": lambda: holder["w"]},
        ctx,
        lambda n, r, g: None,
        lambda w, e: done.set(),
        beat=beat,
    )
    holder["w"] = w
    w.start()
    wait_for(lambda: sum(e[0] == "step" for e in events) >= 3, 5, "three steps")
    retire_and_check(w, events, done, period)
    assert beat.members == []
