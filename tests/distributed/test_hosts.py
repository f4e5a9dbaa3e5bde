"""The train across four hosts (network namespaces): routers, gossip, a client behind a
gateway, the sync leader on another host than the sonars, a host cut off and back, and the
cluster operated and stopped from a host that reaches only one router.

Hosts: h1 (computer, nav_1, spare; router r1, on both networks), h2 (sonar_1; r2), h3
(sonar_2; r3) on network 0; h4 (watcher, a client of r1) on network 1 with h1 only. Each
host runs its own ``hera up --only <its nodes and routers>``, as real hosts would.
"""

from __future__ import annotations

import csv
import os
import time
from pathlib import Path

import pytest
from harness import cluster_env, wait_for
from netns import Hosts, available

WHY_NOT = available()
pytestmark = pytest.mark.skipif(WHY_NOT is not None, reason=f"not run: {WHY_NOT}")

LOCAL = {
    1: ["r1", "computer", "nav_1", "spare"],
    2: ["r2", "sonar_1"],
    3: ["r3", "sonar_2"],
    4: ["watcher"],
}


def spec_text(hosts: Hosts, tmp: Path) -> str:
    a = {h: hosts.addr(h, 0) for h in (1, 2, 3)}
    gate = hosts.addr(1, 1)  # h1 on network 1: the only address h4 reaches
    return f"""
[cluster]
name = "hosts"
base_port = 7400
lease_ms = 2000

[world]
scenario = "train"
radius = 0.6
omega = 0.84
epoch = {time.time():.3f}   # one simulated world for every host

[world.sonars.sonar_1]
position = [-0.3, -1.5, 0.0]
direction = [0.0, 1.0, 0.0]

[world.sonars.sonar_2]
position = [0.3, -1.5, 0.0]
direction = [0.0, 1.0, 0.0]

[logging]
node = "computer"

[[routers]]
name = "r1"
host = "{a[1]}"
listen = ["tcp/{a[1]}:7490", "tcp/{gate}:7490"]
[[routers]]
name = "r2"
host = "{a[2]}"
port = 7490
connect = ["tcp/{a[1]}:7490", "tcp/{a[3]}:7490"]
[[routers]]
name = "r3"
host = "{a[3]}"
port = 7490
connect = ["tcp/{a[1]}:7490", "tcp/{a[2]}:7490"]

[[nodes]]
name = "computer"
host = "{a[1]}"
sync_hosts = ["sonar"]
  [[nodes.measures]]
  use = "track_gyro"
  period = 0.05
  [nodes.measures.args]
  mode = "arrival"
  [nodes.measures.args.model]
  radius = 0.6
  target_length = 0.5
  target_radius = 0.05
  beams = {{ sonar_1 = [0.0, 1.0], sonar_2 = [0.0, 1.0] }}

[[nodes]]
name = "nav_1"
host = "{a[1]}"
sync_hosts = ["sonar"]
  [[nodes.measures]]
  use = "nav"
  period = 0.02

[[nodes]]
name = "spare"
host = "{a[1]}"
sync_hosts = ["sonar"]

[[nodes]]
name = "sonar_1"
host = "{a[2]}"
  [[nodes.measures]]
  use = "sonar"
  period = 0.13
  args = {{ fire_log = "{tmp / "fire_sonar_1.log"}" }}

[[nodes]]
name = "sonar_2"
host = "{a[3]}"
  [[nodes.measures]]
  use = "sonar"
  period = 0.13
  args = {{ fire_log = "{tmp / "fire_sonar_2.log"}" }}

[[nodes]]
name = "watcher"
host = "{hosts.addr(4, 1)}"
mode = "client"
connect = ["tcp/{gate}:7490"]
  [[nodes.measures]]
  use = "omega_acc"
  args = {{ mode = "arrival", model = {{ radius = 0.6 }} }}
"""


def firings(tmp: Path) -> list[tuple[float, float, str]]:
    out = []
    for f in tmp.glob("fire_*.log"):
        for line in f.read_text().splitlines():
            start, end, node = line.split()
            out.append((float(start), float(end), node))
    return sorted(out)


def overlaps(fired: list[tuple[float, float, str]]) -> list[tuple]:
    return [(a, b) for a, b in zip(fired, fired[1:], strict=False) if b[0] < a[1] and a[2] != b[2]]


def samples(run: Path, name: str, node: str) -> list[float]:
    path = run / "measures" / f"{name}_{node}.csv"
    if not path.exists():
        return []
    return [float(row[1]) / 1000.0 for row in csv.reader(path.open()) if row]


@pytest.fixture
def hosts():
    h = Hosts([[1, 2, 3], [1, 4]])
    try:
        yield h
    finally:
        h.close()


def test_the_train_across_hosts_survives_a_cut_off_host(hosts, tmp_path):
    spec = tmp_path / "hosts.toml"
    spec.write_text(spec_text(hosts, tmp_path))
    env = cluster_env(tmp_path)
    certs = str(tmp_path / "certs")  # the hosts share one cluster secret (README)
    assert hosts.hera(1, ["certs", str(spec), "--out", certs], env).returncode == 0
    ups = {}
    for h, names in LOCAL.items():
        run = tmp_path / f"run_h{h}"
        args = ["up", str(spec), "--only", ",".join(names), "--run-dir", str(run), "--cert", certs]
        ups[h] = hosts.run(h, [*args, "--interval", "5"], tmp_path / f"up_h{h}.log", env)
    computer = tmp_path / "run_h1"

    # from h4, which reaches only r1's second address: the whole cluster answers
    def status_from_h4():
        out = hosts.hera(
            4,
            ["status", "--connect", f"tcp/{hosts.addr(1, 1)}:7490", "--json", "--cert", certs],
            env,
        )
        if out.returncode != 0:
            return None
        import json

        nodes = json.loads(out.stdout)["nodes"]
        return nodes if len(nodes) == 6 else None

    wait_for(status_from_h4, 60, "six nodes answering a tool on h4")

    def leader():
        nodes = status_from_h4() or {}
        return (
            nodes.get("computer", {})
            .get("sync", {})
            .get("groups", {})
            .get("sonar", {})
            .get("leader")
        )

    assert wait_for(leader, 20, "a sync leader") in ("computer", "nav_1", "spare")

    for name, node, n in (
        ("sonar", "sonar_1", 20),  # from h2 through r2 and r1
        ("sonar", "sonar_2", 20),  # from h3 through r3 and r1
        ("omega_acc", "watcher", 20),  # from h4 (a client of r1), which read nav from h1
        ("track_gyro", "computer", 50),
    ):
        what = f"{name} of {node} on h1"
        wait_for(lambda a=(name, node, n): len(samples(computer, *a[:2])) > a[2], 60, what)

    # h3 is cut off (a pulled cable) for 5 s, then comes back
    m_cut = time.monotonic()
    hosts.cut(3)
    time.sleep(5.0)
    hosts.heal(3)
    t_heal, m_heal = time.time(), time.monotonic()
    wait_for(
        lambda: any(t > t_heal for t in samples(computer, "sonar", "sonar_2")),
        20,
        "sonar_2 heard on h1 again after the cut",
    )
    back = min(t for t in samples(computer, "sonar", "sonar_2") if t > t_heal)
    assert back - t_heal < 10.0
    # the fire logs are on the (shared) monotonic clock: sonar_1, on the majority side, may
    # pause while the routers notice that h3 is gone (its links' lease, 2 s), no longer
    s1 = [f[0] for f in firings(tmp_path) if f[2] == "sonar_1"]
    around = [b - a for a, b in zip(s1, s1[1:], strict=False) if b > m_cut and a < m_heal]
    assert max(around) < 5.0, f"sonar_1 stopped for {max(around):.2f} s around the cut"

    # the sync leader (on h1) is SIGKILLed: its launcher restarts it, slots flow again
    leader_node = leader()
    pid = status_from_h4()[leader_node]["pid"]
    m_kill = time.monotonic()
    os.kill(pid, 9)  # the namespaces share the process table
    wait_for(
        lambda: (
            any(f[0] > m_kill + 0.5 for f in firings(tmp_path) if f[2] == "sonar_1")
            and any(f[0] > m_kill + 0.5 for f in firings(tmp_path) if f[2] == "sonar_2")
        ),
        20,
        "both sonars firing after the leader was killed",
    )

    # stop everything from h4: every host's launcher ends, nothing is left running
    down = hosts.hera(
        4, ["down", "--connect", f"tcp/{hosts.addr(1, 1)}:7490", "--cert", certs], env
    )
    assert down.returncode == 0, down.stdout + down.stderr
    assert "4 launchers stopping" in down.stdout
    for h, proc in ups.items():
        assert proc.wait(30) == 0, (h, (tmp_path / f"up_h{h}.log").read_text()[-2000:])

    fired = firings(tmp_path)
    assert len(fired) > 100
    assert overlaps(fired) == [], "two sonars sounded at once"
    assert os.path.getsize(computer / "cluster.json") > 0
