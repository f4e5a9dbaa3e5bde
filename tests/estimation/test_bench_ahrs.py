"""``hera bench ahrs`` runs and prints its tables (timings are never asserted); its verdict
and turn-by-turn ratio are checked on made-up rows and a fake clock."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from hera.bench import ahrs as bench


def test_bench_runs_on_both_data_sets(capsys):
    # the smallest data sets it takes (CI time): the same tables as --quick's, on less data
    assert bench.main(["--samples", "300", "--seconds", "3", "--seed", "3"]) == 0
    out = capsys.readouterr().out
    assert "ahrs.Sensors (seed 3" in out and "rotation_fast (Hera's Pmod NAV, seed 3" in out
    for name in bench.FILTERS:
        assert sum(line.startswith(name) for line in out.splitlines()) == 2, name
    assert out.count("x faster (") == 2


def test_bench_without_the_ahrs_package(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ahrs", None)
    assert bench.main(["--quick"]) == 2
    err = capsys.readouterr().err
    assert "not installed" in err and "hera-fusion[bench]" in err


def test_bad_options_are_refused(capsys):
    assert bench.main(["--samples", "10"]) == 2
    assert "--samples must be >= 300" in capsys.readouterr().err
    with pytest.raises(SystemExit) as refused:
        bench.main(["--cpu", "0"])
    assert refused.value.code == 2
    assert "argument --cpu: must be a number > 0, got '0'" in capsys.readouterr().err


def _row(name, ratio, mean):
    return {"filter": name, "us": 1.0, "ratio": ratio, "mean_deg": mean, "max_deg": mean}


def test_verdict_compares_with_the_better_ahrs_ekf():
    rows = [
        _row(bench.OURS, 1.0, 0.30),
        _row(bench.EKFS[0], 20.0, 0.50),
        _row(bench.EKFS[1], 9.0, 0.25),  # the better EKF: the one compared, and 9x only
    ]
    speed, accuracy, ekf = bench.verdict(rows)
    assert ekf["filter"] == bench.EKFS[1] and not speed and not accuracy
    rows[2] = _row(bench.EKFS[1], 12.0, 0.31)
    assert bench.verdict(rows)[:2] == (True, True)


def test_ratio_is_paired_over_turns(monkeypatch):
    """The ratio compares each filter's run with ours in the same turn. On a fake clock
    where the others cost 3x ours per sample and the machine's load changes between runs
    (ours 1, 1, 4, 4, 4 and theirs 1, 4, 4, 1, 1 over five turns: per-turn ratios 3, 12, 3,
    0.75, 0.75), the median of the per-turn ratios is the true 3, while the ratio of the
    filters' own medians would be 0.75."""
    now = [0]
    load = {True: [1, 1, 4, 4, 4], False: [1, 4, 4, 1, 1]}

    def make(cost, ours):
        def build(d):
            def step(k):
                now[0] += cost * load[ours][k // bench.CHUNK]

            return step, lambda: np.array((1.0, 0.0, 0.0, 0.0))

        return build

    filters = {name: make(10 if name == bench.OURS else 30, name == bench.OURS)
               for name in bench.FILTERS}  # fmt: skip
    monkeypatch.setattr(bench, "FILTERS", filters)
    monkeypatch.setattr(bench.time, "perf_counter_ns", lambda: now[0])

    class Data:
        t = np.arange(5 * bench.CHUNK) / 100.0
        q_true = np.tile((1.0, 0.0, 0.0, 0.0), (5 * bench.CHUNK, 1))

    rows = {r["filter"]: r for r in bench.measure(Data())}
    assert rows[bench.OURS]["ratio"] == 1.0
    for name in bench.EKFS:
        assert rows[name]["ratio"] == 3.0, rows[name]
        assert rows[name]["us"] / rows[bench.OURS]["us"] == 0.75  # unpaired: misleading


def test_a_cluster_that_does_not_start_says_why():
    """``--cpu``'s cluster: when ``hera up`` exits, its last words are in the error."""
    with pytest.raises(RuntimeError, match="did not start: .*estimation_backend must be one of"):
        bench.node_cpu("bogus", None, 1.0)


def test_cpu_mode_warms_the_kernels_the_nodes_load(use):
    """On a fresh install the first node compiled the kernels (20-50 s) inside the measured
    window: the node read 99 % of a core "with our AHRS". The bench now compiles (or loads)
    them first, into the caches the nodes read."""
    import numba  # noqa: F401  (a test requirement: the numba rows need it)

    from hera.estimation import backend
    from hera.models.ahrs import kernels_numba

    use("numpy")  # restored after the test
    assert bench.warm_kernels() is True
    assert backend.backend() == "numba" and kernels_numba._COMPILED is not None
