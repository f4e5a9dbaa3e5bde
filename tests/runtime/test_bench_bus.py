"""The bus benchmark runs end to end and prints every figure (values are not asserted:
speed is shown by the benchmark, never by timed assertions)."""

import subprocess
import sys

from harness import cluster_env


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
