"""Multi-seed real-cluster campaigns of the three 3-D specs (slow: ``pytest -m slow``).

Each spec runs as a real cluster (``hera up``) for several board seeds (``[defaults] seed``)
and, for the AHRS, the thesis's benchmark tasks; ``hera eval`` scores the runs against the
simulated world. Targets (issue 11): position RMSE <= 2 cm (ours, position3d.toml); mean
attitude error <= 0.3 / 1 / 3 / 1 deg still / rotation_slow / rotation_fast / shaking
(ahrs.toml); e13's position RMSE <= 5 cm over 60 s (imu6dof.toml). The thesis's models are
scored beside ours; their figures are reported in the README, not required.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from harness import cluster_env

from hera.evaluate import by_model, evaluate

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.slow


def _run(tmp: Path, spec: str, seconds: float, seed: int, scenario: str | None = None) -> dict:
    text = (ROOT / "deploy" / spec).read_text()
    if scenario is not None:
        text = text.replace('scenario = "rotation_slow"', f'scenario = "{scenario}"')
    path = tmp / spec
    path.write_text(f"{text}\n[defaults]\nseed = {seed}\n")
    run = tmp / "run"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "hera",
            "up",
            str(path),
            "--duration",
            str(seconds),
            "--run-dir",
            str(run),
            "--interval",
            "30",
        ],  # fmt: skip
        env=cluster_env(tmp),
        capture_output=True,
        text=True,
        timeout=seconds + 240,
    )
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    return by_model(evaluate(run))


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_position3d_spec(tmp_path, seed):
    res = _run(tmp_path, "position3d.toml", 35, seed)
    for node in ("computer", "sonar_x"):
        print(f"position3d seed {seed} {node}: {res[('position3d', node)]}")  # -s: README
        print(f"e10 seed {seed} {node}: {res[('position3d_thesis', node)]}")
        assert res[("position3d", node)]["pos_rmse_cm"] <= 2.0, res
        assert res[("position3d", node)]["estimates"] > 400


@pytest.mark.parametrize(
    ("scenario", "target"),
    [("still", 0.3), ("rotation_slow", 1.0), ("rotation_fast", 3.0), ("shaking", 1.0)],
)
@pytest.mark.parametrize("seed", [1, 2])
def test_ahrs_spec(tmp_path, scenario, target, seed):
    res = _run(tmp_path, "ahrs.toml", 35, seed, scenario)
    for node in ("computer", "nav_1"):
        ours = res[("attitude_mekf", node)]
        print(f"attitude {scenario} seed {seed} {node}: {ours}")  # -s: README
        assert ours["att_mean_deg"] <= target, (scenario, ours)
        assert ours["estimates"] > 400


@pytest.mark.parametrize("seed", [1, 2])
def test_imu6dof_spec(tmp_path, seed):
    res = _run(tmp_path, "imu6dof.toml", 70, seed)
    for node in ("computer", "nav_1"):
        e13 = res[("imu6dof", node)]
        print(f"imu6dof seed {seed} {node}: {e13}; unaided {res[('imu6dof_inertial', node)]}")
        assert e13["pos_rmse_cm"] <= 5.0, e13
        assert res[("imu6dof_inertial", node)]["drift_10s_cm"] > 10 * e13["drift_10s_cm"]
