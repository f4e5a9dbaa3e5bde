"""Network faults with nftables: nodes in network namespaces of their own, their links cut,
reset and made lossy by rules in those namespaces (``hera campaign --links netns``).

The rules are tested on real namespaces with plain sockets (what each rule does to TCP and
UDP between two nodes, and to nobody else), then (``-m slow``) a short partitions campaign
runs the train with every node in its namespace. Where namespaces or nftables are not available
(not root, no ``nft``), the tests are reported as not run, never as passed.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Iterator

import pytest
from campaign_runs import assert_complete_report, assert_passed, run_campaign

from hera.campaign.manual import _network
from hera.campaign.netns import Namespaces, problem, rule_statements, sweep
from hera.campaign.runner import CampaignRun
from hera.campaign.schema import CampaignError

WHY_NOT = problem()
pytestmark = pytest.mark.skipif(WHY_NOT is not None, reason=f"not run: {WHY_NOT}")

SERVER = """
import socket, sys, threading
t = socket.socket(); t.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
t.bind(("0.0.0.0", 7000)); t.listen()
u = socket.socket(socket.AF_INET, socket.SOCK_DGRAM); u.bind(("0.0.0.0", 7001))
def udp():
    n = 0
    while True:
        data, peer = u.recvfrom(64)
        if data == b"count":
            u.sendto(str(n).encode(), peer); n = 0
        else:
            n += 1
threading.Thread(target=udp, daemon=True).start()
print("ready", flush=True)
while True:
    c, _ = t.accept(); c.sendall(b"hi"); c.close()
"""

DIAL = """
import socket, sys
try:
    s = socket.create_connection((sys.argv[1], 7000), timeout=1.0)
    print(s.recv(8).decode())
except OSError as e:
    print(type(e).__name__)
"""

SEND = """
import socket, sys, time
u = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
for i in range(int(sys.argv[2])):
    u.sendto(b"x", (sys.argv[1], 7001))
    if i % 50 == 49:
        time.sleep(0.005)
"""


def _py(ns: Namespaces | None, node: str | None, code: str, *args: str) -> str:
    """Run ``code`` in ``node``'s namespace (the root namespace when None); its stdout."""
    where = [] if node is None else ["ip", "netns", "exec", ns.nodes[node]["netns"]]
    out = subprocess.run(
        [*where, sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=20
    )
    return out.stdout.strip()


@pytest.fixture
def hosts() -> Iterator[tuple[Namespaces, subprocess.Popen]]:
    """Nodes a, b, c in namespaces; a TCP greeter and a UDP counter on b."""
    ns = Namespaces(Namespaces.new_plan(["a", "b", "c"], seed=11))
    ns.create()
    server = None
    try:
        server = subprocess.Popen(
            ["ip", "netns", "exec", ns.nodes["b"]["netns"], sys.executable, "-c", SERVER],
            stdout=subprocess.PIPE,
            text=True,
        )
        assert server.stdout.readline().strip() == "ready"
        yield ns, server
    finally:
        if server is not None:
            server.kill()
            server.wait()
        ns.close()


def _dial(ns: Namespaces, frm: str | None) -> str:
    return _py(ns, frm, DIAL, ns.addr("b"))


def _udp_received(ns: Namespaces, frm: str, n: int) -> int:
    _py(ns, frm, SEND, ns.addr("b"), str(n))
    code = (
        "import socket, sys\n"
        "u = socket.socket(socket.AF_INET, socket.SOCK_DGRAM); u.settimeout(2)\n"
        "u.sendto(b'count', (sys.argv[1], 7001)); print(u.recv(32).decode())"
    )
    return int(_py(ns, None, code, ns.addr("b")))  # asked from the root: never dropped


def test_rules_cut_reset_and_heal_one_pair_only(hosts):
    ns, _ = hosts
    assert {_dial(ns, x) for x in ("a", "c", None)} == {"hi"}
    ns.command({"op": "set", "pairs": [["a", "b"]], "mode": "blackhole"})
    assert _dial(ns, "a") == "TimeoutError"  # the SYN goes nowhere: a cut cable
    assert _dial(ns, "c") == "hi" and _dial(ns, None) == "hi"  # nobody else, tools neither
    again = Namespaces(json.loads(json.dumps(ns.plan)))  # stateless: from the plan
    again.command({"op": "set", "pairs": [["b", "a"]], "mode": "reset"})  # replaces the cut
    assert _dial(ns, "a") == "ConnectionRefusedError"  # answered by a reset
    counted = {tuple(p["pair"]): p["dropped_packets"] for p in ns.status()}
    assert counted[("a", "b")] >= 1 and counted[("a", "c")] == counted[("b", "c")] == 0
    ns.command({"op": "clear"})
    assert _dial(ns, "a") == "hi"


def test_loss_drops_that_share_of_packets_each_way_once(hosts):
    ns, _ = hosts
    assert _udp_received(ns, "a", 1000) == 1000
    ns.command({"op": "set", "pairs": [["a", "b"]], "loss": 0.3})
    got = _udp_received(ns, "a", 2000)
    assert 1230 <= got <= 1570, got  # 70 % of 2000 +/- 8 sigma (binomial sigma 20.5)
    assert _udp_received(ns, "c", 1000) == 1000  # another pair: untouched
    ns.command({"op": "clear", "pairs": [["a", "b"]]})
    assert _udp_received(ns, "a", 1000) == 1000


def test_bad_rules_are_refused_with_a_sentence(hosts):
    ns, _ = hosts
    with pytest.raises(ValueError, match="delay and jitter need the link proxy"):
        ns.command({"op": "set", "pairs": [["a", "b"]], "delay_ms": 50})
    with pytest.raises(ValueError, match="no node 'z' in the namespaces; nodes: a, b, c"):
        ns.command({"op": "set", "pairs": [["a", "z"]], "mode": "blackhole"})
    with pytest.raises(ValueError, match="loss must be a share within"):
        ns.command({"op": "set", "pairs": [["a", "b"]], "loss": 1.5})
    with pytest.raises(ValueError, match="link mode must be pass, blackhole or reset"):
        rule_statements("cut", 0.0)


def test_hera_inject_sets_rules_from_the_plan_file(hosts, tmp_path):
    """``hera inject a partition`` on a campaign whose nodes run in namespaces: the rule
    comes from links.json alone (no process of the campaign is asked)."""
    ns, _ = hosts
    (tmp_path / "links.json").write_text(json.dumps(ns.plan))
    _network(tmp_path, ["a", "b", "c"], "a", "partition", None, None, 0.0)
    assert _dial(ns, "a") == "TimeoutError" and _dial(ns, "c") == "hi"
    _network(tmp_path, ["a", "b", "c"], "*", "heal", None, None, 0.0)
    assert _dial(ns, "a") == "hi"


def test_namespaces_bridge_and_links_are_gone_after_close_and_the_names_free_at_once():
    for _ in range(5):  # the same plan made again right away: no name is still taken
        ns = Namespaces(Namespaces.new_plan(["a", "b", "c"], seed=12))
        ns.create()
        names = [n["netns"] for n in ns.nodes.values()]
        listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
        assert all(n in listed for n in names)
        ns.close()
        listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
        assert not any(n in listed for n in names)
        links = subprocess.run(["ip", "-o", "link", "show"], capture_output=True, text=True)
        assert ns.plan["veth"] not in links.stdout and ns.plan["bridge"] not in links.stdout


def test_what_a_dead_campaign_left_is_swept_and_a_live_ones_is_not():
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()  # a process id that is gone
    left = Namespaces.new_plan(["a", "b"], seed=13)
    for n in left["nodes"].values():
        n["netns"] = n["netns"].replace(f"-c{os.getpid()}-", f"-c{dead.pid}-")
    orphan, live = Namespaces(left), Namespaces(Namespaces.new_plan(["a"], seed=14))
    orphan.create()
    try:
        live.create()  # sweeps first: the orphan's namespaces and bridge go
        listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
        assert not any(n["netns"] in listed for n in left["nodes"].values())
        assert live.nodes["a"]["netns"] in listed
        bridge = subprocess.run(["ip", "link", "show", left["bridge"]], capture_output=True)
        assert bridge.returncode != 0
        assert sweep() == []  # this process is alive: its namespaces stay
        assert (
            live.nodes["a"]["netns"]
            in subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
        )
    finally:
        live.close()
        orphan.close()


def test_a_delay_fault_is_refused_in_namespaces(tmp_path):
    camp = tmp_path / "slow.toml"
    camp.write_text(
        '[campaign]\nname = "slow"\nbaseline_s = 1\ntail_s = 1\n\n[[faults]]\nname = "slow s1"\n'
        'kind = "delay"\ntarget = "sonar_1"\ndelay_ms = 20\nduration_s = 1\n'
    )
    with pytest.raises(CampaignError) as e:
        CampaignRun("train", str(camp), str(tmp_path / "c"), links="netns")
    assert "slow s1: delay faults need the link proxy" in str(e.value)
    run = CampaignRun("train", str(camp), str(tmp_path / "d"), links="auto")
    assert run.links == "proxy"  # auto: the proxy does delays


@pytest.mark.slow  # CI budget: CI runs the short thesis-ch5 campaign and these rules
def test_partitions_short_with_every_node_in_its_namespace(tmp_path):
    """The short partitions campaign on the train, nftables cutting the links: every
    checker passes, the nodes ran at their namespaces' addresses, and the namespaces are
    gone afterwards."""
    code, folder, out = run_campaign(
        tmp_path, "train", "partitions", "--short", "--links", "netns", "--seed", "1"
    )
    v = assert_passed(code, folder, out)
    assert {r["side"] for r in v["sync_partitions"].rows} == {"majority", "minority"}
    plan = json.loads((folder / "links.json").read_text())
    assert plan["backend"] == "netns" and not (folder / "linkproxy.log").exists()
    spec = json.loads((folder / "run" / "cluster.json").read_text())["resolved_spec"]
    assert {n["name"]: n["host"] for n in spec["nodes"]} == {
        name: n["addr"] for name, n in plan["nodes"].items()
    }
    assert json.loads((folder / "campaign.json").read_text())["links"] == "netns"
    listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    assert not any(n["netns"] in listed for n in plan["nodes"].values())
    assert_complete_report(folder)
