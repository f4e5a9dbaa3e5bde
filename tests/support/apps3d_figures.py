"""Print the offline figures of the 3-D applications that the README quotes.

    python tests/support/apps3d_figures.py [ahrs|disturbance|position|imu6dof ...]
                                                  (a few minutes in all)

The very model objects the live measures run, fed the simulated boards' samples in time
order (:mod:`sim3d`), scored against the simulated world's truth: the AHRS over 3 board
seeds x 3 start phases per scenario, e11 beside it, a 10 s magnetic disturbance over 10
seeds (on rotation_fast also without the gyroscope's scale errors estimated), the sonar
tracker and e10 over 5 seeds x 40 s, e13 aided and unaided over 3 seeds x 60 s.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))

from sim3d import SONARS, run_ahrs, run_imu6dof, run_position  # noqa: E402

from hera.application import Series  # noqa: E402
from hera.models.ahrs.mekf import MekfSettings  # noqa: E402
from hera.models.imu6dof.app import Imu6dofApp, drift_per  # noqa: E402
from hera.models.imu6dof.measures import Imu6dof  # noqa: E402
from hera.models.position3d.app import POS  # noqa: E402

SCENARIOS = ("still", "rotation_slow", "rotation_fast", "shaking", "hand", "target3d")
FIELDS = {"east 0.1 G": [0.1, 0.0, 0.0], "magnet": [0.0, -0.15, 0.25]}


def ahrs_table() -> None:
    print("AHRS, mean error after 3 s (deg): 3 seeds x 3 start phases, 30 s each")
    print("scenario        ours mean (worst)   tilt / heading   e11 mean (worst)")
    for sc in SCENARIOS:
        runs = [
            run_ahrs(sc, seed, start=start, node="nav_1")
            for seed in range(3)
            for start in (3.0, 8.0, 13.0)
        ]
        thesis = [
            run_ahrs(sc, seed, start=start, node="nav_1", thesis=True).att.mean()
            for seed in range(3)
            for start in (3.0, 8.0, 13.0)
        ]
        means = [r.att.mean() for r in runs]
        tilt = np.mean([r.tilt.mean() for r in runs])
        head = np.mean([np.abs(r.heading).mean() for r in runs])
        print(
            f"{sc:14s}  {np.mean(means):5.2f} ({max(means):4.2f})"
            f"        {tilt:4.2f} / {head:4.2f}      {np.mean(thesis):5.2f} ({max(thesis):5.2f})"
        )


def disturbance() -> None:
    print("\nAHRS, 10 s field fault from 15 s, seeds 0-9: worst |heading| during (deg),")
    print("largest tilt change against the same run without it (deg)")
    on, off = 18.0, 28.0
    runs = [(sc, None) for sc in ("still", "rotation_slow", "rotation_fast", "shaking", "hand")]
    runs.append(("rotation_fast", MekfSettings(scale_std0=0.0)))  # the gyroscope's scale: no
    for sc, settings in runs:
        for label, field in FIELDS.items():
            heads, tilts = [], []
            for seed in range(10):
                events = [
                    (on, lambda b, f=field: b.faults.set("field", sensor="mag", value=f)),
                    (off, lambda b: b.faults.clear()),
                ]
                clean = run_ahrs(sc, seed, 40.0, settings=settings)
                hit = run_ahrs(sc, seed, 40.0, events=events, settings=settings)
                d = (hit.t >= on) & (hit.t < off)
                heads.append(np.abs(hit.heading[d]).max())
                tilts.append(np.abs(hit.tilt[d] - clean.tilt[d]).max())
            name = sc if settings is None else f"{sc} (no scale)"
            print(
                f"{name:24s} {label:11s} heading {' '.join(f'{h:3.1f}' for h in heads)}"
                f"  max {max(heads):.2f}   tilt change <= {max(tilts):.3f}"
            )


def position() -> None:
    print("\nposition3d, RMSE on target3d, seeds 0-4 x 40 s (cm)")
    ours = [run_position(s).rmse_cm() for s in range(5)]
    e10 = [run_position(s, thesis=True).rmse_cm() for s in range(5)]
    print(
        f"ours {np.mean(ours):.2f} (worst {max(ours):.2f})   e10 {np.mean(e10):.2f} "
        f"(worst {max(e10):.2f})"
    )
    noisy = {"noise_m": 0.025}  # the data sheet's 2.5 cm as white noise (default 1 cm)
    for lag in (0.2, 0.6):
        r = [run_position(s, sonar_model=noisy, settings={"lag": lag}).rmse_cm() for s in range(5)]
        print(f"2.5 cm white noise + 1 in rounding, lag {lag} s: {min(r):.2f}-{max(r):.2f} cm")
    r = [run_position(s, sonar_model=noisy, thesis=True).rmse_cm() for s in range(5)]
    print(f"the same noise, e10: {min(r):.2f}-{max(r):.2f} cm")
    sys.path.insert(0, str(Path(__file__).parents[1] / "models"))
    from test_position3d import _tilted

    tilted = [run_position(s, sonars=_tilted()).rmse_cm() for s in range(5)]
    print(f"sonars at arbitrary poses, seeds 0-4: {min(tilted):.2f}-{max(tilted):.2f} cm")
    observed, growth, back = 0.0, np.inf, 0.0
    for i, node in enumerate(SONARS):
        others = [k for k in range(3) if k != i]
        for start in np.arange(18.0, 36.0, 1.5):
            end = start + 1.5
            r = run_position(1, down={node: (start, end)}, duration=45.0)
            gone = (r.t >= start) & (r.t < end)
            before = (r.t >= start - 3.0) & (r.t < start)
            after = (r.t >= end + 2.0) & (r.t < end + 8.0)
            rms = np.sqrt(np.mean(r.err[gone][:, others] ** 2, axis=0))
            observed = max(observed, float(rms.max()))
            growth = min(growth, r.std[gone, i].max() / np.median(r.std[before, i]))
            back = max(back, r.rmse_cm(after))
    print(
        f"a sonar gone 1.5 s (3 sonars x 12 phases): observed axes <= {100 * observed:.2f} cm "
        f"RMS, lost axis's std x{growth:.1f} or more, RMSE from 2 s after <= {back:.2f} cm"
    )


def _drift_m(run) -> float:
    """``hera eval``'s drift per 10 s (m) of an offline run."""
    app = Imu6dofApp()
    series = Series("imu6dof", "nav", POS, run.t, run.est, Imu6dof)
    return drift_per(series, app.truth({"scenario": "target3d", "epoch": 0.0}), 10.0, 0.0)


def imu6dof() -> None:
    print("\nimu6dof, seeds 0-2 x 60 s: RMSE and drift per 10 s, aided (cm), unaided (m)")
    aided = [run_imu6dof(s) for s in range(3)]
    free = [run_imu6dof(s, aiding=False) for s in range(3)]
    rmse = [r.rmse_cm() for r in aided]
    drift = [100 * _drift_m(r) for r in aided]
    free_rmse = [r.rmse_cm() / 100 for r in free]
    free_drift = [_drift_m(r) for r in free]
    print(
        f"aided RMSE {min(rmse):.2f}-{max(rmse):.2f} cm, drift {min(drift):.1f}-{max(drift):.1f}"
        f" cm; unaided RMSE {min(free_rmse):.1f}-{max(free_rmse):.1f} m, drift "
        f"{min(free_drift):.1f}-{max(free_drift):.1f} m"
    )


if __name__ == "__main__":
    parts = sys.argv[1:] or ["ahrs", "disturbance", "position", "imu6dof"]
    for p in parts:
        {"ahrs": ahrs_table, "disturbance": disturbance, "position": position, "imu6dof": imu6dof}[
            p
        ]()
