"""``hera bench scale``: many nodes on this machine, in a full peer mesh and behind routers.

For 8, 16 and 32 nodes (``--nodes``), each node publishes 4 streams at 50 Hz and reads the
4 streams of each of the 3 nodes after it (so every stream is read by 3 other nodes; stores
subscribe by interest and take nothing else). Two topologies: a full mesh of peers on
loopback (the embedded default), and client nodes behind one router (two for more than 16
nodes). Two ways to time the streams (``--phases``): ``grid``, the default of a spec (every
stream steps on the same wall-clock instants: 128 samples at once at 32 nodes), and
``staggered`` (node i's streams at ``offset = i / n`` of the period: the nodes take turns).
Measured after a warm-up, over ``--seconds``:

- delivered: samples received by the readers / samples the publishers sent in between
  (seq gaps count as losses);
- publish-to-store latency (wall clock, one host): p50 of the readers' medians, p99 of the
  worst reader, and p99 of every sample of every reader pooled (the cluster's p99);
- CPU per node (mean, % of one core) and in total (% of the machine), RSS per node;
- the whole machine (:mod:`hera.bench.machine`): ``busy %``, every process that ran (the
  cluster, its routers and anything beside it), ``steal %``, what the hypervisor of a
  virtual machine took, and ``worst``, its largest share of one 0.1 s interval (a host
  stalling the whole machine for a moment shows there; latency spikes that come with it
  are not the cluster's);

each in the security modes of ``--security`` (:mod:`hera.bench.security`: ``auth``, the
spec's default user and password with access control; ``tls``, mutual TLS with access
control; ``none``), then the peer, ``zenoh`` (unless ``--no-peer``): the same traffic on
bare zenoh-python (:mod:`hera.bench.peer`), every node's session configured as
hera's, no security, one thread per node publishing its four streams; a last table gives
hera's figures over the peer's for each configuration.

Targets (issue 14): 32 nodes, >= 99.9 % delivered and p99 <= 20 ms in the better topology.
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import zenoh

from hera import cliargs
from hera.bench.latency import LatencyHistogram
from hera.bench.machine import MachineWindow, cpu_seconds, rss_mb
from hera.bench.security import TLS_HINT, measurable_modes, modes, secure
from hera.client import ClusterClient
from hera.launcher import node_command
from hera.measure import Measure, MeasureContext
from hera.schema import Setting, Table, list_of, number, text

STREAMS = 4
READS = 3
PERIOD = 0.02
BIN_PREFIX = "lat_bin_"  # a reader's counters: its latency histogram's non-empty bins
PEER = "zenoh"
PEER_TEXT = "the same traffic on bare zenoh-python, no security (hera.bench.peer)"
NO_MACHINE = {"busy_pct": float("nan"), "steal_pct": float("nan"), "worst_steal_pct": float("nan")}


class Stream(Measure):
    """One published stream of the benchmark: a constant value every period."""

    name = "s"
    period = PERIOD
    columns = ("one [1]",)
    inputs = ()

    def measure(self) -> list[float]:
        return [1.0]


class Reader(Measure):
    """Counts every sample of its streams (after ``warmup`` s) and their transit time;
    reports in its status counters: received, expected (from the seqs), latency p50/p99 and
    its latency histogram's non-empty bins (``BIN_PREFIX``; the benchmark pools them)."""

    name = "reader"
    period = 0.5
    columns = ()
    arguments = Table(
        "reader args",
        [
            Setting("streams", list_of(text(), "a list of name/node"), (), "what it reads"),
            Setting("warmup", number(0), 3.0, "seconds before counting starts"),
        ],
    )

    @classmethod
    def reads(cls, args: Mapping[str, Any]) -> tuple[str, ...]:
        return tuple(cls.prepare_args(args)["streams"])

    def init(self, args: Mapping[str, Any], ctx: MeasureContext) -> None:
        args = self.prepare_args(args)
        super().init(args, ctx)
        self.start = time.monotonic() + args["warmup"]
        self.first: dict[tuple[str, str], int] = {}
        self.last: dict[tuple[str, str], int] = {}
        self.received = 0
        self.latency = LatencyHistogram()  # O(1) a sample: see hera.bench.latency
        self.lock = threading.Lock()
        ctx.store.add_listener(self._on_sample)

    def _on_sample(self, s: Any) -> None:
        if s.arrival < self.start:
            return
        key = (s.name, s.node)
        with self.lock:
            self.first.setdefault(key, s.seq)
            self.last[key] = s.seq
            self.received += 1
            self.latency.add(s.arrival_wall - s.t)

    def measure(self) -> None:
        with self.lock:
            expected = sum(self.last[k] - self.first[k] + 1 for k in self.last)
            received = self.received
            p50, p99 = self.latency.percentile(0.5), self.latency.percentile(0.99)
            bins = self.latency.sparse()
        c = self.ctx.counters
        c["received"], c["expected"] = received, expected
        if p50 is not None and p99 is not None:
            c["p50_ms"], c["p99_ms"] = 1e3 * p50, 1e3 * p99
        c.update({f"{BIN_PREFIX}{i}": n for i, n in bins.items()})
        return None

    def close(self) -> None:
        self.ctx.store.remove_listener(self._on_sample)


def spec_text(
    n: int, topology: str, warmup: float, phases: str = "grid", ports: bool = False
) -> str:
    """The benchmark cluster: ``n`` nodes, ``topology`` ``mesh`` or ``routers``, the streams
    on one grid (``phases`` ``grid``) or the nodes' in turn (``staggered``). ``ports``: the
    peers of a mesh get free ports written in (for processes that ``hera up`` does not
    start: :mod:`hera.bench.peer`)."""
    from hera.ports import free_ports

    lines = [f'[cluster]\nname = "scale{n}{topology}"\nlease_ms = 3000\n']
    routers = free_ports("127.0.0.1", 0 if topology == "mesh" else (1 if n <= 16 else 2))
    for r, port in enumerate(routers):
        lines.append(f'[[routers]]\nname = "r{r + 1}"\nport = {port}\n')
    node_ports = free_ports("127.0.0.1", n) if ports and not routers else []
    for i in range(n):
        node = f"n{i + 1}"
        lines.append(f'[[nodes]]\nname = "{node}"\n')
        if node_ports:
            lines.append(f"port = {node_ports[i]}\n")
        if routers:  # clients, split between the routers
            port = routers[i % len(routers)]
            lines.append(f'mode = "client"\nconnect = ["tcp/127.0.0.1:{port}"]\n')
        offset = f"offset = {PERIOD * i / n:.6f}\n" if phases == "staggered" else ""
        for k in range(1, STREAMS + 1):
            lines.append(
                f'[[nodes.measures]]\nuse = "hera.bench.scale:Stream"\nname = "s{k}"\n'
                f"period = {PERIOD}\n{offset}"
            )
        streams = [
            f"s{k}/n{(i + j) % n + 1}" for j in range(1, READS + 1) for k in range(1, STREAMS + 1)
        ]
        lines.append(
            '[[nodes.measures]]\nuse = "hera.bench.scale:Reader"\nname = "reader"\n'
            f"args = {{ streams = {streams!r}, warmup = {warmup} }}\n".replace("'", '"')
        )
    return "".join(lines)


@contextlib.contextmanager
def cluster(
    spec: str, security: str = "auth"
) -> Iterator[tuple[ClusterClient, subprocess.Popen, Path]]:
    """``hera up`` of ``spec`` in ``security`` mode in a temporary folder (its certificates
    there too), with a client of it; stopped after."""
    with tempfile.TemporaryDirectory(prefix="hera-scale-") as tmp:
        path = Path(tmp) / "spec.toml"
        path.write_text(secure(spec, security, Path(tmp) / "certs"))
        env = {**os.environ, "HERA_REGISTRY": str(Path(tmp) / "registry")}
        proc = subprocess.Popen(
            node_command(
                "up", str(path), "--run-dir", str(Path(tmp) / "run"), "--interval", "3600"
            ),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            env=env,
        )
        client = None
        try:
            deadline = time.monotonic() + 60
            while client is None:  # the launcher's routers may not listen yet
                if time.monotonic() > deadline or proc.poll() is not None:
                    raise RuntimeError("the cluster did not start")
                if (Path(tmp) / "run" / "launcher.json").exists():
                    with contextlib.suppress(zenoh.ZError):
                        client = ClusterClient.from_run_dir(Path(tmp) / "run")
                time.sleep(0.1)
            yield client, proc, Path(tmp)
        finally:
            if client is not None:
                client.close()
            proc.terminate()
            try:
                proc.wait(60)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def figures(
    readers: list[dict[str, Any]],
    cpu_seconds: float,
    elapsed: float,
    rss: list[float],
    window: MachineWindow,
    router_rss: list[float] = (),
) -> dict[str, float]:
    """The row of one run from its readers (``received``, ``expected``, ``bins``: a latency
    histogram's non-empty bins), the CPU seconds its nodes used in ``elapsed`` seconds,
    their RSS (MB), the machine's window and its routers' RSS (MB)."""
    pooled = LatencyHistogram()
    p50s, p99s = [], []
    for r in readers:
        one = LatencyHistogram()
        one.merge(r["bins"])
        pooled.merge(r["bins"])
        if (p50 := one.percentile(0.5)) is not None:
            p50s.append(1e3 * p50)
            p99s.append(1e3 * (one.percentile(0.99) or 0.0))
    p99_all = pooled.percentile(0.99)
    received = sum(r["received"] for r in readers)
    expected = sum(r["expected"] for r in readers)
    cpu = 100 * cpu_seconds / elapsed
    nan = float("nan")
    return {
        "answered": len(readers),
        "delivered_pct": 100 * received / expected if expected else nan,
        "p50_ms": statistics.median(p50s) if p50s else nan,
        "p99_ms": max(p99s) if p99s else nan,
        "p99_all_ms": nan if p99_all is None else 1e3 * p99_all,
        "cpu_node_pct": cpu / len(rss),
        "cpu_machine_pct": cpu / (os.cpu_count() or 1),
        "rss_mb": statistics.mean(rss),
        "router_rss_mb": max(router_rss) if router_rss else nan,
        **(window.figures() or NO_MACHINE),
    }


def run(
    n: int, topology: str, seconds: float, phases: str = "grid", security: str = "auth"
) -> dict[str, float]:
    """One configuration; its figures."""
    warmup = 5.0
    with cluster(spec_text(n, topology, warmup, phases), security) as (client, _proc, tmp):
        deadline = time.monotonic() + 90
        while len(client.status(timeout=2.0)) < n:
            if time.monotonic() > deadline:
                raise RuntimeError(f"not all {n} nodes answered")
            time.sleep(0.5)
        time.sleep(warmup)
        status = client.status(timeout=2.0)
        pids = [st["pid"] for st in status.values()]
        window = MachineWindow()
        c0, t0 = sum(cpu_seconds(p) for p in pids), time.monotonic()
        window.sleep(seconds)
        c1, t1 = sum(cpu_seconds(p) for p in pids), time.monotonic()
        status = client.status(timeout=3.0)
        launched = json.loads((tmp / "run" / "launcher.json").read_text())
        router_rss = [rss_mb(r["pid"]) for r in launched["routers"].values() if r["pid"]]
    readers = []
    for st in status.values():
        c = st["measures"]["reader"]["counters"]
        bins = {int(k[len(BIN_PREFIX) :]): int(v) for k, v in c.items() if k.startswith(BIN_PREFIX)}
        readers.append(
            {"received": c.get("received", 0), "expected": c.get("expected", 0), "bins": bins}
        )
    rss = [st.get("rss_mb") or 0.0 for st in status.values()]
    return figures(readers, c1 - c0, t1 - t0, rss, window, router_rss)


def peer_run(n: int, topology: str, seconds: float, phases: str = "grid") -> dict[str, float]:
    """The same configuration on bare zenoh-python (:mod:`hera.bench.peer`: every node's
    session configured as hera's, no hera runtime on it; routers ``hera router``), without
    security; its figures, as :func:`run`'s."""
    from hera.bench.peer import measure
    from hera.spec import parse_spec, tomllib

    spec = parse_spec(tomllib.loads(spec_text(n, topology, 0.0, phases, ports=True)), "scale")
    with tempfile.TemporaryDirectory(prefix="hera-scale-peer-") as tmp:
        m = measure(spec, Path(tmp), seconds)
    return figures(m.readers, m.cpu_seconds, m.elapsed, m.rss, m.window, m.router_rss)


def main(argv: list[str]) -> int:
    """Run the scale benchmark and print its table; returns 0."""
    ap = argparse.ArgumentParser(prog="hera bench scale", description=__doc__.splitlines()[0])
    ap.add_argument(
        "--nodes",
        type=cliargs.comma_separated(cliargs.whole_at_least(READS + 1)),
        default=[8, 16, 32],
        help=f"comma-separated node counts (each >= {READS + 1}: a node reads {READS} others)",
    )
    ap.add_argument(
        "--topologies",
        type=cliargs.comma_separated(cliargs.one_of("mesh", "routers")),
        default=["mesh", "routers"],
        help="mesh and/or routers",
    )
    ap.add_argument(
        "--phases",
        type=cliargs.comma_separated(cliargs.one_of("grid", "staggered")),
        default=["grid", "staggered"],
        help="grid and/or staggered",
    )
    ap.add_argument(
        "--seconds", type=cliargs.positive, default=15.0, help="measuring window per run"
    )
    ap.add_argument(
        "--security", default="auth", help="auth (the default), tls and/or none: see above"
    )
    ap.add_argument("--quick", action="store_true", help="8 nodes, 5 s (smoke test)")
    ap.add_argument(
        "--no-peer",
        dest="peer",
        action="store_false",
        help=f"skip the peer ({PEER}: {PEER_TEXT}) measured after each configuration",
    )
    args = ap.parse_args(argv)
    try:
        securities = modes(args.security, "--security")
    except ValueError as e:
        print(f"hera bench scale: {e}", file=sys.stderr)
        return 2
    if "tls" in securities and "tls" not in measurable_modes():
        print(f"hera bench scale: --security tls needs the tls extra: {TLS_HINT}", file=sys.stderr)
        return 2
    sizes = [8] if args.quick else args.nodes
    phases = ["grid"] if args.quick else args.phases
    seconds = 5.0 if args.quick else args.seconds
    print(
        f"hera bench scale: {STREAMS} streams at {1 / PERIOD:.0f} Hz per node, each read by "
        f"{READS} other nodes; {os.cpu_count()} cores",
        flush=True,
    )
    head = (
        f"{'nodes':>5} {'topology':<8} {'phases':<9} {'stack':<10} {'delivered %':>11} "
        f"{'p50 ms':>7} {'p99 ms':>7} {'p99 all':>7} {'CPU/node %':>10} {'machine %':>9} "
        f"{'RSS MB':>6} {'router':>6} {'busy %':>6} {'steal %':>7} {'worst':>5}"
    )
    print(head, flush=True)
    stacks = [f"hera/{sec}" for sec in securities] + ([PEER] if args.peer else [])
    ratios: list[str] = []
    for n, topology, phase in itertools.product(sizes, args.topologies, phases):
        rows: dict[str, dict[str, float]] = {}
        for stack in stacks:
            first = f"{n:>5} {topology:<8} {phase:<9} {stack:<10}"
            try:
                if stack == PEER:
                    r = peer_run(n, topology, seconds, phase)
                else:
                    r = run(n, topology, seconds, phase, stack.removeprefix("hera/"))
            except RuntimeError as e:
                print(f"{first} failed: {e}", flush=True)
                continue
            print(f"{first} {_row(r)}", flush=True)
            rows[stack] = r
        peer = rows.pop(PEER, None)
        if peer is not None:
            ratios += [
                f"{n:>5} {topology:<8} {phase:<9} {stack:<10} {_ratio(r, peer)}"
                for stack, r in rows.items()
            ]
    if ratios:
        print(f"hera / {PEER} (same configuration, same run; {PEER}: {PEER_TEXT}):")
        print(
            f"{'nodes':>5} {'topology':<8} {'phases':<9} {'stack':<10} "
            f"{'CPU/node':>8} {'p50':>6} {'p99 all':>7} {'RSS':>6}"
        )
        print("\n".join(ratios))
    print("targets: 32 nodes >= 99.9 % delivered, p99 <= 20 ms (the better topology)")
    return 0


def _row(r: dict[str, float]) -> str:
    return (
        f"{r['delivered_pct']:>11.3f} {r['p50_ms']:>7.2f} "
        f"{r['p99_ms']:>7.2f} {r['p99_all_ms']:>7.2f} {r['cpu_node_pct']:>10.1f} "
        f"{r['cpu_machine_pct']:>9.1f} {r['rss_mb']:>6.0f} {_mb(r['router_rss_mb'])} "
        f"{r['busy_pct']:>6.1f} "
        f"{r['steal_pct']:>7.1f} {r['worst_steal_pct']:>5.1f}"
    )


def _mb(x: float) -> str:
    """A router's RSS in the table, or "-" without routers (a mesh)."""
    return f"{'-':>6}" if math.isnan(x) else f"{x:>6.0f}"


def _ratio(r: dict[str, float], peer: dict[str, float]) -> str:
    """hera's figures over the peer's: CPU per node, p50, pooled p99, RSS."""

    def x(key: str) -> float:
        return r[key] / peer[key] if peer[key] > 0 else float("nan")

    return (
        f"{x('cpu_node_pct'):>7.2f}x {x('p50_ms'):>5.2f}x {x('p99_all_ms'):>6.2f}x "
        f"{x('rss_mb'):>5.2f}x"
    )


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main(sys.argv[1:]))
