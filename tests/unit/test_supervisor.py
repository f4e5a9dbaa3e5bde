"""Supervisor semantics on real worker threads (no bus: a local store and args store)."""

from __future__ import annotations

import threading
import time

import pytest
from harness import wait_for
from nodes_helpers import make_ctx

from hera import worker
from hera.measure import Measure, NotReady
from hera.supervisor import Child, Supervisor
from hera.worker import Worker


class Steps(Measure):
    """Publishes its step count; raises at step ``crash_at`` when given."""

    def init(self, args, ctx):
        super().init(args, ctx)
        self.args = args
        self.n = 0
        self.started = time.monotonic()
        args["inits"].append(self)

    def measure(self):
        self.n += 1
        first = len(self.args["inits"]) == 1
        if self.n == self.args.get("crash_at") and (first or not self.args.get("crash_once")):
            raise ValueError("boom")
        return [float(self.n)]


def make_child(cid, args, published, restart="transient", period=0.005, iterations=None, halt=None):
    def start(on_exit):
        ctx = make_ctx(cid, period=period, iterations=iterations, restart=restart)
        return Worker(
            Steps, args, ctx, lambda name, r, g: published.append((name, r)), on_exit, halt=halt
        )

    return Child(cid, start, restart)


def test_one_for_one_restarts_only_the_crashed_child_with_the_same_args():
    sup = Supervisor(intensity=100, period=10)
    a_args, b_args, pub = {"inits": [], "crash_at": 3}, {"inits": []}, []
    sup.add(make_child("a", a_args, pub))
    sup.add(make_child("b", b_args, pub))
    try:
        wait_for(lambda: sup.children["a"].restarts >= 2, 5, "two restarts of a")
        assert sup.children["b"].restarts == 0
        assert all(m.args is a_args for m in a_args["inits"])
        assert sup.children["a"].last_error == "ValueError: boom"
    finally:
        sup.shutdown()


def test_one_for_all_restarts_every_child():
    sup = Supervisor(intensity=100, period=10, strategy="one_for_all")
    a_args, b_args, pub = {"inits": [], "crash_at": 5, "crash_once": True}, {"inits": []}, []
    sup.add(make_child("a", a_args, pub))
    sup.add(make_child("b", b_args, pub))
    try:
        wait_for(lambda: len(b_args["inits"]) == 2, 5, "b restarted with a")
        assert sup.children["a"].restarts == sup.children["b"].restarts == 1
    finally:
        sup.shutdown()


def test_rest_for_one_restarts_later_children_only():
    sup = Supervisor(intensity=100, period=10, strategy="rest_for_one")
    args = {k: {"inits": []} for k in "abc"}
    args["b"]["crash_at"] = 4
    pub = []
    for k in "abc":
        sup.add(make_child(k, args[k], pub))
    try:
        wait_for(lambda: sup.children["b"].restarts >= 1, 5, "b restart")
        time.sleep(0.05)
        assert sup.children["a"].restarts == 0
        assert sup.children["c"].restarts >= 1
    finally:
        sup.shutdown()


@pytest.mark.parametrize(
    ("restart", "crash", "restarted"),
    [
        ("permanent", False, True),
        ("transient", False, False),
        ("transient", True, True),
        ("temporary", True, False),
    ],
)
def test_restart_types(restart, crash, restarted):
    sup = Supervisor(intensity=3, period=10)
    args, pub = {"inits": []}, []
    if crash:
        args["crash_at"] = 2
    sup.add(make_child("a", args, pub, restart=restart, iterations=2))
    try:
        wait_for(
            lambda: sup.children["a"].state != "running" or sup.children["a"].restarts,
            5,
            "the first end",
        )
        time.sleep(0.1)
        assert (sup.children["a"].restarts > 0) is restarted
        if not restarted:
            assert sup.children["a"].state == ("failed" if crash else "done")
    finally:
        sup.shutdown()


def test_intensity_escalates_on_the_restart_past_the_limit():
    escalations = []
    sup = Supervisor(intensity=3, period=60, on_escalate=escalations.append)
    args, pub = {"inits": [], "crash_at": 1}, []
    sup.add(make_child("a", args, pub))
    try:
        wait_for(lambda: escalations, 5, "escalation")
        time.sleep(0.1)
        assert len(args["inits"]) == 4  # first start + 3 restarts, not one more
        assert sup.children["a"].restarts == 3
        assert "restart intensity exceeded: 4 restarts within 60 s > 3" in escalations[0]
    finally:
        sup.shutdown()


def test_hung_worker_is_abandoned_and_never_publishes_again():
    halt = threading.Event()
    gate = threading.Event()

    class Blocks(Measure):
        def init(self, args, ctx):
            super().init(args, ctx)
            args["inits"].append(self)
            self.first = len(args["inits"]) == 1

        def measure(self):
            if self.first:
                gate.wait(10)
            return [1.0 if self.first else 2.0]

    pub = []
    args = {"inits": []}

    def start(on_exit):
        ctx = make_ctx("h", period=0.01, hang_factor=5, hang_min=0.1)
        return Worker(
            Blocks, args, ctx, lambda n, r, g: pub.append(r.values[0]), on_exit, halt=halt
        )

    sup = Supervisor()
    sup.add(Child("h", start))
    try:
        wait_for(lambda: sup.children["h"].hangs == 1, 5, "hang detection")
        wait_for(lambda: 2.0 in pub, 5, "the replacement publishing")
        gate.set()  # the hung step returns now: its value must be dropped
        time.sleep(0.1)
        assert 1.0 not in pub
        assert sup.children["h"].state == "running"
    finally:
        halt.set()
        sup.shutdown()


def test_stop_and_start_child():
    sup = Supervisor()
    args, pub = {"inits": []}, []
    sup.add(make_child("a", args, pub))
    try:
        sup.stop_child("a")
        wait_for(lambda: not sup.children["a"].worker.thread.is_alive(), 5, "stop")
        assert sup.children["a"].state == "stopped" and sup.children["a"].restarts == 0
        sup.start_child("a")
        assert sup.children["a"].state == "running" and len(args["inits"]) == 2
        with pytest.raises(ValueError, match="already running"):
            sup.start_child("a")
        with pytest.raises(ValueError, match=r"no measure 'zz' .*measures: a"):
            sup.stop_child("zz")
    finally:
        sup.shutdown()


def test_a_child_that_keeps_failing_at_once_backs_off():
    """First restart immediate; later ones wait 50 ms, 100 ms, 200 ms ... (lower bounds
    only: a loaded machine can only make the gaps longer)."""
    from hera.supervisor import backoff_delay

    sup = Supervisor(intensity=100, period=60)
    args, pub = {"inits": [], "crash_at": 1}, []
    sup.add(make_child("a", args, pub, period=0.001))
    starts: list[float] = []
    try:
        wait_for(lambda: len(args["inits"]) >= 5, 10, "5 starts")
        starts = [m.started for m in args["inits"][:5]]
        assert sup.children["a"].fast_crashes >= 4
        assert sup.children["a"].state in ("running", "restarting")
    finally:
        sup.shutdown()
    gaps = [b - a for a, b in zip(starts, starts[1:], strict=False)]
    for k, gap in enumerate(gaps, start=1):
        assert gap >= backoff_delay(k) - 0.005, (k, gaps)
    assert [backoff_delay(k) for k in range(1, 8)] == [0.0, 0.05, 0.1, 0.2, 0.4, 0.8, 1.6]
    assert backoff_delay(20) == 2.0


def test_stop_cancels_a_pending_restart():
    sup = Supervisor(intensity=100, period=60)
    args, pub = {"inits": [], "crash_at": 1}, []
    sup.add(make_child("a", args, pub, period=0.001))
    try:
        wait_for(lambda: sup.children["a"].state == "restarting", 10, "a delayed restart")
        sup.stop_child("a")
        n = len(args["inits"])
        time.sleep(0.3)  # longer than any pending delay so far: nothing may start
        assert len(args["inits"]) == n and sup.children["a"].state == "stopped"
    finally:
        sup.shutdown()


class WaitsForItsBoard(Measure):
    """``init`` raises NotReady until ``args["plugged"]`` is set; then publishes 1.0."""

    def init(self, args, ctx):
        super().init(args, ctx)
        args["tries"].append(time.monotonic())
        if not args["plugged"].is_set():
            raise NotReady("board not answering (unplugged)")

    def measure(self):
        return [1.0]


def _waiting_child(args, published) -> Child:
    def start(on_exit):
        ctx = make_ctx("a", period=0.01, restart="permanent")
        return Worker(WaitsForItsBoard, args, ctx, lambda n, r, g: published.append(r), on_exit)

    return Child("a", start, "permanent")


def test_a_measure_not_ready_at_start_waits_without_crashing_then_starts(monkeypatch):
    monkeypatch.setattr(worker, "NOT_READY_RETRY_S", 0.02)
    sup = Supervisor(intensity=0, period=60)  # a single crash would escalate
    args, pub = {"tries": [], "plugged": threading.Event()}, []
    sup.add(_waiting_child(args, pub))
    try:
        wait_for(lambda: len(args["tries"]) >= 5, 10, "5 tries of init")
        c = sup.children["a"]
        assert (c.state, c.crashes, c.restarts, sup.escalated) == ("running", 0, 0, None)
        assert c.worker.ctx.trouble == "waiting to start: board not answering (unplugged)"
        assert pub == []
        gaps = [b - a for a, b in zip(args["tries"], args["tries"][1:], strict=False)]
        assert min(gaps) >= 0.02 - 0.005, gaps  # not a busy loop
        args["plugged"].set()
        wait_for(lambda: pub, 10, "the first sample once the board answers")
        assert c.worker.ctx.trouble is None and c.crashes == 0 and c.state == "running"
    finally:
        sup.shutdown()


def test_a_waiting_measure_stops_when_asked_without_waiting_out_its_retry(monkeypatch):
    monkeypatch.setattr(worker, "NOT_READY_RETRY_S", 60.0)
    sup = Supervisor()
    args, pub = {"tries": [], "plugged": threading.Event()}, []
    sup.add(_waiting_child(args, pub))
    try:
        wait_for(lambda: sup.children["a"].worker.ctx.trouble, 10, "the measure to wait")
        sup.stop_child("a")
        wait_for(lambda: sup.children["a"].state == "stopped", 5, "the waiting measure to stop")
        assert len(args["tries"]) == 1 and sup.children["a"].crashes == 0
    finally:
        sup.shutdown()
