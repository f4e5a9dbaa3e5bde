"""DataReadyClock (``hera.nodes.data_ready``) on an injected clock: a chip making samples on
its own clock, polled when the clock says, each sample stamped within half a poll of when
it was made, the chip's period learnt, few polls between samples."""

from __future__ import annotations

import math

import pytest

from hera.nodes.data_ready import DataReadyClock


class Chip:
    """Samples made at ``phase + k period`` (s); ``ready(t)``: one newer than the last taken."""

    def __init__(self, period: float, phase: float = 0.0037) -> None:
        self.period, self.phase = period, phase
        self.taken = -1

    def newest(self, t: float) -> int:
        return math.floor((t - self.phase) / self.period)

    def made(self, k: int) -> float:
        return self.phase + k * self.period

    def ready(self, t: float) -> bool:
        return self.newest(t) > self.taken and self.newest(t) >= 0


def follow(chip: Chip, clock: DataReadyClock, until: float, late: dict[int, float] | None = None):
    """Poll ``chip`` when ``clock`` says until ``until``; ``late``: polls pushed back by that
    many s after the sample of that index (a descheduled thread). Returns (error of each
    stamp, polls)."""
    t, errors, polls = 0.0, [], 0
    late = late or {}
    while t < until:
        polls += 1
        if chip.ready(t):
            k = chip.newest(t)
            chip.taken = k
            errors.append((k, clock.ready(t) - chip.made(k)))
        else:
            clock.not_ready(t)
        t = clock.next_poll(t)
        nxt = chip.taken + 1
        if nxt in late and t >= chip.made(nxt):
            t = chip.made(nxt) + late.pop(nxt)
    return errors, polls


@pytest.mark.parametrize("error", [-0.03, -0.015, 0.0, 0.015, 0.03])
def test_each_sample_is_stamped_within_half_a_poll_and_the_period_is_learnt(error):
    nominal, poll = 1 / 26, 0.001
    chip = Chip(nominal / (1 + error))  # the chip's clock off by ``error``
    clock = DataReadyClock(nominal, poll)
    errors, polls = follow(chip, clock, 20.0)
    settled = [abs(e) for k, e in errors if k > 30]
    assert max(settled) <= poll / 2 + 1e-12
    assert clock.period == pytest.approx(chip.period, rel=3e-3)  # nominal: 3 % off
    assert polls / len(errors) < 5  # a few polls before each sample, none between
    assert [k for k, _ in errors] == list(range(len(errors)))  # none missed


def test_a_sample_found_already_there_is_stamped_at_its_predicted_instant():
    nominal = 0.01
    chip = Chip(nominal * 1.01)
    clock = DataReadyClock(nominal, 0.0005)
    errors, _ = follow(chip, clock, 3.0, late={200: 0.004, 250: 0.0071})
    by_index = dict(errors)
    assert abs(by_index[200]) < 0.0005 and abs(by_index[250]) < 0.0005  # not 4 or 7 ms late


def test_a_sample_found_just_after_its_instant_is_not_taken_for_the_last_one():
    clock = DataReadyClock(0.01, 0.001)
    for edge in (0.0, 0.01, 0.02):  # edges, each between a low and a high poll
        clock.not_ready(edge - 0.0001)
        assert clock.ready(edge + 0.0011) == pytest.approx(edge + 0.0005)  # the midpoint
    # the next sample (made at 0.03) found at the first poll, 0.2 ms after it was made,
    # less than a period after the last edge's estimate: that sample's instant, not the
    # last one's (nor when the last one was taken)
    assert clock.ready(0.0302) == pytest.approx(0.03, abs=0.0006)


def test_before_any_edge_a_sample_is_stamped_when_seen():
    clock = DataReadyClock(0.01, 0.001)
    assert clock.ready(5.0) == 5.0
    assert clock.next_poll(5.0) == pytest.approx(5.0 + 0.01 - 0.002)


@pytest.mark.parametrize(("period", "poll"), [(0.0, 0.001), (0.01, 0.0), (-1.0, 0.001)])
def test_bad_periods_are_refused(period, poll):
    with pytest.raises(ValueError, match="period_s and poll_s must be > 0"):
        DataReadyClock(period, poll)
