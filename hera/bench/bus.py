"""``hera bench bus``: the node runtime's figures on real node processes over loopback.

Prints, each measured in this run:

- publish-to-peer-store latency (p50, p99) between two node processes at 100 Hz and 1 kHz;
- how many messages per second one node's store absorbs from a flooding peer;
- the CPU share and the memory (RSS of each node) of the 5-node observer cluster
  (deploy/observers.toml: 20 counters at 10 Hz; a node that runs no filter loads neither
  numba nor numpy), and its CPU share once its counters are stopped through the control
  plane (truly idle: what the runtime itself costs); and the CPU share of its peer, the
  same traffic on bare zenoh-python (:mod:`hera.bench.peer`: each node's session
  configured as hera's, no security, no counting of alive observers), with the ratio;
- how fast a crashed measure runs again, and how fast peers notice a SIGKILLed and a
  SIGSTOPped node;
- the latency cost of security: publish-to-store p50 at 1 kHz with user/password
  authentication (the default), and with mutual TLS and access control, against no
  security at all, in
  alternating rounds of the same run,

next to the targets of issue 2 and the original Hera's published figures (thesis ch. 5).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import statistics
import subprocess
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

from hera import cliargs
from hera.bench.machine import cpu_seconds
from hera.bench.security import LABELS, MODES, TLS_HINT, measurable_modes, secure
from hera.bus import BusConfig, open_session
from hera.client import ClusterClient
from hera.launcher import node_command
from hera.security.access import OPERATOR
from hera.security.credentials import secured
from hera.supervisor import FAST_CRASH_S
from hera.wire import encode


def observers_spec() -> Path:
    """The observers example shipped in the package (``hera.deploy``)."""
    from hera.examples import examples

    return examples()["observers"]


PAIR = """
[cluster]
name = "{name}"
[[nodes]]
name = "a"
[[nodes.measures]]
use = "beacon"
name = "beacon"
period = {period}
[[nodes]]
name = "b"
store = "all"
"""


@contextlib.contextmanager
def running(spec_text: str | None, spec_path: Path | None = None) -> Iterator[ClusterClient]:
    """Start ``hera up`` on a spec in a temporary run dir; stop it and its nodes after."""
    with tempfile.TemporaryDirectory(prefix="hera-bench-") as tmp:
        if spec_path is None:
            spec_path = Path(tmp) / "spec.toml"
            spec_path.write_text(spec_text)
        run_dir = Path(tmp) / "run"
        env = {**os.environ, "HERA_REGISTRY": str(Path(tmp) / "registry")}
        proc = subprocess.Popen(
            node_command("up", str(spec_path), "--run-dir", str(run_dir), "--interval", "3600"),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            env=env,
        )
        client = None
        try:
            deadline = time.monotonic() + 30
            while not (run_dir / "launcher.json").exists():
                if time.monotonic() > deadline or proc.poll() is not None:
                    raise RuntimeError("the cluster did not start")
                time.sleep(0.05)
            client = ClusterClient.from_run_dir(run_dir)
            n = len(client.spec.nodes)
            while len(client.status(0.5)) < n:
                if time.monotonic() > deadline:
                    raise RuntimeError("not every node answered within 30 s")
                time.sleep(0.1)
            yield client
        finally:
            if client is not None:
                client.close()
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def latency(period: float, seconds: float, security: str = "auth") -> dict[str, float]:
    """Transit p50/p99 (ms) of node a's samples into node b's store at 1/period Hz, with
    the given security mode (:data:`hera.bench.security.MODES`)."""
    text = PAIR.format(name=f"lat{int(1 / period)}", period=period)
    with (
        tempfile.TemporaryDirectory(prefix="hera-bench-certs-") as certs,
        running(secure(text, security, certs)) as c,
    ):
        deadline = time.monotonic() + 30  # the window starts once a's stream reaches b
        while "a" not in c.query("b", "status")["b"]["transit_ms"]:
            if time.monotonic() > deadline:
                raise RuntimeError("node b received no sample of node a within 30 s")
            time.sleep(0.1)
        time.sleep(seconds)
        return c.query("b", "status")["b"]["transit_ms"]["a"]


def security_cost(
    seconds: float, rounds: int, modes: list[str] | None = None
) -> dict[str, dict[str, float]]:
    """Median over ``rounds`` alternating rounds of the 1 kHz transit p50 and p99 (ms) in
    each security mode of ``modes`` (default: every one of :data:`hera.bench.security.MODES`)."""
    modes = list(MODES) if modes is None else modes
    runs: dict[str, list[dict[str, float]]] = {mode: [] for mode in modes}
    for _ in range(rounds):
        for mode in modes:
            runs[mode].append(latency(0.001, seconds, mode))
    return {
        mode: {q: statistics.median(r[q] for r in rs) for q in ("p50", "p99")}
        for mode, rs in runs.items()
    }


def absorb(seconds: float) -> float:
    """Samples per second node b's store accepted while a local session floods it."""
    with (
        running(PAIR.format(name="absorb", period=1.0)) as c,
        open_session(secured(c.spec, OPERATOR, BusConfig(connect=(c.spec.endpoint("b"),)))) as s,
    ):
        pubs = [s.declare_publisher(f"hera/absorb/data/flood{i}/a") for i in range(8)]
        time.sleep(0.3)
        before = c.query("b", "status")["b"]["store"]["accepted"]
        t0 = time.monotonic()
        seq = 0
        now = time.time()
        while time.monotonic() - t0 < seconds:
            seq += 1
            payload = encode(seq, now, (1.0, 2.0, 3.0))
            for p in pubs:
                p.put(payload)
        time.sleep(0.5)  # let the receiver drain its queue
        after = c.query("b", "status")["b"]["store"]["accepted"]
        return (after - before) / (time.monotonic() - t0)


def _down_seen(c: ClusterClient, victim: str, since: float, timeout: float) -> float | None:
    """Seconds from ``since`` (wall) to the first peer reporting ``victim`` down."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        seen = [
            e["t"] - since
            for node, st in c.status(0.5).items()
            if node != victim
            for e in st["peer_events"]
            if e["node"] == victim and e["event"] == "down" and e["t"] >= since
        ]
        if seen:
            return min(seen)
        time.sleep(0.05)
    return None


def _cpu_share(pids: dict[str, int], seconds: float) -> float:
    """Percent of one core the processes ``pids`` used together over ``seconds``."""
    before = {n: cpu_seconds(p) for n, p in pids.items()}
    t0 = time.monotonic()
    time.sleep(seconds)
    span = time.monotonic() - t0
    return 100 * sum(cpu_seconds(p) - before[n] for n, p in pids.items()) / span


def _each_measure(c: ClusterClient, measures: dict[str, list[str]], verb: str) -> None:
    """Send ``verb`` (start or stop) for every measure of every node; RuntimeError if one
    is refused or unanswered."""
    for node, names in measures.items():
        for m in names:
            reply = c.query(node, verb, {"measure": m}).get(node, {})
            if not reply.get("ok"):
                raise RuntimeError(f"{verb} {m} on {node}: {reply.get('error', 'no answer')}")


def observers(cpu_seconds: float, crashes: int) -> dict[str, object]:
    """CPU share (counters running, then stopped), crash restart time and failure detection
    on the 5-node observer cluster."""
    out: dict[str, object] = {}
    with running(None, observers_spec()) as c:
        time.sleep(2.0)
        status = c.status(1.0)
        pids = {n: st["pid"] for n, st in status.items()}
        out["rss_mb"] = [st["rss_mb"] for st in status.values() if st.get("rss_mb") is not None]
        out["cpu_total_pct"] = _cpu_share(pids, cpu_seconds)
        out["cpu_machine_pct"] = out["cpu_total_pct"] / os.cpu_count()
        # truly idle: every counter stopped through the control plane, the nodes, their
        # links, liveliness and supervisors still running
        counters = {n: sorted(st["measures"]) for n, st in status.items()}
        _each_measure(c, counters, "stop")
        time.sleep(1.0)
        out["idle_cpu_pct"] = _cpu_share(pids, cpu_seconds)
        _each_measure(c, counters, "start")
        restarts = []
        for _ in range(crashes):
            # a crash of a measure that has run a while: one within FAST_CRASH_S of its
            # start is a crash loop, which the supervisor backs off from on purpose
            time.sleep(FAST_CRASH_S + 0.1)
            before_r = c.query("n2", "status")["n2"]["measures"]["obs1"]["restarts"]
            c.query("n2", "inject", {"fault": "crash", "measure": "obs1"})
            deadline = time.monotonic() + 5
            while time.monotonic() < deadline:
                m = c.query("n2", "status")["n2"]["measures"]["obs1"]
                if m["restarts"] > before_r and m["restart_ms"] is not None:
                    restarts.append(m["restart_ms"])
                    break
                time.sleep(0.02)
        out["restart_ms"] = restarts
        t_kill = time.time()
        os.kill(pids["n3"], signal.SIGKILL)
        out["sigkill_s"] = _down_seen(c, "n3", t_kill, 5.0)
        t_stop = time.time()
        os.kill(pids["n4"], signal.SIGSTOP)
        try:
            out["sigstop_s"] = _down_seen(c, "n4", t_stop, 10.0)
        finally:
            os.kill(pids["n4"], signal.SIGCONT)
    return out


def observers_peer(cpu_seconds: float) -> float:
    """Percent of one core the observer cluster's traffic costs on bare zenoh-python
    (:func:`hera.bench.peer.measure`), over ``cpu_seconds``."""
    from hera.bench.peer import measure
    from hera.ports import free_ports
    from hera.spec import load_spec

    spec = load_spec(observers_spec())
    spec = spec.with_ports(free_ports("127.0.0.1", len(spec.unported())))
    with tempfile.TemporaryDirectory(prefix="hera-bus-peer-") as tmp:
        m = measure(spec, Path(tmp), cpu_seconds)
    return 100 * m.cpu_seconds / m.elapsed


def security_rows(sec: dict[str, dict[str, float]]) -> list[tuple[str, str, str, str]]:
    """The table's rows of the security comparison: each mode's 1 kHz p50/p99 and its cost
    at p50 against no security; a mode not measured (the tls extra missing) says so."""
    rows = []
    base = sec["none"]["p50"]
    for mode, what in LABELS.items():
        target = "" if mode == "none" else "<= +30 %"
        if mode not in sec:
            rows.append((f"1 kHz p50/p99, {what}", f"not measured: {TLS_HINT}", target, ""))
            continue
        p50, p99 = sec[mode]["p50"], sec[mode]["p99"]
        cost = "" if mode == "none" else f" ({100 * (p50 / base - 1):+.0f} % at p50)"
        rows.append((f"1 kHz p50/p99, {what}", f"{p50:.3f} / {p99:.3f} ms{cost}", target, ""))
    return rows


def main(argv: list[str]) -> int:
    """Run the bus benchmark and print its table; returns 0."""
    ap = argparse.ArgumentParser(prog="hera bench bus", description=__doc__.splitlines()[0])
    ap.add_argument(
        "--seconds", type=cliargs.positive, default=5.0, help="duration of each latency run"
    )
    ap.add_argument(
        "--crashes", type=cliargs.non_negative_int, default=5, help="injected measure crashes"
    )
    ap.add_argument("--quick", action="store_true", help="short runs (for smoke tests)")
    ap.add_argument(
        "--rounds",
        type=cliargs.count,
        default=3,
        help="alternating rounds of the security comparison",
    )
    args = ap.parse_args(argv)
    secs = 1.0 if args.quick else args.seconds
    print("hera bench bus: real node processes, Zenoh peers on 127.0.0.1", flush=True)
    modes = measurable_modes()
    if "tls" not in modes:
        print(f"hera bench bus: the mutual TLS row needs the tls extra ({TLS_HINT})", flush=True)
    lat100 = latency(0.01, secs)
    lat1k = latency(0.001, secs)
    rate = absorb(1.0 if args.quick else 3.0)
    obs = observers(1.0 if args.quick else 5.0, 2 if args.quick else args.crashes)
    peer = observers_peer(1.0 if args.quick else 5.0)
    sec = security_cost(secs, 1 if args.quick else args.rounds, modes)

    def fmt(x, unit, digits=2):
        return "n/a" if x is None else f"{x:.{digits}f} {unit}"

    rs = obs["restart_ms"]
    mem = obs["rss_mb"]
    rows = [
        ("latency p50 @100 Hz", fmt(lat100.get("p50"), "ms", 3), "", ""),
        ("latency p99 @100 Hz", fmt(lat100.get("p99"), "ms", 3), "<= 2 ms", ""),
        ("latency p50 @1 kHz", fmt(lat1k.get("p50"), "ms", 3), "", ""),
        ("latency p99 @1 kHz", fmt(lat1k.get("p99"), "ms", 3), "", ""),
        ("store absorbs", f"{rate:,.0f} msg/s", "", ""),
        (
            "5-node observers CPU, 20 counters at 10 Hz",
            f"{obs['cpu_total_pct']:.1f} % of one core "
            f"({obs['cpu_machine_pct']:.1f} % of {os.cpu_count()} cores)",
            "<= 10 %",
            "",
        ),
        (
            "the same traffic on bare zenoh-python",
            f"{peer:.1f} % of one core (hera / zenoh: {obs['cpu_total_pct'] / peer:.2f}x)"
            if peer > 0
            else "n/a",
            "",
            "",
        ),
        (
            "5-node observers CPU, counters stopped",
            f"{obs['idle_cpu_pct']:.1f} % of one core",
            "<= 3 %",
            "",
        ),
        (
            "observer node RSS (each)",
            f"{min(mem):.0f}-{max(mem):.0f} MB" if mem else "n/a",
            "<= 50 MB",
            "",
        ),
        (
            "crashed measure running again",
            f"median {statistics.median(rs):.1f} ms, max {max(rs):.1f} ms" if rs else "n/a",
            "<= 100 ms",
            "about 2 s (thesis 5.1)",
        ),
        (
            "SIGKILLed node noticed",
            fmt(obs["sigkill_s"], "s", 3),
            "<= 0.5 s",
            "6-10 s (thesis 5.3)",
        ),
        ("SIGSTOPped node noticed", fmt(obs["sigstop_s"], "s", 3), "<= 3 s", "6-10 s (thesis 5.3)"),
    ]
    rows += security_rows(sec)
    w = max(len(r[0]) for r in rows)
    v = max(len(r[1]) for r in rows)
    print(f"{'figure':<{w}}  {'measured':<{v}}  {'target':<9}  original Hera")
    for name, value, target, ref in rows:
        print(f"{name:<{w}}  {value:<{v}}  {target:<9}  {ref}")
    kill, stop = obs["sigkill_s"], obs["sigstop_s"]
    if kill:
        print(f"ratio: SIGKILL detection {8.0 / kill:,.0f}x faster than the original's 8 s")
    if stop:
        print(f"ratio: hang detection {8.0 / stop:,.1f}x faster than the original's 8 s")
    return 0
