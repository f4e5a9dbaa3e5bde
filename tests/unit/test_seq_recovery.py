"""A restarted node takes its seqs back from its peers (``DataPath.recover_seqs``): the
answers are stood in for by a fake session in this unit test of one class; the cluster
tests run the real thing (tests/runtime/test_security_cluster.py, the forged cases).

Found live: a node SIGKILLed and restarted reported ``rejected foreign_seq=1`` about one
restart in four. Its own queryable answers its own query too, and when that answer came
after a peer's, it held the seq just adopted, under the new incarnation: counted as a
foreign answer, a problem on the console after an ordinary crash."""

from __future__ import annotations

from types import SimpleNamespace

import msgpack

from hera.datapath import DataPath
from hera.keys import Keys
from hera.store import Store

OLD, NEW, FORGED = 11, 22, 33


def reply(seqs: dict) -> SimpleNamespace:
    payload = SimpleNamespace(to_bytes=lambda: msgpack.packb(seqs))
    return SimpleNamespace(ok=SimpleNamespace(key_expr="hera/c/seq/all/n1", payload=payload))


def restarted(*answers: dict) -> DataPath:
    """n1's data path after a restart (incarnation NEW, OLD before), given ``answers``."""
    dp = DataPath("n1", Keys("c"), Store(), incarnation=NEW)
    dp.previous_incarnation = OLD
    session = SimpleNamespace(get=lambda *a, **k: [reply(s) for s in answers])
    dp.recover_seqs(session, 0.1)
    return dp


def test_its_own_answer_after_a_peers_is_not_a_foreign_one():
    dp = restarted({"sonar": [OLD, 84]}, {"sonar": [NEW, 84]}, {"sonar": [OLD, 84]})
    assert dp.rejected == {} and dp.last_rejection is None
    assert dp._seq == {"sonar": 84}  # it continues after its previous incarnation


def test_an_answer_of_another_incarnation_is_still_refused_and_counted():
    dp = restarted({"sonar": [OLD, 84]}, {"sonar": [FORGED, 10**9], "mag": [OLD, 5]})
    assert dp.rejected == {"foreign_seq": 1}
    assert dp._seq == {"sonar": 84, "mag": 5}
