"""The tilt application live on the real I2C driver, its chip's clock off by a few percent.

``python tests/support/tilt_i2c.py [SECONDS] [CLOCK_ERRORS...]`` runs ``deploy/tilt.toml``
(``hera up``, then ``hera eval``) once on the simulator itself and, for each clock error
(a fraction: 0.015 is a chip 1.5 % fast), once with the robot's LSM6DSL read through
:class:`hera.nodes.lsm6dsl.i2c.I2cLsm6dsl` from a chip that plays the same simulator at
register level on its own clock (``fake_i2c.SimChipOnFakeBus``), and once read the naive
way (``fake_i2c.StampedWhenRead``: the newest sample, stamped when read). It prints, per
run, the robot node's scores of the four filters (RMSE, push RMSE and largest error, deg)
and what the published stamps say: the median and spread of the sample interval and the
gaps (intervals over 1.5 periods: samples lost, where the stamps can tell). Runs one
cluster at a time (take
``/tmp/hera-cluster.lock``); the figures are quoted in the README (the LSM6DSL section).
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
ARGS = 'args = { odr_hz = 26.0, calibration = "at_start", calib_samples = 100 }'


def spec_text(driver: str | None, run: Path, clock_error: float) -> str:
    base = (ROOT / "deploy" / "tilt.toml").read_text()
    assert ARGS in base, "deploy/tilt.toml's imu args changed: update this script"
    if driver is None:
        return base
    extra = (
        f'driver = "fake_i2c:{driver}", driver_args = {{ world_file = "{run}/cluster.json", '
        f"clock_error = {clock_error}, odr_hz = 26.0 }}"
    )
    return base.replace(ARGS, ARGS[:-2] + ", " + extra + " }")


def one(tmp: Path, label: str, driver: str | None, clock_error: float, seconds: str) -> str:
    run = tmp / label
    spec = tmp / f"{label}.toml"
    spec.write_text(spec_text(driver, run, clock_error))
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).parent))
    hera = [sys.executable, "-m", "hera"]
    subprocess.run(
        [*hera, "up", str(spec), "--run-dir", str(run), "--duration", seconds],
        env=env,
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        check=True,
    )
    out = subprocess.run(
        [*hera, "eval", str(run), "--json", "--no-plots"],
        env=env,
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    )
    scores = [r for r in json.loads(out.stdout) if r["node"] == "robot"]
    lines = (run / "measures" / "imu_robot.csv").read_text().splitlines()[1:]
    t = [float(line.split(",")[1]) for line in lines if line]  # ms
    steps = [b - a for a, b in zip(t, t[1:], strict=False)]
    q = statistics.quantiles(steps, n=100)
    gaps = sum(s > 1.5 * 1000 / 26 for s in steps)  # lost samples, when stamped well
    filters = " ".join(
        f"{r['model'][5:]} {r['rmse_deg']:.3f}/{r['push_deg']:.3f}/{r['max_deg']:.3f}"
        for r in scores
    )
    return (
        f"{label:>22}  {filters}  interval ms median {statistics.median(steps):.2f} "
        f"p1 {q[0]:.2f} p99 {q[-1]:.2f}, gaps {gaps} in {len(t)}"
    )


def main(argv: list[str]) -> None:
    seconds = argv[0] if argv else "50"
    errors = [float(e) for e in argv[1:]] or [0.015, -0.015]
    print("run                     filter RMSE/push RMSE/max deg (robot node)")
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        print(one(tmp, "simulator", None, 0.0, seconds), flush=True)
        for e in errors:
            for driver in ("SimChipOnFakeBus", "StampedWhenRead"):
                label = f"{'edges' if driver == 'SimChipOnFakeBus' else 'naive'} {e:+.3f}"
                print(one(tmp, label.replace(" ", "_"), driver, e, seconds), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
