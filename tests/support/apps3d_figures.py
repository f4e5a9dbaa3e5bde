"""Print the offline figures of the 3-D applications that the README quotes.

    python tests/support/apps3d_figures.py [ahrs|disturbance|position|noise|imu6dof ...]
                                                  (a few minutes in all)

The very model objects the live measures run, fed the simulated boards' samples in time
order (:mod:`sim3d`), scored against the simulated world's truth: the AHRS over 3 board
seeds x 3 start phases per scenario, e11 beside it, a 10 s magnetic disturbance over 10
seeds (on rotation_fast also without the gyroscope's scale errors estimated), the sonar
tracker and e10 over 5 seeds x 40 s, the tracker at the data sheet's 2.5 cm of noise over
8 seeds beside an oracle that is told which axis moves (``noise``: what the sonars' rate and
noise allow), e13 aided and unaided over 3 seeds x 60 s.
"""

from __future__ import annotations

import math
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
from hera.models.position3d.tracker import RangeTracker  # noqa: E402
from hera.nodes.world import make_scenario  # noqa: E402

SCENARIOS = ("still", "rotation_slow", "rotation_fast", "shaking", "hand", "target3d")

NOISY = {"noise_m": 0.025}
"""The MaxSonar data sheet's "about 2.5 cm", read as white noise (the simulator's default is
1 cm); with the 1-inch rounding (0.73 cm RMS) a reading is off by 2.6 cm RMS."""

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
    r = [run_position(s, sonar_model=NOISY, thesis=True).rmse_cm() for s in range(5)]
    print(f"e10 at 2.5 cm white noise (ours: part `noise`): {min(r):.2f}-{max(r):.2f} cm")
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


def _split_cm(run) -> tuple[float, float]:
    """RMS error (cm) of the axis that moves and of the two that stand still (target3d)."""
    axis = np.floor(run.t / make_scenario({"scenario": "target3d"}).period).astype(int) % 3
    rows = np.arange(len(axis))
    moving = run.err[rows, axis]
    still = np.where(np.arange(3)[None, :] != axis[:, None], run.err, np.nan)
    return 100 * float(np.sqrt(np.mean(moving**2))), 100 * float(np.sqrt(np.nanmean(still**2)))


def _oracle(q_move: float, q_still: float) -> type:
    """A diagnostic, not a model: our tracker with a constant-velocity model whose white
    acceleration noise (m^2/s^3) is ``q_move`` on the axis target3d moves along at that
    time (read from the scenario: the truth) and ``q_still`` on the two others. No causal
    tracker knows this; it bounds what deciding "which way does the target move" can win."""
    period = make_scenario({"scenario": "target3d"}).period

    class Oracle(RangeTracker):
        def _Q(self, dt: float) -> np.ndarray:
            a = np.full(3, q_still)
            a[int(math.floor((self.t or 0.0) / period)) % 3] = q_move
            A = np.diag(a)
            return np.block([[A * dt**3 / 3, A * dt**2 / 2], [A * dt**2 / 2, A * dt]])

    return Oracle


def noise() -> None:
    print("\nposition3d at 2.5 cm white noise + 1 in rounding, seeds 0-7 x 40 s: RMSE (cm);")
    print("split: RMS of the moving axis / of the still axes, worst seed")
    seeds = range(8)
    rows = [("ours, lag 0.2 s (default)", {}, None), ("ours, lag 0.6 s", {"lag": 0.6}, None)]
    for lag in (0.2, 0.4, 0.6):
        for q_still in (1e-8, 1e-4):
            label = f"oracle, q_still {q_still:g}, lag {lag} s"
            rows.append((label, {"lag": lag, "tau_v": 1e3}, _oracle(0.03, q_still)))
    for label, settings, cls in rows:
        runs = [
            run_position(s, sonar_model=NOISY, settings=settings, model_class=cls) for s in seeds
        ]
        rmse = [r.rmse_cm() for r in runs]
        split = max((_split_cm(r) for r in runs), key=lambda m: m[0])
        print(
            f"{label:34s} {' '.join(f'{v:.2f}' for v in rmse)}   max {max(rmse):.2f}"
            f"   split {split[0]:.2f} / {split[1]:.2f}"
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
    parts = sys.argv[1:] or ["ahrs", "disturbance", "position", "noise", "imu6dof"]
    table = {
        "ahrs": ahrs_table,
        "disturbance": disturbance,
        "position": position,
        "noise": noise,
        "imu6dof": imu6dof,
    }
    for p in parts:
        table[p]()
