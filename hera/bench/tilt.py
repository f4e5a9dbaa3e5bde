"""``hera bench tilt``: per-step time of the tilt filters of seed 003 in one run, next to the
seed's operation counts (Table 5).

The same stream of samples (a robot swinging 20 deg at 0.8 Hz, 26 Hz, noisy accelerometer and
gyroscope) goes through the seed's split filter (Table 8, written out on scalars), the full
EKF and the UKF (:mod:`hera.estimation`), all on eqs. 25-26 (n = 2 states, m = 2
measurements, p = 2 commands), the EKF with the bias as a third state (n = 3, p = 1), and
the bias filter with the robot's model and its wheels (n = 4, p = 1, two scalar corrections:
the accelerometer's tilt and the wheels' travel, which is not Table 5's form). A step is one
sample: evolution with the gyroscope, correction with the accelerometer (and the wheels). The
filters take turns in runs of ``CHUNK`` steps with the garbage collector paused; each
filter's figure is the median step time, and a ratio is the median over the turns of the
two filters' run medians, so load changes on the machine hit both sides alike.

Table 5 of the seed counts floating-point operations: (E)KF T = 4n^3 + 4m^3 + 6m^2 n +
4n^2 m + 3n^2, UKF T = 10n^3 + 4n^2 m + 14m^2 n + 23n^2 + 6m^2 (lower terms left out by the
seed); their UKF/EKF ratio is printed beside the measured one. The counts ignore the
non-linear functions themselves, and a Python step is dominated by per-call overhead rather
than arithmetic at these sizes, so the two ratios need not agree: the table shows by how much
they do not.
"""

from __future__ import annotations

import argparse
import gc
import math
import statistics
import sys
import time
from collections.abc import Callable

import numpy as np

from hera import cliargs

CHUNK = 100


def table5(kind: str, n: int, m: int) -> int:
    """Seed 003 Table 5: the operation count T of one (E)KF or UKF step."""
    if kind == "UKF":
        return 10 * n**3 + 4 * n * n * m + 14 * m * m * n + 23 * n * n + 6 * m * m
    return 4 * n**3 + 4 * m**3 + 6 * m * m * n + 4 * n * n * m + 3 * n * n


PENDULUM_M = 0.12
"""The wheels filter's pendulum length (its default), which the stream's travel obeys."""


def samples(steps: int, seed: int = 3) -> list[tuple[float, float, tuple[float, float], float]]:
    """(g_Y, b_gyro, (a_X, a_Z), x_wheel) per step of a robot swinging 20 deg at 0.8 Hz,
    26 Hz; the wheels' travel x_wheel (m) from the pendulum the wheels filter models."""
    rng = np.random.default_rng(seed)
    dt, w, amp, g, b = 1.0 / 26.0, 2.0 * math.pi * 0.8, math.radians(20.0), 9.81, 0.01
    out = []
    p = v = 0.0
    for k in range(steps):
        t = k * dt
        th, dth = amp * math.sin(w * t), amp * w * math.cos(w * t)
        rate = dth + b + rng.normal(0.0, 0.005)
        acc = (g * math.sin(th) + rng.normal(0.0, 0.3), g * math.cos(th) + rng.normal(0.0, 0.3))
        out.append((rate, b, acc, p - PENDULUM_M * math.sin(th)))
        a = g * math.tan(th) - PENDULUM_M * math.sin(th) * dth * dth
        p, v = p + v * dt + 0.5 * a * dt * dt, v + a * dt
    return out


def steppers() -> dict[str, Callable[[tuple], None]]:
    """One step function per filter (split, EKF, UKF, bias, wheels), fresh filters."""
    from hera.models.tilt.tilt import Tilt2D
    from hera.models.tilt.wheels import WheelsFilter
    from hera.store import Sample

    dt = 1.0 / 26.0
    out = {}
    for kind in ("split", "ekf", "ukf", "bias", "wheels"):
        model = Tilt2D(kind=kind, start="any", pendulum_m=PENDULUM_M)
        model.process(Sample("imu", "bench", 1, 0.0, 0.0, 0.0, (0.0, 9.81, 0.0, 0.01, 2.0)))
        f = model.filter
        assert f is not None
        if isinstance(f, WheelsFilter):
            f.wheels(0.0, True, 0.0)  # placed: the next readings correct

            def step(s: tuple, f=f, gate=model.wheel_input.gate) -> None:  # type: ignore[union-attr]
                f.step(dt, s[0], s[2])
                f.wheels(s[3], True, 0.0, gate)
        else:

            def step(s: tuple, f=f) -> None:
                f.step(dt, s[0], s[1], s[2])

        out[kind] = step
    return out


def measure(steps: int, warmup: int = 50) -> dict[str, object]:
    """Median step time (us) of every filter and the median per-turn ratios."""
    stream = samples(steps + warmup)
    fns = steppers()
    for s in stream[:warmup]:
        for fn in fns.values():
            fn(s)
    clock = time.perf_counter_ns
    times: dict[str, list[int]] = {k: [] for k in fns}
    turns: list[dict[str, float]] = []
    timed = stream[warmup:]
    gc_on = gc.isenabled()
    gc.disable()
    try:
        for lo in range(0, len(timed), CHUNK):
            medians = {}
            for name, fn in fns.items():
                run = []
                for s in timed[lo : lo + CHUNK]:
                    t0 = clock()
                    fn(s)
                    run.append(clock() - t0)
                medians[name] = statistics.median(run)
                times[name] += run
            turns.append(medians)
    finally:
        if gc_on:
            gc.enable()
    med = {k: statistics.median(v) / 1000.0 for k, v in times.items()}

    def ratio(a: str, b: str) -> float:
        return statistics.median(t[a] / max(t[b], 1) for t in turns)

    return {
        "us": med,
        "ukf/ekf": ratio("ukf", "ekf"),
        "ekf/split": ratio("ekf", "split"),
        "bias/ekf": ratio("bias", "ekf"),
        "wheels/bias": ratio("wheels", "bias"),
        "turns": len(turns),
    }


def format_report(res: dict, steps: int, backend: str) -> str:
    us = res["us"]
    ekf, ukf = table5("EKF", 2, 2), table5("UKF", 2, 2)
    lines = [
        f"tilt filters of seed 003, one step = evolution + correction, median of {steps} steps "
        f"(hera.estimation backend: {backend})",
        f"{'filter':<28} {'n':>2} {'m':>2} {'p':>2} {'us/step':>9} {'Table 5 T':>10}",
        "-" * 58,
        f"{'split (seed Table 8)':<28} {2:>2} {2:>2} {2:>2} {us['split']:>9.1f} {'-':>10}",
        f"{'EKF (hera.estimation)':<28} {2:>2} {2:>2} {2:>2} {us['ekf']:>9.1f} {ekf:>10}",
        f"{'UKF (hera.estimation)':<28} {2:>2} {2:>2} {2:>2} {us['ukf']:>9.1f} {ukf:>10}",
        f"{'bias EKF (hera.estimation)':<28} {3:>2} {2:>2} {1:>2} {us['bias']:>9.1f} "
        f"{table5('EKF', 3, 2):>10}",
        f"{'wheels EKF (robot model)':<28} {4:>2} {'1+1':>2} {1:>2} {us['wheels']:>9.1f} {'-':>10}",
        "",
        f"UKF / EKF: measured {res['ukf/ekf']:.2f}x, counted (Table 5) {ukf / ekf:.2f}x",
        f"EKF / split: measured {res['ekf/split']:.2f}x (Table 8 on scalars: A = I, P H^T kept, "
        "no matrix library)",
        f"bias EKF / EKF: measured {res['bias/ekf']:.2f}x, counted "
        f"{table5('EKF', 3, 2) / ekf:.2f}x",
        f"wheels EKF / bias EKF: measured {res['wheels/bias']:.2f}x (two corrections a step; "
        "the robot's model in Python)",
        f"(ratios: median over {res['turns']} turns of {CHUNK} steps per filter)",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """CLI entry point (``hera bench tilt``). Returns a process exit code."""
    ap = argparse.ArgumentParser(prog="hera bench tilt", description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=cliargs.count, default=3000, help="timed steps per filter")
    ap.add_argument("--backend", choices=["numpy", "numba", "auto"], default="auto")
    args = ap.parse_args(argv if argv is not None else sys.argv[1:])
    from hera.estimation import backend

    try:
        name = backend.set_backend(args.backend)
    except ImportError as e:
        print(f"hera bench tilt: {e}", file=sys.stderr)
        return 2
    backend.warmup()
    res = measure(args.steps)
    print(format_report(res, args.steps, name))
    return 0
