"""The three 3-D specs ship in the package and pass every check; a bad model setting in a
spec is refused by ``hera up`` before anything starts, naming the measure and the setting."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from hera.examples import examples
from hera.preflight import spec_problems
from hera.spec import load_spec

SPECS = ("position3d", "ahrs", "imu6dof")


@pytest.mark.parametrize("name", SPECS)
def test_the_spec_ships_and_passes_the_checks(name):
    path = examples()[name]  # hera up NAME finds it from any folder
    spec = load_spec(path)
    assert spec_problems(spec) == []
    assert path.read_text().startswith("# ")  # hera examples describes it


BAD = """
[cluster]
name = "bad"

[world]
scenario = "target3d"

[[nodes]]
name = "a"

  [[nodes.measures]]
  use = "position3d"
  args = { model = { sonars = { s1 = { position = [0, 0], direction = [1, 0, 0] } } } }

  [[nodes.measures]]
  use = "position3d_thesis"
  args = { model = { sonars = { s1 = { position = [0, 0, 0], direction = [1, 1, 0] } } } }

  [[nodes.measures]]
  use = "attitude_mekf"
  args = { model = { gyro_noise = -1 } }

  [[nodes.measures]]
  use = "imu6dof"
  args = { model = { q_jerk = "x" } }
"""


def test_bad_model_values_are_refused_before_anything_starts(tmp_path):
    spec = tmp_path / "bad.toml"
    spec.write_text(BAD)
    out = subprocess.run(
        [sys.executable, "-m", "hera", "up", str(spec), "--run-dir", str(tmp_path / "run")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 4, out.stderr
    for line, (measure, words) in zip(
        lines,
        [
            ("position3d", "sonars.s1.position must be 3 finite numbers"),
            ("position3d_thesis", "not along an axis"),
            ("attitude_mekf", "gyro_noise must be a number > 0"),
            ("imu6dof", "q_jerk must be a number > 0, got 'x'"),
        ],
        strict=True,
    ):
        assert f"bad.toml: measure '{measure}' of node 'a': args: model: " in line, line
        assert words in line, line
    assert not Path(tmp_path / "run").exists()  # nothing started
