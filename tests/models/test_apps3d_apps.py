"""The three 3-D applications' scores, plots and live panels on offline runs (what ``hera
eval`` and ``hera up`` ask them), and their truth for any simulated world."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from sim3d import run_ahrs, run_position

from hera.application import Estimate, EvalOptions, Series
from hera.models.ahrs.app import AhrsApp
from hera.models.ahrs.measures import Ahrs
from hera.models.ahrs.model import QUAT
from hera.models.imu6dof.app import Imu6dofApp
from hera.models.imu6dof.measures import Imu6dof
from hera.models.position3d.app import POS, STD, Position3dApp
from hera.models.position3d.measures import Position3d, Position3dThesis

TARGET3D = {"scenario": "target3d", "epoch": 0.0}


def _position_series(measure=Position3d, thesis=False) -> Series:
    r = run_position(0, duration=20.0, thesis=thesis, after=0.0)
    return Series(measure.name, "computer", (*POS, *STD), r.t, np.hstack((r.est, r.std)), measure)


def test_position3d_scores_plots_and_panel(tmp_path):
    app = Position3dApp()
    truth = app.truth(TARGET3D)
    ours, e10 = _position_series(), _position_series(Position3dThesis, thesis=True)
    s = app.score(ours, truth, EvalOptions())
    assert 0.5 < s["pos_rmse_cm"] < 2.0 and s["pos_max_cm"] >= s["pos_rmse_cm"]
    assert 0.1 < s["std_ratio"] < 2.0 and s["axis_rms_cm"] <= s["pos_rmse_cm"]
    assert app.score(e10, truth, EvalOptions())["pos_rmse_cm"] > 3.0
    files = app.plots([ours, e10], truth, tmp_path, EvalOptions())
    assert [f.name for f in files] == ["position.png", "position_error.png"]
    assert all(f.stat().st_size > 10_000 for f in files)
    t = float(ours.t[-1])
    values = dict(zip(ours.columns, ours.values[-1], strict=True))
    est = Estimate("position3d", "computer", t, values, Position3d)
    panel = app.panel([est], truth)
    assert panel.rows[0][0] == "position3d (ours)" and panel.rows[-1][0] == "truth"
    assert float(panel.rows[0][-1]) < 5.0  # cm from the truth
    web = app.web_panel([est], truth)
    assert web.kind == "plane" and json.loads(json.dumps(web.data)) == web.data
    mine, true_point = web.data["points"]
    assert (mine["x"], mine["y"]) == (values[POS[0]], values[POS[1]])
    assert true_point["truth"] is True and true_point["x"] == truth.at(t)[POS[0]]
    assert app.web_panel([est], None).data["points"] == [mine]
    assert app.label("position3d_thesis", Position3dThesis) == "position3d_thesis (e10)"
    assert app.truth({"scenario": "no such world"}) is None
    assert app.score(ours, None, EvalOptions()) == {}


def test_attitude_scores_plots_and_panel(tmp_path):
    app = AhrsApp()
    world = {"scenario": "rotation_slow", "epoch": 0.0}
    truth = app.truth(world)
    r = run_ahrs("rotation_slow", 0, 12.0, after=0.0)
    # estimates at the run's times: the truth turned by a small known error (world frame)
    true = np.array([[truth.at(float(t))[c] for c in QUAT] for t in r.t])
    small = np.array((np.cos(0.005), 0.0, 0.0, np.sin(0.005)))  # 0.57 deg about z
    w1, x1, y1, z1 = true.T
    w2, _, _, z2 = small
    est = np.column_stack(
        (w1 * w2 - z1 * z2, x1 * w2 + y1 * z2, y1 * w2 - x1 * z2, z1 * w2 + w1 * z2)
    )
    series = Series("attitude_mekf", "nav_1", QUAT, r.t, est, Ahrs)
    s = app.score(series, truth, EvalOptions(after=0.0))
    assert abs(s["att_mean_deg"] - 0.573) < 1e-3 and s["tilt_mean_deg"] < 1e-6
    assert abs(s["heading_mean_deg"] - 0.573) < 1e-3
    files = app.plots([series], truth, tmp_path, EvalOptions())
    assert [f.name for f in files] == ["attitude_error.png", "attitude.png"]
    e = Estimate(
        "attitude_mekf", "nav_1", float(r.t[-1]), dict(zip(QUAT, est[-1], strict=True)), Ahrs
    )
    panel = app.panel([e], truth)
    assert panel.rows[0][0] == "attitude_mekf (ours)" and panel.rows[-1][0] == "truth"
    assert panel.rows[0][-1] == "-0.57"  # heading error: the estimate turned 0.57 deg ccw
    web = app.web_panel([e], truth)
    assert web.kind == "attitude" and json.loads(json.dumps(web.data)) == web.data
    ours, true_body = web.data["bodies"]
    assert ours["label"] == "attitude_mekf (ours) nav_1" and true_body["truth"] is True
    assert ours["yaw"] - true_body["yaw"] == pytest.approx(0.01, abs=1e-9)  # 2 x 0.005 rad
    assert ours["roll"] == pytest.approx(true_body["roll"], abs=1e-9)
    assert ours["pitch"] == pytest.approx(true_body["pitch"], abs=1e-9)
    assert app.web_panel([Estimate("other", "n", 1.0, {"x": 1.0})], truth) is None
    # the compass's N is the world's magnetic north (the page drew yaw from +y's place, so
    # a body facing north showed east); +y without a simulated world
    assert web.data["north"] == pytest.approx(math.pi / 2)
    turned = app.truth({**world, "mag_north_deg": 30.0})
    assert app.web_panel([e], turned).data["north"] == pytest.approx(math.radians(30.0))
    assert app.web_panel([e], None).data["north"] == pytest.approx(math.pi / 2)


def test_imu6dof_truth_has_position_and_orientation(tmp_path):
    app = Imu6dofApp()
    truth = app.truth(TARGET3D)
    at = truth.at(3.0)
    assert set(at) == {*POS, *QUAT}
    ours = _position_series(Imu6dof)
    s = app.score(ours, truth, EvalOptions())
    assert s["pos_rmse_cm"] < 2.0 and s["drift_10s_cm"] is not None and "att_mean_deg" not in s
    values = dict(zip(ours.columns, ours.values[-1], strict=True))
    web = app.web_panel([Estimate("imu6dof", "nav_1", 3.0, values, Imu6dof)], truth)
    assert [p["label"] for p in web.data["points"]] == ["imu6dof (e13) nav_1", "truth"]
    files = app.plots([ours], truth, tmp_path, EvalOptions())
    assert all(f.parent.name == "imu6dof" for f in files) and len(files) == 2
