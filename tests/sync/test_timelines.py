"""The three timelines of issue 19, replayed on the pure state machines (``sync_simnet``).

Each one made two sonars sound at once with the earlier protocol:

1. a leader whose clock froze (system suspend under ``CLOCK_MONOTONIC``, a VM pause)
   resumes believing its lease valid and grants to a client that has not seen the new
   term;
2. all hosts restart, epochs and tokens repeat, and a late release of the old term frees
   the slot of the new term's holder; with the state lost, clients that know a higher epoch
   refuse every grant for ever;
3. (the trigger check: ``test_trigger.py`` and the live ``test_cluster_safety.py``).
"""

from __future__ import annotations

from sync_simnet import Group, Sim, SimClient, SimClock, SimHost, make_group, overlaps

from hera.sync.election import Timing
from hera.sync.protocol import Release

T = Timing(lease=0.3, max_slot=0.15, margin=0.05)
SLOT = 0.06  # the 60 ms slot (a sonar ping)


def _group(clients: int = 2, seed: int = 7) -> Group:
    return make_group(T, hosts=3, clients=clients, slot=SLOT, seed=seed)


def _flowing(g: Group, n: int = 6, limit: float = 10.0) -> SimHost:
    assert g.sim.run_until(lambda: len(g.sim.emissions) >= n, limit), "no slots flowed"
    leader = g.leader()
    assert leader is not None
    return leader


def _assert_no_overlap(sim: Sim) -> None:
    bad = overlaps(sim.emissions)
    assert bad == [], f"{len(bad)} overlapping emissions, first {bad[0]}"


def test_timeline_1_a_leader_whose_clock_froze_grants_nothing_after_it_resumes():
    g = _group(clients=2)
    sim = g.sim
    a = _flowing(g)
    epoch_a = a.core.term.epoch
    # freeze A right after a renewal came back: its lease looks fresh for ~L on its clock
    renewed = a.core.term.lease_end
    assert sim.run_until(lambda: a.core.term.lease_end > renewed, sim.now + 1.0)
    a.pause(freeze_clock=True)
    # X has not seen the next term: it reaches only A (cut off from the others)
    SimClient(sim, "x", SLOT, SimClock(offset=5.0), start=sim.now)
    sim.cut_off("x", [h.name for h in g.hosts if h is not a])
    # the others elect a new term and the clients sound under it
    assert sim.run_until(lambda: any(e.epoch > epoch_a for e in sim.emissions), sim.now + 3.0), (
        "no new term"
    )
    a.resume()  # its clock reads what it read when it froze
    sim.run(sim.now + 1.0)
    _assert_no_overlap(sim)
    assert not any(e.holder == "x" and e.epoch == epoch_a for e in sim.emissions)


def test_timeline_2_a_late_release_after_a_full_restart_frees_nothing():
    g = _group(clients=3)
    sim = g.sim
    _flowing(g)
    c1 = g.clients[0]
    # c1 sounds, then stalls before its release (held by the network), and asks no more
    rels: list[Release] = []

    def c1_release(src: str, dst: str, msg: object) -> bool:
        mine = src == c1.name and isinstance(msg, Release) and msg.used
        if mine and (not rels or msg == rels[0]):
            rels.append(msg)
            c1.stopped = True
            return True
        return False

    box = sim.hold(c1_release)
    assert sim.run_until(lambda: bool(rels), sim.now + 2.0), "no release to hold"
    rel = rels[0]
    for h in g.hosts:  # a redeploy or a power blip: every host at once
        h.restart()
    # the new term hands out slots; deliver the stale release while the slot that is out
    # carries the same token number (with a repeated epoch, the very same token)
    n = rel.token & 0xFFFFFFFF

    def same_number() -> bool:
        ld = g.leader()
        cur = ld.core.table.current if ld is not None and ld.core.table else None
        return cur is not None and cur.token & 0xFFFFFFFF == n and cur.holder != c1.name

    sim.run_until(same_number, sim.now + 6.0, step=0.001)
    sim.unhold(box)
    sim.run(sim.now + 1.0)
    _assert_no_overlap(sim)
    new_terms = [h.core.term.epoch for h in g.hosts if h.core.term is not None]
    assert new_terms and min(new_terms) > rel.epoch, "an epoch was reused after the restart"


def test_timeline_2_clients_that_know_a_higher_epoch_get_slots_after_the_state_is_lost():
    g = _group(clients=2)
    sim = g.sim
    a = _flowing(g)
    # a second term, so that the clients know epoch >= 2
    a.restart()
    assert sim.run_until(
        lambda: {e.epoch for e in sim.emissions if e.holder == "c0"} - {1}, sim.now + 5.0
    ), "no second term"
    known = max(e.epoch for e in sim.emissions)
    t_restart = sim.now
    for h in g.hosts:
        h.restart(wipe=True)  # promises and epochs lost
    ok = sim.run_until(
        lambda: sum(1 for e in sim.emissions if e.start > t_restart) >= 10, sim.now + 6.0
    )
    stale = {c.name: c.stale for c in g.clients}
    assert ok, f"no slots after the restart: stale grants refused {stale}"
    after = [e for e in sim.emissions if e.start > t_restart]
    assert min(e.epoch for e in after) > known
    _assert_no_overlap(sim)
