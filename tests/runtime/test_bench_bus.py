"""The bus and scale benchmarks run end to end and print every figure (values are not asserted:
speed is shown by the benchmark, never by timed assertions)."""

import subprocess
import sys

import pytest
from harness import cluster_env


@pytest.mark.slow  # CI budget (34 s: seven clusters); bench scale's quick run stays in CI
def test_bench_bus_quick_prints_every_figure(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "hera", "bench", "bus", "--quick"],
        env=cluster_env(tmp_path),
        capture_output=True,
        text=True,
        timeout=240,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    rows = {line.split("  ")[0]: line for line in out.stdout.splitlines()}
    for figure in (
        "latency p99 @100 Hz",
        "latency p99 @1 kHz",
        "store absorbs",
        "5-node observers CPU, 20 counters at 10 Hz",
        "5-node observers CPU, counters stopped",
        "observer node RSS (each)",
        "crashed measure running again",
        "SIGKILLed node noticed",
        "SIGSTOPped node noticed",
        "1 kHz p50/p99, no security",
        "1 kHz p50/p99, user/password",
        "1 kHz p50/p99, mutual TLS + ACL",
    ):
        assert figure in rows, out.stdout
        assert "n/a" not in rows[figure], rows[figure]


def test_bench_scale_quick_runs_behind_a_router_with_mutual_tls(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "hera", "bench", "scale", "--quick"]
        + ["--topologies", "routers", "--security", "tls"],
        env=cluster_env(tmp_path),
        capture_output=True,
        text=True,
        timeout=240,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    rows = [line.split() for line in out.stdout.splitlines() if line.lstrip().startswith("8 ")]
    assert len(rows) == 1 and rows[0][:4] == ["8", "routers", "grid", "tls"], out.stdout
    delivered = float(rows[0][4])  # a number, not "failed: ..."
    assert delivered > 0.0, out.stdout
