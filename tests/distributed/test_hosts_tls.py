"""Mutual TLS across hosts (network namespaces), and a hostile host on the same network.

h1 runs ``hera up --only r1,a1`` with the operator's credentials; h2 runs its router and
node by hand (``hera router``, ``hera node``) holding only their own certificates; h3 is
another host of the network. From h3, a plain ``zenoh`` + ``msgpack`` client (the README's
wire format alone) cannot join without a certificate of the cluster's CA, nor over plain
TCP; holding a2's certificate it can neither publish as a1, nor stop or crash a node, nor
write args; the operator's certificate runs the cluster from there. a1's CSV logs keep
every legitimate sample of both nodes.
"""

from __future__ import annotations

import csv
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from harness import cluster_env, wait_for
from netns import Hosts, available

WHY_NOT = available()
pytestmark = pytest.mark.skipif(WHY_NOT is not None, reason=f"not run: {WHY_NOT}")

ATTACK = r"""
import json, sys, time
import msgpack, zenoh
endpoint, certs, ident = sys.argv[1], sys.argv[2], sys.argv[3]

def open_(ep, who=None, folder=None):
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"client"')
    cfg.insert_json5("connect/endpoints", json.dumps([ep]))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    if who:
        cfg.insert_json5("transport/link/tls", json.dumps({
            "root_ca_certificate": f"{folder}/ca.pem", "enable_mtls": True,
            "connect_private_key": f"{folder}/{who}.key",
            "connect_certificate": f"{folder}/{who}.pem"}))
    return zenoh.open(cfg)

out = {}
for label, ep, who, folder in (
    ("no_cert", endpoint, None, None),
    ("plain_tcp", "tcp/" + endpoint[4:], None, None),
    ("other_ca", endpoint, ident, certs + "/../other"),
):
    try:
        open_(ep, who, folder).close()
        out[label] = "joined"
    except Exception:
        out[label] = "refused"
s = open_(endpoint, ident, certs)
time.sleep(0.5)
sample = lambda seq: msgpack.packb({"v": 1, "seq": seq, "t": time.time(), "val": [99.0]})
s.put("hera/tlsx/data/obs1/a1", sample(10**12))
s.put("hera/tlsx/args/gain", msgpack.packb({"ts": 2**62, "origin": "a1", "value": 9}))
ask = lambda key, p="{}": [r for r in s.get(key, payload=p, timeout=1.0) if r.ok is not None]
out["shutdown_replies"] = len(ask("hera/tlsx/ctl/a1/shutdown"))
out["crash_replies"] = len(ask("hera/tlsx/ctl/a1/inject", json.dumps({"fault": "crash_node"})))
out["status_replies"] = len(ask("hera/tlsx/ctl/*/status"))
s.close()
print(json.dumps(out))
"""


def spec_text(hosts: Hosts) -> str:
    a1, a2 = hosts.addr(1), hosts.addr(2)
    return f"""
[cluster]
name = "tlsx"
base_port = 7400
[security]
tls = true
[logging]
node = "a1"
[[routers]]
name = "r1"
host = "{a1}"
port = 7490
[[routers]]
name = "r2"
host = "{a2}"
port = 7490
[[nodes]]
name = "a1"
host = "{a1}"
[[nodes]]
name = "a2"
host = "{a2}"
[[measures]]
on = "*"
use = "counter"
name = "obs{{i}}"
count = 2
period = 0.1
"""


def rows(run: Path, name: str, node: str) -> list[int]:
    path = run / "measures" / f"{name}_{node}.csv"
    return [int(r[0]) for r in csv.reader(path.open()) if r] if path.exists() else []


@pytest.fixture
def hosts():
    h = Hosts([[1, 2, 3]])
    try:
        yield h
    finally:
        h.close()


def test_mutual_tls_across_hosts_keeps_a_hostile_host_out(hosts, tmp_path):
    spec = tmp_path / "tlsx.toml"
    spec.write_text(spec_text(hosts))
    env = cluster_env(tmp_path)
    full = tmp_path / "certs"
    made = hosts.hera(1, ["certs", str(spec), "--out", str(full)], env)
    assert made.returncode == 0, made.stderr
    h2 = tmp_path / "h2"  # what h2 gets: the CA certificate and its own identities
    h2.mkdir(mode=0o700)
    for f in ("ca.pem", "r2.pem", "r2.key", "a2.pem", "a2.key"):
        shutil.copy2(full / f, h2 / f)
    subprocess.run(  # another CA's certificate for a2, for the attacker
        [sys.executable, "-c", NODE_CERTS, str(tmp_path / "other")], check=True, env=env
    )
    run1 = tmp_path / "run_h1"
    up = hosts.run(
        1,
        ["up", str(spec), "--only", "r1,a1", "--run-dir", str(run1), "--cert", str(full)],
        tmp_path / "up_h1.log",
        env,
    )
    hosts.run(2, ["router", str(spec), "--name", "r2", "--cert", str(h2)], tmp_path / "r2.log", env)
    hosts.run(
        2,
        ["node", str(spec), "--node", "a2", "--cert", str(h2), "--run-dir", str(tmp_path / "a2")],
        tmp_path / "a2.log",
        env,
    )
    r1 = f"tls/{hosts.addr(1)}:7490"
    op = ["--connect", r1, "--cert", str(full)]

    def status_from_h3():
        out = hosts.hera(3, ["status", *op, "--json"], env)
        return json.loads(out.stdout)["nodes"] if out.returncode == 0 else None

    wait_for(lambda: len(status_from_h3() or {}) == 2, 60, "both nodes answering h3's tool")
    wait_for(lambda: len(rows(run1, "obs1", "a2")) > 20, 30, "a2's samples logged on h1")
    pid_a1 = status_from_h3()["a1"]["pid"]

    attack = subprocess.run(
        ["ip", "netns", "exec", hosts.ns(3), sys.executable, "-c", ATTACK, r1, str(h2), "a2"],
        capture_output=True,
        text=True,
        env=env,
        timeout=60,
    )
    assert attack.returncode == 0, attack.stderr
    got = json.loads(attack.stdout.strip().splitlines()[-1])
    assert got == {
        "no_cert": "refused",
        "plain_tcp": "refused",
        "other_ca": "refused",
        "shutdown_replies": 0,
        "crash_replies": 0,
        "status_replies": 2,
    }
    time.sleep(1.0)
    nodes = status_from_h3()
    assert nodes["a1"]["pid"] == pid_a1
    assert all(st["args"] == 0 for st in nodes.values())
    # the operator's certificate runs the cluster from h3: stop it
    down = hosts.hera(3, ["down", *op], env)
    assert down.returncode == 0, down.stdout + down.stderr
    assert up.wait(30) == 0
    for name, node in (("obs1", "a1"), ("obs1", "a2"), ("obs2", "a2")):
        seqs = rows(run1, name, node)
        assert len(seqs) > 20 and max(seqs) < 10**6, (name, node)
        assert all(b == a + 1 for a, b in zip(seqs, seqs[1:], strict=False)), (name, node)


NODE_CERTS = """
import sys
from hera.security.certs import make_certs
make_certs(sys.argv[1], "tlsx", {"a2": []})
"""
