"""Unit tests of the election state machines (fake clock); the model check of the whole
protocol is in ``test_model_check.py``."""

from __future__ import annotations

import pytest

from hera.sync.election import Term, Timing, Voter
from hera.sync.promises import PromiseFile

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


def test_timing_sizes_the_tolerated_trigger_pause_from_the_margin_and_the_drift():
    # condition C of sync/README.md: 2 rho (L + D) / (1 - rho) + (1 + rho) p <= m
    assert T.drift == 0.01
    assert T.trigger_pause == pytest.approx((0.05 - 2 * 0.01 * 0.45 / 0.99) / 1.01)
    assert T.trigger_pause == pytest.approx(0.0405, abs=1e-4)
    assert Timing(drift=0.0).trigger_pause == pytest.approx(0.05)
    # the largest drift the default margin takes with no pause at all: ~5.3 % per clock
    assert Timing(drift=0.0526).trigger_pause > 0
    with pytest.raises(ValueError, match="margin 0.05 s is too small for a clock drift"):
        Timing(drift=0.06)


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


def test_a_backlog_of_renewals_after_a_cut_does_not_make_the_voter_sticky_again():
    """A link that delivered nothing for 0.4 s, then everything at once (what a blackholed
    TCP link does when it heals): the leader behind it lost its term by its own lease, so
    its held-up renewals must not make this voter refuse the others again."""
    v = ready_voter()
    t = T.quiet
    assert v.request(1, "a", t, always)
    for k in range(1, 4):  # renewals every renew period: fresh all along
        assert v.request(1, "a", t + k * T.renew, always)
        assert v.leader(t + k * T.renew) == "a"
    last = t + 3 * T.renew
    heal = last + 0.4  # the cut: nothing arrives for longer than a lease
    for k in range(6):  # the backlog, within 3 ms: confirmed (it is the promised term) ...
        assert v.request(1, "a", heal + k * 0.0005, always)
    assert v.leader(heal + 0.003) is None  # ... but the leader is not fresh again
    assert v.would(2, "b", heal + 0.003, always)  # so another candidate may be elected


def test_renewals_that_keep_coming_for_a_lease_make_a_stale_leader_fresh_again():
    """A voter that was itself cut off from a leader that kept its term (the others renewed
    it) follows that leader again once its renewals have kept coming for a whole lease,
    however often they come (back-to-back rounds backing slot requests included)."""
    v = ready_voter()
    t = T.quiet
    assert v.request(1, "a", t, always)
    back = t + 0.5  # stale since t + L
    k, now = 0, back
    while now < back + T.lease:  # rounds 5 ms apart: the leader's renewals and backing rounds
        assert v.request(1, "a", now, always)
        assert v.leader(now) is None, now - back
        k += 1
        now = back + k * 0.005
    assert v.request(1, "a", now, always)
    assert v.leader(now) == "a"
    assert not v.would(2, "b", now, always)


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


class MemoryPromises:
    def __init__(self, fail: bool = False) -> None:
        self.saved: list[tuple[int, str]] = []
        self.fail = fail

    def load(self) -> tuple[int, str]:
        return self.saved[-1] if self.saved else (0, "")

    def save(self, epoch: int, candidate: str) -> None:
        if self.fail:
            raise OSError("disk full")
        self.saved.append((epoch, candidate))


def test_voter_saves_a_changed_promise_before_saying_yes_and_keeps_it_across_restarts():
    disk = MemoryPromises()
    v = Voter("v", T, 0.0, disk)
    assert v.request(3, "a", T.quiet, always)
    assert v.request(3, "a", T.quiet + 0.05, always)  # a renewal: nothing to write
    assert disk.saved == [(3, "a")]
    again = Voter("v", T, 100.0, disk)  # restarted: it remembers
    t = 100.0 + T.quiet
    assert (again.epoch, again.candidate) == (3, "a")
    assert not again.request(3, "b", t, always)  # one candidate per epoch, for ever
    assert not again.request(2, "b", t, always)  # epochs never go back
    assert again.request(4, "b", t, always) and disk.saved[-1] == (4, "b")


def test_voter_that_cannot_save_its_promise_says_no():
    v = Voter("v", T, 0.0, MemoryPromises(fail=True))
    assert not v.request(1, "a", T.quiet, always)
    assert (v.epoch, v.candidate, v.save_failures) == (0, "", 1)


def test_promise_file_round_trip_and_clear_errors(tmp_path):
    f = PromiseFile(tmp_path / "state" / "sync-sonar.promise.json", "sonar")
    assert f.load() == (0, "")
    f.save(7, "s2")
    assert f.load() == (7, "s2") and f.writes == 1
    assert not list((tmp_path / "state").glob("*.tmp"))
    with pytest.raises(ValueError, match="is for group 'sonar', not 'other'"):
        PromiseFile(f.path, "other").load()
    f.path.write_text('{"group": "sonar", "epoch": -1, "candidate": "s2"}')
    with pytest.raises(ValueError, match=r"sync-sonar.promise.json: epoch -1 is not an int"):
        f.load()
    f.path.write_text("{")
    with pytest.raises(ValueError, match="not JSON"):
        f.load()
