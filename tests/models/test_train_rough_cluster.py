"""The train ladder on the rough rig with a real cluster, the train running clockwise
(issue 20): deploy/train_rough.toml (wide sonar cones, missed pings, bounces, far-side
echoes, ~6 Hz nav and ~2 Hz sonars, gyro scale, accelerometer bias, magnetometer heading
offset, rails that are not round) with omega = -0.7 rad/s, 60 s, models on two nodes.

On both model nodes, scored by hera eval (settled: after 30 s): every rung e5-e9 locks
within two laps and never stays on a wrong branch for more than a lap; e7-e9 settled omega
within 0.5 %; e8/e9 radius within the rails with a standard deviation <= 5 mm over the
second half; no omega once locked under half the truth. A replay of the recordings
reproduces the live scores (tests/models/test_train_offline.py holds the same over 20
offline runs).

Marked slow (``pytest -m slow``): the run takes about 62 s, more than the CI budget of
issue 20's tests allows beside the offline campaigns; CI's real-cluster accuracy test of
the train is tests/models/test_train_cluster.py, and the rough rig's bounds are held in CI
by the offline runs (the same model code: ``hera replay --start-like`` reproduces a live
node's estimates, tested there)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from harness import cluster_env

from hera.application import EvalOptions
from hera.evaluate import by_model, evaluate

ROOT = Path(__file__).resolve().parents[2]
NODES = ("computer", "nav_1")
RUNGS = ("track_bilat", "track_sonar", "track_gyro", "track_radius", "track_mag")
OPTIONS = EvalOptions(settle=30.0)

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def rough_run(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("rough")
    text = (ROOT / "deploy" / "train_rough.toml").read_text()
    assert "\nomega = 0.7 " in text
    spec = tmp / "rough_cw.toml"
    spec.write_text(text.replace("\nomega = 0.7 ", "\nomega = -0.7 "))
    run = tmp / "run"
    proc = subprocess.run(
        [sys.executable, "-m", "hera", "up", str(spec), "--duration", "60", "--run-dir", str(run)]
        + ["--interval", "20"],
        env=cluster_env(tmp),
        capture_output=True,
        text=True,
        timeout=240,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return run


def test_the_rough_rig_clockwise_meets_the_issue_on_both_model_nodes(rough_run):
    res = by_model(evaluate(rough_run, OPTIONS))
    for node in NODES:
        for rung in RUNGS:
            r = res[(rung, node)]
            assert r["lock_laps"] is not None and r["lock_laps"] <= 2.0, (node, rung, r)
            assert r["wrong_laps"] <= 1.0, (node, rung, r)
            assert r["omega_low_pct"] > 50.0, (node, rung, r)
        for rung in RUNGS[2:]:
            assert res[(rung, node)]["omega_settled_rms_pct"] <= 0.5, (node, rung)
        for rung in RUNGS[3:]:
            r = res[(rung, node)]
            assert r["radius_off_mm"] == 0.0 and r["radius_std_mm"] <= 5.0, (node, rung, r)


def test_a_replay_of_the_rough_run_scores_like_it(rough_run, tmp_path):
    out = tmp_path / "replay"
    proc = subprocess.run(
        [sys.executable, "-m", "hera", "replay", str(rough_run), "--out", str(out)]
        + ["--start-like", "computer"],
        env=cluster_env(tmp_path),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    live = by_model(evaluate(rough_run, OPTIONS))
    again = by_model(evaluate(out, OPTIONS))
    for rung in RUNGS[2:]:
        ref, got = live[(rung, "computer")], again[(rung, "replay")]
        assert got["omega_settled_rms_pct"] == pytest.approx(ref["omega_settled_rms_pct"], abs=0.05)
        assert got["lock_laps"] == pytest.approx(ref["lock_laps"], abs=0.1)
