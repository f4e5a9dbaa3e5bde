"""The overlap checker compares firings on the clock their fire logs were written on.

Found in a clean-clone CI run (2026-12-02): one "overlap" of 0.1 ms in 451 firings, in the
quiet settle of a campaign, between two firings 1 ms apart on the sync clock. Each firing is
placed on the wall clock through its own offset, interpolated between samples of the two
clocks read one after the other (``clock.csv``); a sample read across a deschedule moves
that offset by milliseconds, enough to pass one firing over the next.
"""

from __future__ import annotations

import dataclasses

from hera.campaign.check_firings import overlapping
from hera.campaign.clockmap import sync_to_wall
from hera.campaign.history import parse_fire_line

# wall - sync: 100 s, but the sample at sync 10.0 was read 20 ms late on the wall clock
ANCHORS = [(100.0 + s, s) for s in (9.75, 10.25, 10.5)] + [(110.02, 10.0)]


def _firings(lines: list[str]):
    to_wall = sync_to_wall(ANCHORS, fallback_offset=0.0)
    return [parse_fire_line(x, "sonar", "sonar", to_wall) for x in lines]


def test_firings_a_millisecond_apart_do_not_overlap_however_the_clocks_were_sampled():
    fs = _firings(["10.000 10.049 s1 1 1 10.100", "10.050 10.099 s2 1 2 10.150"])
    assert fs[1].start < fs[0].end  # on the wall clock they pass each other ...
    assert overlapping(fs) == []  # ... on their own clock they do not
    on_wall = [dataclasses.replace(f, clock_start=None, clock_end=None) for f in fs]
    assert overlapping(on_wall) == [(on_wall[0], on_wall[1])]  # the old check: a false alarm


def test_a_real_overlap_is_found_on_the_sync_clock():
    fs = _firings(["10.000 10.049 s1 1 1 10.100", "10.045 10.094 s2 1 2 10.150"])
    assert overlapping(fs) == [(fs[0], fs[1])]
