"""DataReadyClock (``hera.nodes.data_ready``) on an injected clock: a chip making samples on
its own clock, polled when the clock says (on time, woken late at random, or late as
measured on a loaded host), each sample stamped within a tenth of a poll of when it was made
once the chip's clock is tracked, the period learnt without bias, few polls between
samples, a reset chip and a stale prediction recovered."""

from __future__ import annotations

import math
import random
import statistics
from collections.abc import Callable
from itertools import pairwise

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


def follow(
    chip: Chip,
    clock: DataReadyClock,
    until: float,
    late: dict[int, float] | None = None,
    wake: Callable[[], float] | None = None,
    read: Callable[[], float] | None = None,
    start: float = 0.0,
):
    """Poll ``chip`` when ``clock`` says until ``until``; ``late``: polls pushed back by that
    many s after the sample of that index (a descheduled thread); ``wake()``: how late (s)
    each poll's thread wakes; ``read()``: how long after the chip was read the read is seen
    to end. Returns (error of each stamp, polls)."""
    t, errors, polls = start, [], 0
    late = late or {}
    while t < until:
        polls += 1
        if wake is not None:
            t += wake()
        end = t + (read() if read is not None else 0.0)
        if chip.ready(t):
            k = chip.newest(t)
            chip.taken = k
            errors.append((k, clock.ready(end) - chip.made(k)))
        else:
            clock.not_ready(t)
        t = clock.next_poll(end)
        nxt = chip.taken + 1
        if nxt in late and t >= chip.made(nxt):
            t = chip.made(nxt) + late.pop(nxt)
    return errors, polls


def woken_at_random(rng: random.Random) -> tuple[Callable[[], float], Callable[[], float]]:
    """(wake, read) for :func:`follow`: a third of the polls woken up to 5 ms late, and a
    tenth of the reads ending up to 1 ms after the chip was read (the thread descheduled
    within the read)."""
    return (
        lambda: rng.uniform(0.0, 0.005) if rng.random() < 1 / 3 else 0.0,
        lambda: rng.uniform(0.0, 0.001) if rng.random() < 0.1 else 0.0,
    )


@pytest.mark.parametrize("error", [-0.03, -0.015, 0.0, 0.015, 0.03])
def test_each_sample_is_stamped_on_the_chips_clock_and_the_period_is_learnt(error):
    nominal, poll = 1 / 26, 0.001
    chip = Chip(nominal / (1 + error))  # the chip's clock off by ``error``
    clock = DataReadyClock(nominal, poll)
    errors, polls = follow(chip, clock, 20.0)
    settled = [e for k, e in errors if k > 30]
    stamps = [chip.made(k) + e for k, e in errors if k > 30]
    # Raw edge midpoints would be off by up to half a poll (0.5 ms), in a pattern that
    # repeats as the chip's instants slide along the host's poll grid; tracked, a tenth.
    assert max(abs(e) for e in settled) <= poll / 10
    intervals = [b - a for a, b in pairwise(stamps)]
    assert statistics.median(intervals) == pytest.approx(chip.period, abs=poll / 10)
    mean = (stamps[-1] - stamps[0]) / (len(stamps) - 1)
    assert mean == pytest.approx(chip.period, abs=1e-6)
    assert clock.period == pytest.approx(chip.period, rel=2e-4)  # nominal: 3 % off
    assert polls / len(errors) < 5  # a few polls before each sample, none between
    assert [k for k, _ in errors] == list(range(len(errors)))  # none missed
    assert clock.relocks == 0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_thread_woken_late_still_stamps_on_the_chips_clock(seed):
    # A third of the polls woken up to 5 ms late (a loaded 2-core host), a tenth of the
    # reads seen to end up to 1 ms late: the stamps still follow the chip's clock.
    nominal, poll = 1 / 104, 0.001
    chip = Chip(nominal / 1.03)
    clock = DataReadyClock(nominal, poll)
    wake, read = woken_at_random(random.Random(seed))
    errors, _ = follow(chip, clock, 20.0, wake=wake, read=read)
    settled = [abs(e) for k, e in errors if k > 200]
    assert statistics.median(settled) < poll / 10
    assert sum(e < poll / 2 for e in settled) >= 0.99 * len(settled)
    assert clock.period == pytest.approx(chip.period, rel=1e-3)


def woken_late(rng: random.Random) -> float:
    """How late (s) a poll's thread wakes on a loaded 2-core host: measured for the I2C
    driver's sampler while a CI run used both cores (median 0.17 ms, 90th percentile
    1.05 ms, 99th 10 ms)."""
    u = rng.random()
    if u < 0.8:
        return rng.uniform(0.0001, 0.00025)
    return rng.uniform(0.0009, 0.0011) if u < 0.95 else rng.uniform(0.001, 0.012)


@pytest.mark.parametrize("error", [-0.03, 0.0, 0.03])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_polls_always_late_do_not_bias_the_period(seed, error):
    # Every poll late, and late more often than not by a poll or more: the stamps are kept
    # between the two polls, and the period learnt only from the tracked clock (kept out of
    # it, the clamp would hide from the period the drift it corrects: 9-15e-4 short here).
    rng = random.Random(seed)
    chip = Chip((1 / 104) / (1 + error))
    clock = DataReadyClock(1 / 104, 0.001)
    errors, _ = follow(chip, clock, 3.0, wake=lambda: woken_late(rng), read=lambda: 3e-5)
    assert clock.period == pytest.approx(chip.period, rel=2e-4)
    assert statistics.median(abs(e) for _, e in errors[100:]) < 0.0003


def test_a_reset_chip_is_tracked_again_with_its_period_kept():
    nominal, poll = 0.01, 0.001
    chip = Chip(nominal * 1.02)
    clock = DataReadyClock(nominal, poll)
    follow(chip, clock, 5.0)
    learnt = clock.period
    # the chip reset: its samples now come half a period off the old instants
    restarted = Chip(chip.period, phase=chip.made(chip.taken) + 1.5 * chip.period)
    restarted.taken = -1
    errors, _ = follow(restarted, clock, 10.0, start=5.0)
    assert clock.relocks == 1
    assert clock.period == pytest.approx(learnt, rel=1e-3)
    assert max(abs(e) for k, e in errors if k >= 5) <= poll / 2


def test_a_sample_that_fits_no_prediction_is_stamped_when_seen_and_the_next_edge_found():
    clock = DataReadyClock(0.01, 0.001)
    for edge in (0.0, 0.01, 0.02, 0.03):
        clock.not_ready(edge - 0.0004)
        clock.ready(edge + 0.0006)
    # none seen at 0.044, 4 ms after the predicted 0.04; then, after a 3 ms gap (no edge),
    # a sample: the prediction has gone stale
    clock.not_ready(0.044)
    assert clock.ready(0.047) == 0.047
    # the next sample is looked for every poll, not two polls before a prediction
    assert clock.next_poll(0.047) == pytest.approx(0.048)


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


def test_before_any_edge_a_sample_is_stamped_when_seen_and_polls_find_the_first_edge():
    clock = DataReadyClock(0.01, 0.001)
    assert clock.ready(5.0) == 5.0
    assert clock.next_poll(5.0) == pytest.approx(5.001)
    chip = Chip(0.0101, phase=5.0033)
    errors, polls = follow(chip, clock, 5.05, start=5.001)  # its first sample: 5.0033 s
    assert polls < 5 * len(errors) and abs(errors[0][1]) <= 0.0005


@pytest.mark.parametrize(("period", "poll"), [(0.0, 0.001), (0.01, 0.0), (-1.0, 0.001)])
def test_bad_periods_are_refused(period, poll):
    with pytest.raises(ValueError, match="period_s and poll_s must be > 0"):
        DataReadyClock(period, poll)
