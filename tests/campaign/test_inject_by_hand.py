"""``hera inject`` does by hand what a campaign does: a board fault, clock skew, a partition
and its healing, on a cluster a holding campaign (``manual``) runs and records; Ctrl-C ends
the campaign, which judges and reports the faults injected by hand."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from harness import cluster_env, run_hera, wait_for

from hera.campaign import history
from hera.campaign.manual import _network
from hera.campaign.runner import processes_of

SPEC = """
[cluster]
name = "byhand"
lease_ms = 600

[world]
scenario = "still"
position = [0.0, 2.0, 0.0]

[[nodes]]
name = "n1"
sync_hosts = ["sonar"]

  [[nodes.measures]]
  use = "counter"
  name = "count"
  period = 0.05

[[nodes]]
name = "n2"
sync_hosts = ["sonar"]

  [[nodes.measures]]
  use = "sonar"
  period = 0.1
  args = { position = [0.0, 0.0, 0.0], direction = [0.0, 1.0, 0.0] }

[[nodes]]
name = "n3"
sync_hosts = ["sonar"]
"""

CAMPAIGN = """
[campaign]
name = "byhand"
baseline_s = 2
tail_s = 1
hold_s = 120
links = true

[checks]
skip = ["figures"]
"""


def hera(tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    return run_hera(tmp_path, *args, cwd=Path.cwd(), timeout=30)


def test_faults_by_hand_on_a_holding_campaign(tmp_path):
    (tmp_path / "spec.toml").write_text(SPEC)
    (tmp_path / "hold.toml").write_text(CAMPAIGN)
    folder = tmp_path / "c"
    run = folder / "run"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "hera",
            "campaign",
            str(tmp_path / "spec.toml"),
            str(tmp_path / "hold.toml"),
            "--run-dir",
            str(folder),
            "--seed",
            "1",
        ],
        env=cluster_env(tmp_path),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:

        def meta() -> dict:
            try:
                return json.loads((folder / "campaign.json").read_text())
            except (OSError, ValueError):
                return {}

        wait_for(lambda: "schedule_end" in meta().get("times", {}), 60, "the campaign to hold")
        d = ["--run-dir", str(run)]

        r = hera(
            tmp_path, "inject", "n2", "board", "stuck", "--board", "n2/sonar", "--for", "2", *d
        )
        assert r.returncode == 0, r.stderr
        assert json.loads(r.stdout)["fault"]["fault"] == "stuck"

        r = hera(tmp_path, "inject", "n1", "clock", "0.5", *d)
        assert r.returncode == 0 and json.loads(r.stdout)["skew_s"] == 0.5, r.stderr
        t_skew = time.time()
        time.sleep(1.0)
        assert hera(tmp_path, "inject", "n1", "clock", "0", *d).returncode == 0

        r = hera(tmp_path, "inject", "n1", "partition", *d)
        assert r.returncode == 0, r.stderr
        assert sorted(map(tuple, json.loads(r.stdout)["pairs"])) == [("n1", "n2"), ("n1", "n3")]

        def n2_peers() -> list[str]:
            out = hera(tmp_path, "status", "n2", "--json", *d)
            return json.loads(out.stdout)["peers"] if out.returncode == 0 else []

        wait_for(lambda: "n1" not in n2_peers(), 10, "n2 to lose n1 (link lease 0.6 s)")
        assert hera(tmp_path, "inject", "n1", "heal", *d).returncode == 0
        wait_for(lambda: "n1" in n2_peers(), 10, "n2 to see n1 again")

        r = hera(tmp_path, "inject", "n1", "loss", "lots", *d)
        assert r.returncode == 2 and "the loss share must be a number" in r.stderr
        r = hera(tmp_path, "inject", "n1", "crash", "nosuch", *d)  # refused by the node
        assert r.returncode == 2 and r.stdout == "", r.stdout
        assert r.stderr.startswith("hera inject: n1: no measure 'nosuch' on this node"), r.stderr

        proc.send_signal(signal.SIGINT)  # ends the hold: stop, judge, report
        out, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert not processes_of(folder)
    h = history.load(folder)
    assert [m["kind"] for m in h.manual] == ["board", "clock", "clock", "partition", "heal"]
    assert not h.meta["interrupted"]  # Ctrl-C is how a hold ends
    # the skewed node's samples carry its clock: 0.5 s ahead of their arrival
    s = h.streams[("count", "n1")]
    lag = s.t - s.arrival
    during = lag[(s.arrival > t_skew + 0.2) & (s.arrival < t_skew + 0.8)]
    before = lag[s.arrival < t_skew - 0.2]
    assert np.median(during) == pytest.approx(0.5, abs=0.05)
    assert abs(np.median(before)) < 0.05
    md = (folder / "report.md").read_text()
    assert "5 injected by hand" in md
    verdicts = {line.split("|")[1].strip(): line for line in md.splitlines() if "|" in line}
    assert "pass" in verdicts["overlaps"] and "pass" in verdicts["sequences"], out


def test_network_faults_need_a_cluster_started_by_a_campaign():
    with pytest.raises(ValueError, match="started by 'hera campaign'"):
        _network(None, ["a", "b"], "a", "partition", None, None, 0.0)


class _Reached:
    """A tool client reached with --connect (no spec, no run directory): it records the
    queries it is asked to send."""

    spec = None

    def __init__(self) -> None:
        self.asked: list[tuple] = []

    def query(self, node, verb, request, timeout=2.0):
        self.asked.append((node, verb, request))
        return {node: {"ok": True, "verb": verb}}


def test_board_and_clock_faults_work_through_connect_and_network_faults_say_why_not():
    from hera.campaign.manual import inject

    client = _Reached()
    reply = inject(client, None, "n2", "board", "stuck", board="n2/sonar", seconds=2.0)
    assert reply["ok"] and client.asked[-1] == (
        "n2",
        "board",
        {"board": "n2/sonar", "fault": "stuck", "duration": 2.0},
    )
    inject(client, None, "n1", "clock", "0.25")
    assert client.asked[-1] == ("n1", "clock", {"skew_s": 0.25})
    with pytest.raises(ValueError, match="network faults need the cluster's run directory"):
        inject(client, None, "n1", "partition", None)
