"""Unit tests of GroupCore, the host's pure state machine (fake clock, no network)."""

from __future__ import annotations

import pytest

from hera.sync.core import GroupCore, Round
from hera.sync.election import Timing
from hera.sync.protocol import AcquireRequest, GrantReply, Release, VoteReply

T = Timing(lease=0.3, max_slot=0.15, margin=0.05)
HOSTS = ["a", "b", "c"]


def yes(voter: str, epoch: int, candidate: str = "a") -> VoteReply:
    return VoteReply(voter, True, epoch, candidate)


def no(voter: str, epoch: int, candidate: str) -> VoteReply:
    return VoteReply(voter, False, epoch, candidate)


def elected(timing: Timing = T) -> tuple[GroupCore, float]:
    """Core "a", elected at epoch 1 and past its wait; returns it and the time."""
    core = GroupCore("a", HOSTS, timing, 0.0)
    now = timing.quiet
    for h in HOSTS:
        core.on_alive(h, True)
    out, probe = core.step(now)
    assert probe is not None and probe.kind == "probe" and probe.epoch == 1
    _, elect = core.round_done(probe, [yes("a", 0, ""), yes("b", 0, "")], now)
    assert elect is not None and elect.kind == "elect"
    core.round_done(elect, [yes("a", 1), yes("b", 1)], now)
    assert core.term is not None and core.term.epoch == 1
    t = now
    while t < now + timing.wait:  # renewals keep the lease while it waits out W
        t += timing.renew * 1.01
        _, renew = core.step(t)
        assert renew is not None and renew.kind == "renew"
        core.round_done(renew, [yes("a", 1), yes("b", 1)], t)
    return core, t


def ask(core: GroupCore, holder: str, now: float, **kw) -> list:
    return core.on_acquire(AcquireRequest(holder, 0.01, 0.3, **kw), now, holder)


def granted(out: list) -> list[tuple[str, GrantReply]]:
    return [(ticket, GrantReply.decode(p)) for ticket, p in out if p is not None]


def test_a_request_is_granted_only_after_a_majority_round_started_after_it_arrived():
    core, t = elected()
    assert granted(ask(core, "x", t)) == []  # no round since it arrived
    out, rnd = core.step(t)  # so the runner starts one at once
    assert rnd is not None and rnd.kind == "renew"
    assert granted(ask(core, "y", t + 0.001)) == []  # arrived during that round
    out, nxt = core.round_done(rnd, [yes("a", 1), yes("b", 1)], t + 0.002)
    assert [h for h, _ in granted(out)] == ["x"]
    assert nxt is None
    # y needs the next round, even after x's release frees the slot
    g = granted(out)[0][1]
    assert granted(core.on_release(Release(1, g.token, "x", True), t + 0.02)) == []
    out, rnd = core.step(t + 0.02)
    assert rnd is not None
    out, _ = core.round_done(rnd, [yes("a", 1), yes("c", 1)], t + 0.021)
    assert [h for h, _ in granted(out)] == ["y"]


def test_a_leader_outvoted_by_a_higher_epoch_grants_nothing_and_steps_down():
    """Timeline 1: whatever its clock says, a leader the majority has left grants nothing."""
    core, t = elected()
    ask(core, "x", t)
    _, rnd = core.step(t)
    out, _ = core.round_done(rnd, [yes("a", 1), no("b", 2, "b"), no("c", 2, "b")], t)
    assert granted(out) == [] and [ticket for ticket, _ in out] == ["x"]  # dropped
    assert core.term is None and core.demotions == {"higher epoch": 1}


def renewed(core: GroupCore, t: float) -> list:
    _, rnd = core.step(t)
    assert rnd is not None
    out, _ = core.round_done(rnd, [yes("a", 1), yes("b", 1)], t)
    return out


def test_a_request_older_than_the_lease_is_not_granted_but_later_ones_are():
    wide = Timing(lease=0.3, max_slot=0.15, margin=0.2)  # a slot expires 0.35 s after
    core, t = elected(timing=wide)
    core.on_acquire(AcquireRequest("busy", 0.15, 1.0), t, "busy")
    assert [h for h, _ in granted(renewed(core, t))] == ["busy"]  # and never released
    ask(core, "old", t + 0.01)
    now = t + 0.01
    while now < t + 0.01 + wide.lease:  # renewals back "old", but the slot is out
        now += wide.renew * 1.01
        assert granted(renewed(core, now)) == []
    ask(core, "new", now)
    now = t + 0.15 + wide.margin + 0.001  # "busy" expires: "old" waited more than L
    out = renewed(core, now)
    ((who, g),) = granted(out)
    assert who == "new" and g.duration <= wide.lease + wide.max_slot
    assert list(core.table.queue) == ["old"]  # kept: its asker's next attempt replaces it


def test_a_release_frees_the_slot_only_from_its_holder_for_its_grant():
    core, t = elected()
    ask(core, "x", t)
    ask(core, "y", t)
    _, rnd = core.step(t)
    out, _ = core.round_done(rnd, [yes("a", 1), yes("b", 1)], t)
    g = granted(out)[0][1]
    assert core.on_release(Release(1, g.token, "y", True), t + 0.001) == []
    assert core.on_release(Release(2, g.token, "x", True), t + 0.001) == []
    assert core.table.current is not None and core.table.current.holder == "x"
    out = core.on_release(Release(1, g.token, "x", True), t + 0.002)
    assert [h for h, _ in granted(out)] == ["y"]


@pytest.mark.parametrize("known", [(2, ""), (2, "b#1"), (1, "b#1"), (1, "a#before-restart")])
def test_a_client_that_knows_a_newer_term_makes_the_leader_step_down_and_rise_above(known):
    """(1, "a#before-restart"): this host led epoch 1 in a former life (its promises lost
    with its state); its term now has the same epoch but another id: a client granted under
    the old one must not take the new one for it (tokens restart with the term)."""
    core, t = elected()
    out = ask(core, "x", t, known_epoch=known[0], known_leader=known[1])
    assert out[0] == ("x", None) and core.term is None
    assert core.demotions == {"a client knows a newer term": 1}
    # it runs again (its own voter no longer sticks to it), above what the client knew
    later = t + 0.001
    out, probe = core.step(later)
    while probe is None:
        later += 0.01
        out, probe = core.step(later)
    assert probe.epoch == max(known[0], 1) + 1


def test_a_client_that_knows_this_term_or_an_older_one_is_served():
    core, t = elected()
    for known in [(0, ""), (1, core.term_id), (1, "")]:
        ask(core, "x", t, known_epoch=known[0], known_leader=known[1])
        assert core.term is not None


def test_an_election_needs_the_candidates_own_vote():
    core = GroupCore("a", HOSTS, T, 0.0)
    for h in HOSTS:
        core.on_alive(h, True)
    elect = Round("elect", 1, T.quiet, 1)
    core.round_done(elect, [yes("b", 1), yes("c", 1)], T.quiet)
    assert core.term is None  # a majority, but its own promise was not saved


@pytest.mark.parametrize("how", ["lease", "late confirmation"])
def test_a_leader_that_lost_its_majority_stands_back_one_lease_before_running_again(how):
    """The host that just failed to reach a majority in time runs last: the others, which
    stayed in touch, elect one of theirs first (a leader behind a flapping link would
    otherwise win the group back at each healing, and lose it at the next cut)."""
    core, t = elected()
    _, renew = core.step(t + T.renew * 1.01)
    assert renew is not None
    lost = t + T.lease + 0.01
    if how == "lease":
        core.step(lost)  # no renewal came back: the lease has run out
    else:  # the confirmation comes back after the lease ran out
        core.round_done(renew, [yes("a", 1), yes("b", 1)], lost)
    assert core.term is None
    now = lost
    while now < lost + T.lease - 0.005:  # rank 0, yet it does not run for a lease
        _, rnd = core.step(now)
        assert rnd is None, now - lost
        now += 0.005
    _, rnd = core.step(lost + T.lease + 0.001)
    assert rnd is not None and rnd.kind == "probe"


def test_a_lone_host_does_not_stand_back():
    """Nobody else can lead a group of one: it runs again at once."""
    core = GroupCore("a", ["a"], T, 0.0)
    now = T.quiet
    _, probe = core.step(now)
    _, elect = core.round_done(probe, [yes("a", 0, "")], now)
    core.round_done(elect, [yes("a", 1)], now)
    assert core.term is not None
    lost = now + T.lease + 0.01
    _, rnd = core.step(lost)
    assert core.term is None and rnd is not None and rnd.kind == "probe"
