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
        "the same traffic on bare zenoh-python",
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


def test_bench_scale_runs_small_behind_a_router_with_mutual_tls_and_its_zenoh_peer(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "hera", "bench", "scale", "--nodes", "4", "--seconds", "3"]
        + ["--phases", "grid", "--topologies", "routers", "--security", "tls"],
        env=cluster_env(tmp_path),
        capture_output=True,
        text=True,
        timeout=240,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    lines = [line.split() for line in out.stdout.splitlines() if line.lstrip().startswith("4 ")]
    rows = {r[3]: r for r in lines if len(r) == 15}  # the table: hera, then its peer
    assert list(rows) == ["hera/tls", "zenoh"], out.stdout
    for r in rows.values():
        assert r[:3] == ["4", "routers", "grid"], r
        assert float(r[4]) > 99.0, out.stdout  # delivered %, a number: not "failed: ..."
        busy, steal, worst = (float(x) for x in r[12:])  # the whole machine's figures
        assert 0.0 < busy <= 100.0 and 0.0 <= steal <= worst <= 100.0, r
        assert float(r[10]) > 10 and float(r[11]) > 10, r  # node and router memory, MB
    # the busy machine holds at least the processes measured on it
    assert all(float(r[12]) >= 0.9 * float(r[9]) for r in rows.values()), rows
    ratios = [r for r in lines if len(r) == 8]
    assert len(ratios) == 1 and ratios[0][3] == "hera/tls", out.stdout
    cpu = float(rows["hera/tls"][8]) / float(rows["zenoh"][8])
    assert float(ratios[0][4].rstrip("x")) == pytest.approx(cpu, rel=0.1, abs=0.06), out.stdout


def without_cryptography(monkeypatch) -> None:
    """As if the tls extra were not installed."""
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util,
        "find_spec",
        lambda name, *a: None if name == "cryptography" else real(name, *a),
    )


def test_without_the_tls_extra_bench_bus_measures_the_rest_and_says_what_is_missing(
    monkeypatch,
):
    """An install without cryptography (the README's, without the tls extra) leaves the
    mutual TLS row out, named with the install that measures it, instead of stopping after
    a minute of measurements with 'certificates need the cryptography package'."""
    from hera.bench import bus

    assert bus.measurable_modes() == ["none", "auth", "tls"]  # the test extras have it
    without_cryptography(monkeypatch)
    assert bus.measurable_modes() == ["none", "auth"]
    rows = bus.security_rows({"none": {"p50": 0.2, "p99": 0.4}, "auth": {"p50": 0.3, "p99": 0.5}})
    shown = {name: value for name, value, _, _ in rows}
    assert shown == {
        "1 kHz p50/p99, no security": "0.200 / 0.400 ms",
        "1 kHz p50/p99, user/password": "0.300 / 0.500 ms (+50 % at p50)",
        "1 kHz p50/p99, mutual TLS + ACL": "not measured: pip install 'hera-fusion[tls]'",
    }


def test_without_the_tls_extra_bench_scale_refuses_tls_before_starting_anything(
    monkeypatch, capsys
):
    """--security tls without cryptography: one sentence naming the install, exit code 2,
    at once (not after the configurations before it have run)."""
    from hera.bench import scale

    without_cryptography(monkeypatch)
    monkeypatch.setattr(scale, "run", None)  # starting a cluster would raise
    assert scale.main(["--quick", "--security", "auth,tls"]) == 2
    err = capsys.readouterr().err
    assert err == (
        "hera bench scale: --security tls needs the tls extra: pip install 'hera-fusion[tls]'\n"
    )
