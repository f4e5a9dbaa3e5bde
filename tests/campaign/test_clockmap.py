"""The campaign's map from the sync clock to the wall clock (``hera.campaign.clockmap``)."""

from __future__ import annotations

import time

import pytest

from hera.campaign import clockmap

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
