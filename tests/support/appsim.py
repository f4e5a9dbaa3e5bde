"""Offline runs of the seed-001/003 applications: the simulated boards read on a fake clock,
their samples fed in time order to the very model objects the fusion measures run, scored by
the applications. Many seeds and worlds in seconds, no cluster.

``python tests/support/appsim.py tof|tilt|drift [SEEDS]`` prints the multi-seed tables quoted
in the README.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hera.application import EvalOptions, Series
from hera.store import Sample

SENSORS = ("left", "centre", "right")
MOUNTS = {"left": (-0.03, -0.02), "centre": (0.0, 0.0), "right": (0.03, -0.02)}


@dataclass
class Fault:
    """Switch ``kind`` on the board of ``sensor`` at ``at`` s after the epoch."""

    sensor: str
    at: float
    kind: str = "stuck"
    params: Mapping[str, Any] | None = None


def sample_of(name: str, node: str, seq: int, t: float, values: Sequence[float]) -> Sample:
    return Sample(name, node, seq, t, 0.0, 0.0, tuple(float(v) for v in values))


def tof_boards(
    world: Mapping[str, Any], seed: int = 1, model: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """The three simulated sensors of :func:`tof_samples` (by sensor name), on a clock that
    stays at 0 until set through ``board.clock_cell[0]``."""
    from hera.nodes.noise import stable_seed
    from hera.nodes.tof.model import TofModel
    from hera.nodes.tof.sim import SimVl53l1
    from hera.nodes.world import make_scenario

    scenario = make_scenario(world)
    cell = [0.0]
    out = {}
    for s in SENSORS:
        out[s] = SimVl53l1(
            f"tof_{s}/tof",
            scenario,
            0.0,
            TofModel.from_args(model),
            MOUNTS[s],
            stable_seed("vl53l1", f"tof_{s}", "tof", seed),
            clock=lambda: cell[0],
        )
        out[s].clock_cell = cell
    return out


def tof_samples(
    world: Mapping[str, Any],
    duration: float,
    seed: int = 1,
    faults: Sequence[Fault] = (),
    model: Mapping[str, Any] | None = None,
    phases: Mapping[str, float] | None = None,
) -> list[tuple[float, Sample]]:
    """(time available to a fusion node, sample) of three ``vl53l1`` sensors on nodes
    ``tof_<sensor>`` at 10 Hz, in availability order; each sensor's phase (s) from
    ``phases``, random without it."""
    boards = tof_boards(world, seed, model)
    clock = boards[SENSORS[0]].clock_cell
    rng = np.random.default_rng(seed)
    phase = {s: float(rng.uniform(0.0, 0.1)) for s in SENSORS}
    phase.update(phases or {})
    events = sorted(faults, key=lambda f: f.at)
    out = []
    for s in SENSORS:
        seq, t = 0, phase[s] + 0.3
        while t < duration:
            clock[0] = t
            for f in events:
                if f.sensor == s and f.at <= t and not getattr(f, f"_on_{s}", False):
                    boards[s].faults.set(f.kind, **dict(f.params or {}))
                    setattr(f, f"_on_{s}", True)
            try:
                r = boards[s].read_ranging()
            except OSError:
                t += 0.1
                continue
            seq += 1
            sample = sample_of("vl53l1", f"tof_{s}", seq, r.t, (*r.values(), *MOUNTS[s]))
            out.append((t + 0.002, sample))  # published when read, then the transit
            t += 0.1 + float(rng.normal(0.0, 0.0005))
    out.sort(key=lambda x: (x[0], x[1].node))
    return out


def run_model(
    model: Any,
    feed: Sequence[tuple[float, Sample]],
    forecast_hz: float | None = 100.0,
    duration: float | None = None,
) -> Series:
    """Feed ``model`` in availability order; the output series is the model's forecast at
    each step of ``forecast_hz`` (as a forecasting measure publishes) or, without it, the
    estimate after each changed step."""
    ts, rows = [], []
    if forecast_hz is None:
        for _, s in feed:
            if model.process(s):
                est = model.estimate()
                if est is not None:
                    ts.append(est[0])
                    rows.append(est[1])
    else:
        end = duration if duration is not None else feed[-1][0]
        step, i = 1.0 / forecast_hz, 0
        for k in range(int(end / step)):
            now = k * step
            while i < len(feed) and feed[i][0] <= now:
                model.process(feed[i][1])
                i += 1
            est = model.forecast(now)
            if est is not None and (not ts or est[0] > ts[-1]):
                ts.append(est[0])
                rows.append(est[1])
    return Series("model", "sim", tuple(model.columns), ts, rows)


def tof_scores(
    kinds: Sequence[str],
    world: Mapping[str, Any],
    duration: float,
    seed: int,
    faults: Sequence[Fault] = (),
    settings: Mapping[str, Mapping[str, Any]] | None = None,
    board: Mapping[str, Any] | None = None,
    after: float = 1.0,
) -> dict[str, dict[str, float | None]]:
    """The ToF app's scores of each kind over one offline run."""
    from hera.models.tof.app import desk_truth, score_height
    from hera.models.tof.height import TofHeight

    feed = tof_samples(world, duration, seed, faults, board)
    truth = desk_truth(world)
    out = {}
    for kind in kinds:
        model = TofHeight(kind=kind, **dict((settings or {}).get(kind, {})))
        series = run_model(model, feed, duration=duration)
        out[kind] = score_height(series, truth, EvalOptions(after=after))
        out[kind]["counters"] = model.counters()  # type: ignore[assignment]
        out[kind]["series"] = series  # type: ignore[assignment]
    return out


def imu_samples(
    world: Mapping[str, Any],
    duration: float,
    seed: int = 1,
    odr: float = 26.0,
    model: Mapping[str, Any] | None = None,
    calibrate_at: float | None = 0.0,
    calib: Callable[..., Any] | None = None,
) -> tuple[list[Sample], Any]:
    """The samples an ``lsm6dsl`` measure publishes (its calibration included: from
    ``calibrate_at`` s, 100 still samples) and the board."""
    from hera.nodes.lsm6dsl.calibration import GyroCalibration
    from hera.nodes.lsm6dsl.model import ImuModel
    from hera.nodes.lsm6dsl.sim import SimLsm6dsl
    from hera.nodes.noise import stable_seed
    from hera.nodes.world import G, make_scenario

    clock = [0.0]
    board = SimLsm6dsl(
        "robot/imu",
        make_scenario(world),
        0.0,
        ImuModel.from_args(model),
        stable_seed("lsm6dsl", "robot", "imu", seed),
        odr_hz=odr,
        clock=lambda: clock[0],
    )
    out = []
    cal = None
    bias, state = 0.0, 0.0
    t, seq = 0.5 + (seed % 7) * 0.003, 0
    while t < duration:
        clock[0] = t
        r = board.read_imu()
        if calibrate_at is not None and cal is None and t >= calibrate_at and state == 0.0:
            cal = GyroCalibration(100)
            state = 1.0
        if cal is not None and cal.feed(r.acc, r.gyro):
            bias, state, cal = math.radians(cal.result[1]), 2.0, None
        seq += 1
        out.append(
            sample_of(
                "imu",
                "robot",
                seq,
                r.t,
                (-r.acc[0] * G, r.acc[2] * G, math.radians(r.gyro[1]), bias, state),
            )
        )
        t += 1.0 / odr
    return out, board


def wheel_samples(
    world: Mapping[str, Any],
    duration: float,
    seed: int = 1,
    rate: float = 26.0,
    wheels: Mapping[str, Any] | None = None,
    fault: tuple[float, str] | None = None,
) -> list[Sample]:
    """The samples a ``wheel_encoder`` measure publishes ([x_wheel (m), balancing]) at
    ``rate`` Hz, on a schedule of its own (another phase than :func:`imu_samples`');
    ``wheels``: keyword arguments of the simulated board; ``fault``: (from when, kind) a
    board fault (no sample while a read fails)."""
    from hera.nodes.driver import BoardDisconnected, NoReading
    from hera.nodes.noise import stable_seed
    from hera.nodes.wheels.sim import SimWheels
    from hera.nodes.world import make_scenario

    clock = [0.0]
    board = SimWheels(
        "robot/wheels",
        make_scenario(world),
        0.0,
        stable_seed("wheels", "robot", "wheels", seed),
        clock=lambda: clock[0],
        **(wheels or {}),
    )
    out = []
    t, seq = 0.5 + 0.011 + (seed % 5) * 0.005, 0
    while t < duration:
        clock[0] = t
        if fault is not None and t >= fault[0] and board.faults.current() is None:
            board.faults.set(fault[1])
        t += 1.0 / rate
        try:
            r = board.read_wheels()
        except (NoReading, BoardDisconnected):
            continue
        seq += 1
        x = r.counts / board.counts_per_m
        out.append(sample_of("wheels", "robot", seq, r.t, (x, 1.0 if r.balancing else 0.0)))
    return out


def robot_samples(
    world: Mapping[str, Any],
    duration: float,
    seed: int = 1,
    model: Mapping[str, Any] | None = None,
    wheels: Mapping[str, Any] | None = None,
    fault: tuple[float, str] | None = None,
) -> tuple[list[Sample], Any]:
    """The balancing robot's two measures, IMU and wheels (``fault`` on the wheels: see
    :func:`wheel_samples`), in time order, and the IMU."""
    imu, board = imu_samples(world, duration, seed, model=model)
    both = imu + wheel_samples(world, duration, seed, wheels=wheels, fault=fault)
    return sorted(both, key=lambda s: s.t), board


WHEEL_RIGS: dict[str, tuple[dict[str, Any], dict[str, Any]]] = {
    # (world keys, wheel board keys): rigs the wheels filter's model does not describe exactly
    # the wheels' reaction torque (a heavy pair: the board reads a third of the slow tilt)
    "reaction": ({"reaction_k": 0.5, "wheel_radius_m": 0.04}, {}),
    # the robot's pendulum 25 % shorter and 50 % longer than the filter's 0.12 m
    "short": ({"pendulum_m": 0.09}, {}),
    "long": ({"pendulum_m": 0.18}, {}),
    # wheels 3 % (sigma) off their nominal size
    "scale": ({}, {"scale_error_sigma": 0.03}),
    # back on its stand for 10 s mid-run, then up again
    "parked": ({"parked": [[30.0, 40.0]]}, {}),
    # pushes 50 % larger
    "pushes": ({"push_deg": 30.0}, {}),
}


def with_true_bias(samples: Sequence[Sample], board: Any) -> list[Sample]:
    """``samples`` with the board's true gyroscope bias (rad/s) in place of the calibrated
    one: what a calibrated-only filter would do if it knew the bias exactly at every sample
    (the floor the accelerometer alone leaves)."""
    out = []
    for s in samples:
        if s.name != "imu":
            out.append(s)
            continue
        v = list(s.values)
        v[3] = math.radians(board.bias(s.t)[1])
        out.append(dataclasses.replace(s, values=tuple(v)))
    return out


def main(argv: Sequence[str]) -> int:
    """``tof N``, ``stuck N``, ``draws N [WORLD_SEED [SECONDS]] [staggered]``, ``tilt N``,
    ``drift N``, ``rigs N``, ``pushes N [WORLD_SEED]``: the offline tables of the README."""
    from hera.models.tof.app import desk_truth, score_height
    from hera.models.tof.height import TofHeight

    what = argv[0] if argv else "tof"
    seeds = range(int(argv[1]) if len(argv) > 1 else 5)
    if what == "tof":
        kinds = ("cv", "ca", "fused", "plane")
        head = ("seed", "kind", "rmse", "still", "settle", "fast", "lag", "max", "tilt")
        print(" ".join(f"{h:>7}" for h in head))
        for seed in seeds:
            res = tof_scores(kinds, {"scenario": "desk", "seed": seed}, 75.0, seed)
            for k in kinds:
                r = res[k]
                cells = [r[x] for x in ("rmse_mm", "still_mm", "settle_mm", "fast_mm", "lag_ms")]
                cells += [r["max_mm"], r.get("tilt_deg") or float("nan")]
                print(f"{seed:>7} {k:>7} " + " ".join(f"{c:7.2f}" for c in cells))
    elif what == "draws":
        # one world, many noise draws: the spread a single live run samples from
        world = {"scenario": "desk", "seed": int(argv[2]) if len(argv) > 2 else 0}
        seconds = float(argv[3]) if len(argv) > 3 else 60.0
        phases = {"left": 0.0, "centre": 0.0333, "right": 0.0667} if "staggered" in argv else None
        still, rmse = [], []
        for draw in seeds:
            feed = [
                x for x in tof_samples(world, seconds, 100 + draw, phases=phases) if x[0] >= 2.0
            ]
            s = run_model(TofHeight(kind="plane"), feed, duration=seconds)
            s = Series(s.name, s.node, s.columns, s.t[s.t >= 2.0], s.values[s.t >= 2.0])
            r = score_height(s, desk_truth(world), EvalOptions(after=1.0))
            still.append(r["still_mm"])
            rmse.append(r["rmse_mm"])
        for name, v, target in (("still", still, 1.5), ("rmse", rmse, 4.0)):
            print(
                f"{name:>5} mm over {len(v)} draws: mean {np.mean(v):.2f} p90 "
                f"{np.percentile(v, 90):.2f} worst {np.max(v):.2f}, "
                f"over {target}: {sum(x > target for x in v)}"
            )
    elif what == "stuck":
        for seed in seeds:
            for sensor, kind in (("left", "stuck"), ("centre", "stuck"), ("right", "dropout")):
                world = {"scenario": "desk", "seed": seed}
                feed = tof_samples(world, 75.0, seed, [Fault(sensor, 20.0, kind)])
                s = run_model(TofHeight(kind="plane"), feed, duration=75.0)
                bit = {"left": 1, "centre": 2, "right": 4}[sensor]
                mask = s.column("faulty [mask]").astype(int)
                hit = np.nonzero((s.t >= 20.0) & (mask & bit > 0))[0]
                keep = s.t >= 20.0
                late = Series("m", "n", s.columns, s.t[keep], s.values[keep])
                r = score_height(late, desk_truth(world), EvalOptions(after=0.0))
                print(
                    f"seed {seed} {sensor:>6} {kind:>7}: reported after "
                    f"{s.t[hit[0]] - 20.0:.2f} s, RMSE after {r['rmse_mm']:.2f} mm"
                )
    elif what == "pushes":
        # many boards (biases, scales, noise) of one world: the tilt test's 42 s window
        from hera.models.tilt.app import robot_truth, score_tilt
        from hera.models.tilt.tilt import Tilt2D

        world = {"scenario": "balancing", "seed": int(argv[2]) if len(argv) > 2 else 0}
        got: dict[str, list[float]] = {k: [] for k in ("split", "ekf", "ukf", "bias")}
        for board in seeds:
            samples, _ = imu_samples(world, 42.0, 100 + board)
            feed = [(x.t, x) for x in samples]
            for kind, v in got.items():
                r = score_tilt(
                    run_model(Tilt2D(kind=kind), feed, None), robot_truth(world), EvalOptions()
                )
                v.append(r["push_deg"])
        for kind, v in got.items():
            print(
                f"{kind:>5} push RMSE deg over {len(v)} boards: mean {np.mean(v):.3f} p90 "
                f"{np.percentile(v, 90):.3f} worst {np.max(v):.3f}, "
                f"over 0.5: {sum(x > 0.5 for x in v)}"
            )
    elif what == "rigs":
        # the wheels filter, with the drift, on rigs its model does not describe exactly
        from hera.models.tilt.app import robot_truth, score_tilt
        from hera.models.tilt.tilt import Tilt2D

        drift = {"gyro_ramp_dps_s": 0.5 / 60.0, "ramp_start_s": 12.0, "ramp_s": 60.0}
        for rig, (extra, wheels) in WHEEL_RIGS.items():
            worst = []
            for seed in seeds:
                world = {"scenario": "balancing", **extra, "seed": seed}
                samples, _ = robot_samples(world, 80.0, seed, model=drift, wheels=wheels)
                r = score_tilt(
                    run_model(Tilt2D(kind="wheels"), [(x.t, x) for x in samples], None),
                    robot_truth(world),
                    EvalOptions(after=0.0),
                )
                worst.append(r["max_deg"])
            print(f"{rig:>9}: max error {min(worst):.2f}-{max(worst):.2f} deg over {len(worst)}")
    elif what in ("tilt", "drift"):
        from hera.models.tilt.app import robot_truth, score_tilt
        from hera.models.tilt.tilt import Tilt2D

        drift = {"gyro_ramp_dps_s": 0.5 / 60.0, "ramp_start_s": 12.0, "ramp_s": 60.0}
        keys = ("converge_s", "still_deg", "rmse_deg", "push_deg", "max_deg", "final_deg")
        print(f"{'seed':>4} {'filter':>6} " + " ".join(f"{k:>10}" for k in keys))
        for seed in seeds:
            world = {"scenario": "balancing", "seed": seed}
            samples, board = robot_samples(
                world,
                80.0 if what == "drift" else 60.0,
                seed,
                model=drift if what == "drift" else None,
            )
            stream = [(x.t, x) for x in samples]
            # true_b: the EKF told the true bias at every sample (not a filter one can run)
            oracle = [(x.t, x) for x in with_true_bias(samples, board)]
            for label, kind, feed in (
                ("split", "split", stream),
                ("ekf", "ekf", stream),
                ("ukf", "ukf", stream),
                ("bias", "bias", stream),
                ("wheels", "wheels", stream),
                ("true_b", "ekf", oracle),
            ):
                after = 0.0 if what == "drift" else 3.0
                r = score_tilt(
                    run_model(Tilt2D(kind=kind), feed, None),
                    robot_truth(world),
                    EvalOptions(after=after),
                )
                print(f"{seed:>4} {label:>6} " + " ".join(f"{r[k]:10.3f}" for k in keys))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
