"""The benchmark CLI runs and prints its table (timings are never asserted)."""

import sys

from hera.bench import kalman as bench


def test_bench_runs_tiny(capsys):
    assert bench.main(["--steps", "3"]) == 0
    out = capsys.readouterr().out
    assert "filterpy us" in out and "ratio" in out
    for kind in ("KF", "EKF", "UKF"):
        assert sum(line.startswith(kind + " ") for line in out.splitlines()) == 9


def test_bench_without_filterpy(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "filterpy", None)
    assert bench.main(["--quick"]) != 0
    err = capsys.readouterr().err
    assert "not installed" in err and "hera-fusion[bench]" in err
