"""Seed 000 on real clusters: deploy/ir_tracking.toml and deploy/ir_grid.toml run by
``hera up``, scored by ``hera eval`` through the ``ir`` application.

All marked slow (``pytest -m slow``; CI's 20 minutes run the live accuracy runs of the
train and the AHRS, and the IR models offline in tests/models/test_ir_models.py). One run
of each spec is shared by the tests of this module:

- tracking (constant velocity, about 35 s): RMSE <= 0.5 cm on both model nodes with the
  medium + long pair while the long sensor's board is disconnected for 8 s mid-run
  (estimates never stop, the error stays bounded, the long sensor is fused again when it
  is back); the seed's Q/R study on the same run;
- the map (a plate already warm, about 30 s): >= 95 % of the cells right on both model
  nodes, the hot block within one cell, the fused map no worse than IR alone, and a replay
  of the recordings giving the same maps.

Also: the same over several seeds and the other scenarios (poor initial guess, the
short sensor's outliers, a cold plate mapped for 60 s, the hidden hot block).
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from harness import Cluster, cluster_env, wait_for
from ir_specs import replace, spec

from hera.evaluate import by_model, evaluate, load_outputs, run_spec
from hera.models.ir.app import ir_truth, plate_maps
from hera.recordings import read_recordings

MODEL_NODES = ("computer", "ir_medium")
MAP_NODES = ("mapper", "plate")


def _start(tmp: Path, name: str, text: str) -> Cluster:
    path = tmp / f"{name}.toml"
    path.write_text(text)
    c = Cluster(path, tmp / name, cluster_env(tmp), None)
    try:
        c.connect(30.0)
    except BaseException:
        c.stop()
        raise
    return c


def _published(c: Cluster, node: str, measure: str) -> int:
    reply = c.client.query(node, "status", timeout=0.5).get(node)
    return -1 if reply is None else reply["measures"][measure]["published"]


@pytest.fixture(scope="module")
def tracking(tmp_path_factory):
    """A run of deploy/ir_tracking.toml; ``ir_long``'s board is disconnected from about
    12 s to 20 s. Returns (run dir, wall time of the fault, of the reconnection, the long
    sensor's use counted by the computer's tracker before the fault and at the end)."""
    tmp = tmp_path_factory.mktemp("ir_tracking")
    c = _start(tmp, "run", spec("ir_tracking"))
    try:
        # time told by the medium sensor's readings (50 a second), not by the estimates
        wait_for(lambda: _published(c, "ir_medium", "ir_medium") > 500, 40, "10 s of readings")
        before = c.status("computer")["measures"]["ir_track"]["counters"]["ir_long_used"]
        reply = c.control("ir_long", "board", {"board": "ir_long/ir", "fault": "disconnect"})
        t_off = time.time()  # the reply came: the board is disconnected from now on at least
        assert reply.get("ok", True) and reply["fault"]["fault"] == "disconnect", reply
        time.sleep(8.0)
        t_on = time.time()
        c.control("ir_long", "board", {"board": "ir_long/ir", "fault": "clear"})
        during = c.status("ir_long")["measures"]["ir_long"]["counters"]["disconnected"]
        back = _published(c, "ir_medium", "ir_medium")
        wait_for(lambda: _published(c, "ir_medium", "ir_medium") > back + 500, 40, "10 s more")
        after = c.status("computer")["measures"]["ir_track"]["counters"]["ir_long_used"]
    finally:
        c.stop()
    return c.run_dir, t_off, t_on, before, after, during


def _errors(series, truth):
    true = np.array([truth.at(float(t))["distance [cm]"] for t in series.t])
    return series.column("distance [cm]") - true


@pytest.mark.slow  # CI budget: see the module docstring
def test_tracking_rmse_is_under_half_a_cm_through_a_board_disconnection(tracking):
    run, t_off, t_on, *_ = tracking
    res = by_model(evaluate(run))
    for node in MODEL_NODES:
        s = res[("ir_track", node)]
        assert s["estimates"] > 1000, (node, s)  # ~45 per second for ~30 s
        assert s["rmse_cm"] <= 0.5, (node, s)


@pytest.mark.slow  # CI budget: see the module docstring
def test_tracking_goes_on_without_the_long_sensor_and_takes_it_back(tracking):
    run, t_off, t_on, before, after, during = tracking
    assert during >= 300  # ~50 readings a second were missing for 8 s
    assert after > before + 400  # fused again once back (~50 a second for 10 s)
    longs = [s.t for s in read_recordings(run, ["ir_long"])]
    assert not any(t_off + 0.1 < t < t_on - 0.1 for t in longs)  # really silent
    truth = ir_truth(run_spec(run).world)
    for s in load_outputs(run):
        if s.name != "ir_track":
            continue
        err = _errors(s, truth)
        fault = (s.t >= t_off) & (s.t < t_on)
        assert np.max(np.diff(s.t[fault])) < 0.2, s.node  # estimates never stop
        assert np.sqrt(np.mean(err[fault] ** 2)) <= 1.0, s.node
        late = s.t >= t_on + 3.0
        assert np.sqrt(np.mean(err[late] ** 2)) <= 0.5, s.node


@pytest.mark.slow  # CI budget: see the module docstring
def test_the_seeds_q_r_study_on_the_live_run(tracking):
    """Seed lab 2 scenarios 2 and 3 on the same data: a 150x larger R lags the most; a
    300x larger Q lags the least and is noisier than the default."""
    res = by_model(evaluate(tracking[0]))
    good, high_r, high_q = (
        res[(n, "computer")] for n in ("ir_track", "ir_track_high_r", "ir_track_high_q")
    )
    assert high_r["lag_s"] > good["lag_s"] >= high_q["lag_s"], (good, high_r, high_q)
    assert high_q["rmse_cm"] > good["rmse_cm"], (good, high_q)


@pytest.fixture(scope="module")
def plate_run(tmp_path_factory):
    """A run of deploy/ir_grid.toml on a plate warmed for 300 s (the heat has arrived), the
    maps told so (``baseline_s = 0``)."""
    tmp = tmp_path_factory.mktemp("ir_grid")
    text = replace(spec("ir_grid"), "hot_since_s = 0.0", "hot_since_s = 300.0")
    # a warm plate: no offset calibration (baseline_s = 0) for the maps
    text = text.replace(
        'args = { mode = "arrival" }', 'args = { mode = "arrival", model = { baseline_s = 0.0 } }'
    )
    text = replace(text, "cell_cm = 1.0 }", "cell_cm = 1.0, baseline_s = 0.0 }")
    c = _start(tmp, "run", text)
    try:
        wait_for(lambda: _published(c, "mapper", "occupancy_grid") >= 25, 60, "25 maps")
    finally:
        c.stop()
    return tmp, c.run_dir


@pytest.mark.slow
def test_the_warm_plate_is_mapped_and_its_hot_block_found(plate_run):
    _, run = plate_run
    res = by_model(evaluate(run))
    for node in MAP_NODES:
        s = res[("occupancy_grid", node)]
        assert s["map_pct"] >= 95.0 and s["hot_err_cm"] <= 1.0, (node, s)
    fused, ir = res[("occupancy_grid", "mapper")], res[("occupancy_ir", "mapper")]
    assert fused["map_pct"] >= ir["map_pct"] and ir["hot_err_cm"] is None


@pytest.mark.slow
def test_a_replay_of_the_plate_gives_the_same_maps(plate_run):
    tmp, run = plate_run
    out = tmp / "again"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "hera",
            "replay",
            str(run),
            "--out",
            str(out),
            "--start-like",
            "mapper",
        ],
        env=cluster_env(tmp),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    live = {s.name: plate_maps(s) for s in load_outputs(run) if s.node == "mapper"}
    again = {s.name: plate_maps(s) for s in load_outputs(out)}
    for name in ("occupancy_grid", "occupancy_ir", "occupancy_thermal"):
        a = {round(m[0], 3): m for m in live[name]}
        b = {round(m[0], 3): m for m in again[name]}
        common = sorted(set(a) & set(b))
        assert len(common) >= 0.9 * len(a), (name, len(a), len(b))
        same = sum(np.allclose(a[t][1], b[t][1], atol=1e-3) for t in common)
        assert same >= len(common) - 1, (name, same, len(common))


# -- slow campaigns (pytest -m slow) --------------------------------------------------------


def _tracking_run(tmp: Path, name: str, text: str, seconds: float) -> Path:
    c = _start(tmp, name, text)
    try:
        n = int(seconds * 50)  # the medium sensor's readings
        wait_for(lambda: _published(c, "ir_medium", "ir_medium") > n, seconds + 40, f"{seconds} s")
    finally:
        c.stop()
    return c.run_dir


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_campaign_tracking_over_seeds(tmp_path, seed):
    """Constant velocity and back-and-forth over several board seeds: RMSE <= 0.5 cm on
    the constant-velocity run, the random run tracked with a lag under 0.5 s."""
    text = replace(spec("ir_tracking"), "[[nodes]]", f"[defaults]\nseed = {seed}\n\n[[nodes]]")
    res = by_model(evaluate(_tracking_run(tmp_path, "cv", text, 30)))
    for node in MODEL_NODES:
        assert res[("ir_track", node)]["rmse_cm"] <= 0.5, res[("ir_track", node)]
    world = {"scenario": "ir_back_and_forth", "seed": seed}
    text = replace(
        spec("ir_tracking", world), "[[nodes]]", f"[defaults]\nseed = {seed}\n\n[[nodes]]"
    )
    res = by_model(evaluate(_tracking_run(tmp_path, "random", text, 30)))
    assert res[("ir_track", "computer")]["lag_s"] <= 0.5, res[("ir_track", "computer")]


@pytest.mark.slow
def test_campaign_poor_initial_guess(tmp_path):
    """Seed scenario 4 live: started at 50 cm, the block still at 70 cm: within 1 cm (and
    its RMS over the next second) in 1 s, the target, is met by 117 of 120 offline starts
    (``test_ir_models``: the sensor noise can hold the estimate 1-2 cm off for a while
    after any start; worst 1.47 s), so one live start is held to 2 s, and each node's
    start is one draw of that distribution."""
    text = replace(
        spec("ir_tracking", {"scenario": "ir_stationary", "distance_cm": 70.0}),
        'model = { sensors = { ir_medium = "GP2Y0A21YK0F", ir_long = "GP2Y0A02YK0F" } }',
        "model = { x0 = [50.0, 0.0] }",
    )
    res = by_model(evaluate(_tracking_run(tmp_path, "still", text, 15)))
    for node in MODEL_NODES:
        s = res[("ir_track", node)]
        assert s["converge_s"] is not None and s["converge_s"] <= 2.0, (node, s)


SHORT_NODE = """
[[nodes]]
name = "ir_short"

  [[nodes.measures]]
  use = "sharp_ir"
  name = "ir_short"
  args = { variant = "GP2Y0A41SK0F" }
"""


@pytest.mark.slow
def test_campaign_the_short_sensors_outliers_are_gated(tmp_path):
    """The block at 24 cm with the short sensor added: its second spike is gated (counted in
    the ``gated`` column and the node status) and the estimate stays within 1 cm."""
    text = replace(
        spec("ir_tracking", {"scenario": "ir_stationary", "distance_cm": 24.0}, SHORT_NODE),
        'ir_long = "GP2Y0A02YK0F" }',
        'ir_long = "GP2Y0A02YK0F", ir_short = "GP2Y0A41SK0F" }',
    )
    res = by_model(evaluate(_tracking_run(tmp_path, "short", text, 25)))
    for node in MODEL_NODES:
        s = res[("ir_track", node)]
        assert s["gated"] >= 150 and s["max_err_cm"] <= 1.0, (node, s)


def _map_run(tmp: Path, name: str, world: dict, maps: int) -> Path:
    c = _start(tmp, name, spec("ir_grid", world))
    try:
        wait_for(
            lambda: _published(c, "mapper", "occupancy_grid") >= maps, maps + 60, f"{maps} maps"
        )
    finally:
        c.stop()
    return c.run_dir


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1])
def test_campaign_cold_plate_60_s(tmp_path, seed):
    """The hot block put down at the start: >= 95 % right at 60 s, the hot block within one
    cell once the heat has arrived (found within a minute)."""
    run = _map_run(tmp_path, "cold", {"scenario": "ir_plate", "seed": seed}, 100)
    res = by_model(evaluate(run))
    for node in MAP_NODES:
        s = res[("occupancy_grid", node)]
        assert s["map60_pct"] >= 95.0 and s["hot_err_cm"] <= 1.0 and s["hot_found_s"] <= 60, s


@pytest.mark.slow
def test_campaign_hidden_hot_block(tmp_path):
    """The seed's ambiguity case live: fused beats IR alone and thermal alone."""
    world = {
        "scenario": "ir_plate",
        "blocks": [
            {"x": 4.0, "y": 7.0, "w": 2.0, "h": 2.0, "hot": True},
            {"x": 2.0, "y": 7.0, "w": 1.0, "h": 2.0},
            {"x": 4.0, "y": 5.0, "w": 2.0, "h": 1.0},
        ],
    }
    res = by_model(evaluate(_map_run(tmp_path, "hidden", world, 140)))
    fused, ir, th = (
        res[(n, "mapper")] for n in ("occupancy_grid", "occupancy_ir", "occupancy_thermal")
    )
    assert fused["map_pct"] >= ir["map_pct"] + 2 > th["map_pct"], (fused, ir, th)
    assert fused["hot_err_cm"] <= 1.0 and ir["hot_err_cm"] is None, (fused, ir)
