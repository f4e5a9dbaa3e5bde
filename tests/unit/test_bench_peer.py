"""The benchmarks' peer (hera.bench.peer): a spec's traffic planned from its measures, a
window of counts, one publishing wake per period and offset (no bus: one class each)."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import msgpack
import pytest

from hera.bench.peer import Counts, plan, publish
from hera.bench.scale import PERIOD, STREAMS, spec_text
from hera.keys import Keys
from hera.spec import load_spec, parse_spec, tomllib

ROOT = Path(__file__).resolve().parents[2]


def test_the_observers_traffic_is_four_names_on_one_wake_reading_their_prefix():
    spec = load_spec(ROOT / "deploy" / "observers.toml")
    p = plan(spec, "n2")
    assert p.groups == {(0.1, 0.0): ["obs1", "obs2", "obs3", "obs4"]}
    assert p.reads == ["obs*"]
    assert plan(spec, "n1").reads is None  # the logging node takes every sample


def test_the_scale_traffic_is_its_streams_and_the_readers_streams():
    spec = parse_spec(tomllib.loads(spec_text(8, "routers", 1.0, "staggered")), "scale.toml")
    p = plan(spec, "n3")
    offset = round(PERIOD * 2 / 8, 6)
    assert p.groups == {(PERIOD, offset): [f"s{k}" for k in range(1, STREAMS + 1)]}
    assert sorted(p.reads) == sorted(f"s{k}/n{j}" for j in (4, 5, 6) for k in range(1, 5))


def test_a_synchronised_measure_is_refused():
    text = """
[cluster]
name = "s"
[[nodes]]
name = "a"
sync_hosts = ["sonar"]
[[nodes.measures]]
use = "hera.bench.scale:Stream"
name = "sonar"
sync = true
"""
    spec = parse_spec(tomllib.loads(text), "s.toml")
    with pytest.raises(ValueError, match="node a: measure sonar is synchronised"):
        plan(spec, "a")


def test_reads_subscribe_as_a_nodes_data_path():
    k = Keys("c")
    assert k.data_read("obs*") == "hera/c/data/obs$*/*"
    assert k.data_read("s1/n4") == "hera/c/data/s1/n4"
    assert k.data_read("temp") == "hera/c/data/temp/*"


class _Sample:
    def __init__(self, key: str, seq: int, t: float) -> None:
        self.key_expr = key
        self.payload = self
        self._bytes = msgpack.packb([seq, t, 1.0])

    def to_bytes(self) -> bytes:
        return self._bytes


def test_the_peer_counts_inside_its_window_only_and_sees_gaps():
    c = Counts()
    c.on_sample(_Sample("a", 1, time.time()))  # no window yet: not counted
    now = time.time()
    c.start, c.end = now - 10, now + 10
    for seq in (5, 6, 8):  # 7 lost
        c.on_sample(_Sample("a", seq, time.time() - 0.002))
    c.on_sample(_Sample("b", 1, time.time()))
    f = c.figures()
    assert (f["received"], f["expected"]) == (4, 5)
    assert sum(f["bins"].values()) == 4
    c.end = now - 5  # the window is over
    c.on_sample(_Sample("a", 9, time.time()))
    assert c.figures()["received"] == 4


class _Pub:
    def __init__(self, log: list) -> None:
        self.log = log

    def put(self, payload: bytes) -> None:
        self.log.append((self, msgpack.unpackb(payload)))


def test_the_peer_publishes_every_name_once_a_wake_with_one_seq():
    log: list = []
    pubs = [_Pub(log), _Pub(log), _Pub(log)]
    stop = threading.Event()
    t = threading.Thread(target=publish, args=(pubs, 0.01, 0.0, stop))
    t.start()
    time.sleep(0.2)
    stop.set()
    t.join(5)
    assert not t.is_alive()
    wakes = [log[i : i + 3] for i in range(0, len(log), 3)]
    assert 5 <= len(wakes) <= 0.2 / 0.01 + 2, len(wakes)  # never twice on one instant
    for k, wake in enumerate(wakes, 1):
        assert [p for p, _ in wake] == pubs and all(m[0] == k for _, m in wake), wake
        assert len({m[1] for _, m in wake}) == 1  # one payload for all
