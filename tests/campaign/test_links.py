"""The link proxy: bytes pass, wait in a blackhole, arrive late, are reset; and with real
Zenoh peers on loopback, a partition cuts exactly the chosen pairs while a tool joined to
every node still sees them all (peers do not relay, and gossip is off)."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from harness import wait_for

from hera.bus import OVERRIDES_ENV, BusConfig, open_session, with_overrides
from hera.campaign.links import (
    ProxyProcess,
    control,
    cut_pairs,
    links_of,
    node_env,
    plan_links,
    write_plan,
)
from hera.node import node_bus
from hera.ports import free_ports
from hera.security.access import OPERATOR
from hera.security.certs import make_certs
from hera.security.credentials import secured
from hera.spec import parse_spec


def _spec(names):
    spec = parse_spec({"cluster": {"name": "links"}, "nodes": [{"name": n} for n in names]})
    return spec.with_ports(free_ports("127.0.0.1", len(names)))


class Echo:
    """A TCP server that echoes every byte back (the 'node' behind the proxy)."""

    def __init__(self, port: int) -> None:
        self.sock = socket.socket()
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind(("127.0.0.1", port))
        self.sock.listen()
        self.conns: list[socket.socket] = []
        self.closed = threading.Event()
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while not self.closed.is_set():
            try:
                c, _ = self.sock.accept()
            except OSError:
                return
            self.conns.append(c)
            threading.Thread(target=self._echo, args=(c,), daemon=True).start()

    def _echo(self, c: socket.socket) -> None:
        try:
            while data := c.recv(65536):
                c.sendall(data)
        except OSError:
            pass

    def close(self) -> None:
        self.closed.set()
        self.sock.close()
        for c in self.conns:
            c.close()


@pytest.fixture
def proxied(tmp_path) -> Iterator[tuple]:
    """Nodes a, b, c; an echo server on b's port; the proxy in front of every node."""
    spec = _spec(["a", "b", "c"])
    plan = plan_links(spec, free_ports("127.0.0.1", 6), seed=3)
    proxy = ProxyProcess(write_plan(plan, tmp_path), tmp_path / "proxy.log")
    echo = Echo(spec.node("b").port)
    proxy.start()
    try:
        yield spec, plan, proxy
    finally:
        proxy.stop()
        echo.close()


def _port(plan, a: str, b: str) -> int:
    return next(k["port"] for k in plan["links"] if k["from"] == a and k["to"] == b)


def _dial(plan, a: str = "a", b: str = "b") -> socket.socket:
    s = socket.create_connection(("127.0.0.1", _port(plan, a, b)), timeout=5)
    s.settimeout(5)
    return s


def _roundtrip(s: socket.socket, data: bytes = b"ping") -> float:
    t = time.monotonic()
    s.sendall(data)
    got = b""
    while len(got) < len(data):
        got += s.recv(65536)
    assert got == data
    return time.monotonic() - t


def test_bytes_pass_both_ways_and_delays_add_up(proxied):
    _, plan, proxy = proxied
    with _dial(plan) as s:
        assert _roundtrip(s) < 0.05
        proxy.command({"op": "set", "pairs": [["a", "b"]], "delay_ms": 100})
        rtt = _roundtrip(s, b"slow")
        assert 0.19 <= rtt < 0.5  # 100 ms each way
        proxy.command({"op": "clear"})
        assert _roundtrip(s) < 0.05


def test_a_blackhole_holds_bytes_and_keeps_the_socket_open_until_healed(proxied):
    _, plan, proxy = proxied
    with _dial(plan) as s:
        _roundtrip(s)
        proxy.command({"op": "set", "pairs": cut_pairs([["a"], ["b", "c"]]), "mode": "blackhole"})
        s.sendall(b"held")
        s.settimeout(0.5)
        with pytest.raises(TimeoutError):
            s.recv(10)  # nothing comes back, and the connection is not closed
        proxy.command({"op": "clear", "pairs": [["a", "b"]]})
        s.settimeout(5)
        assert s.recv(10) == b"held"  # delivered on healing, like a retransmission
    # a new connection during a blackhole is accepted but goes nowhere
    proxy.command({"op": "set", "pairs": [["a", "b"]], "mode": "blackhole"})
    with _dial(plan) as s:
        s.sendall(b"x")
        s.settimeout(0.3)
        with pytest.raises(TimeoutError):
            s.recv(10)
        proxy.command({"op": "clear"})
        s.settimeout(5)
        assert s.recv(10) == b"x"


def _refused(plan) -> bool:
    """A new connection of pair (a, b) is reset or closed: the proxy accepts and resets it,
    and the reset may reach this side before connect() returns (seen under load) or after."""
    try:
        again = _dial(plan)
    except ConnectionResetError:
        return True
    with again:
        try:
            return again.recv(10) == b""
        except ConnectionResetError:
            return True


def test_reset_closes_every_connection_of_the_pair_with_a_reset(proxied):
    _, plan, proxy = proxied
    s = _dial(plan)
    other = _dial(plan, "c", "b")  # another pair: untouched
    try:
        _roundtrip(s)
        _roundtrip(other)
        proxy.command({"op": "set", "pairs": links_of("a", ["b"]), "mode": "reset"})
        with pytest.raises(ConnectionResetError):
            s.sendall(b"x")
            time.sleep(0.1)
            s.sendall(b"x")
            s.recv(10)
        assert _refused(plan)  # while the reset lasts
        assert _roundtrip(other) < 0.05
    finally:
        s.close()
        other.close()
    status = {tuple(p["pair"]): p for p in proxy.command({"op": "status"})["pairs"]}
    assert status[("a", "b")]["resets"] >= 1 and status[("b", "c")]["resets"] == 0


def test_loss_holds_chunks_a_retransmission_timeout_in_order(proxied):
    _, plan, proxy = proxied
    proxy.command({"op": "set", "pairs": [["a", "b"]], "loss": 0.5})
    with _dial(plan) as s:
        times = [_roundtrip(s, f"{i:04d}".encode()) for i in range(20)]
    retrans = proxy.command({"op": "status"})["pairs"][0]["retransmits"]
    assert retrans >= 5  # about 20 of 40 chunk passes lost once at least
    assert max(times) >= 0.2  # a lost chunk waits a whole timeout
    assert sorted(times)[len(times) // 4] < 0.05  # and the rest do not


def test_the_control_socket_refuses_bad_requests_with_a_sentence(proxied):
    _, plan, _ = proxied
    with pytest.raises(ValueError, match="no link between a and z"):
        control(plan["control"], {"op": "set", "pairs": [["a", "z"]], "mode": "blackhole"})
    with pytest.raises(ValueError, match="link mode must be one of"):
        control(plan["control"], {"op": "set", "pairs": [["a", "b"]], "mode": "cut"})
    with pytest.raises(ValueError, match="op must be set, clear or status"):
        control(plan["control"], {"op": "drop"})


def test_the_proxy_stops_when_its_parent_is_gone(tmp_path):
    import subprocess
    import sys

    spec = _spec(["a", "b"])
    plan_path = write_plan(plan_links(spec, free_ports("127.0.0.1", 2)), tmp_path)
    script = (
        "import sys, time; from pathlib import Path; "
        "from hera.campaign.links import ProxyProcess; "
        f"p = ProxyProcess(Path({str(plan_path)!r}), Path({str(tmp_path / 'l')!r})); "
        "p.start(); print(p.pid, flush=True); time.sleep(60)"
    )
    parent = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    pid = int(parent.stdout.readline())
    parent.kill()
    parent.wait()

    def gone() -> bool:
        try:
            with open(f"/proc/{pid}/stat") as f:
                return f.read().rsplit(")", 1)[1].split()[0] == "Z"
        except FileNotFoundError:
            return True

    wait_for(gone, 5, "the orphaned proxy to stop")


# -- with Zenoh ----------------------------------------------------------------------------


@pytest.mark.parametrize("tls", [False, True], ids=["tcp", "tls"])
def test_a_partition_of_zenoh_peers_cuts_only_the_chosen_pairs(tmp_path, tls):
    """Three peers behind the proxy, with the overrides a node applies and then its
    credentials (as a node does: with TLS, mutual TLS and access control pass through the
    proxy, which carries bytes); an observer joined directly to all three. Cut a from b
    and c: a hears nobody, b and c hear each other, the observer hears all three; healed,
    a hears the others again."""
    spec = _spec(["a", "b", "c"])
    auth = spec.with_security(auth=False)
    if tls:
        certs = tmp_path / "certs"
        make_certs(certs, spec.name, {n: [] for n in ("a", "b", "c", OPERATOR)})
        auth = spec.with_security(tls=True, certs=str(certs))
    plan_path = write_plan(plan_links(spec, free_ports("127.0.0.1", 6)), tmp_path)
    env = node_env(plan_path, {})
    assert env[OVERRIDES_ENV] == str(plan_path)
    proxy = ProxyProcess(plan_path, tmp_path / "proxy.log")
    proxy.start()
    sessions = {}
    heard: dict[str, dict[str, int]] = {}
    lock = threading.Lock()
    stop = threading.Event()
    try:
        for n in spec.nodes:
            others = {m.port for m in spec.nodes if m.name != n.name}
            cfg = node_bus(auth, n.name, env)  # what the node process opens
            assert cfg.extra["scouting/gossip/enabled"] is False
            assert len(cfg.connect) == 2 and not others & {
                int(e.rsplit(":")[-1]) for e in cfg.connect
            }
            assert all(e.startswith("tls/" if tls else "tcp/") for e in cfg.connect)
            sessions[n.name] = open_session(cfg)
        everyone = tuple(spec.endpoint(n.name) for n in spec.nodes)
        sessions["observer"] = open_session(
            secured(auth, OPERATOR, BusConfig(connect=everyone, lease_ms=1000))
        )
        subs = []
        for who, s in sessions.items():
            heard[who] = {}

            def on(sample, who=who):
                src = str(sample.key_expr).rsplit("/", 1)[-1]
                with lock:
                    heard[who][src] = heard[who].get(src, 0) + 1

            subs.append(s.declare_subscriber("hera/links/data/t/*", on))

        def publish() -> None:
            while not stop.is_set():
                for n in ("a", "b", "c"):
                    sessions[n].put(f"hera/links/data/t/{n}", b"x")  # its own key
                time.sleep(0.01)

        threading.Thread(target=publish, daemon=True).start()

        def window(seconds: float) -> dict[str, set[str]]:
            with lock:
                for v in heard.values():
                    v.clear()
            time.sleep(seconds)
            with lock:
                return {w: {src for src, k in v.items() if k >= 5} for w, v in heard.items()}

        wait_for(lambda: window(0.3)["a"] == {"a", "b", "c"}, 10, "the mesh to form")
        proxy.command({"op": "set", "pairs": cut_pairs([["a"], ["b", "c"]]), "mode": "blackhole"})
        window(0.2)  # what was in flight
        cut = window(1.5)
        assert cut["a"] == {"a"}
        assert cut["b"] == {"b", "c"} and cut["c"] == {"b", "c"}
        assert cut["observer"] == {"a", "b", "c"}  # the tool is not cut, and relays nothing
        proxy.command({"op": "clear"})
        wait_for(lambda: window(0.3)["a"] == {"a", "b", "c"}, 10, "a to hear b and c again")
    finally:
        stop.set()
        for s in sessions.values():
            s.close()
        proxy.stop()


def test_overrides_naming_a_bad_file_stop_the_node_with_the_reason(tmp_path):
    bad = tmp_path / "links.json"
    bad.write_text("{not json")
    with pytest.raises(ValueError, match="bus overrides .* cannot be used"):
        with_overrides(BusConfig(), "a", {OVERRIDES_ENV: str(bad)})
    assert with_overrides(BusConfig(), "a", {}) == BusConfig()
    good = tmp_path / "ok.json"
    good.write_text('{"nodes": {"b": {"connect": ["tcp/127.0.0.1:9"]}}}')
    assert with_overrides(BusConfig(), "a", {OVERRIDES_ENV: str(good)}) == BusConfig()
    assert with_overrides(BusConfig(), "b", {OVERRIDES_ENV: str(good)}).connect == (
        "tcp/127.0.0.1:9",
    )


def test_plan_files_give_every_ordered_pair_its_own_port(tmp_path):
    spec = _spec(["a", "b", "c", "d"])
    plan = plan_links(spec, free_ports("127.0.0.1", 12))
    assert len({k["port"] for k in plan["links"]}) == 12
    assert {(k["from"], k["to"]) for k in plan["links"]} == {
        (x, y) for x in "abcd" for y in "abcd" if x != y
    }
    assert len(plan["nodes"]["a"]["connect"]) == 3
    assert len(plan["control"]) < 100  # a Unix socket path must stay short
    assert cut_pairs([["a"], ["b", "c"], ["d"]]) == [
        ["a", "b"],
        ["a", "c"],
        ["a", "d"],
        ["b", "d"],
        ["c", "d"],
    ]
    with pytest.raises(ValueError, match="two sides"):
        cut_pairs([["a"], ["a", "b"]])
    assert Path(plan["control"]).parent.exists()
