"""Timeline 3 of issue 19 on the real code path: a pause between the fit check and the
trigger. The check belongs at the physical trigger, inside the driver; a stall anywhere
before it (the measure's own code, a lock, a GC pause) must be caught there."""

from __future__ import annotations

import time

from nodes_helpers import make_ctx

from hera.nodes.measures.sonar import Sonar
from hera.sync import clock
from hera.sync.client import Grant, run_in_slot

WORLD = {"scenario": "still", "position": [0.0, 2.0, 0.0], "epoch": 0.0}


class OneGrant:
    """A SlotClient that grants at once a lease of ``duration`` s counted from now."""

    def __init__(self, duration: float) -> None:
        self.duration = duration
        self.released: list[tuple[int, bool]] = []
        self.late: list[Grant] = []

    def acquire(self, group, holder, duration, timeout):
        return Grant(group, holder, 1, 7, self.duration, clock.now(), "x")

    def release(self, grant, used):
        self.released.append((grant.token, used))

    def note_late(self, grant):
        self.late.append(grant)


def _sonar():
    ctx = make_ctx("sonar", WORLD, slot=0.01)
    m = Sonar()
    m.init({"ping_ms": 5, "position": [0, 0, 0], "direction": [0, 1, 0]}, ctx)
    return m, ctx


def test_timeline_3_a_stall_in_the_measure_before_the_trigger_is_caught_by_the_driver():
    m, ctx = _sonar()
    client = OneGrant(duration=0.03)  # 30 ms of lease for a 10 ms slot

    def step(turn):
        # what the runtime's wrapper does (ctx.grant), then the measure, whose own code
        # stalls (a lock, a GC pause, another thread holding the GIL) before the driver
        ctx.grant = turn
        try:
            time.sleep(0.05)
            return m.measure()
        finally:
            ctx.grant = None

    fired, result, grant = run_in_slot(client, "sonar", "n1/sonar", 0.01, step, 1.0)
    assert ctx.counters.get("pings", 0) == 0, "the sonar pinged after its lease had run out"
    assert (fired, result) == (False, None)
    assert client.released == [(7, False)] and client.late == [grant]


def test_a_step_without_a_stall_pings_in_its_slot():
    m, ctx = _sonar()
    client = OneGrant(duration=0.5)

    def step(turn):
        ctx.grant = turn
        try:
            return m.measure()
        finally:
            ctx.grant = None

    fired, result, _ = run_in_slot(client, "sonar", "n1/sonar", 0.01, step, 1.0)
    assert fired and result is not None and ctx.counters["pings"] == 1
    assert client.released == [(7, True)]
