"""``hera bench kalman``: per-step (predict + update) time of hera.estimation vs FilterPy.

For KF, EKF and UKF with state size n in {2, 4, 9} and measurement size m in {1, 2, 3}, the
same model and the same measurements are run through both libraries; the time of every
step is measured with ``time.perf_counter_ns`` and the median is reported (microseconds).
The two libraries take turns in runs of ``CHUNK`` steps and the ratio is the median over
the turns of FilterPy's run median over ours, so a change of load on the machine during
a case hits both sides of each comparison alike; the garbage collector is paused while
timing, as ``timeit`` does. Our timed step includes building the observation block, as
a fusion model does. The target is judged on ``predict(dt)`` then ``update(obs)``; the
``step`` columns time ``step(dt, obs)`` (the same two in one call, fused into one kernel
for the KF and EKF), paired with FilterPy the same way, for information. The EKF's
``compiled`` columns time the same model written as numba functions
(:mod:`hera.bench.kalman_compiled`) in ``CompiledExtendedKalmanFilter.fuse(dt, z)``, one
compiled call a step, against FilterPy with the Python functions it takes. The estimation
backend (numba or numpy) is printed; its one-off compile / cache-load time is measured
first and reported separately (warm-up steps then run before any timing).
"""

from __future__ import annotations

import argparse
import gc
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Callable

import numpy as np

from hera import cliargs
from hera.estimation.backend import BACKENDS, ENV_VAR, cache_dir
from hera.launcher import code_command
from hera.nodestatus import rss_mb

TARGET = 3.0
TARGETS = {"KF": TARGET, "EKF": 4.0, "UKF": TARGET}  # issue 21: >= 3x everywhere, EKF >= 4x
CHUNK = 100  # steps per turn when the two libraries alternate
INSTALL_HINT = "pip install 'hera-fusion[bench]' (or: pip install filterpy)"


class _Model:
    """The benchmark problem, identical for both libraries.

    Process: a constant-velocity chain x' = F x (F = I plus dt on the superdiagonal), one
    numpy matmul, with its constant Jacobian F. Measurements: KF, the linear H x (each row
    sees one coordinate plus half of the next); EKF/UKF, the nonlinear h(x) = sin(x[idx])
    of m coordinates (idx cycles when m > n) with its analytic Jacobian. The user functions
    are cheap on purpose, so the table measures the libraries, not the models; both
    libraries call exactly these functions the same number of times per step except that
    our UKF redraws sigma points from the predicted state before the update (eq. 12).
    """

    def __init__(self, n: int, m: int, dt: float = 0.1) -> None:
        rng = np.random.default_rng(1000 * n + m)
        self.n, self.m, self.dt = n, m, dt
        F = np.eye(n)
        for i in range(n - 1):
            F[i, i + 1] = dt
        self.F = F
        self.Q = 0.01 * dt * np.eye(n)
        self.H = np.zeros((m, n))
        for i in range(m):
            self.H[i, i % n] = 1.0
            self.H[i, (i + 1) % n] += 0.5
        self.R = np.diag(np.linspace(0.1, 0.3, m))
        self.var = np.diag(self.R).copy()
        self.x0 = 0.1 * rng.normal(size=n)
        self.P0 = 0.1 * np.eye(n)
        self.idx = np.arange(m) % n  # measured coordinates (m may exceed n)
        self.sel = np.zeros((m, n))  # selection matrix: sel[i, idx[i]] = 1
        self.sel[np.arange(m), self.idx] = 1.0

    def f(self, x: np.ndarray, dt: float, u=None) -> np.ndarray:
        return self.F @ x

    def f_jac(self, x: np.ndarray, dt: float, u=None) -> np.ndarray:
        return self.F

    def h(self, x: np.ndarray) -> np.ndarray:
        return np.sin(x[self.idx])

    def h_jac(self, x: np.ndarray) -> np.ndarray:
        return self.sel * np.cos(x)  # row i: cos(x[idx[i]]) in column idx[i]

    def measurements(self, steps: int) -> np.ndarray:
        rng = np.random.default_rng(7 * self.n + self.m)
        return rng.normal(scale=0.3, size=(steps, self.m))


def _alternating_medians(
    a: Callable[[np.ndarray], None],
    b: Callable[[np.ndarray], None],
    zs: np.ndarray,
    warmup: int,
    chunk: int = CHUNK,
) -> tuple[float, float, float]:
    """Median step times (microseconds) of ``a`` and ``b`` fed the same measurements, and
    the speed ratio b / a. The two take turns in runs of ``chunk`` steps (each runs hot, as
    in a loop of its own) with the garbage collector paused; the ratio is the median over
    the turns of (median of b's run) / (median of a's run), so each pair of runs, a few
    milliseconds apart, is compared under the same load on the machine."""
    for z in zs[:warmup]:
        a(z)
        b(z)
    clock = time.perf_counter_ns
    ta: list[int] = []
    tb: list[int] = []
    ratios: list[float] = []
    timed = zs[warmup:]
    median = statistics.median
    gc_was_on = gc.isenabled()
    gc.disable()
    try:
        for lo in range(0, len(timed), chunk):
            run_a: list[int] = []
            run_b: list[int] = []
            for step, times in ((a, run_a), (b, run_b)):
                for z in timed[lo : lo + chunk]:
                    t0 = clock()
                    step(z)
                    times.append(clock() - t0)
            ratios.append(median(run_b) / max(median(run_a), 1))
            ta += run_a
            tb += run_b
    finally:
        if gc_was_on:
            gc.enable()
    return median(ta) / 1000.0, median(tb) / 1000.0, median(ratios)


def _ours(kind: str, md: _Model) -> Callable[[np.ndarray], None]:
    from hera.estimation import (
        ExtendedKalmanFilter,
        KalmanFilter,
        Observations,
        UnscentedKalmanFilter,
    )

    dt = md.dt
    if kind == "KF":
        kf = KalmanFilter(md.x0, md.P0, F=md.F, Q=md.Q)
        H, var = md.H, md.var

        def step(z: np.ndarray) -> None:
            kf.predict(dt)
            kf.update(Observations().add("z", z, H=H, R=var))

        return step
    if kind == "EKF":
        ekf = ExtendedKalmanFilter(md.x0, md.P0, f=md.f, F=md.f_jac, Q=md.Q)
        h, hj, var = md.h, md.h_jac, md.var

        def step(z: np.ndarray) -> None:
            ekf.predict(dt)
            ekf.update(Observations().add("z", z, h=h, jacobian=hj, R=var))

        return step
    ukf = UnscentedKalmanFilter(md.x0, md.P0, f=md.f, Q=md.Q, alpha=0.5, beta=2.0, kappa=0.0)
    h, var = md.h, md.var

    def step(z: np.ndarray) -> None:
        ukf.predict(dt)
        ukf.update(Observations().add("z", z, h=h, R=var))

    return step


def _ours_step(kind: str, md: _Model) -> Callable[[np.ndarray], None]:
    """As ``_ours``, with ``step(dt, obs)`` in place of predict then update."""
    from hera.estimation import (
        ExtendedKalmanFilter,
        KalmanFilter,
        Observations,
        UnscentedKalmanFilter,
    )

    dt = md.dt
    if kind == "KF":
        kf = KalmanFilter(md.x0, md.P0, F=md.F, Q=md.Q)
        H, var = md.H, md.var

        def step(z: np.ndarray) -> None:
            kf.step(dt, Observations().add("z", z, H=H, R=var))

        return step
    if kind == "EKF":
        ekf = ExtendedKalmanFilter(md.x0, md.P0, f=md.f, F=md.f_jac, Q=md.Q)
        h, hj, var = md.h, md.h_jac, md.var

        def step(z: np.ndarray) -> None:
            ekf.step(dt, Observations().add("z", z, h=h, jacobian=hj, R=var))

        return step
    ukf = UnscentedKalmanFilter(md.x0, md.P0, f=md.f, Q=md.Q, alpha=0.5, beta=2.0, kappa=0.0)
    h, var = md.h, md.var

    def step(z: np.ndarray) -> None:
        ukf.step(dt, Observations().add("z", z, h=h, R=var))

    return step


def _ours_blocks(kind: str, md: _Model) -> Callable[[np.ndarray], None]:
    """As ``_ours``, each of the m rows its own block (a model fusing m one-value sensors
    in one update; FilterPy, paired with it, takes them stacked as one z)."""
    from hera.estimation import (
        ExtendedKalmanFilter,
        KalmanFilter,
        Observations,
        UnscentedKalmanFilter,
    )

    dt, rows, vs = md.dt, range(md.m), md.var.tolist()
    filt: KalmanFilter | ExtendedKalmanFilter | UnscentedKalmanFilter
    if kind == "KF":
        filt = KalmanFilter(md.x0, md.P0, F=md.F, Q=md.Q)
        given = [{"H": md.H[i : i + 1], "R": vs[i]} for i in rows]
    else:
        hs = [lambda x, j=int(md.idx[i]): np.sin(x[j : j + 1]) for i in rows]
        given = [{"h": hs[i], "R": vs[i]} for i in rows]
        if kind == "EKF":
            filt = ExtendedKalmanFilter(md.x0, md.P0, f=md.f, F=md.f_jac, Q=md.Q)
            for i in rows:
                given[i]["jacobian"] = lambda x, s=md.sel[i : i + 1]: s * np.cos(x)
        else:
            filt = UnscentedKalmanFilter(
                md.x0, md.P0, f=md.f, Q=md.Q, alpha=0.5, beta=2.0, kappa=0.0
            )

    def step(z: np.ndarray) -> None:
        filt.predict(dt)
        obs = Observations()
        for i in rows:
            obs.add(f"z{i}", z[i : i + 1], **given[i])
        filt.update(obs)

    return step


def _filterpy(kind: str, md: _Model) -> Callable[[np.ndarray], None]:
    from filterpy.kalman import (
        ExtendedKalmanFilter,
        KalmanFilter,
        MerweScaledSigmaPoints,
        UnscentedKalmanFilter,
    )

    n, m, dt = md.n, md.m, md.dt
    if kind == "KF":
        kf = KalmanFilter(dim_x=n, dim_z=m)
        kf.x, kf.P, kf.F, kf.Q, kf.H, kf.R = md.x0.copy(), md.P0.copy(), md.F, md.Q, md.H, md.R

        def step(z: np.ndarray) -> None:
            kf.predict()
            kf.update(z)

        return step
    if kind == "EKF":

        class _EKF(ExtendedKalmanFilter):
            def predict_x(self, u=0):
                self.x = md.f(self.x, dt)

        ekf = _EKF(dim_x=n, dim_z=m)
        ekf.x, ekf.P, ekf.Q, ekf.R = md.x0.copy(), md.P0.copy(), md.Q, md.R
        h, hj = md.h, md.h_jac

        def step(z: np.ndarray) -> None:
            ekf.F = md.f_jac(ekf.x, dt)
            ekf.predict()
            ekf.update(z, hj, h)

        return step
    pts = MerweScaledSigmaPoints(n, alpha=0.5, beta=2.0, kappa=0.0)
    ukf = UnscentedKalmanFilter(dim_x=n, dim_z=m, dt=dt, hx=md.h, fx=md.f, points=pts)
    ukf.x, ukf.P, ukf.Q, ukf.R = md.x0.copy(), md.P0.copy(), md.Q, md.R

    def step(z: np.ndarray) -> None:
        ukf.predict()
        ukf.update(z)

    return step


def run(
    steps: int, kinds: list[str], sizes: list[int], dims: list[int], compiled: bool = False
) -> list[dict]:
    """Measure every case; returns rows with the medians in microseconds (``compiled``: the
    EKF rows also time the compiled model, numba backend only)."""
    rows = []
    warmup = max(5, steps // 10)
    if compiled:
        from . import kalman_compiled
    for kind in kinds:
        for n in sizes:
            for m in dims:
                md = _Model(n, m)
                zs = md.measurements(steps + warmup)
                ours, theirs, ratio = _alternating_medians(
                    _ours(kind, md), _filterpy(kind, md), zs, warmup
                )
                fused, _, step_ratio = _alternating_medians(
                    _ours_step(kind, md), _filterpy(kind, md), zs, warmup
                )
                row = {
                    "filter": kind,
                    "n": n,
                    "m": m,
                    "ours_us": ours,
                    "filterpy_us": theirs,
                    "ratio": ratio,
                    "step_us": fused,
                    "step_ratio": step_ratio,
                }
                if m > 1:
                    row["blocks_us"], _, row["blocks_ratio"] = _alternating_medians(
                        _ours_blocks(kind, md), _filterpy(kind, md), zs, warmup
                    )
                if kind == "EKF" and compiled:
                    row["compiled_us"], _, row["compiled_ratio"] = _alternating_medians(
                        kalman_compiled.stepper(md), _filterpy(kind, md), zs, warmup
                    )
                rows.append(row)
    return rows


def format_table(rows: list[dict]) -> str:
    """The bench's table; the compiled columns only when a row has them."""
    head = (
        f"{'filter':<6} {'n':>2} {'m':>2} {'ours us':>9} {'filterpy us':>12} {'ratio':>7}  "
        f"{'target':<15} {'step us':>8} {'step ratio':>10} {'blocks us':>9} {'ratio':>6}"
    )
    if any("compiled_us" in r for r in rows):
        head += f" {'compiled us':>11} {'ratio':>6}"
    lines = [head, "-" * len(head)]
    for r in rows:
        ratio = r["ratio"]
        target = TARGETS[r["filter"]]
        ok = "met" if ratio >= target else "MISSED"
        step = ""
        if "step_us" in r:
            step = f" {r['step_us']:>8.1f} {r['step_ratio']:>10.2f}"
        if "blocks_us" in r:
            step += f" {r['blocks_us']:>9.1f} {r['blocks_ratio']:>6.2f}"
        elif "step_us" in r:
            step += f" {'-':>9} {'-':>6}"
        if "compiled_us" in r:
            step += f" {r['compiled_us']:>11.1f} {r['compiled_ratio']:>6.2f}"
        lines.append(
            f"{r['filter']:<6} {r['n']:>2} {r['m']:>2} {r['ours_us']:>9.1f} "
            f"{r['filterpy_us']:>12.1f} {ratio:>7.2f}  {ok + f' (>= {target:g}x)':<15}{step}"
        )
    return "\n".join(lines)


def run_each_filter_once() -> None:
    """Build the KF, EKF and UKF of the smallest case and run a few steps of each: what a
    node that runs filters has loaded (the probe of ``loaded_rss_mb``)."""
    md = _Model(2, 1)
    for kind in TARGETS:
        step = _ours(kind, md)
        for z in md.measurements(3):
            step(z)


def loaded_rss_mb(timeout: float = 120.0, backend: str | None = None) -> float | None:
    """RSS in MB of a fresh Python process that loads the kernels from the cache (on
    ``backend``, default the environment's) and runs every filter: what a node pays for
    them. This process's own figure is larger when it has just compiled them (the
    compiler's memory stays). None if the probe failed."""
    probe = "from hera.bench import kalman as k; k.run_each_filter_once(); print(k.rss_mb())"
    env = dict(os.environ)
    if backend is not None:
        env[ENV_VAR] = backend
    try:
        out = subprocess.run(
            code_command(probe),
            env=env,
            capture_output=True,
            text=True,
            timeout=timeout,
            check=True,
        )
        return float(out.stdout.split()[-1])
    except (OSError, subprocess.SubprocessError, ValueError, IndexError):
        return None


def _why(name: str, asked: str | None, warm: float) -> str:
    """Why the bench runs on backend ``name`` (and the kernels' load time on numba)."""
    if name == "numba":
        return f"kernels compiled or loaded in {warm:.2f} s, cached in {cache_dir()}"
    if asked == "numpy":
        return "asked by --backend numpy"
    if asked is None and os.environ.get(ENV_VAR, "").strip().lower() == "numpy":
        return f"asked by {ENV_VAR}=numpy"
    return "numba not installed"


def main(argv: list[str] | None = None) -> int:
    """CLI entry point (``hera bench kalman``). Returns a process exit code."""
    ap = argparse.ArgumentParser(prog="hera bench kalman", description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=cliargs.count, default=3000, help="timed steps per case")
    ap.add_argument("--quick", action="store_true", help="few steps (200), rough numbers")
    ap.add_argument("--filter", choices=["KF", "EKF", "UKF"], action="append", dest="kinds")
    ap.add_argument(
        "--backend",
        choices=BACKENDS,
        help=f"estimation backend to time (default: {ENV_VAR}, else auto: numba if installed)",
    )
    args = ap.parse_args(argv if argv is not None else sys.argv[1:])
    try:
        import filterpy  # noqa: F401
    except ImportError:
        print(
            "hera bench kalman: FilterPy is not installed, nothing to compare with.\n"
            f"Install it with: {INSTALL_HINT}",
            file=sys.stderr,
        )
        return 2
    steps = 200 if args.quick else max(1, args.steps)
    kinds = args.kinds or ["KF", "EKF", "UKF"]
    from hera.estimation import backend

    t0 = time.perf_counter()
    try:  # compiles the kernels the first time on this machine
        name = backend.set_backend(args.backend) if args.backend else backend.backend()
    except ImportError as e:
        print(f"hera bench kalman: {e}", file=sys.stderr)
        return 2
    warm = time.perf_counter() - t0
    print(f"hera.estimation backend: {name} ({_why(name, args.backend, warm)})")
    loaded = loaded_rss_mb(backend=name)
    print(
        "memory: a process that runs these filters "
        + (f"{loaded:.0f} MB RSS" if loaded is not None else "(probe failed)")
        + f"; this one {rss_mb() or 0:.0f} MB"
        + (" (more if it compiled the kernels)" if name == "numba" else "")
    )
    dims = [1, 2, 3]
    compiled = name == "numba" and "EKF" in kinds
    if compiled:
        from . import kalman_compiled

        t1 = time.perf_counter()
        where = kalman_compiled.prepare(dims)
        print(
            f"compiled EKF models (m = 1-3): compiled or loaded in {time.perf_counter() - t1:.2f} s"
            f", {where}"
        )
    rows = run(steps, kinds, [2, 4, 9], dims, compiled)
    print(
        f"Kalman filter step (predict + update), median of {steps} steps per case; ratio: "
        f"FilterPy / ours, median over turns of {CHUNK} steps each; step: the same with "
        "step(dt, obs) (information, not the target); blocks: the m rows as m blocks of one "
        "row (a model fusing m sensors), FilterPy with them stacked"
        + (
            "; compiled: the EKF's model as numba functions, CompiledExtendedKalmanFilter"
            ".fuse(dt, z)"
            if compiled
            else ""
        )
    )
    print(format_table(rows))
    met = sum(r["ratio"] >= TARGETS[r["filter"]] for r in rows)
    at3 = sum(r["ratio"] >= TARGET for r in rows)
    print(
        f"{met} of {len(rows)} cases meet their target (EKF {TARGETS['EKF']:g}x, else "
        f"{TARGET:g}x); {at3} of {len(rows)} are >= {TARGET:g}x"
    )
    fast = [r["compiled_ratio"] for r in rows if "compiled_ratio" in r]
    if fast:
        print(
            f"with a compiled model (CompiledExtendedKalmanFilter.fuse) the EKF is at "
            f"{min(fast):.2f}-{max(fast):.2f}x FilterPy, "
            f"{sum(v >= TARGETS['EKF'] for v in fast)} of {len(fast)} cases >= "
            f"{TARGETS['EKF']:g}x"
        )
    print(f"total {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
