"""The short versions of the three shipped campaigns on a real train cluster, and a broken
sync setting the overlap checker must catch.

Each runs ``hera campaign`` as a user would (a process, real nodes on loopback, the link
proxy for network faults) and checks its verdicts, its report and that nothing is left
running. CI runs the short thesis-ch5 and the broken sync setting; the short partitions
and nemesis (about 40 s each) and the full campaigns (minutes each) are marked slow
(``pytest -m slow tests/campaign``); README "Fault campaigns" has their figures and
commands.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from harness import cluster_env

from hera.campaign import checkers, history
from hera.campaign.runner import processes_of

MUST_PASS = (
    "schedule",
    "overlaps",
    "stale_firings",
    "sync_partitions",
    "gaps",
    "sequences",
    "args",
    "recovery",
    "estimates",
    "agreement",
    "restarts",
    "figures",
    "leftovers",
)


def run_campaign(tmp_path: Path, *args: str, timeout: float = 600) -> tuple[int, Path, str]:
    """``hera campaign ARGS --run-dir DIR``; its exit code, directory and output."""
    folder = tmp_path / "campaign"
    cmd = [sys.executable, "-m", "hera", "campaign", *args, "--run-dir", str(folder)]
    out = subprocess.run(
        cmd, env=cluster_env(tmp_path), capture_output=True, text=True, timeout=timeout
    )
    assert not processes_of(folder), "processes of the campaign outlived it"
    return out.returncode, folder, out.stdout + out.stderr


def verdicts(folder: Path) -> dict[str, checkers.Verdict]:
    return {v.name: v for v in checkers.run_all(history.load(folder))}


def assert_complete_report(folder: Path) -> None:
    md = (folder / "report.md").read_text()
    for section in ("## Verdict", "## Timeline", "## Faults", "## Checkers"):
        assert section in md
    assert "![timeline](timeline.png)" in md
    html = (folder / "report.html").read_text()
    assert "<img src='timeline.png'" in html and "<table>" in html
    png = (folder / "timeline.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000


def test_thesis_ch5_short(tmp_path):
    code, folder, out = run_campaign(tmp_path, "train", "thesis-ch5", "--short", "--seed", "1")
    v = verdicts(folder)
    assert code == 0, out + "\n".join(f"{k}: {x.summary}" for k, x in v.items())
    for name in MUST_PASS:
        assert v[name].passed and not v[name].skipped, (name, v[name].summary)
    h = history.load(folder)
    assert [f.name for f in h.faults] == ["crash nav", "kill leader mid-slot", "power off sonar_2"]
    assert all(f.done for f in h.faults)
    figures = {r["figure"]: r for r in v["figures"].rows}
    measured = [r for r in figures.values() if r["verdict"] == "ok"]
    assert len(measured) >= 4  # killed measure, killed node noticed, paused one, leader kill
    assert h.faults[1].extra.get("firing_log")  # the kill struck while a sonar sounded
    assert_complete_report(folder)


@pytest.mark.slow  # CI budget: the link proxy is in tests/campaign/test_inject_by_hand.py
def test_partitions_short(tmp_path):
    code, folder, out = run_campaign(tmp_path, "train", "partitions", "--short", "--seed", "1")
    v = verdicts(folder)
    assert code == 0, out + "\n".join(f"{k}: {x.summary}" for k, x in v.items())
    for name in MUST_PASS:
        assert v[name].passed and not v[name].skipped, (name, v[name].summary)
    sides = v["sync_partitions"].rows
    assert {r["side"] for r in sides} == {"majority", "minority"}
    assert (folder / "links.json").exists() and (folder / "linkproxy.log").exists()
    assert_complete_report(folder)


@pytest.mark.slow  # CI budget: the link proxy is in tests/campaign/test_inject_by_hand.py
def test_nemesis_short(tmp_path):
    code, folder, out = run_campaign(tmp_path, "train", "nemesis", "--short", "--seed", "3")
    v = verdicts(folder)
    assert code == 0, out + "\n".join(f"{k}: {x.summary}" for k, x in v.items())
    for name in ("schedule", "overlaps", "stale_firings", "sequences", "args", "leftovers"):
        assert v[name].passed and not v[name].skipped, (name, v[name].summary)
    h = history.load(folder)
    assert len(h.faults) >= 2 and all(f.done for f in h.faults)
    assert_complete_report(folder)


BROKEN = """
# two sonars that do not ask for slots (sync = false): they sound over each other
[cluster]
name = "brokensync"

[world]
scenario = "train"
radius = 0.6
omega = 0.84
center = [0.0, 0.0]

[world.sonars.s1]
position = [-0.3, -1.5, 0.0]
direction = [0.0, 1.0, 0.0]

[world.sonars.s2]
position = [0.3, -1.5, 0.0]
direction = [0.0, 1.0, 0.0]

[[nodes]]
name = "s1"
sync_hosts = ["sonar"]

  [[nodes.measures]]
  use = "sonar"
  period = 0.07
  sync = false

[[nodes]]
name = "s2"
sync_hosts = ["sonar"]

  [[nodes.measures]]
  use = "sonar"
  period = 0.07
  sync = false

[[nodes]]
name = "host"
sync_hosts = ["sonar"]
"""

CAMPAIGN = """
[campaign]
name = "broken"
baseline_s = 3
gap_s = 3
tail_s = 2

[[faults]]
name = "crash s1's sonar"
kind = "crash"
target = "s1"
measure = "sonar"
"""


def test_the_overlap_checker_catches_a_broken_sync_setting(tmp_path):
    spec, camp = tmp_path / "broken.toml", tmp_path / "broken-campaign.toml"
    spec.write_text(BROKEN)
    camp.write_text(CAMPAIGN)
    code, folder, out = run_campaign(tmp_path, str(spec), str(camp), "--seed", "1")
    v = verdicts(folder)
    assert code == 1, out
    assert not v["overlaps"].passed
    overlaps = v["overlaps"].rows[0]["overlaps"]
    assert overlaps >= 10, v["overlaps"].summary  # two sonars at 14 Hz, 49 ms pings
    assert "firings without a grant" in v["stale_firings"].summary
    assert "failed: " in out and "overlaps" in out


@pytest.mark.slow
@pytest.mark.parametrize("campaign", ["thesis-ch5", "partitions", "nemesis"])
def test_full_campaign(tmp_path, campaign):
    """The whole campaigns (3, 3 and 11 minutes): every checker passes."""
    code, folder, out = run_campaign(tmp_path, "train", campaign, "--seed", "7", timeout=1800)
    v = verdicts(folder)
    assert code == 0, out + "\n".join(f"{k}: {x.summary}" for k, x in v.items())
    assert_complete_report(folder)
