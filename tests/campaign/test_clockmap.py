"""The campaign's map from the sync clock to the wall clock (``hera.campaign.clockmap``)."""

from __future__ import annotations

import time

import pytest

from hera.campaign import clockmap, journal
from hera.sync import clock as sync_clock

W0 = 1_800_000_000.0


def test_the_offset_is_interpolated_between_samples_and_held_outside():
    # wall - sync: 100 s, then the wall clock set 18 s forward between sync 50 and 50.25
    pairs = [(100.0 + s, s) for s in (0.0, 25.0, 50.0)] + [(118.0 + s, s) for s in (50.25, 80.0)]
    to_wall = clockmap.sync_to_wall(pairs, fallback_offset=-1.0)
    assert to_wall(10.0) == pytest.approx(110.0)
    assert to_wall(60.0) == pytest.approx(178.0)  # after the step: the new offset
    assert to_wall(50.125) == pytest.approx(50.125 + 109.0)  # inside a period: halfway
    assert to_wall(-5.0) == pytest.approx(95.0) and to_wall(500.0) == pytest.approx(618.0)
    assert clockmap.sync_to_wall([], fallback_offset=7.0)(3.0) == 10.0  # a campaign before


def test_a_pause_is_a_step_of_the_offset_and_slewing_is_none():
    slewing = [(W0 + s * 1.004, s) for s in [k * 0.25 for k in range(800)]]  # NTP: 4 ms/s
    assert clockmap.pauses(slewing) == []
    paused = [(W0 + s, s) for s in (0.0, 0.25, 0.5)] + [(W0 + 18.75, 0.75), (W0 + 19.0, 1.0)]
    assert clockmap.pauses(paused) == [(W0 + 0.5, W0 + 18.75, pytest.approx(18.0))]


def test_the_writer_samples_both_clocks_and_the_reader_skips_torn_lines(tmp_path):
    w = clockmap.AnchorWriter(tmp_path, period=0.01).start()
    time.sleep(0.2)
    w.stop()
    with open(tmp_path / clockmap.ANCHORS, "a") as f:
        f.write("garbled\n1800000000.5,12")  # a torn last line: its number is cut, not bad
        f.write("x\n")
    pairs = clockmap.read_anchors(tmp_path)
    assert len(pairs) >= 5
    offsets = [wall - sync for wall, sync in pairs]
    assert max(offsets) - min(offsets) < 0.05  # read together: one offset, this machine
    assert pairs == sorted(pairs)
    assert clockmap.read_anchors(tmp_path / "none") == []


def test_a_pair_read_across_a_deschedule_is_not_kept():
    """The clocks are read wall, sync, wall: of three tries, the one whose wall reads lie
    closest wins, so a try the process was descheduled in (5 ms between its wall reads, the
    sample that once moved a firing by a millisecond) pairs nothing. Wall - sync is -90 s."""
    # try 1 descheduled (sync read 5 ms late), tries 2 and 3 tight (20 us and 10 us)
    walls = iter([10.000, 10.005, 10.006, 10.00602, 10.007, 10.00701])
    syncs = iter([100.005, 100.00601, 100.007005])
    w, c = journal.now(tries=3, wall=walls.__next__, sync=syncs.__next__)
    assert (w, c) == (pytest.approx(10.007005), pytest.approx(100.007005))
    assert w - c == pytest.approx(-90.0, abs=1e-6)
    # one try alone keeps the descheduled pair: 2.5 ms off
    walls, syncs = iter([10.000, 10.005]), iter([100.005])
    w, c = journal.now(tries=1, wall=walls.__next__, sync=syncs.__next__)
    assert w - c == pytest.approx(-90.0025, abs=1e-6)


def test_the_real_clocks_pair_within_a_millisecond():
    w, c = journal.now()
    assert abs((time.time() - sync_clock.now()) - (w - c)) < 1e-3
