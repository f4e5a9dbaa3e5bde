"""The scale benchmark's clusters are valid specs; staggered, the nodes take turns."""

from __future__ import annotations

import threading
import time

import msgpack
import pytest
import tomllib

from hera.bench.scale import PERIOD, STREAMS, main, spec_text
from hera.bench.scale_peer import Counts, plan, publish
from hera.bench.security import secure
from hera.spec import parse_spec


def _offsets(text: str) -> dict[str, set]:
    spec = parse_spec(tomllib.loads(text), "scale.toml")
    return {n.name: {m.offset for m in n.measures if m.name != "reader"} for n in spec.nodes}


def test_on_the_grid_every_stream_takes_the_default_phase():
    offsets = _offsets(spec_text(4, "mesh", 1.0, "grid"))
    assert offsets == {f"n{i}": {None} for i in range(1, 5)}


def test_staggered_the_nodes_spread_over_the_period():
    text = spec_text(4, "routers", 1.0, "staggered")
    offsets = _offsets(text)
    assert offsets == {f"n{i + 1}": {round(PERIOD * i / 4, 6)} for i in range(4)}
    assert text.count("offset =") == 4 * STREAMS


def test_an_unknown_phases_value_is_refused(capsys):
    assert main(["--phases", "grid,random"]) == 2
    assert "--phases: unknown 'random'" in capsys.readouterr().err


def test_an_unknown_security_mode_is_refused(capsys):
    assert main(["--security", "auth,ssh"]) == 2
    assert "--security: unknown 'ssh'; use none, auth, tls" in capsys.readouterr().err


def test_tls_mode_makes_a_certificate_for_every_node_and_router(tmp_path):
    text = secure(spec_text(4, "routers", 1.0, "staggered"), "tls", tmp_path / "certs")
    spec = parse_spec(tomllib.loads(text), "scale.toml")
    assert spec.tls and spec.certs == (tmp_path / "certs").as_posix()
    made = {p.stem for p in (tmp_path / "certs").glob("*.crt")} | {
        p.stem for p in (tmp_path / "certs").glob("*.pem")
    }
    assert {"n1", "n2", "n3", "n4", "r1"} <= made, made
    assert secure("x", "auth", tmp_path / "unused") == "x"
    assert not (tmp_path / "unused").exists()


def test_with_ports_every_mesh_peer_gets_its_own_and_clients_none():
    mesh = parse_spec(tomllib.loads(spec_text(4, "mesh", 1.0, ports=True)), "scale.toml")
    ports = [n.port for n in mesh.nodes]
    assert all(ports) and len(set(ports)) == 4, ports
    routed = parse_spec(tomllib.loads(spec_text(4, "routers", 1.0, ports=True)), "scale.toml")
    assert [n.port for n in routed.nodes] == [0] * 4 and routed.routers[0].port


def test_the_peer_plans_the_nodes_streams_and_reads_from_the_spec():
    spec = parse_spec(tomllib.loads(spec_text(8, "routers", 1.0, "staggered")), "scale.toml")
    names, period, offset, reads = plan(spec, "n3")
    assert names == [f"s{k}" for k in range(1, STREAMS + 1)]
    assert period == PERIOD and offset == pytest.approx(PERIOD * 2 / 8)
    assert sorted(reads) == sorted(f"s{k}/n{j}" for j in (4, 5, 6) for k in range(1, STREAMS + 1))


def test_the_peer_refuses_streams_of_different_offsets():
    text = spec_text(2, "mesh", 1.0, "staggered").replace(
        'name = "s2"\nperiod = 0.02\noffset = 0.000000',
        'name = "s2"\nperiod = 0.02\noffset = 0.005',
    )
    spec = parse_spec(tomllib.loads(text), "scale.toml")
    with pytest.raises(ValueError, match="node n1: its streams need one period and offset"):
        plan(spec, "n1")


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


def test_the_peer_publishes_every_stream_once_a_wake_with_one_seq():
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
