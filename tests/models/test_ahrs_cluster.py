"""deploy/ahrs.toml as a real cluster on the fast turns (rotation_fast), with a magnetic
disturbance of 10 s switched on the board mid-run (issue 11).

One run of about 25 s is shared by the tests of this module: after 8 s of estimates, a
``field`` fault (0.1 gauss fixed in the world, to the east: the field's heading turns by
26 deg, its norm and dip hardly) is switched on ``nav_1``'s board for 10 s through the
simulator's ``board`` verb. Asserted on both nodes that run the models: our mean attitude
error <= 3 deg outside the disturbance (rotation_fast's target); during it the tilt as
outside and the heading within 5 deg, while the thesis's e11, which has no gate, is
pulled off by the disturbance (reported, not required).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from harness import Cluster, cluster_env, wait_for

from hera.evaluate import load_outputs, run_spec
from hera.models.ahrs.app import attitude_errors, orientation_truth

# CI budget (a 28 s live run on a slow 2-core machine): -m slow runs it; CI keeps the AHRS's
# offline accuracy tests (tests/models/test_ahrs_accuracy.py) and the live 2-D train.
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
NODES = ("computer", "nav_1")
FIELD = [0.1, 0.0, 0.0]
SECONDS = 10.0


@pytest.fixture(scope="module")
def disturbed_run(tmp_path_factory):
    """(run directory, epoch times the disturbance was switched on and went off)."""
    tmp = tmp_path_factory.mktemp("ahrs")
    text = (ROOT / "deploy" / "ahrs.toml").read_text()
    assert 'scenario = "rotation_slow"' in text
    spec = tmp / "ahrs.toml"
    spec.write_text(text.replace('scenario = "rotation_slow"', 'scenario = "rotation_fast"'))
    c = Cluster(spec, tmp / "run", cluster_env(tmp), None)
    try:
        c.connect(timeout=60)

        def published() -> int:
            return c.status("computer")["measures"]["attitude_mekf"]["published"]

        wait_for(lambda: published() > 160, 90, "8 s of attitude estimates")
        request = {"board": "nav_1/nav", "fault": "field", "sensor": "mag"}
        t_on = time.time()
        reply = c.control("nav_1", "board", {**request, "value": FIELD, "duration": SECONDS})
        assert reply["ok"], reply
        t_off = t_on + SECONDS
        start = published()
        wait_for(lambda: published() > start + 20 * (SECONDS + 5), 60, "the fault and 5 s more")
    finally:
        c.stop()
    return c.run_dir, t_on, t_off


def _errors(run: Path, name: str):
    truth = orientation_truth(run_spec(run).world)
    for s in load_outputs(run):
        if s.name == name:
            yield s, attitude_errors(s, truth)


def test_ours_meets_its_target_and_shrugs_off_the_disturbance(disturbed_run):
    run, t_on, t_off = disturbed_run
    seen = 0
    for s, (att, tilt, head) in _errors(run, "attitude_mekf"):
        seen += 1
        t = s.t
        settled = t >= t[0] + 3.0
        during = (t >= t_on + 0.1) & (t < t_off - 0.1)  # the reply may land a step late
        outside = settled & ((t < t_on) | (t >= t_off + 2.0))
        assert during.sum() > 150 and outside.sum() > 120, s.node
        assert att[outside].mean() <= 3.0, (s.node, att[outside].mean())
        assert np.abs(head[during]).max() <= 5.0, (s.node, np.abs(head[during]).max())
        assert tilt[during].mean() <= tilt[outside].mean() + 0.1, s.node
        assert tilt[during].max() <= tilt[outside].max() + 0.1, s.node
        print(  # pytest -s: the README's figures
            f"{s.node}: mean error outside {att[outside].mean():.3f} deg; during the "
            f"disturbance heading max {np.abs(head[during]).max():.2f} deg, tilt mean "
            f"{tilt[during].mean():.3f} (outside {tilt[outside].mean():.3f}) deg"
        )
    assert seen == len(NODES)


def test_the_disturbance_was_real_for_the_thesis_filter(disturbed_run):
    run, t_on, t_off = disturbed_run
    seen = 0
    for s, (_att, _tilt, head) in _errors(run, "attitude_thesis"):
        seen += 1
        during = (s.t >= t_on + 1.0) & (s.t < t_off)
        assert np.abs(head[during]).max() > 10.0, s.node  # e11 follows the false north
    assert seen == len(NODES)
