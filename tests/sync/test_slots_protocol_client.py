"""Unit tests of the slot table, the messages and the client-side step (fake clocks)."""

from __future__ import annotations

import msgpack
import pytest

from hera.sync import clock
from hera.sync.client import Grant, KnownTerms, SlotLost, Turn, run_in_slot, slot_duration
from hera.sync.protocol import (
    AcquireRequest,
    GrantReply,
    ProtocolError,
    Release,
    VoteReply,
    VoteRequest,
)
from hera.sync.service import _normalise
from hera.sync.slots import TOKEN_BITS, SlotTable, Waiting


def yes(_: float) -> bool:
    return True


def ask(table: SlotTable, holder: str, now: float, d: float = 0.01, timeout: float = 1.0):
    return table.enqueue(Waiting(holder, d, now, now + timeout, ticket=holder))


def test_one_slot_at_a_time_fifo_and_round_robin():
    table = SlotTable(epoch=2, expiry_margin=0.05)
    for h in ("a", "b", "c"):
        ask(table, h, 0.0)
    order = []
    for step in range(6):
        now = 0.1 * (step + 1)
        w, g = table.grant(now, yes)
        assert table.grant(now, yes) is None  # one slot at a time
        order.append(w.holder)
        assert table.release(g.epoch, g.token, g.holder, used=True)
        ask(table, w.holder, now)  # asks again: back of the queue
    assert order == ["a", "b", "c", "a", "b", "c"]


def test_asking_again_while_queued_keeps_the_place():
    table = SlotTable(epoch=1, expiry_margin=0.05)
    ask(table, "a", 0.0)
    ask(table, "b", 0.1)
    old = ask(table, "a", 0.2)
    assert old is not None and old.ticket == "a"
    w, g = table.grant(0.3, yes)
    assert w.holder == "a" and w.queued_since == 0.0
    # the lease counts from the request answered, never from the older one it replaced
    assert w.received_at == 0.2
    assert SlotTable.grant_duration(w, g) == pytest.approx(0.1 + 0.01)


def test_tokens_strictly_increase_across_terms():
    tokens = []
    for epoch in (1, 2):
        table = SlotTable(epoch=epoch, expiry_margin=0.0)
        for i in range(3):
            ask(table, "a", float(i))
            _, g = table.grant(float(i), yes)
            tokens.append(g.token)
            table.release(g.epoch, g.token, g.holder, used=True)
    assert tokens == sorted(set(tokens))
    assert tokens[3] >> TOKEN_BITS == 2


def test_slot_freed_on_release_or_after_its_lease_never_earlier():
    table = SlotTable(epoch=1, expiry_margin=0.05)
    ask(table, "a", 0.0, d=0.02, timeout=5.0)
    ask(table, "b", 0.0, d=0.02, timeout=5.0)
    _, g = table.grant(1.0, yes)
    assert not table.release(1, g.token + 1, "a", used=True)  # not the slot that is out
    assert not table.release(0, g.token, "a", used=True)  # other term
    assert not table.release(1, g.token, "b", used=True)  # not its holder
    table.expire(1.0 + 0.02 + 0.049)
    assert table.grant(1.07, yes) is None  # lease (+ margin) not over: still taken
    table.expire(1.0 + 0.02 + 0.05)
    w, _ = table.grant(1.08, yes)
    assert w.holder == "b" and table.expired == 1


def test_grant_duration_counts_the_wait_in_the_queue():
    table = SlotTable(epoch=1, expiry_margin=0.0)
    ask(table, "a", 5.0, d=0.02)
    w, g = table.grant(5.3, yes)
    assert SlotTable.grant_duration(w, g) == pytest.approx(0.32)


def test_head_that_may_not_be_granted_blocks_and_givers_up_leave():
    table = SlotTable(epoch=1, expiry_margin=0.0)
    ask(table, "a", 0.0, timeout=0.5)
    ask(table, "b", 0.0, timeout=2.0)
    assert table.grant(0.1, lambda d: False) is None
    gone = table.expire(0.6)
    assert [w.holder for w in gone] == ["a"]
    w, _ = table.grant(0.7, yes)
    assert w.holder == "b"
    st = table.status(0.7)
    assert st["holder"] == "b" and st["wait"]["b"]["grants"] == 1


def test_clear_returns_every_held_request():
    table = SlotTable(epoch=1, expiry_margin=0.0)
    ask(table, "a", 0.0)
    ask(table, "b", 0.0)
    table.grant(0.0, yes)
    assert [w.holder for w in table.clear()] == ["b"]
    assert table.current is None


@pytest.mark.parametrize(
    "msg",
    [
        VoteRequest(3, "s1", probe=True),
        VoteReply("s2", True, 3, "s1"),
        AcquireRequest("s1/sonar", 0.0625, 1.0),
        AcquireRequest("s1/sonar", 0.0625, 1.0, 4, "s2"),
        GrantReply(3, (3 << 32) | 7, 0.07, "s1"),
        Release(3, (3 << 32) | 7, "s1/sonar", False),
    ],
)
def test_messages_round_trip(msg):
    assert type(msg).decode(msg.encode()) == msg


@pytest.mark.parametrize(
    "payload",
    [
        b"",
        b"\xc1",
        msgpack.packb([1, 2]),
        msgpack.packb({"e": 1}),
        msgpack.packb({"e": "1", "c": "a", "p": False}),
        msgpack.packb({"e": True, "c": "a", "p": False}),
        msgpack.packb({"e": -1, "c": "a", "p": False}),
        b"\x00" * 5000,
    ],
)
def test_bad_vote_requests_are_rejected_clearly(payload):
    with pytest.raises(ProtocolError):
        VoteRequest.decode(payload)


def test_an_acquire_without_the_known_term_decodes_as_knowing_nothing():
    req = AcquireRequest.decode(msgpack.packb({"h": "a", "d": 0.01, "t": 1.0}))
    assert (req.known_epoch, req.known_leader) == (0, "")
    with pytest.raises(ProtocolError, match="'k' must be an int >= 0"):
        AcquireRequest.decode(msgpack.packb({"h": "a", "d": 0.01, "t": 1.0, "k": -1}))
    with pytest.raises(ProtocolError, match="'kl' has the wrong type"):
        AcquireRequest.decode(msgpack.packb({"h": "a", "d": 0.01, "t": 1.0, "kl": 3}))


def test_bad_acquire_and_grant_are_rejected():
    with pytest.raises(ProtocolError):
        AcquireRequest.decode(msgpack.packb({"h": "a", "d": 0.0, "t": 1.0}))
    with pytest.raises(ProtocolError):
        AcquireRequest.decode(msgpack.packb({"h": "a", "d": float("nan"), "t": 1.0}))
    with pytest.raises(ProtocolError):
        GrantReply.decode(msgpack.packb({"e": 1, "k": 2, "d": -1.0, "l": "x"}))


class FakeClient:
    def __init__(self, grant_after: float, duration_slack: float = 0.0) -> None:
        self.grant_after = grant_after
        self.slack = duration_slack
        self.released: list[tuple[int, bool]] = []
        self.asked: list[float] = []

    def acquire(self, group, holder, duration, timeout):
        asked_at = clock.now()
        self.asked.append(duration)
        if self.grant_after is None:
            return None
        return Grant(group, holder, 1, 7, duration + self.slack, asked_at - self.grant_after, "x")

    def release(self, grant, used):
        self.released.append((grant.token, used))


def test_run_in_slot_fires_and_releases():
    c = FakeClient(grant_after=0.0)
    fired, result, grant = run_in_slot(c, "g", "n/m", 0.01, lambda g: 42, timeout=1.0)
    assert (fired, result, grant.epoch, grant.token) == (True, 42, 1, 7)
    assert c.released == [(7, True)]
    assert c.asked == [slot_duration(0.01)]


def test_run_in_slot_gives_a_late_grant_back_unused():
    c = FakeClient(grant_after=1.0)  # the grant's lease ran out long ago
    called = []
    fired, result, grant = run_in_slot(c, "g", "n/m", 0.01, lambda g: called.append(1), 1.0)
    assert not fired and called == [] and c.released == [(7, False)]


def test_a_step_that_finds_its_slot_gone_at_the_trigger_gives_it_back_unused():
    c = FakeClient(grant_after=0.0)
    late = []
    c.note_late = late.append

    def trigger(turn):
        raise SlotLost  # what turn.check_at_trigger() raises when the sound no longer fits

    fired, result, grant = run_in_slot(c, "g", "n/m", 0.01, trigger, timeout=1.0)
    assert (fired, result) == (False, None) and grant.token == 7
    assert c.released == [(7, False)] and late == [grant]


class FakeClock:
    def __init__(self, t: float = 100.0) -> None:
        self.t = t
        self.slept: list[float] = []

    def __call__(self) -> float:
        return self.t

    def sleep(self, s: float) -> None:
        self.slept.append(s)
        self.t += s


def test_turn_checks_at_the_trigger_and_the_sound_starts_at_that_reading():
    clock = FakeClock()
    g = Grant("g", "h", 3, 9, duration=0.05, asked_at=100.0, leader="x")
    turn = Turn(g, 0.02, clock)
    assert (turn.epoch, turn.token, turn.ends_at) == (3, 9, None)
    clock.t = 100.031  # a pause since the grant: 0.031 + 0.02 > 0.05
    with pytest.raises(SlotLost):
        turn.check_at_trigger()
    assert turn.fired_at is None
    clock.t = 100.03
    reading = turn.check_at_trigger(wall=lambda: 1.7e9, lasts=0.015)
    assert reading.clock == 100.03 and reading.wall == 1.7e9
    assert turn.ends_at == pytest.approx(100.045)
    with pytest.raises(RuntimeError, match="one trigger per turn"):
        turn.check_at_trigger()
    with pytest.raises(ValueError, match="does not fit the 0.02 s slot"):
        Turn(g, 0.02, clock).check_at_trigger(lasts=0.03)
    assert Turn(g, 0.001, clock).fire(lambda r: r.clock * 2) == pytest.approx(200.06)


def test_run_in_slot_releases_only_after_the_sound_has_ended():
    clock = FakeClock()
    released_at = []

    class Client(FakeClient):
        def acquire(self, group, holder, duration, timeout):
            return Grant(group, holder, 1, 7, duration, clock.t, "x")

        def release(self, grant, used):
            released_at.append((clock.t, used))

    def driver(turn):  # triggers, returns at once (a driver that does not block)
        turn.check_at_trigger()
        return "ok"

    fired, result, _ = run_in_slot(Client(0.0), "g", "h", 0.02, driver, 1.0, clock, clock.sleep)
    assert (fired, result) == (True, "ok")
    assert released_at == [(pytest.approx(100.02), True)] and clock.slept


def test_known_terms_refuse_older_and_reused_terms():
    k = KnownTerms()
    assert k.get("g") == (0, "") and k.accept("g", 2, "a")
    assert k.accept("g", 2, "a") and k.accept("g", 3, "b")
    assert not k.accept("g", 2, "a")  # older
    assert not k.accept("g", 3, "c")  # the same epoch from another leader: reused
    assert k.get("g") == (3, "b") and k.get("other") == (0, "")


def test_the_sync_clock_counts_suspend_where_the_platform_allows():
    import sys

    if sys.platform.startswith("linux"):
        assert clock.NAME == "CLOCK_BOOTTIME" and clock.COUNTS_SUSPEND
    a, b = clock.now(), clock.now()
    assert b >= a


def test_run_in_slot_without_a_grant_and_with_a_failing_step():
    assert run_in_slot(FakeClient(grant_after=None), "g", "h", 0.01, lambda g: 1, 0.1) == (
        False,
        None,
        None,
    )
    c = FakeClient(grant_after=0.0)

    def boom(grant):
        raise RuntimeError("sensor")

    with pytest.raises(RuntimeError):
        run_in_slot(c, "g", "h", 0.01, boom, 1.0)
    assert c.released == [(7, True)]


def test_grant_fits_is_measured_from_before_the_ask():
    g = Grant("g", "h", 1, 1, duration=0.05, asked_at=10.0, leader="x")
    assert g.deadline == pytest.approx(10.05)
    assert g.fits(0.02, now=10.03)
    assert not g.fits(0.02, now=10.031)


def test_slot_duration_adds_a_slack():
    assert slot_duration(0.05) == pytest.approx(0.0625)
    assert slot_duration(0.004) == pytest.approx(0.009)


def test_host_groups_forms_and_errors():
    assert _normalise({"sonar": ["s1", "s2"]}) == {"sonar": ["s1", "s2"]}
    assert _normalise([("sonar", ["s1"])]) == {"sonar": ["s1"]}
    assert _normalise([{"group": "g", "hosts": ["a"]}]) == {"g": ["a"]}
    assert _normalise([]) == {}
    for bad in ({"g": "s1"}, {"g": []}, {"g": ["a", "a"]}, {"a/b": ["x"]}):
        with pytest.raises(ValueError):
            _normalise(bad)
