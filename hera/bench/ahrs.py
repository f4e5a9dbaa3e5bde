"""``hera bench ahrs``: time per sample and attitude error of our AHRS, the thesis's (e11), and
the ``ahrs`` package's EKF and Madgwick filter, on the same data, in the same run.

Data (both seeded):

- ``ahrs.Sensors``: the ``ahrs`` package's own synthetic 9-axis data (random orientations,
  gyroscope noise and bias, accelerometer, magnetometer in nT), 100 Hz;
- ``rotation_fast``: Hera's simulated Pmod NAV (``nav3`` calibrated ``full``) on the
  thesis's fast 360 deg turn (2 s a turn, 2 s still between turns), 100 Hz with the live
  schedule's jitter; the world's magnetic north along +x (the frame every filter here
  assumes).

Every filter starts from the attitude the first sample's accelerometer and magnetometer
give (ours from its own 1 s alignment, started on the same samples), is given each
sample's own dt, and is told the reference vectors of the data (gravity along +z, the
magnetic field). The ``ahrs`` EKF runs twice, with its default noises and with the data's
(the sensors' noise figures), and the better of the two is the one compared. On
``rotation_fast`` ours runs with its defaults, which describe the Pmod NAV; on
``ahrs.Sensors`` it is told that data's figures as the EKF is: the noise per gyroscope
axis, no scale error, rates that are means over each interval (the data are made by
differencing orientations), no linear acceleration or disturbance (so the magnetometer is
fused as a vector, with the reference field's dip). The errors are the angle of
``q_est^-1 q_true`` over the samples from 2 s on. The time of each sample's update is
measured with ``time.perf_counter_ns``; the filters take turns in runs of ``CHUNK``
samples and the speed ratio is the median over the turns of (their run's median / ours),
with the garbage collector paused, so a change of load on the machine hits every filter
of a turn alike. Targets: ours at least ``TARGET`` times faster than the ``ahrs`` EKF, with
a mean error no worse.

``--cpu SECONDS`` measures instead the live CPU of each AHRS at 100 Hz: the ``computer``
node of a real two-node cluster fed ``nav3`` at 100 Hz, with the model and without, on
each estimation backend.
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hera import cliargs
from hera.bench.machine import cpu_seconds
from hera.launcher import node_command

TARGET = 10.0
CHUNK = 100
SETTLE_S = 2.0
INSTALL_HINT = "pip install 'hera-fusion[bench]'"


@dataclass
class Dataset:
    """Samples (rows) of one data set: times (s), gyroscope (rad/s), accelerometer
    (m/s^2), magnetometer (any unit), the true quaternions (body -> reference), the
    reference's gravity direction (what the accelerometer reads at identity) and magnetic
    field, the sensors' noise figures (``gyro_sd`` rad/s per axis, ``acc_sd`` m/s^2,
    ``mag_rel`` relative, ``gravity`` m/s^2), and whether ours is told them (else it runs
    with its defaults, which describe the Pmod NAV)."""

    name: str
    t: np.ndarray
    gyr: np.ndarray
    acc: np.ndarray
    mag: np.ndarray
    q_true: np.ndarray
    up: np.ndarray
    field: np.ndarray
    noise: dict[str, Any]
    ours_told: bool = True


def sensors_data(seed: int, n: int) -> Dataset:
    """``n`` samples of ``ahrs.Sensors`` at 100 Hz, seeded."""
    from ahrs import Sensors

    s = Sensors(num_samples=n, freq=100.0, rng=np.random.default_rng(seed))
    g = np.asarray(s.reference_gravitational_vector, dtype=np.float64)
    m = np.asarray(s.reference_magnetic_vector, dtype=np.float64)
    gyr_sd = np.atleast_1d(np.asarray(s.gyr_noise, dtype=np.float64)) * math.pi / 180.0
    return Dataset(
        f"ahrs.Sensors (seed {seed}, {n} samples)",
        np.arange(n) / 100.0,
        np.asarray(s.gyroscopes, dtype=np.float64),
        np.asarray(s.accelerometers, dtype=np.float64),
        np.asarray(s.magnetometers, dtype=np.float64),
        np.asarray(s.quaternions.array if hasattr(s.quaternions, "array") else s.quaternions),
        g / np.linalg.norm(g),
        m,
        {
            "gyro_sd": tuple(float(x) for x in np.broadcast_to(gyr_sd, 3)),  # rad/s per axis
            "acc_sd": float(s.acc_noise),
            "mag_rel": float(s.mag_noise) / float(np.linalg.norm(m)),
            "gravity": float(np.linalg.norm(g)),
        },
    )


def rotation_fast_data(seed: int, seconds: float) -> Dataset:
    """``seconds`` of Hera's simulated ``nav3`` on ``rotation_fast``, seeded."""
    from hera.nodes.imu_model import NavModel
    from hera.nodes.streams import nav3_stream
    from hera.nodes.world import G, environment, make_scenario, state_at

    world = {"scenario": "rotation_fast", "epoch": 0.0, "mag_north_deg": 0.0}
    stream = nav3_stream(world, seconds, seed=seed)
    sc = make_scenario(world)
    v = np.array([s.values for s in stream.samples])
    t = np.array([s.t for s in stream.samples])
    field = np.array(environment(world).field)
    nav = NavModel()  # the simulator's noise figures, for the ahrs EKF
    return Dataset(
        f"rotation_fast (Hera's Pmod NAV, seed {seed}, {len(t)} samples)",
        t,
        v[:, 3:6],
        v[:, 0:3],
        v[:, 6:9],
        np.array([state_at(sc, 0.0, x).orientation for x in t]),
        np.array((0.0, 0.0, 1.0)),
        field,
        {
            "gyro_sd": (math.radians(nav.gyro_noise),) * 3,
            "acc_sd": nav.acc_noise * G,
            "mag_rel": nav.mag_noise / float(np.linalg.norm(field)),
            "gravity": G,
        },
        ours_told=False,
    )


Step = Callable[[int], None]


def _ours(d: Dataset) -> tuple[Step, Callable[[], np.ndarray]]:
    from hera.models.ahrs.frames import Reference
    from hera.models.ahrs.mekf import Mekf, MekfSettings

    kw: dict[str, Any] = {}
    if d.ours_told:
        dt = float(np.median(np.diff(d.t)))
        up, m = d.up, d.field / np.linalg.norm(d.field)
        mh = float(np.linalg.norm(m - (m @ up) * up))
        kw = {
            "gyro_noise": tuple(sd * math.sqrt(dt) for sd in d.noise["gyro_sd"]),
            "gyro_scale": 0.0,  # the data has no scale error
            "acc_block": 0.0,  # nor linear acceleration: no block means (README)
            "acc_noise": d.noise["acc_sd"],
            "mag_noise": d.noise["mag_rel"],
            "gravity": d.noise["gravity"],
            "gyro_trapezoid": False,  # the data's rate is the mean over the interval
            "mag_mode": "vector",  # no disturbance, the reference field known:
            "dip_deg": math.degrees(math.atan2(-float(m @ up), mh)),  # as the ahrs EKF has
        }
    f = Mekf(Reference.of(d.up, d.field), MekfSettings(**kw))
    t, gyr, acc, mag = d.t.tolist(), d.gyr.tolist(), d.acc.tolist(), d.mag.tolist()

    def step(k: int) -> None:
        f.step(t[k], acc[k], gyr[k], mag[k])

    return step, lambda: f.q.copy()


def _thesis(d: Dataset) -> tuple[Step, Callable[[], np.ndarray]]:
    from hera.models.ahrs.frames import Reference
    from hera.models.ahrs.thesis import ThesisAhrs

    f = ThesisAhrs(Reference.of(d.up, d.field))
    t, gyr, acc, mag = d.t.tolist(), d.gyr.tolist(), d.acc.tolist(), d.mag.tolist()

    def step(k: int) -> None:
        f.step(t[k], acc[k], gyr[k], mag[k])

    return step, lambda: f.q.copy()


def _start_q(d: Dataset) -> np.ndarray:
    from hera.models.ahrs.frames import Reference, triad_quat

    q = triad_quat(d.acc[0], d.mag[0], Reference.of(d.up, d.field))
    return np.array((1.0, 0.0, 0.0, 0.0)) if q is None else q


def _ahrs_ekf(d: Dataset, data_noise: bool) -> tuple[Step, Callable[[], np.ndarray]]:
    from ahrs.filters import EKF

    kw = {}
    if data_noise:
        kw["noises"] = [
            float(np.mean(np.square(d.noise["gyro_sd"]))),
            (d.noise["acc_sd"] / d.noise["gravity"]) ** 2,
            d.noise["mag_rel"] ** 2,
        ]
    # mag given (and no gyr/acc: nothing computed in batch) tells its update to use it
    f = EKF(mag=d.mag, frequency=100.0, frame="NED", magnetic_ref=np.array(d.field), **kw)
    state = {"q": _start_q(d)}
    t, gyr, acc, mag = d.t, d.gyr, d.acc, d.mag

    def step(k: int) -> None:
        if k:
            state["q"] = f.update(state["q"], gyr[k], acc[k], mag[k], dt=t[k] - t[k - 1])

    return step, lambda: np.array(state["q"], dtype=float)


def _madgwick(d: Dataset) -> tuple[Step, Callable[[], np.ndarray]]:
    from ahrs.filters import Madgwick

    f = Madgwick(frequency=100.0)
    state = {"q": _start_q(d)}
    t, gyr, acc, mag = d.t, d.gyr, d.acc, d.mag

    def step(k: int) -> None:
        if k:
            state["q"] = f.updateMARG(state["q"], gyr[k], acc[k], mag[k], dt=t[k] - t[k - 1])

    return step, lambda: np.array(state["q"], dtype=float)


FILTERS: dict[str, Callable[[Dataset], tuple[Step, Callable[[], np.ndarray]]]] = {
    "ours (multiplicative EKF)": _ours,
    "thesis e11 (quaternion KF)": _thesis,
    "ahrs EKF (default noises)": lambda d: _ahrs_ekf(d, False),
    "ahrs EKF (data's noises)": lambda d: _ahrs_ekf(d, True),
    "ahrs Madgwick": _madgwick,
}
OURS = "ours (multiplicative EKF)"
EKFS = ("ahrs EKF (default noises)", "ahrs EKF (data's noises)")


def measure(d: Dataset) -> list[dict]:
    """Run every filter over ``d`` taking turns in runs of ``CHUNK`` samples; rows with the
    median time per sample (us), the speed ratio to ours and the errors (deg)."""
    from hera.models.ahrs.scoring import attitude_error_deg

    made = {name: make(d) for name, make in FILTERS.items()}
    n = len(d.t)
    times: dict[str, list[int]] = {name: [] for name in made}
    ratios: dict[str, list[float]] = {name: [] for name in made}
    quats: dict[str, list[np.ndarray]] = {name: [] for name in made}
    clock, median = time.perf_counter_ns, statistics.median
    gc_was_on = gc.isenabled()
    gc.disable()
    try:
        for lo in range(0, n, CHUNK):
            run_medians = {}
            for name, (step, q) in made.items():
                run = []
                for k in range(lo, min(n, lo + CHUNK)):
                    t0 = clock()
                    step(k)
                    run.append(clock() - t0)
                    quats[name].append(q())
                times[name] += run
                run_medians[name] = median(run)
            for name in made:
                ratios[name].append(run_medians[name] / max(run_medians[OURS], 1))
    finally:
        if gc_was_on:
            gc.enable()
    late = d.t - d.t[0] >= SETTLE_S
    rows = []
    for name in made:
        err = attitude_error_deg(np.array(quats[name])[late], d.q_true[late])
        rows.append(
            {
                "filter": name,
                "us": median(times[name]) / 1000.0,
                "ratio": median(ratios[name]),
                "mean_deg": float(np.mean(err)),
                "max_deg": float(np.max(err)),
            }
        )
    return rows


def verdict(rows: list[dict]) -> tuple[bool, bool, dict]:
    """(speed met, accuracy met, the ``ahrs`` EKF row compared: the better of the two)."""
    by = {r["filter"]: r for r in rows}
    ekf = min((by[n] for n in EKFS), key=lambda r: r["mean_deg"])
    ours = by[OURS]
    return ekf["ratio"] >= TARGET, ours["mean_deg"] <= ekf["mean_deg"], ekf


def format_table(rows: list[dict]) -> str:
    lines = [
        f"{'filter':<28} {'us/sample':>10} {'x ours':>8} {'mean deg':>9} {'max deg':>8}",
        "-" * 67,
    ]
    for r in rows:
        lines.append(
            f"{r['filter']:<28} {r['us']:>10.1f} {r['ratio']:>8.1f} {r['mean_deg']:>9.3f} "
            f"{r['max_deg']:>8.2f}"
        )
    return "\n".join(lines)


CPU_SPEC = """
[cluster]
name = "ahrscpu{tag}"
estimation_backend = "{backend}"

[world]
scenario = "rotation_slow"

[[nodes]]
name = "nav_1"

  [[nodes.measures]]
  use = "nav3"
  period = 0.01
  args = {{ calibration = "full" }}

[[nodes]]
name = "computer"
{model}
"""
CPU_MODEL = """
  [[nodes.measures]]
  use = "{use}"
  period = 0.05
  args = {{ mode = "arrival" }}
"""


def node_cpu(backend: str, use: str | None, seconds: float, settle: float = 12.0) -> float:
    """CPU (% of one core) of the node ``computer`` of a two-node cluster (``nav_1``
    publishing ``nav3`` at 100 Hz, on ``rotation_slow``) running measure ``use`` (or
    nothing) on the estimation ``backend``, over ``seconds`` after ``settle`` s (start,
    calibration, kernels loaded)."""
    with tempfile.TemporaryDirectory() as tmp:
        spec = Path(tmp) / "cpu.toml"
        model = CPU_MODEL.format(use=use) if use else ""
        spec.write_text(CPU_SPEC.format(tag=os.getpid(), backend=backend, model=model))
        run = Path(tmp) / "run"
        cmd = node_command("up", str(spec), "--run-dir", str(run))
        log = Path(tmp) / "up.log"
        with log.open("wb") as out:
            proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=out)
        try:
            # a fresh install compiles its numba kernels on the first `hera up` (20-50 s,
            # more on a busy machine) before any node starts
            deadline = time.monotonic() + 240.0
            pid = None
            while pid is None:
                if time.monotonic() > deadline or proc.poll() is not None:
                    tail = log.read_text(errors="replace").strip().splitlines()[-5:]
                    why = " | ".join(tail) or "no output"
                    raise RuntimeError(f"the cluster of {spec} did not start: {why}")
                try:
                    state = json.loads((run / "launcher.json").read_text())
                    pid = state["nodes"]["computer"]["pid"]
                except (OSError, ValueError, KeyError, TypeError):
                    time.sleep(0.2)
            time.sleep(settle)
            c0, t0 = cpu_seconds(pid), time.monotonic()
            time.sleep(seconds)
            return 100.0 * (cpu_seconds(pid) - c0) / (time.monotonic() - t0)
        finally:
            proc.terminate()
            proc.wait(30)


def warm_kernels() -> bool:
    """Compile (or load) the estimation kernels and our AHRS's in this process, into the
    caches the nodes load from: on a fresh install the first node would compile them
    (20-50 s) inside the measured window. False when numba is not installed."""
    from hera.estimation import backend

    try:
        backend.set_backend("numba")
    except ImportError:
        return False
    backend.warmup()
    from hera.models.ahrs.kernels_numba import compiled

    compiled()
    return True


def cpu_table(seconds: float) -> str:
    """The node CPU with each AHRS at 100 Hz less the node's CPU without, per backend (numba
    only where it is installed)."""
    head = ("backend", "node alone %", "ours %", "+ours", "e11 %", "+e11")
    lines = [f"{head[0]:<8} {head[1]:>13} {head[2]:>8} {head[3]:>7} {head[4]:>7} {head[5]:>7}"]
    for backend in ("numba", "numpy") if warm_kernels() else ("numpy",):
        base = node_cpu(backend, None, seconds)
        ours = node_cpu(backend, "attitude_mekf", seconds)
        thesis = node_cpu(backend, "attitude_thesis", seconds)
        lines.append(
            f"{backend:<8} {base:>13.1f} {ours:>8.1f} {ours - base:>7.1f} {thesis:>7.1f} "
            f"{thesis - base:>7.1f}"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """CLI entry point (``hera bench ahrs``). Returns a process exit code."""
    ap = argparse.ArgumentParser(
        prog="hera bench ahrs", description=" ".join(__doc__.split("\n\n")[0].split())
    )
    ap.add_argument(
        "--seed", type=cliargs.non_negative_int, default=42, help="seed of both data sets"
    )
    ap.add_argument(
        "--samples", type=cliargs.count, default=3000, help="ahrs.Sensors samples (100 Hz)"
    )
    ap.add_argument("--seconds", type=cliargs.positive, default=30.0, help="rotation_fast seconds")
    ap.add_argument("--quick", action="store_true", help="small data sets, rough numbers")
    ap.add_argument(
        "--cpu",
        type=cliargs.positive,
        metavar="SECONDS",
        help="instead: the live node CPU of each AHRS at 100 Hz, measured over SECONDS on "
        "real clusters (six of them, one after the other: hold the cluster lock)",
    )
    args = ap.parse_args(argv if argv is not None else sys.argv[1:])
    if args.cpu is not None:
        print("node CPU (% of one core): the computer node fed nav3 at 100 Hz, with and without")
        print(cpu_table(args.cpu))
        return 0
    try:
        import ahrs  # noqa: F401
    except ImportError:
        print(
            "hera bench ahrs: the ahrs package is not installed, nothing to compare with.\n"
            f"Install it with: {INSTALL_HINT}",
            file=sys.stderr,
        )
        return 2
    if args.samples < 300 or args.seconds < 3:
        print("hera bench ahrs: --samples must be >= 300 and --seconds >= 3", file=sys.stderr)
        return 2
    from hera.estimation import backend

    t0 = time.perf_counter()
    name = backend.backend()
    print(f"hera.estimation backend: {name} (our AHRS's kernels follow it)")
    samples, seconds = (600, 6.0) if args.quick else (args.samples, args.seconds)
    ok = True
    for d in (sensors_data(args.seed, samples), rotation_fast_data(args.seed, seconds)):
        rows = measure(d)
        speed, accuracy, ekf = verdict(rows)
        ok = ok and speed and accuracy
        print(f"\n{d.name}: per-sample update, errors from {SETTLE_S:g} s on")
        print(format_table(rows))
        print(
            f"ours vs {ekf['filter']}: {ekf['ratio']:.1f}x faster "
            f"({'met' if speed else 'MISSED'}: >= {TARGET:g}x), mean error "
            f"{rows[0]['mean_deg']:.3f} vs {ekf['mean_deg']:.3f} deg "
            f"({'met' if accuracy else 'MISSED'}: no worse)"
        )
    summary = "all targets met" if ok else "targets MISSED"
    print(f"\n{summary}; total {time.perf_counter() - t0:.1f} s")
    return 0
