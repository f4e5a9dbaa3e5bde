"""``hera bench console``: what the live web view costs and whether it keeps up.

On real node processes over loopback, with the page open in headless Chromium
(``/usr/bin/chromium``, Playwright for Python) and served by a ``hera view`` process:

1. the 5-node observer cluster (deploy/observers.toml, 20 streams at 10 Hz): the CPU of
   the nodes alone, then of the nodes plus the view server while the page is open; what
   the view adds (server + extra node CPU), in % of one core, against the target of 5 %;
2. the same cluster with its 20 observers at 100 Hz: the view server's CPU, how many
   points a second each plot receives, and how far behind the newest point on the page
   is (the page's lag), sampled every 0.5 s;
3. the time from opening the page to its first points, three times (target 2 s).

The peer of the comparison is the cluster without the view, measured in the same run.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import re
import signal
import statistics
import subprocess
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

from hera import cliargs
from hera.bench.bus import observers_spec
from hera.bench.machine import cpu_seconds
from hera.client import ClusterClient
from hera.launcher import node_command

FAST = re.compile(r"period = 0\.1\b")


def _node_pids(client) -> dict[str, int]:
    return {n: st["pid"] for n, st in client.status(1.0).items()}


def _view(run_dir: Path, env: dict) -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen(
        node_command("view", "--port", "0", "--run-dir", str(run_dir)),
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        env=env,
    )
    line = proc.stdout.readline()
    m = re.search(r"on (http://\S+)", line)
    if m is None:
        proc.kill()
        raise RuntimeError(f"hera view did not start: {line!r}")
    return proc, m.group(1)


def _browser(playwright, profile: str):
    return playwright.chromium.launch_persistent_context(
        profile,
        executable_path=os.environ.get("HERA_CHROMIUM", "/usr/bin/chromium"),
        headless=True,
        args=[
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
        ],
    )


@contextlib.contextmanager
def cluster(spec_path: Path) -> Iterator[tuple[ClusterClient, Path]]:
    """``hera up`` of a spec in a temporary run dir: its client and run dir; stopped after."""
    with tempfile.TemporaryDirectory(prefix="hera-bench-") as tmp:
        run_dir = Path(tmp) / "run"
        proc = subprocess.Popen(
            node_command("up", str(spec_path), "--run-dir", str(run_dir), "--interval", "3600"),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            env={**os.environ, "HERA_REGISTRY": str(Path(tmp) / "registry")},
        )
        client = None
        try:
            deadline = time.monotonic() + 30
            while not (run_dir / "launcher.json").exists():
                if time.monotonic() > deadline or proc.poll() is not None:
                    raise RuntimeError("the cluster did not start")
                time.sleep(0.05)
            client = ClusterClient.from_run_dir(run_dir)
            while len(client.status(0.5)) < len(client.spec.nodes):
                if time.monotonic() > deadline:
                    raise RuntimeError("not every node answered within 30 s")
                time.sleep(0.1)
            yield client, run_dir
        finally:
            if client is not None:
                client.close()
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def measure(spec_path: Path, seconds: float, streams: int) -> dict[str, float]:
    """Run one cluster: nodes alone, then with the view and the page open."""
    from playwright.sync_api import sync_playwright

    out: dict[str, float] = {}
    with cluster(spec_path) as (client, run_dir), tempfile.TemporaryDirectory() as profile:
        env = {**os.environ}
        pids = _node_pids(client)
        time.sleep(2.0)
        before = {n: cpu_seconds(p) for n, p in pids.items()}
        t0 = time.monotonic()
        time.sleep(seconds)
        span = time.monotonic() - t0
        out["nodes_alone_pct"] = (
            100 * sum(cpu_seconds(p) - before[n] for n, p in pids.items()) / span
        )
        view, url = _view(run_dir, env)
        try:
            with sync_playwright() as pw:
                browser = _browser(pw, profile)
                firsts = []
                for _ in range(3):
                    page = browser.new_page()
                    page.goto(
                        url
                        + "?streams="
                        + ",".join(f"obs{i % 4 + 1}/n{i // 4 + 1}" for i in range(streams))
                    )
                    page.wait_for_function("window.hera.firstPointsMs !== null", timeout=20000)
                    firsts.append(page.evaluate("window.hera.firstPointsMs"))
                    page.close()
                out["first_points_ms_max"] = max(firsts)
                page = browser.new_page()
                page.goto(
                    url
                    + "?streams="
                    + ",".join(f"obs{i % 4 + 1}/n{i // 4 + 1}" for i in range(streams))
                )
                page.wait_for_function("window.hera.firstPointsMs !== null", timeout=20000)
                time.sleep(2.0)
                v0 = cpu_seconds(view.pid)
                n0 = {n: cpu_seconds(p) for n, p in pids.items()}
                p0 = page.evaluate("Object.values(window.hera.points).reduce((a, b) => a + b, 0)")
                lags = []
                t0 = time.monotonic()
                while time.monotonic() - t0 < seconds:
                    time.sleep(0.5)
                    lag = page.evaluate(
                        "(() => { const p = window.hera.lastPoll; let worst = 0;"
                        " for (const s of window.hera.selected) {"
                        "  const d = p.data[s]; if (!d || !d.points.length) continue;"
                        "  worst = Math.max(worst, p.time - d.points[d.points.length - 1][1]); }"
                        " return worst; })()"
                    )
                    lags.append(lag)
                span = time.monotonic() - t0
                p1 = page.evaluate("Object.values(window.hera.points).reduce((a, b) => a + b, 0)")
                out["view_pct"] = 100 * (cpu_seconds(view.pid) - v0) / span
                out["nodes_with_view_pct"] = (
                    100 * sum(cpu_seconds(p) - n0[n] for n, p in pids.items()) / span
                )
                out["points_per_s_per_stream"] = (p1 - p0) / span / streams
                out["lag_p50_s"] = statistics.median(lags)
                out["lag_max_s"] = max(lags)
                browser.close()
        finally:
            view.terminate()
            view.wait(10)
    out["added_pct"] = out["view_pct"] + out["nodes_with_view_pct"] - out["nodes_alone_pct"]
    return out


def check_tools() -> None:
    """ImportError, in one sentence saying what to install, when Playwright, the console
    extra (the view's server) or the Chromium binary is missing."""
    import importlib.util

    missing = [m for m in ("playwright", "aiohttp") if importlib.util.find_spec(m) is None]
    chromium = os.environ.get("HERA_CHROMIUM", "/usr/bin/chromium")
    if not os.access(chromium, os.X_OK):
        missing.append(f"a Chromium at {chromium}")
    if missing:
        raise ImportError(
            f"the console benchmark drives the web view in a headless Chromium and lacks "
            f"{', '.join(missing)}: pip install 'hera-fusion[console]' playwright, and "
            "apt-get install chromium (or set HERA_CHROMIUM to a Chromium binary)"
        )


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="hera bench console", description=__doc__.split("\n")[0])
    p.add_argument(
        "--seconds", type=cliargs.positive, default=10.0, help="length of each measurement"
    )
    args = p.parse_args(argv)
    check_tools()
    spec = observers_spec()
    slow = measure(spec, args.seconds, 20)
    with tempfile.TemporaryDirectory() as tmp:
        fast_spec = Path(tmp) / "observers100.toml"
        text = spec.read_text().replace('name = "observers"', 'name = "observers100"')
        fast_spec.write_text(FAST.sub("period = 0.01", text))
        fast = measure(fast_spec, args.seconds, 20)
    print("hera bench console (5 nodes x 4 observers; page open in headless Chromium)")
    print(
        f"  20 streams at 10 Hz:  nodes alone {slow['nodes_alone_pct']:.1f} % of a core, "
        f"with the view {slow['nodes_with_view_pct']:.1f} % + view server "
        f"{slow['view_pct']:.1f} %"
    )
    print(
        f"    the view adds {slow['added_pct']:.1f} % of a core (target < 5 %: "
        f"{'met' if slow['added_pct'] < 5 else 'MISSED'})"
    )
    print(
        f"  20 streams at 100 Hz: view server {fast['view_pct']:.1f} % of a core, nodes "
        f"{fast['nodes_alone_pct']:.1f} -> {fast['nodes_with_view_pct']:.1f} %; "
        f"{fast['points_per_s_per_stream']:.1f} points/s per plot (10 expected); page lag "
        f"p50 {fast['lag_p50_s']:.2f} s, max {fast['lag_max_s']:.2f} s"
    )
    worst_first = max(slow["first_points_ms_max"], fast["first_points_ms_max"])
    print(
        f"  first points after opening the page: at most {worst_first:.0f} ms over 6 opens "
        f"(target 2000 ms: {'met' if worst_first < 2000 else 'MISSED'})"
    )
    return 0
