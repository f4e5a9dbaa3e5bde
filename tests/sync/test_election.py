"""Unit tests of the election state machines (fake clock) and a randomised model check."""

from __future__ import annotations

import heapq
import random

import pytest

from hera.sync.election import Term, Timing, Voter

T = Timing(lease=0.3, max_slot=0.15, margin=0.05)


def always(_: str) -> bool:
    return True


def never(_: str) -> bool:
    return False


def ready_voter() -> Voter:
    return Voter("v", T, now=0.0)


def test_timing_rejects_slots_that_cannot_fit_a_lease():
    with pytest.raises(ValueError):
        Timing(lease=0.3, max_slot=0.2)
    assert T.wait == pytest.approx(0.5) and T.quiet == T.wait


def test_voter_is_quiet_after_start_but_remembers_the_highest_epoch_asked():
    v = ready_voter()
    assert not v.request(7, "a", 0.1, always)
    assert not v.would(8, "b", 0.1, always)
    assert not v.request(5, "b", T.quiet + 0.01, always)  # below what a live term may hold
    assert v.request(7, "a", T.quiet + 0.01, always)  # the term it saw may go on


def test_voter_epochs_only_grow_and_one_candidate_per_epoch():
    v = ready_voter()
    t = T.quiet
    assert v.request(3, "a", t, always)
    assert not v.request(3, "b", t + 10, always)  # same epoch, other candidate: never
    assert not v.request(2, "b", t + 10, always)  # lower epoch: never
    assert v.request(4, "b", t + 10, always)  # higher epoch once "a" is stale
    assert (v.epoch, v.candidate) == (4, "b")
    assert not v.request(3, "a", t + 20, always)


def test_voter_is_sticky_while_its_leader_is_fresh_and_alive():
    v = ready_voter()
    t = T.quiet
    assert v.request(1, "a", t, always)
    assert v.request(1, "a", t + 0.2, always)  # renewal
    assert not v.would(2, "b", t + 0.3, always)
    assert not v.request(2, "b", t + 0.3, always)
    assert v.would(2, "b", t + 0.3, never)  # its leader's token is gone
    assert v.request(2, "a", t + 0.3, always)  # the leader itself may start a new term
    assert v.request(3, "b", t + 0.31 + T.lease, always)  # stale: may switch


def test_pre_vote_changes_nothing():
    v = ready_voter()
    assert v.would(5, "a", T.quiet, always)
    assert (v.epoch, v.candidate) == (0, "")
    assert v.leader(T.quiet) is None


def test_unstick_lets_the_voter_switch_at_once():
    v = ready_voter()
    assert v.request(1, "a", T.quiet, always)
    v.unstick("a")
    assert v.request(2, "b", T.quiet + 0.01, always)


def test_term_waits_before_its_first_grant_and_grants_only_inside_its_lease():
    term = Term(4, T, asked_at=10.0, now=10.001)
    assert not term.may_grant(0.01, 10.2)  # still waiting out the old leader's slots
    assert term.granting_from() == pytest.approx(10.001 + T.wait)
    # lease from the election ended at 10.3: renewals keep it alive
    t = 10.0
    while t < 10.6:
        t += T.renew
        assert term.tick(t)
        term.confirmed(asked_at=t, now=t + 0.001)
    assert term.may_grant(0.01, t + 0.01)
    assert not term.may_grant(T.max_slot + 0.001, t + 0.01)  # longer than any slot
    assert not term.may_grant(0.1, term.lease_end - 0.05)  # would outlive the lease


def test_term_ends_on_a_pause_in_its_own_loop():
    term = Term(1, T, asked_at=0.0, now=0.0)
    assert term.tick(0.05)
    assert not term.tick(0.05 + T.pause + 0.01)
    assert not term.may_grant(0.01, 1.0)
    term.confirmed(asked_at=0.3, now=0.31)  # a late confirmation does not revive it
    assert term.over


def test_term_ends_when_a_renewal_comes_back_after_the_lease():
    term = Term(1, T, asked_at=0.0, now=0.0)
    term.confirmed(asked_at=0.25, now=0.35)
    assert term.over and not term.tick(0.36)


# -- randomised model check ---------------------------------------------------------------------


def simulate(seed: int, n: int = 3, horizon: float = 20.0) -> tuple[list[tuple], int]:
    """Hosts electing and renewing over a network that delays, reorders and loses messages,
    with hosts paused (SIGSTOP-like: clock runs, nothing processed) and restarted (state
    lost). Every leader grants back-to-back slots whenever its term allows. Returns the
    slot windows [t, t + d] of all grants, and the number of distinct terms that granted."""
    rnd = random.Random(seed)
    names = [f"h{i}" for i in range(n)]
    majority = n // 2 + 1
    voters = {h: Voter(h, T, 0.0) for h in names}
    terms: dict[str, Term | None] = dict.fromkeys(names)
    free_at = dict.fromkeys(names, 0.0)
    paused_until = dict.fromkeys(names, 0.0)
    next_try = {h: rnd.uniform(0, 0.3) for h in names}
    rounds: dict[int, dict] = {}
    grants: list[tuple] = []
    granting_terms: set[tuple[str, int]] = set()
    events: list[tuple] = []
    seq = 0

    def push(t: float, *ev) -> None:
        nonlocal seq
        seq += 1
        heapq.heappush(events, (t, seq, *ev))

    def delay() -> float:
        r = rnd.random()
        return rnd.uniform(0, 0.002) if r < 0.9 else rnd.uniform(0, 0.6)  # some very late

    for h in names:
        push(rnd.uniform(0, T.renew), "tick", h)
    push(rnd.uniform(1, 3), "fault")
    rid = 0
    while events:
        t, _, kind, *args = heapq.heappop(events)
        if t > horizon:
            break
        if kind == "fault":
            h = rnd.choice(names)
            what = rnd.random()
            if what < 0.6:
                paused_until[h] = t + rnd.uniform(0.05, 3 * T.lease)
            else:  # restart: promises forgotten, term lost
                voters[h] = Voter(h, T, t)
                terms[h] = None
            push(t + rnd.uniform(0.1, 1.0), "fault")
            continue
        h = args[0]
        if t < paused_until[h]:
            push(paused_until[h] + rnd.uniform(0, 0.001), kind, *args)  # processed late
            continue
        if kind == "tick":
            term = terms[h]
            if term is not None and not term.tick(t):
                terms[h] = term = None
                voters[h].unstick(h)
            if term is not None:
                rid += 1
                rounds[rid] = {"h": h, "e": term.epoch, "at": t, "acks": set(), "kind": "renew"}
                for v in names:
                    if rnd.random() > 0.05:
                        push(t + delay(), "req", v, rid)
                if free_at[h] <= t:
                    d = rnd.uniform(0.001, T.max_slot)
                    if term.may_grant(d, t):
                        grants.append((t, t + d, h, term.epoch))
                        granting_terms.add((h, term.epoch))
                        free_at[h] = t + d
            elif voters[h].leader(t) is None and t >= next_try[h] and t >= voters[h].quiet_until:
                rid += 1
                e = voters[h].epoch + 1 + rnd.randrange(2)
                rounds[rid] = {"h": h, "e": e, "at": t, "acks": set(), "kind": "elect"}
                for v in names:
                    if rnd.random() > 0.05:
                        push(t + delay(), "req", v, rid)
                next_try[h] = t + rnd.uniform(0.0, 0.2)
            push(t + rnd.uniform(0.3, 1.0) * T.renew, "tick", h)
        elif kind == "req":
            r = rounds[args[1]]
            # liveliness is unreliable (a partition, a lease false alarm): half the time the
            # voter believes its leader gone and is not sticky
            ok = voters[h].request(r["e"], r["h"], t, lambda _: rnd.random() < 0.5)
            if ok and rnd.random() > 0.05:
                push(t + delay(), "rep", r["h"], args[1], h)
        elif kind == "rep":
            r = rounds[args[1]]
            if t > r["at"] + T.lease / 6:
                continue  # the asker stopped listening
            r["acks"].add(args[2])
            if len(r["acks"]) != majority:
                continue
            term = terms[h]
            if r["kind"] == "renew" and term is not None and term.epoch == r["e"]:
                term.confirmed(r["at"], t)
                if term.over:
                    terms[h] = None
            elif r["kind"] == "elect" and term is None:
                terms[h] = Term(r["e"], T, r["at"], t)
    return grants, len(granting_terms)


@pytest.mark.parametrize("n", [1, 2, 3, 5])
def test_model_check_no_two_slots_overlap(n):
    total_terms = 0
    for seed in range(60 if n != 1 else 10):
        grants, terms = simulate(seed, n=n)
        total_terms += terms
        grants.sort()
        for a, b in zip(grants, grants[1:], strict=False):
            assert b[0] >= a[1], f"seed {seed}: {a} overlaps {b}"
    assert total_terms > (10 if n != 1 else 2)  # leaders did change under the faults


def test_model_check_has_teeth(monkeypatch):
    """Without the new leader's wait, the same model finds overlapping slots."""

    def no_wait(self: Term, duration: float, now: float) -> bool:
        return (
            not self.over and duration <= self.timing.max_slot and now + duration <= self.lease_end
        )

    monkeypatch.setattr(Term, "may_grant", no_wait)
    found = 0
    for seed in range(20):
        grants, _ = simulate(seed)
        grants.sort()
        found += any(b[0] < a[1] for a, b in zip(grants, grants[1:], strict=False))
    assert found > 0
