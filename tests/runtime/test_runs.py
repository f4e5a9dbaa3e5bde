"""Runs never mix, and a cluster that cannot start says why: run directories, the registry
of running clusters, busy ports, nodes that cannot start (real ``hera up`` processes)."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from harness import cluster_env, wait_for
from harness import run_hera as hera

SPEC = """
[cluster]
name = "{name}"
[logging]
node = "a"
[[nodes]]
name = "a"
[[nodes.measures]]
use = "counter"
name = "obs1"
[[nodes]]
name = "b"
"""


def start(tmp_path: Path, *args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "hera", "up", *args, "--interval", "0.5"],
        env=cluster_env(tmp_path),
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


NAV = """
[world]
scenario = "still"
[[nodes.measures]]
use = "nav"
period = 0.05
args = { calib_samples = 20 }
"""


def _calibration(state: Path) -> list:
    import msgpack

    return msgpack.unpackb((state / "args.msgpack").read_bytes())["calib/b/nav"]


def test_each_run_gets_its_own_directory_and_the_latest_is_linked(tmp_path):
    spec = tmp_path / "s.toml"
    spec.write_text(SPEC.format(name="mix") + NAV)
    first = hera(tmp_path, "up", str(spec), "--duration", "2")
    calibrated = _calibration(tmp_path / "hera-run" / "mix.state" / "b")
    second = hera(tmp_path, "up", str(spec), "--duration", "2")
    assert first.returncode == 0 and second.returncode == 0, first.stdout + second.stdout
    runs = sorted(p for p in (tmp_path / "hera-run").iterdir() if p.name.startswith("mix-"))
    assert len(runs) == 2 and all((r / "cluster.json").exists() for r in runs)
    latest = tmp_path / "hera-run" / "mix"
    assert latest.is_symlink() and latest.resolve() == runs[-1].resolve()
    for r in runs:  # each run's log holds its own samples only: seqs never restart inside
        seqs = [int(row.split(",")[0]) for row in (r / "measures" / "obs1_a.csv").open()]
        assert seqs == sorted(seqs) and len(seqs) == len(set(seqs))
    assert f"the run is in hera-run/{runs[-1].name}" in second.stdout
    # the calibration lives beside the runs: the second run used it, it did not redo it
    assert _calibration(tmp_path / "hera-run" / "mix.state" / "b") == calibrated


def test_a_run_directory_holding_a_run_is_refused_unless_overwritten(tmp_path):
    spec = tmp_path / "s.toml"
    spec.write_text(SPEC.format(name="again"))
    run = tmp_path / "run"
    assert hera(tmp_path, "up", str(spec), "--duration", "1", "--run-dir", str(run)).returncode == 0
    old = (run / "cluster.json").read_text()
    refused = hera(tmp_path, "up", str(spec), "--duration", "1", "--run-dir", str(run))
    assert refused.returncode == 2
    assert refused.stderr == (
        f"hera up: run directory {run} holds a previous run: give another --run-dir, leave it "
        "out for a new one, or add --overwrite to replace it\n"
    )
    assert (run / "cluster.json").read_text() == old  # untouched
    again = hera(tmp_path, "up", str(spec), "--duration", "1", "--run-dir", str(run), "--overwrite")
    assert again.returncode == 0 and (run / "cluster.json").read_text() != old


def test_two_runs_of_one_spec_are_both_registered_and_stopped_one_by_one(tmp_path):
    spec = tmp_path / "s.toml"
    spec.write_text(SPEC.format(name="twins"))
    procs = [start(tmp_path, str(spec), "--run-dir", str(tmp_path / f"r{i}")) for i in (1, 2)]
    try:
        for i in (1, 2):
            wait_for(lambda i=i: (tmp_path / f"r{i}" / "launcher.json").exists(), 20, f"run {i}")
        listed = hera(tmp_path, "status")
        assert listed.returncode == 0
        assert str(tmp_path / "r1") in listed.stdout and str(tmp_path / "r2") in listed.stdout
        ambiguous = hera(tmp_path, "down", "--cluster", "twins")
        assert ambiguous.returncode == 2
        assert "2 clusters are running (twins in " in ambiguous.stderr
        assert "pick one with --run-dir DIR" in ambiguous.stderr
        down = hera(tmp_path, "down", "--run-dir", str(tmp_path / "r1"))
        assert down.returncode == 0, down.stderr
        procs[0].wait(20)
        assert procs[1].poll() is None  # the other run goes on
        status = hera(tmp_path, "status", "--json")  # the one left is found without options
        assert json.loads(status.stdout)["cluster"] == "twins"
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
                p.wait(20)


def test_a_busy_port_is_refused_before_anything_starts(tmp_path):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        spec = tmp_path / "s.toml"
        spec.write_text(
            SPEC.format(name="busy").replace(
                '[[nodes]]\nname = "b"', f'[[nodes]]\nname = "b"\nport = {port}'
            )
        )
        out = hera(tmp_path, "up", str(spec), "--run-dir", str(tmp_path / "run"))
    assert out.returncode == 2
    assert f"node 'b': port {port} on 127.0.0.1 is not free (Address already in use)" in out.stderr
    assert not (tmp_path / "run").exists()


def test_a_node_whose_port_is_taken_says_so_and_exits_78(tmp_path):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        spec = tmp_path / "s.toml"
        spec.write_text(f'[cluster]\nname = "n"\n[[nodes]]\nname = "a"\nport = {port}\n')
        out = hera(tmp_path, "node", str(spec), "--node", "a")
    assert out.returncode == 78
    assert f"FATAL: its port tcp/127.0.0.1:{port} is in use by another process" in out.stderr


def test_the_launcher_does_not_restart_a_node_that_cannot_start(tmp_path, monkeypatch):
    """A node exiting 78 is not restarted in a loop: its cause is printed, the cluster
    stops and ``hera up`` exits 1."""
    import io

    from hera import launcher as launcher_mod

    def fake(*args: str) -> list[str]:
        name = args[args.index("--node") + 1]
        code = 78 if name == "b" else 0
        script = (
            "import sys, time\n"
            f"print('x hera.node ERROR FATAL: its port tcp/127.0.0.1:1 is in use', flush=True)\n"
            f"sys.exit({code}) if {code} else time.sleep(30)\n"
        )
        return [sys.executable, "-c", script]

    monkeypatch.setattr(launcher_mod, "node_command", fake)
    monkeypatch.setenv("HERA_REGISTRY", str(tmp_path / "registry"))
    spec = tmp_path / "s.toml"
    spec.write_text(SPEC.format(name="fatal"))
    out = io.StringIO()
    la = launcher_mod.Launcher(spec, tmp_path / "run", duration=20, out=out, interval=60)
    t0 = time.monotonic()
    assert la.run() == 1
    assert time.monotonic() - t0 < 10
    text = out.getvalue()
    assert "node b cannot start: its port tcp/127.0.0.1:1 is in use; stopping the cluster" in text
    assert "restarting" not in text
    assert la.nodes["b"].restarts == 0 and la.nodes["b"].state == "stopped"
    assert not any(
        os.path.exists(f"/proc/{p.proc.pid}") and p.proc.poll() is None for p in la.nodes.values()
    )


def test_a_node_run_by_hand_checks_its_whole_spec_first(tmp_path):
    """``hera node`` checks the spec (in a child process, so the node never holds every
    installed application) and starts nothing when it is wrong; ``--check-only`` checks
    and exits."""
    spec = tmp_path / "s.toml"
    spec.write_text(
        '[cluster]\nname = "n"\n[[nodes]]\nname = "a"\n[[nodes.measures]]\nuse = "counter"\n'
        'name = "obs1"\nargs = { prefxi = "obs" }\n'
    )
    wrong = (
        f"hera node: {spec}: measure 'obs1' of node 'a': args: unknown key 'prefxi' "
        "(did you mean 'prefix'?)"
    )
    for extra in ((), ("--check-only",)):
        out = hera(tmp_path, "node", str(spec), "--node", "a", *extra)
        assert out.returncode == 2, out.stderr
        assert out.stderr.count(wrong) == 1, out.stderr
        assert "node a up" not in out.stderr
    spec.write_text(spec.read_text().replace("prefxi", "prefix"))
    out = hera(tmp_path, "node", str(spec), "--node", "a", "--check-only")
    assert (out.returncode, out.stderr) == (0, "")


@pytest.mark.parametrize(
    ("option", "says"),
    [("--run-dir", "cannot make the run directory"), ("--mcap", "--mcap: cannot write")],
)
def test_an_output_that_cannot_be_written_is_one_sentence_and_nothing_starts(
    tmp_path, option, says
):
    spec = tmp_path / "s.toml"
    spec.write_text(SPEC.format(name="nowhere"))
    (tmp_path / "file").write_text("x")
    target = tmp_path / "file" / "out"
    out = hera(tmp_path, "up", str(spec), option, str(target))
    assert out.returncode == 2
    assert out.stderr == f"hera up: {says} {target}: Not a directory\n"
    assert not (tmp_path / "hera-run").exists()
