"""A hostile client on a running cluster: nobody gets in, nothing is lost (issue 15).

The foreign client is written from the README's wire format alone: plain ``zenoh`` and
``msgpack``, no ``hera`` import in what it sends. It tries every attack of the issue
against a five-node observer cluster started by ``hera up`` with mutual TLS and access
control on loopback (``hera certs``, ``--cert``; the default user/password authentication
is checked in tests/unit/test_security.py); afterwards the logging node's CSV
logs hold every legitimate sample and none of the forged ones, every node is still up, and
every refusal is counted in the status with its reason.
"""

from __future__ import annotations

import csv
import json
import subprocess
import sys
import time
from pathlib import Path

import msgpack
import pytest
import zenoh
from harness import Cluster, cluster_env, wait_for

SPEC = """
[cluster]
name = "sec"
[supervisor]
intensity = 50
period = 10
[logging]
node = "n1"
[security]
tls = true
certs = "certs"
max_names_per_node = 32
max_open_logs = 8
{nodes}
[[measures]]
on = "*"
use = "counter"
name = "obs{{i}}"
count = 4
period = 0.1
"""
NODES = [f"n{i}" for i in range(1, 6)]


CERTS: Path = Path()


def foreign(endpoint: str, who: str | None = None, folder: Path | None = None) -> zenoh.Session:
    """A plain Zenoh client of one node, with ``who``'s certificate (raises when the node
    refuses the link)."""
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"client"')
    cfg.insert_json5("connect/endpoints", json.dumps([endpoint]))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    if who is not None:
        d = folder or CERTS
        tls = {
            "root_ca_certificate": f"{d}/ca.pem",
            "enable_mtls": True,
            "connect_private_key": f"{d}/{who}.key",
            "connect_certificate": f"{d}/{who}.pem",
        }
        cfg.insert_json5("transport/link/tls", json.dumps(tls))
    return zenoh.open(cfg)


def sample(seq: int, value: float = 1.0, **extra) -> bytes:
    """A valid sample (README "Wire format")."""
    return msgpack.packb({"v": 1, "seq": seq, "t": time.time(), "val": [value], **extra})


def rows(run: Path, name: str, node: str) -> list[int]:
    path = run / "measures" / f"{name}_{node}.csv"
    return [int(r[0]) for r in csv.reader(path.open()) if r] if path.exists() else []


def ask(s: zenoh.Session, key: str, payload: str = "{}", timeout: float = 1.0) -> list:
    return [r.ok for r in s.get(key, payload=payload, timeout=timeout) if r.ok is not None]


@pytest.fixture(scope="module")
def sec(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("sec")
    spec = tmp / "sec.toml"
    spec.write_text(SPEC.format(nodes="\n".join(f'[[nodes]]\nname = "{n}"' for n in NODES)))
    global CERTS
    CERTS = tmp / "certs"
    made = subprocess.run(
        [sys.executable, "-m", "hera", "certs", str(spec), "--out", str(CERTS)],
        env=cluster_env(tmp),
        capture_output=True,
        text=True,
    )
    assert made.returncode == 0, made.stderr
    c = Cluster(spec, tmp / "run", cluster_env(tmp), None)
    try:
        c.connect(30)
        wait_for(
            lambda: all(st["store"]["entries"] >= 20 for st in c.client.status(0.5).values()),
            15,
            "every store holding the 20 observers",
        )
        yield c
    finally:
        c.stop()


def endpoint(c: Cluster, node: str) -> str:
    """A node's TLS endpoint."""
    return "tls/" + c.client.spec.endpoint(node).split("/", 1)[1]


def test_without_a_certificate_of_the_cluster_nobody_gets_in(sec, tmp_path):
    assert (CERTS / "n2.key").stat().st_mode & 0o777 == 0o600
    with pytest.raises(zenoh.ZError):
        foreign(endpoint(sec, "n1")).close()  # no certificate
    with pytest.raises(zenoh.ZError):
        foreign("tcp/" + endpoint(sec, "n1")[4:]).close()  # plain TCP
    other = tmp_path / "other"
    subprocess.run(
        [
            sys.executable,
            "-m",
            "hera",
            "certs",
            str(CERTS.parent / "sec.toml"),
            "--out",
            str(other),
        ],
        check=True,
        capture_output=True,
    )
    with pytest.raises(zenoh.ZError):  # the right name, another CA
        foreign(endpoint(sec, "n1"), "operator", other).close()


def test_with_a_nodes_identity_it_cannot_act_as_another_or_run_the_cluster(sec):
    c = sec
    pids = {n: c.pid(n) for n in NODES}
    n3_before = rows(c.run_dir, "obs1", "n3")
    s = foreign(endpoint(c, "n1"), "n2")
    try:
        c.reached(s, ["n1"])  # n1 declared its subscribers to this client
        # publish as another node, with a seq that would have frozen it for good
        s.put("hera/sec/data/obs1/n3", sample(10**12, 99.0))
        s.put("hera/sec/data/obs1/n3", sample(2**63 - 1, 99.0))
        # stop a node, crash one past the launcher's start limit, write args by hand
        assert ask(s, "hera/sec/ctl/n5/shutdown") == []
        for _ in range(6):
            assert ask(s, "hera/sec/ctl/n4/inject", json.dumps({"fault": "crash_node"})) == []
        s.put("hera/sec/args/gain", msgpack.packb({"ts": 2**62, "origin": "n1", "value": 9}))
        # pass for a new node
        token = s.liveliness().declare_token("hera/sec/alive/n9")
        # what a node may ask: the read-only status
        assert len(ask(s, "hera/sec/ctl/*/status")) == 5
        time.sleep(1.0)
        token.undeclare()
    finally:
        s.close()
    assert {n: c.pid(n) for n in NODES} == pids, "no node was stopped or crashed"
    assert all(v["restarts"] == 0 for v in c.launcher_state().values())
    for n in NODES:
        st = c.status(n)
        assert "n9" not in st["peers"]
        assert st["args_rejected"] == {}
        assert c.control(n, "args", {})["args"] == {}
        assert all(s["seq"] < 10**6 for s in c.control(n, "store", {"name": "obs1"})["samples"])
    wait_for(lambda: len(rows(c.run_dir, "obs1", "n3")) > len(n3_before) + 10, 5, "n3 logs")
    assert max(rows(c.run_dir, "obs1", "n3")) < 10**6


def test_what_a_node_may_write_of_its_own_is_bounded_refused_and_counted(sec):
    c = sec
    before = {n: c.status(n) for n in NODES}
    s = foreign(endpoint(c, "n1"), "n2")
    try:
        c.reached(s, ["n1"])  # n1 declared its subscribers to this client
        # its own key, a huge seq of another incarnation: the real samples go on
        s.put("hera/sec/data/obs1/n2", sample(10**12, 99.0, inc=12345))
        # its own args, from the far future
        s.put("hera/sec/args/calib/n2/x", msgpack.packb({"ts": 2**62, "origin": "n2", "value": 1}))
        block = zenoh.CongestionControl.BLOCK  # a burst: not dropped on a full queue
        for i in range(100):  # many names of its own: the store takes 32 per node
            s.put(f"hera/sec/data/flood{i}/n2", sample(1), congestion_control=block)
        s.put("hera/sec/data/" + "x" * 3000 + "/n2", sample(1), congestion_control=block)
        s.put("hera/sec/data/ob s/n2", sample(1), congestion_control=block)
        s.put("hera/sec/data/\u00f1ode/n2", sample(1), congestion_control=block)
        # n1, the node it linked to, refuses and counts each write; the others never see
        # them: n1 forwarding another node's key is refused by their access control (a node
        # may put its own keys only; README "Threat model")
        wait_for(
            lambda: c.status("n1")["args_rejected"].get("future", 0) >= 1,
            5,
            "n1 refusing the far-future args write",
        )
        wait_for(
            lambda: c.status("n1")["rejected"].get("too_many_names", 0) >= 60,
            5,
            "n1 refusing the names past its 32 per node",
        )
    finally:
        s.close()
    rej = c.status("n1")["rejected"]
    assert rej.get("bad_key", 0) - before["n1"]["rejected"].get("bad_key", 0) >= 3
    assert rej.get("too_many_names", 0) >= 60  # the logging node n1 mirrors every name
    for n in NODES:
        st = c.status(n)
        assert st["store"]["entries"] <= 5 * 32
        assert c.control(n, "args", {})["args"] == {}
    n1 = c.status("n1")
    assert n1["log_files_open"] <= 8
    logged = {p.name for p in (c.run_dir / "measures").glob("*.csv")}
    assert logged == {f"obs{i}_{n}.csv" for i in range(1, 5) for n in NODES}
    # the real obs1 of n2 goes on being stored and logged after the forged sample
    t = time.time()
    wait_for(
        lambda: any(
            s["node"] == "n2" and s["seq"] < 10**6 and s["t"] > t
            for s in c.control("n3", "store", {"name": "obs1"})["samples"]
        ),
        5,
        "n2's real obs1 stored again",
    )


def test_a_foreign_sample_of_a_stranger_is_not_counted(sec):
    c = sec
    s = foreign(endpoint(c, "n1"), "operator")
    try:
        c.reached(s, ["n1"])  # n1 declared its subscribers to this client
        for seq in range(1, 20):
            s.put(
                "hera/sec/data/obs9/stranger",
                sample(seq),
                congestion_control=zenoh.CongestionControl.BLOCK,
            )
        wait_for(  # before the session closes: closing may drop a burst's tail
            lambda: c.status("n1")["rejected"].get("unknown_node", 0) >= 19,
            5,
            "n1 refusing every sample of the stranger",
        )
    finally:
        s.close()
    for n in NODES:
        assert "stranger" not in {s["node"] for s in c.control(n, "store", {})["samples"]}
        counts = [s["values"][0] for s in c.control(n, "store", {"name": "obs1"})["samples"]]
        assert counts and max(counts) <= 20


def test_a_restarted_node_adopts_no_forged_seq_and_a_wedged_source_shows(sec):
    c = sec
    s = foreign(endpoint(c, "n1"), "operator")
    try:
        c.reached(s, ["n1"])  # n1 declared its subscribers to this client
        # the operator (trusted) answers seq queries about n3 with seqs at the end of the
        # range, of another incarnation and of n3's own, then n3 restarts
        inc = c.status("n3")["incarnation"]

        def lie(q):
            with q:
                forged = {"obs1": [777, 2**63 - 1], "obs2": [inc, 2**63 - 1]}
                q.reply("hera/sec/seq/all/n3", msgpack.packb(forged))

        liar = s.declare_queryable("hera/sec/seq/*/n3", lie, complete=True)
        old = c.pid("n3")
        seq_before = c.status("n3")["measures"]["obs1"]["seq"]
        c.control("n3", "inject", {"fault": "crash_node"})
        wait_for(lambda: c.restarted("n3", old), 15, "n3 back")
        liar.undeclare()
        st = wait_for(
            lambda: (x := c.status("n3"))["measures"]["obs1"]["published"] > 5 and x, 10, "n3"
        )
        assert seq_before < st["measures"]["obs1"]["seq"] < 10**6  # continued, not forged
        assert st["measures"]["obs2"]["seq"] < 10**6
        assert st["rejected"].get("foreign_seq", 0) >= 2
        # a trusted identity that forges a node's *current* incarnation wedges that source
        # until the node restarts: the status says so (README "Threat model")
        inc = c.status("n4")["incarnation"]
        s.put("hera/sec/data/obs2/n4", sample(10**12, 99.0, inc=inc))
        wait_for(
            lambda: "obs2/n4" in c.status("n1")["refused_sources"], 5, "the wedged source shown"
        )
    finally:
        s.close()
    c.control("n4", "inject", {"fault": "crash_node"})  # the cure: a new incarnation
    t = time.time()
    wait_for(
        lambda: any(
            s["node"] == "n4" and s["t"] > t and s["seq"] < 10**6
            for s in c.control("n2", "store", {"name": "obs2"})["samples"]
        ),
        15,
        "n4's obs2 accepted after its restart",
    )


def test_no_legitimate_sample_was_lost(sec):
    """Runs last (pytest keeps file order): every declared CSV is gap-free and holds no
    forged seq; but n2's obs1, where n2's own identity wrote one sample of its own (logged,
    it is n2's), and n4's obs2, which a trusted identity wedged on purpose above."""
    c = sec
    time.sleep(0.5)
    for i in range(1, 5):
        for n in NODES:
            if (i, n) == (2, "n4"):
                continue
            seqs = rows(c.run_dir, f"obs{i}", n)
            if (i, n) == (1, "n2"):
                assert seqs.count(10**12) == 1
                seqs = [x for x in seqs if x != 10**12]
            assert len(seqs) > 20, (i, n)
            assert max(seqs) < 10**6, (i, n, "a forged seq was logged")
            gaps = [(a, b) for a, b in zip(seqs, seqs[1:], strict=False) if b != a + 1]
            assert gaps == [], (f"obs{i}_{n}", gaps[:5])
