"""Distributed behaviour of the node runtime: real node processes, real Zenoh on 127.0.0.1."""

from __future__ import annotations

import os
import signal
import subprocess
import sys

import msgpack
import pytest
import zenoh
from harness import cluster_env, wait_for

from hera.bus import open_session
from hera.wire import encode

FIVE = """
[cluster]
name = "five"
[supervisor]
intensity = 50
period = 10
{nodes}
[[measures]]
on = "*"
use = "counter"
name = "obs{{i}}"
count = 2
period = 0.05
[[measures]]
on = "*"
use = "fixture_measures:Calibrated"
name = "cal"
period = 0.05
args = {{ value = 4.5, calib_log = "{calib_log}" }}
"""


def five_nodes(tmp_path) -> str:
    nodes = "\n".join(f'[[nodes]]\nname = "n{i}"' for i in range(1, 6))
    return FIVE.format(nodes=nodes, calib_log=tmp_path / "calib.log")


def seen_everywhere(c, names=("obs1", "obs2", "cal"), timeout: float = 10.0) -> None:
    """Wait until every node's store holds a sample of every name from every node. A store
    never forgets a (name, node), so a node found full stays so: it is not asked again (on
    a loaded machine one status query seldom gets all five answers within its timeout)."""
    full: set[str] = set()
    seen: dict[str, int] = {}

    def settled() -> bool:
        for node, st in c.client.status(0.5).items():
            seen[node] = st["store"]["entries"]
            if seen[node] >= 5 * len(names):
                full.add(node)
        return len(full) == 5

    try:
        wait_for(settled, timeout, "every store to hold every (name, node)")
    except AssertionError as e:
        raise AssertionError(f"{e}; store entries by node: {seen}") from None


def mapped_numpy(pid: int) -> bool:
    """Whether process ``pid`` has numpy's compiled core loaded (from its memory maps)."""
    with open(f"/proc/{pid}/maps") as f:
        return "_multiarray_umath" in f.read()


def test_the_numpy_check_sees_numpy_where_it_is_loaded():
    import numpy  # noqa: F401 - this process has it; the check must say so

    assert mapped_numpy(os.getpid())


def test_every_store_sees_every_node_and_observers_count_all(cluster, tmp_path):
    c = cluster(five_nodes(tmp_path))
    seen_everywhere(c)
    # a node that runs no filter never loads numpy (issue 21: <= 50 MB RSS); its spec was
    # checked, with every installed application and model, by the launcher
    assert not [n for n in c.client.spec.nodes if mapped_numpy(c.pid(n.name))]
    # the observers themselves report all 10 observers alive, on every node
    with open_session(
        c.operator_bus(connect=tuple(c.client.spec.endpoint(n.name) for n in c.client.spec.nodes))
    ) as s:
        got: dict[tuple[str, str], float] = {}

        def on(sample):
            from hera.wire import decode

            name, node = sample.key_expr.__str__().split("/")[-2:]
            got[(name, node)] = decode(sample.payload.to_bytes()).values[0]

        sub = s.declare_subscriber("hera/five/data/obs1/*", on)
        wait_for(
            lambda: len(got) == 5 and all(v == 10.0 for v in got.values()),
            10,
            "every obs1 reporting 10 alive observers",
        )
        sub.undeclare()


@pytest.mark.parametrize("victim", ["n1", "n4"])
def test_sigkilled_node_restarts_recovers_args_and_continues_seq(cluster, tmp_path, victim):
    c = cluster(five_nodes(tmp_path))
    seen_everywhere(c)
    # calibration happened once per node, and every node holds all five calibrations
    wait_for(lambda: len(c.control("n2", "args", {})["args"]) == 5, 5, "replicated args")
    calib_before = (tmp_path / "calib.log").read_text().splitlines()
    assert sorted(line.split()[0] for line in calib_before) == [f"n{i}" for i in range(1, 6)]

    old_pid = c.pid(victim)
    seq_before = c.status(victim)["measures"]["cal"]["seq"]
    witness = "n2" if victim != "n2" else "n3"
    before = c.status(witness)["measures"]["obs1"]["published"]
    os.kill(old_pid, signal.SIGKILL)

    # the others keep publishing while the victim is down and comes back
    wait_for(
        lambda: c.status(witness)["measures"]["obs1"]["published"] > before + 5,
        5,
        f"{witness} to keep publishing",
    )
    wait_for(lambda: c.launcher_state()[victim]["restarts"] == 1, 10, "the launcher restart")
    wait_for(
        lambda: c.restarted(victim, old_pid),
        10,
        f"{victim} answering again",
    )
    st = c.status(victim)
    # seq continues after the restart: strictly above what it had published before
    assert st["measures"]["cal"]["seq"] > seq_before
    # the restarted node recovered its calibration from peers instead of recalibrating
    assert (tmp_path / "calib.log").read_text().splitlines() == calib_before
    assert len(c.control(victim, "args", {})["args"]) == 5

    # and the peers' stores accept its new samples (seq continued, nothing dropped as stale)
    def witness_has_new_cal():
        samples = c.control(witness, "store", {"name": "cal"})["samples"]
        return any(s["node"] == victim and s["seq"] > seq_before for s in samples)

    wait_for(witness_has_new_cal, 5, "the witness to accept the restarted node's samples")


def test_raising_measure_is_restarted_with_its_original_arguments(cluster, tmp_path):
    init_log = tmp_path / "init.log"
    spec = f"""
[cluster]
name = "crash"
[supervisor]
intensity = 1000
period = 1
[[nodes]]
name = "a"
[[nodes.measures]]
use = "fixture_measures:Crasher"
name = "crasher"
period = 0.01
args = {{ crash_at = 3, init_log = "{init_log}", tag = "original" }}
"""
    c = cluster(spec)
    wait_for(lambda: c.status("a")["measures"]["crasher"]["restarts"] >= 3, 10, "3 restarts")
    inits = init_log.read_text().splitlines()
    assert len(inits) >= 4
    args = {line.split(" ", 1)[1] for line in inits}
    assert args == {
        str(sorted({"crash_at": 3, "init_log": str(init_log), "tag": "original"}.items()))
    }
    st = c.status("a")["measures"]["crasher"]
    assert st["last_error"] == "RuntimeError: planned crash"
    assert st["crashes"] >= 3


@pytest.mark.parametrize("intensity", [2, 4])
def test_crash_loop_escalates_exactly_past_the_intensity(tmp_path, intensity):
    """A node whose supervisor allows N restarts restarts exactly N times, then exits 3."""
    init_log = tmp_path / "init.log"
    spec = tmp_path / "loop.toml"
    spec.write_text(f"""
[cluster]
name = "loop"
base_port = {_free_port()}
[supervisor]
intensity = {intensity}
period = 60
[[nodes]]
name = "a"
[[nodes.measures]]
use = "fixture_measures:Crasher"
name = "crasher"
period = 0.01
args = {{ crash_at = 1, init_log = "{init_log}" }}
""")
    proc = subprocess.run(
        [sys.executable, "-m", "hera", "node", str(spec), "--node", "a"],
        env=cluster_env(tmp_path),
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert proc.returncode == 3, proc.stderr[-2000:]
    assert "restart intensity exceeded" in proc.stderr
    # first start + `intensity` restarts, and not one more
    assert len(init_log.read_text().splitlines()) == intensity + 1


def test_hung_measure_is_replaced(cluster, tmp_path):
    init_log = tmp_path / "init.log"
    c = cluster(f"""
[cluster]
name = "hang"
[[nodes]]
name = "a"
[[nodes.measures]]
use = "fixture_measures:Sleeper"
name = "sleeper"
period = 0.02
hang_factor = 5
hang_min = 0.3
args = {{ hang_at = 5, sleep = 60, init_log = "{init_log}" }}
""")
    wait_for(lambda: c.status("a")["measures"]["sleeper"]["hangs"] >= 1, 10, "a hang report")
    st = c.status("a")["measures"]["sleeper"]
    assert st["state"] == "running" and st["restarts"] >= 1
    assert "hung" in st["last_error"]
    seq = st["seq"]
    wait_for(lambda: c.status("a")["measures"]["sleeper"]["seq"] > seq, 5, "publishing again")


def test_injected_faults_through_the_control_plane(cluster, tmp_path):
    c = cluster(five_nodes(tmp_path).replace('name = "five"', 'name = "inject"'))
    assert c.control("n3", "inject", {"fault": "crash", "measure": "obs1"})["ok"]
    wait_for(lambda: c.status("n3")["measures"]["obs1"]["restarts"] == 1, 5, "crash restart")
    assert c.control("n3", "stop", {"measure": "obs2"})["state"] == "stopped"
    assert c.status("n3")["measures"]["obs2"]["state"] == "stopped"
    assert c.control("n3", "start", {"measure": "obs2"})["state"] == "running"
    bad = c.control("n3", "inject", {"fault": "explode", "measure": "obs1"})
    assert not bad["ok"] and "unknown fault 'explode'" in bad["error"]
    bad = c.control("n3", "stop", {"measure": "nope"})
    assert not bad["ok"] and "no measure 'nope'" in bad["error"]
    old = c.pid("n5")
    assert c.control("n5", "inject", {"fault": "crash_node"})["ok"]
    wait_for(lambda: c.launcher_state()["n5"]["restarts"] == 1, 10, "n5 restarted")
    wait_for(lambda: c.restarted("n5", old), 10, "n5 back")
    assert c.launcher_state()["n5"]["last_exit"] == 70


def _free_port() -> int:
    from hera.ports import free_ports

    return free_ports("127.0.0.1", 1)[0]


BAD_PAYLOADS = {
    "malformed": b"\xc1\xc1not msgpack",
    "truncated": encode(7, 1.0, [1.0, 2.0])[:-3],
    "oversized": b"\x00" * 100_000,
    "wrong_type_list": msgpack.packb([1, 7, 1.0, [1.0]]),
    "wrong_type_values": msgpack.packb({"v": 1, "seq": 7, "t": 1.0, "val": ["a"]}),
    "nan": msgpack.packb({"v": 1, "seq": 7, "t": 1.0, "val": [float("nan")]}),
    "negative_seq": msgpack.packb({"v": 1, "seq": -1, "t": 1.0, "val": [1.0]}),
    "bad_version": msgpack.packb({"v": 99, "seq": 7, "t": 1.0, "val": [1.0]}),
    "missing_fields": msgpack.packb({"v": 1}),
}


def test_bad_payloads_are_rejected_counted_and_harmless(cluster, tmp_path):
    c = cluster(five_nodes(tmp_path).replace('name = "five"', 'name = "bad"'))
    seen_everywhere(c)
    pids = {n.name: c.pid(n.name) for n in c.client.spec.nodes}
    nodes = [n.name for n in c.client.spec.nodes]
    with open_session(c.operator_bus(connect=tuple(c.client.spec.endpoint(n) for n in nodes))) as s:
        c.reached(s, nodes)
        # Zenoh's default for a put is to drop it when the link's queue is full (a burst on
        # a loaded machine): these must all arrive
        block = zenoh.CongestionControl.BLOCK
        for payload in BAD_PAYLOADS.values():
            s.put("hera/bad/data/evil/x", payload, congestion_control=block)
        s.put("hera/bad/data/evil", encode(1, 1.0, [1.0]), congestion_control=block)  # no node
        # a well-formed sample still goes through afterwards
        s.put("hera/bad/data/good/n1", encode(1, 1.0, [42.0]), congestion_control=block)
        counted: dict[str, dict[str, int]] = {}

        def all_counted():
            counted.clear()
            counted.update({n: st["rejected"] for n, st in c.client.status(1.0).items()})
            return len(counted) == 5 and all(
                sum(r.values()) == len(BAD_PAYLOADS) + 1 for r in counted.values()
            )

        try:
            wait_for(all_counted, 10, "every node to count every bad payload")
        except AssertionError as e:
            raise AssertionError(f"{e}; rejected by node: {counted}") from None
    for node, st in c.client.status(0.5).items():
        assert st["pid"] == pids[node]
        assert st["rejected"]["oversized"] == 1
        assert st["rejected"]["bad_key"] == 1
        samples = c.control(node, "store", {"name": "good"})["samples"]
        assert [s["values"] for s in samples] == [[42.0]]
        assert c.control(node, "store", {"name": "evil"})["samples"] == []
        assert all(m["state"] == "running" for m in st["measures"].values())


def test_up_with_duration_exits_zero_and_leaves_nothing(cluster, tmp_path):
    c = cluster(
        five_nodes(tmp_path).replace('name = "five"', 'name = "dur"'), duration=4, connect=False
    )
    wait_for(c._mine, 10, "launcher up")
    pids = wait_for(
        lambda: (
            [n["pid"] for n in c.launcher_state().values() if n["pid"]]
            if len(c.launcher_state()) == 5
            else None
        ),
        10,
        "5 node pids",
    )
    assert c.proc.wait(30) == 0
    # the run's 4 s count from when every node answered, not from the spawn
    said = c.log.read_text()
    up = said.index("all 5 nodes up in ")
    assert said[up:].splitlines()[0].endswith(" s; running 4 s"), said
    assert said.index("stopping") > up
    for pid in pids:
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)
    csvs = sorted(p.name for p in (tmp_path / "run" / "measures").glob("*.csv"))
    assert csvs == []  # this spec asks for no logging


def test_down_from_another_terminal_stops_the_cluster(cluster, tmp_path):
    c = cluster(five_nodes(tmp_path).replace('name = "five"', 'name = "down"'))
    pids = [n["pid"] for n in c.launcher_state().values()]
    env = cluster_env(tmp_path)
    status = subprocess.run(
        [sys.executable, "-m", "hera", "status", "--json"],
        env=env,
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert status.returncode == 0, status.stderr
    import json

    assert sorted(json.loads(status.stdout)["nodes"]) == ["n1", "n2", "n3", "n4", "n5"]
    down = subprocess.run(
        [sys.executable, "-m", "hera", "down"], env=env, capture_output=True, text=True, timeout=30
    )
    assert down.returncode == 0, down.stderr
    assert c.proc.wait(10) == 0
    for pid in pids:
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)
    again = subprocess.run(
        [sys.executable, "-m", "hera", "status"],
        env=env,
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert again.returncode == 2 and "no running cluster" in again.stderr


def test_whole_cluster_restart_keeps_the_args_without_recalibrating(cluster, tmp_path):
    """Args are persisted under each node's state dir: a second run of the whole cluster in
    the same run dir (``--overwrite``: the records go, the state stays) finds every
    calibration and calibrates nothing again."""
    spec = five_nodes(tmp_path).replace('name = "five"', 'name = "again"')
    first = cluster(spec, name="run")
    wait_for(lambda: len(first.control("n1", "args", {})["args"]) == 5, 10, "5 calibrations")
    first.stop()
    assert len((tmp_path / "calib.log").read_text().splitlines()) == 5
    second = cluster(spec, name="run", overwrite=True)  # a new run, the same state dirs
    seen_everywhere(second)
    assert len((tmp_path / "calib.log").read_text().splitlines()) == 5
    assert len(second.control("n3", "args", {})["args"]) == 5


def test_launcher_gives_up_on_a_node_that_keeps_dying(cluster, tmp_path):
    """Like systemd's start limit: at most 5 starts within 10 s, then the node stays failed
    while the rest of the cluster runs on."""
    c = cluster(
        f"""
[cluster]
name = "limit"
[supervisor]
intensity = 0
[[nodes]]
name = "ok"
[[nodes.measures]]
use = "counter"
name = "obs1"
[[nodes]]
name = "bad"
[[nodes.measures]]
use = "fixture_measures:Crasher"
name = "crasher"
args = {{ crash_at = 1, init_log = "{tmp_path / "init.log"}" }}
""",
        connect=False,
    )
    wait_for(c._mine, 10, "launcher up")
    wait_for(lambda: c.launcher_state()["bad"]["state"] == "failed", 20, "the start limit")
    state = c.launcher_state()
    assert state["bad"]["restarts"] == 4 and state["bad"]["last_exit"] == 3
    assert len((tmp_path / "init.log").read_text().splitlines()) == 5
    assert state["ok"]["state"] == "up" and state["ok"]["restarts"] == 0


def test_hera_up_stops_when_every_node_has_failed(tmp_path):
    """With every node past its start limit nothing runs any more: hera up kept showing an
    empty cluster until Ctrl-C (or --duration); it stops, exit 1, with the last line of the
    node's log."""
    spec = tmp_path / "dying.toml"
    spec.write_text(
        '[cluster]\nname = "dying"\n[supervisor]\nintensity = 0\n[[nodes]]\nname = "bad"\n'
        '[[nodes.measures]]\nuse = "fixture_measures:Crasher"\nname = "crasher"\n'
        "args = { crash_at = 1 }\n"
    )
    out = subprocess.run(
        [sys.executable, "-m", "hera", "up", str(spec), "--duration", "600", "--run-dir",
         str(tmp_path / "run")],
        env=cluster_env(tmp_path),
        capture_output=True,
        text=True,
        timeout=120,
    )  # fmt: skip
    assert out.returncode == 1, out.stdout[-2000:] + out.stderr[-2000:]
    said = "node bad: start limit hit (5 starts within 10 s); not restarting it (its log ends: "
    assert said in out.stdout, out.stdout[-2000:]
    assert "stopped: every node failed (node bad's log ends: " in out.stdout, out.stdout[-2000:]


def test_unknown_measure_fails_before_anything_starts(tmp_path):
    spec = tmp_path / "bad.toml"
    spec.write_text(
        '[cluster]\nname = "u"\n[[nodes]]\nname = "a"\n'
        '[[nodes.measures]]\nuse = "no_such_measure"\n'
    )
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "hera",
            "up",
            str(spec),
            "--duration",
            "5",
            "--run-dir",
            str(tmp_path / "run"),
        ],
        env=cluster_env(tmp_path),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2
    assert "unknown measure 'no_such_measure'; known measures:" in out.stderr
    assert "counter" in out.stderr
    assert not (tmp_path / "run" / "launcher.json").exists()


SHARED = """
[cluster]
name = "shared"
[[nodes]]
name = "a"
[[nodes]]
name = "b"
[[measures]]
on = "*"
use = "counter"
name = "obs{i}"
count = 3
period = 0.05
thread = "shared"
hang_factor = 5
hang_min = 0.5
"""


def test_shared_measures_fail_and_recover_alone_on_a_real_node(cluster):
    c = cluster(SHARED)

    def published(node: str) -> dict[str, int]:
        return {m: s["published"] for m, s in c.status(node)["measures"].items()}

    wait_for(lambda: all(v > 5 for v in published("a").values()), 10, "every shared measure")
    # a crash restarts that measure alone; the others of its beat keep publishing
    assert c.control("a", "inject", {"fault": "crash", "measure": "obs1"})["ok"]
    wait_for(lambda: c.status("a")["measures"]["obs1"]["restarts"] == 1, 5, "crash restart")
    before = published("a")
    wait_for(lambda: all(published("a")[m] > before[m] + 5 for m in before), 5, "all stepping")
    # a hang holds up its beat until it is reported, then the others step on a new thread
    assert c.control("a", "inject", {"fault": "hang", "measure": "obs2"})["ok"]
    wait_for(lambda: c.status("a")["measures"]["obs2"]["hangs"] == 1, 10, "a hang report")
    before = published("a")
    wait_for(lambda: all(published("a")[m] > before[m] + 5 for m in before), 5, "all stepping")
    st = c.status("a")["measures"]
    assert st["obs2"]["state"] == "running" and "hung" in st["obs2"]["last_error"]
    assert st["obs3"]["restarts"] == 0 and st["obs3"]["hangs"] == 0
    # stop and start one; the other node never noticed any of it
    assert c.control("a", "stop", {"measure": "obs3"})["state"] == "stopped"
    assert c.control("a", "start", {"measure": "obs3"})["state"] == "running"
    wait_for(lambda: published("a")["obs3"] > before["obs3"] + 5, 5, "obs3 stepping again")
    assert all(s["restarts"] == 0 for s in c.status("b")["measures"].values())


def shm_maps(pid: int) -> list[str]:
    """The Zenoh shared-memory segments process ``pid`` has mapped."""
    with open(f"/proc/{pid}/maps") as f:
        return sorted({line.split()[-1] for line in f if line.rstrip().endswith(".zenoh")})


def test_no_node_maps_a_shared_memory_pool_even_after_large_replies(cluster, tmp_path):
    # a status reply this large is one Zenoh would send through a 16 MB pool in /dev/shm,
    # mapped by the node and by every process that takes it, were shared memory on
    spec = five_nodes(tmp_path).replace('name = "five"', 'name = "shm"')
    c = cluster(spec.replace("count = 2", "count = 14"))  # 15 measures: a large status
    seen_everywhere(c)
    sizes = [len(msgpack.packb(c.status(n.name))) for n in c.client.spec.nodes]
    assert min(sizes) >= 3072, sizes  # Zenoh's threshold for its shared-memory transport
    wait_for(lambda: len(c.control("n2", "args", {})["args"]) == 5, 5, "replicated args")
    assert {n.name: shm_maps(c.pid(n.name)) for n in c.client.spec.nodes} == {
        n.name: [] for n in c.client.spec.nodes
    }
