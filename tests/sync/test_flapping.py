"""A leader behind a flapping link, on the pure state machines (``sync_simnet``).

The campaign's "flapping leader" fault (``deploy/campaigns/partitions.toml``): the leader's
links are blackholed for 0.4 s, then pass for 0.6 s, ten times. A blackholed link drops
nothing: what was sent in the cut arrives at once when it heals, the renewals of a term the
leader has meanwhile lost by its own lease among it. Before the voters' and the deposed
leader's rules for this (``Voter`` and ``GroupCore.end_term``), those late renewals made the
voters refuse everyone but the old leader, which then won the group back at each healing and
lost it at the next cut: the majority side paused 1.9 s once in a live campaign, and through
the whole flapping (5-10 s) in most of these runs with 0.35 s cuts.
"""

from __future__ import annotations

import pytest
from sync_simnet import make_group, overlaps

from hera.sync.election import Timing

T = Timing(lease=0.3, max_slot=0.15, margin=0.05)
SLOT = 0.049  # a MaxSonar ping

# The longest the sonars may wait when their leader is cut off: its lease lapses (L), the
# others notice at their next loop turn (L/6), the last of them in rank runs (2 L/4), a
# pre-vote and a vote round (2 L/6), the new leader waits W, then a slot: 1.15 s here.
BOUND = T.lease + T.renew + T.lease / 2 + 2 * T.renew + T.wait + SLOT


def flapping(seed: int, cut: float, phase: float, delay: float = 0.005) -> tuple[float, str, set]:
    """Flap the leader's links (``cut`` s blackholed, ``1 - cut`` s passing) ten times;
    return the longest pause between two sounds from the first cut to 3 s after the last,
    the flapping host, and the leaders of the sounds made while it flapped."""
    g = make_group(T, hosts=3, clients=2, slot=SLOT, seed=seed)
    sim = g.sim
    sim.delay = lambda: sim.rnd.uniform(0.0005, delay)
    assert sim.run_until(lambda: len(sim.emissions) >= 6, 10.0), "no slots flowed"
    sim.run(sim.now + phase)
    leader = g.leader()
    assert leader is not None
    name = leader.name
    start = sim.now
    for _ in range(10):
        box = sim.hold(lambda src, dst, _msg: src != dst and name in (src, dst))
        sim.run(sim.now + cut)
        sim.unhold(box)  # the blackhole heals: everything held arrives at once
        sim.run(sim.now + 1.0 - cut)
    end = sim.now
    sim.run(end + 3.0)
    assert overlaps(sim.emissions) == []
    starts = sorted(e.start for e in sim.emissions if e.start >= start - 0.2)
    longest = max(b - a for a, b in zip(starts, starts[1:], strict=False))
    leaders = {e.leader for e in sim.emissions if start + 2.0 <= e.start <= end}
    return longest, name, leaders


@pytest.mark.parametrize("cut", [0.35, 0.4])
def test_the_others_elect_one_of_theirs_and_keep_sounding_while_the_leader_flaps(cut):
    worst = 0.0
    for seed in range(4):
        for phase in (0.0, 0.017, 0.034):
            longest, flapper, leaders = flapping(seed, cut, phase)
            worst = max(worst, longest)
            assert flapper not in leaders, (seed, phase, flapper, leaders)
    assert worst <= BOUND, (worst, BOUND)
