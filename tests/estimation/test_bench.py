"""The benchmark CLI runs and prints its table (timings are never asserted)."""

import gc
import re
import sys

import numpy as np

from hera.bench import kalman as bench


def test_bench_runs_tiny(capsys):
    assert bench.main(["--steps", "3"]) == 0
    out = capsys.readouterr().out
    assert "filterpy us" in out and "ratio" in out
    for kind in ("KF", "EKF", "UKF"):
        assert sum(line.startswith(kind + " ") for line in out.splitlines()) == 9
    # the EKF rows add the compiled model's two columns (time and ratio) on numba
    widths = {len(line.split()) for line in out.splitlines() if line.startswith(("KF ", "UKF "))}
    ekf = {len(line.split()) for line in out.splitlines() if line.startswith("EKF ")}
    assert ekf == {w + 2 for w in widths}, out
    assert re.search(r"the EKF is at [\d.]+-[\d.]+x FilterPy, \d of 9 cases >= 4x", out), out
    assert re.search(r"compiled EKF models \(m = 1-3\): compiled or loaded in [\d.]+ s", out)
    # the memory a node pays, read off a fresh process that ran every filter
    loaded = re.search(r"a process that runs these filters (\d+) MB RSS; this one (\d+) MB", out)
    assert loaded, out
    assert 0 < int(loaded[1]) <= int(loaded[2]) + 50, loaded[0]


def test_bench_on_the_numpy_backend_says_why(use, monkeypatch, capsys):
    """--backend numpy times the path nodes fuse on by default; the first line says which
    backend runs and why (it said "numba not installed" when numba was only not chosen),
    and there is no compiled column (a compiled model needs numba)."""
    use("numba")  # restored after the test, whatever the bench switched to
    monkeypatch.delenv(bench.ENV_VAR, raising=False)
    assert bench.main(["--steps", "3", "--backend", "numpy", "--filter", "EKF"]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[0] == "hera.estimation backend: numpy (asked by --backend numpy)"
    rows = [line.split() for line in out.splitlines() if line.startswith("EKF ")]
    # filter n m ours filterpy ratio MISSED (>= 4x) step ratio blocks ratio: no compiled
    assert len(rows) == 9 and {len(r) for r in rows} == {13}, out
    # the m rows as m blocks: timed where m > 1, a dash where there is one row
    assert all((r[-2:] == ["-", "-"]) == (r[2] == "1") for r in rows), out
    assert all(float(r[-2]) > 0 and float(r[-1]) > 0 for r in rows if r[2] != "1"), out
    assert "compiled" not in out  # no compiled models, nor their column named
    monkeypatch.setenv(bench.ENV_VAR, "numpy")
    assert bench.main(["--steps", "3", "--filter", "KF"]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[0] == f"hera.estimation backend: numpy (asked by {bench.ENV_VAR}=numpy)"


def test_bench_without_filterpy(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "filterpy", None)
    assert bench.main(["--quick"]) != 0
    err = capsys.readouterr().err
    assert "not installed" in err and "hera-fusion[bench]" in err


def test_ratio_is_paired_over_turns(monkeypatch):
    """The ratio compares each turn of FilterPy with the turn of ours just before it. On a
    fake clock where FilterPy's step costs 3x ours and the load on the machine changes
    between turns, the libraries' own medians follow the load (here the ratio of the two
    medians would be 0.75) while the median of the per-turn ratios is the true 3; the
    garbage collector is on again afterwards."""
    now = [0]
    calls = {"ours": 0, "theirs": 0}
    # load per turn (5 turns of 50 steps): ours 1, 1, 4, 4, 4 and FilterPy 1, 4, 4, 1, 1
    # -> per-turn ratios 3, 12, 3, 0.75, 0.75
    load = {"ours": [1, 1, 4, 4, 4], "theirs": [1, 4, 4, 1, 1]}
    cost = {"ours": 10, "theirs": 30}

    def stepper(side):
        def step(z):
            now[0] += cost[side] * load[side][calls[side] // 50]
            calls[side] += 1

        return step

    monkeypatch.setattr(bench.time, "perf_counter_ns", lambda: now[0])
    zs = np.zeros((250, 1))
    ours_us, theirs_us, ratio = bench._alternating_medians(
        stepper("ours"), stepper("theirs"), zs, warmup=0, chunk=50
    )
    assert calls == {"ours": 250, "theirs": 250}
    assert (ours_us, theirs_us) == (0.04, 0.03)
    assert ratio == 3.0
    assert gc.isenabled()


def test_the_compiled_case_runs_the_benchmarks_model():
    """The EKF's compiled columns time the same model as the others: the numba f, F, h, H
    of ``kalman_compiled`` give what ``kalman._Model``'s give, at every case's n and m (so
    a failing copy, say a Jacobian left out, cannot make the compiled case look fast)."""
    from hera.bench import kalman_compiled as kc

    rng = np.random.default_rng(3)
    for n in (2, 4, 9):
        for m in (1, 2, 3):
            md = bench._Model(n, m)
            x, u = rng.normal(size=n), np.zeros(0)
            h, H = kc._MEASUREMENTS[m]
            np.testing.assert_allclose(kc.f(x, md.dt, u), md.f(x, md.dt), rtol=0, atol=1e-15)
            np.testing.assert_array_equal(kc.F(x, md.dt, u), md.f_jac(x, md.dt))
            np.testing.assert_array_equal(h(x), md.h(x))
            np.testing.assert_array_equal(H(x), md.h_jac(x))
