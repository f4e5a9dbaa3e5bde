"""Train tracking goes on while a sonar node is SIGKILLed and comes back (issue 6)."""

from __future__ import annotations

import math
import os
import signal
import time
from pathlib import Path

import pytest
from harness import wait_for

from hera.evaluate import load_outputs, run_spec
from hera.models.train.app import train_truth
from hera.recordings import read_recordings

ROOT = Path(__file__).resolve().parents[2]


def _rms_cm(rows, truth, lo, hi):
    errs = [
        math.hypot(v[0] - tr["x [m]"], v[1] - tr["y [m]"])
        for t, v in rows
        if lo <= t < hi
        for tr in (truth.at(t),)
    ]
    assert errs, (lo, hi)
    return 100 * math.sqrt(sum(e * e for e in errs) / len(errs))


@pytest.mark.slow  # 66 s; CI keeps the train's live accuracy run and the short thesis-ch5
# campaign, whose estimate checkers see sonar_2 powered off and the sync leader killed
def test_e7_keeps_tracking_through_a_sonar_node_kill(cluster):
    """Issue 6: with sonar_1 SIGKILLed, e7's position RMSE from the kill until 5 s after the
    node is back stays within twice the baseline, and within it again afterwards.

    The baseline is the RMSE over the rest of the settled run, about 45 s (6 laps) of it:
    e7's position error wanders slowly between about 0.1 and 1.2 cm (lap-long swings), so
    over 6 s it ranges 0.46-1.56x the long-run RMSE with no fault at all (a 90 s run), and
    a baseline of only ~5 s before the kill made the 2x bound fail on quiet runs."""
    c = cluster((ROOT / "deploy" / "train.toml").read_text(), name="run")

    def published() -> int:
        return c.status("computer")["measures"]["track_gyro"]["published"]

    wait_for(lambda: published() > 700, 60, "35 s of e7 estimates (25 s settled)")
    victim = c.pid("sonar_1")  # asked first: the kill follows the clock read at once
    t_kill = time.time()
    os.kill(victim, signal.SIGKILL)
    wait_for(lambda: c.launcher_state()["sonar_1"]["restarts"] == 1, 10, "sonar_1 restarted")

    def sonar_1_published() -> int:
        """Samples the restarted sonar_1 published (-1 while it does not answer yet)."""
        reply = c.client.query("sonar_1", "status", timeout=0.5).get("sonar_1")
        return -1 if reply is None else reply["measures"]["sonar"]["published"]

    wait_for(lambda: sonar_1_published() > 40, 30, "sonar_1 publishing again")
    back = published()
    wait_for(lambda: published() > back + 400, 40, "20 s more of e7 estimates")
    c.stop()

    run = c.run_dir
    truth = train_truth(run_spec(run).world)
    sonar_1 = [s.t for s in read_recordings(run, ["sonar"]) if s.node == "sonar_1"]
    t_back = min(t for t in sonar_1 if t > t_kill)
    assert t_back - t_kill < 5.0  # the node is back (launcher restart + sync grant)
    fault_end = t_back + 5.0
    for s in load_outputs(run):
        if s.name != "track_gyro":
            continue
        rows = list(zip(s.t.tolist(), s.values.tolist(), strict=True))
        t0 = rows[0][0]
        # estimates never stop while the node is down
        during = [t for t, _ in rows if t_kill - 1 <= t <= fault_end]
        assert max(b - a for a, b in zip(during, during[1:], strict=False)) < 0.5, s.node
        settled = [(t, v) for t, v in rows if t >= t0 + 10]
        outside = [(t, v) for t, v in settled if not t_kill <= t < fault_end]
        baseline = _rms_cm(outside, truth, t0 + 10, float("inf"))
        fault = _rms_cm(settled, truth, t_kill, fault_end)
        after = _rms_cm(settled, truth, fault_end, float("inf"))
        assert fault <= 2 * baseline, (s.node, fault, baseline)
        assert after <= 2 * baseline, (s.node, after, baseline)
