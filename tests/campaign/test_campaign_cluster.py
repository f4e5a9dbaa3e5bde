"""The short versions of the three shipped campaigns on a real train cluster, and a broken
sync setting the overlap checker must catch.

Each runs ``hera campaign`` as a user would (a process, real nodes on loopback, the link
proxy for network faults) and checks its verdicts, its report and that nothing is left
running. CI runs the short thesis-ch5 and the broken sync setting; the short partitions
(behind the link proxy, and with nftables in namespaces in ``test_netns_links.py``) and
nemesis (about 40 s each) and the full campaigns (minutes each) are marked slow
(``pytest -m slow tests/campaign``); README "Fault campaigns" has their figures and
commands.
"""

from __future__ import annotations

import pytest
from campaign_runs import assert_complete_report, assert_passed, run_campaign, verdicts

from hera.campaign import history


def test_thesis_ch5_short(tmp_path):
    code, folder, out = run_campaign(tmp_path, "train", "thesis-ch5", "--short", "--seed", "1")
    v = assert_passed(code, folder, out)
    h = history.load(folder)
    assert [f.name for f in h.faults] == [
        "crash nav",
        "crash e7",
        "kill leader mid-slot",
        "power off sonar_2",
    ]
    assert all(f.done for f in h.faults)
    # the crashed e7 resumed its model from its checkpoint instead of starting cold (its
    # node's log says so: the node itself may be killed later, as the sync leader)
    log = (folder / "run" / "logs" / "computer.log").read_text().splitlines()
    crashed = [i for i, x in enumerate(log) if "track_gyro crashed: InjectedFault" in x]
    resumed = [i for i, x in enumerate(log) if "track_gyro INFO resumed the model" in x]
    assert len(crashed) == 1 and resumed and resumed[0] > crashed[0], (crashed, resumed)
    if h.faults[2].nodes == ["computer"]:  # the leader was computer (as a rule): its new
        # process resumed e7 from the checkpoint the killed one left on disk
        again = [x for x in log[crashed[0] :] if "checkpoint its node's previous process" in x]
        assert any("track_gyro INFO resumed" in x for x in again), again
    figures = {r["figure"]: r for r in v["figures"].rows}
    measured = [r for r in figures.values() if r["verdict"] == "ok"]
    assert len(measured) >= 4  # killed measure, killed node noticed, paused one, leader kill
    assert h.faults[2].extra.get("firing_log")  # the kill struck while a sonar sounded
    assert_complete_report(folder)


@pytest.mark.slow  # CI budget: the link proxy is in tests/campaign/test_inject_by_hand.py
def test_partitions_short(tmp_path):
    code, folder, out = run_campaign(
        tmp_path, "train", "partitions", "--short", "--links", "proxy", "--seed", "1"
    )
    v = assert_passed(code, folder, out)
    sides = v["sync_partitions"].rows
    assert {r["side"] for r in sides} == {"majority", "minority"}
    assert (folder / "links.json").exists() and (folder / "linkproxy.log").exists()
    assert_complete_report(folder)


@pytest.mark.slow  # CI budget: the link proxy is in tests/campaign/test_inject_by_hand.py
def test_nemesis_short(tmp_path):
    code, folder, out = run_campaign(tmp_path, "train", "nemesis", "--short", "--seed", "3")
    names = ("schedule", "overlaps", "stale_firings", "sequences", "args", "leftovers")
    assert_passed(code, folder, out, names)
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
    assert_passed(code, folder, out, ())
    assert_complete_report(folder)
