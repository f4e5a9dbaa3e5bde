"""The peer of the bus and scale benchmarks: a spec's traffic on bare zenoh-python.

``python -m hera.bench.peer SPEC NODE`` opens the Zenoh session of node ``NODE`` of a
cluster spec exactly as a hera node opens it (:func:`hera.topology.bus_config`: the same
endpoints, mode, lease, keep-alive and scouting; the spec's security is not applied) and
then runs nothing of hera's runtime. It publishes what the node's measures publish and
subscribes to what their node would take, and no more:

- one thread per (period, offset) of the node's measures puts, at each instant ``offset``
  past a multiple of the period on the wall clock, one sample under each of their names
  (payload: the msgpack of ``[seq, t, 1.0]``; a measure that declares no ``columns``
  publishes nothing);
- one subscriber per name its measures read (:meth:`hera.measure.Measure.reads`:
  ``name``, ``prefix*`` or ``name/node``; a full mirror ``data/**`` when one of them reads
  everything, the node keeps a full store or writes the cluster's CSV log) decodes each
  sample and counts it, its seq gaps and its publish-to-receive time (wall clock).

It is what a program written straight on zenoh-python must do for the same traffic: the
floor hera's figures are compared with, in the same run and on the same Zenoh
configuration. The measures' own work (what a counter counts) is not done.

The protocol with the benchmark, one line each way: the peer prints ``ready`` once its
session, subscribers and publishers are declared and it publishes; it then reads ``START
END`` (epoch seconds) from its standard input, counts what arrives between the two, and at
``END`` prints its figures as one JSON line (``received``, ``expected``, ``bins``: the
non-empty bins of its :class:`~hera.bench.latency.LatencyHistogram`) and exits.
:func:`measure` runs a whole cluster of peers that way.
"""

from __future__ import annotations

import contextlib
import json
import math
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgpack

from hera.bench.latency import LatencyHistogram
from hera.bench.machine import MachineWindow, cpu_seconds, rss_mb
from hera.bus import open_session
from hera.keys import Keys
from hera.spec import ClusterSpec, load_spec
from hera.topology import bus_config

WARMUP = 3.0
"""Seconds of the peers' traffic before their window: links settled, caches warm."""


class Counts:
    """What one peer received between ``start`` and ``end`` (epoch seconds; nothing is
    counted until they are set)."""

    def __init__(self) -> None:
        self.start, self.end = math.inf, math.inf
        self.first: dict[str, int] = {}
        self.last: dict[str, int] = {}
        self.received = 0
        self.latency = LatencyHistogram()
        self.lock = threading.Lock()

    def on_sample(self, sample: Any) -> None:
        """Decode one sample and count it when it arrives inside the window."""
        now = time.time()
        seq, t, _value = msgpack.unpackb(sample.payload.to_bytes())
        if not self.start <= now < self.end:
            return
        key = str(sample.key_expr)
        with self.lock:
            self.first.setdefault(key, seq)
            self.last[key] = seq
            self.received += 1
            self.latency.add(now - t)

    def figures(self) -> dict[str, Any]:
        """``received``, ``expected`` (from the first and last seq of each stream) and the
        latency histogram's non-empty bins."""
        with self.lock:
            expected = sum(self.last[k] - self.first[k] + 1 for k in self.last)
            return {
                "received": self.received,
                "expected": expected,
                "bins": self.latency.sparse(),
            }


@dataclass
class Plan:
    """One node's traffic: the names it publishes by (period, offset) in seconds, and
    the names it takes (None: every sample of the cluster)."""

    groups: dict[tuple[float, float], list[str]] = field(default_factory=dict)
    reads: list[str] | None = field(default_factory=list)


def plan(spec: ClusterSpec, node: str) -> Plan:
    """The traffic of ``node`` of ``spec`` (its measures' classes say what they read);
    ValueError for a synchronised measure (the peer has no sync service)."""
    from hera.plugins import find_measure

    out = Plan()
    mirror = spec.node(node).store == "all" or spec.log_node == node
    for m in spec.node(node).measures:
        cls = find_measure(m.use)
        r = m.resolve(cls)
        if r.sync:
            raise ValueError(f"node {node}: measure {r.name} is synchronised: not in the peer")
        if cls.columns:  # a measure without columns publishes nothing (a reader)
            out.groups.setdefault((float(r.period), r.offset or 0.0), []).append(str(r.name))
        names = cls.reads(cls.prepare_args(m.args))
        if names is None:
            mirror = True
        else:
            out.reads.extend(n for n in names if n not in out.reads)
    if mirror:
        out.reads = None
    return out


def publish(pubs: list[Any], period: float, offset: float, stop: threading.Event) -> None:
    """Put the next sample of every publisher at each instant ``offset`` past a multiple of
    ``period`` on the wall clock, until ``stop`` is set: one wake for all of them."""
    seq = 0
    packb = msgpack.packb
    now = time.time()
    due = now + (offset - now) % period
    while not stop.wait(max(0.0, due - time.time())):
        seq += 1
        t = time.time()
        payload = packb([seq, t, 1.0])
        for pub in pubs:
            pub.put(payload)
        due += period
        now = time.time()
        if now > due:  # late past the next instant: the next one on the grid, as a worker
            due = now + (offset - now) % period


def main(argv: list[str]) -> int:
    """Run one peer (see the module docstring); returns 0."""
    spec_path, node = argv
    spec = load_spec(spec_path)
    keys = Keys(spec.name)
    traffic = plan(spec, node)
    counts = Counts()
    stop = threading.Event()
    session = open_session(bus_config(spec, node))
    threads = []
    try:
        reads = ["**"] if traffic.reads is None else traffic.reads
        for r in reads:
            key = f"{keys.prefix}/data/**" if r == "**" else keys.data_read(r)
            session.declare_subscriber(key, counts.on_sample)
        for (period, offset), names in traffic.groups.items():
            pubs = [session.declare_publisher(keys.data(name, node)) for name in names]
            threads.append(threading.Thread(target=publish, args=(pubs, period, offset, stop)))
            threads[-1].start()
        print("ready", flush=True)
        start, end = (float(x) for x in sys.stdin.readline().split())
        counts.start, counts.end = start, end
        time.sleep(max(0.0, end - time.time()))
        print(json.dumps(counts.figures()), flush=True)
    finally:
        stop.set()
        for t in threads:
            t.join()
        session.close()
    return 0


# -- the benchmark's side ----------------------------------------------------------------
def _wait_listening(port: int, procs: list[subprocess.Popen], deadline: float) -> None:
    """Return once 127.0.0.1:``port`` takes connections; RuntimeError when a process of
    ``procs`` ended or ``deadline`` (monotonic) passed first."""
    while True:
        with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), 0.5):
            return
        if time.monotonic() > deadline or any(p.poll() is not None for p in procs):
            raise RuntimeError(f"the router on port {port} did not listen")
        time.sleep(0.05)


@dataclass
class Measured:
    """What :func:`measure` found: each peer's figures (``received``, ``expected``,
    ``bins``), the CPU seconds the peers used in ``elapsed`` seconds, their RSS (MB), the
    machine's window and the routers' RSS (MB)."""

    readers: list[dict[str, Any]]
    cpu_seconds: float
    elapsed: float
    rss: list[float]
    window: MachineWindow
    router_rss: list[float]


@contextlib.contextmanager
def _processes(
    spec: ClusterSpec, path: Path
) -> Iterator[tuple[list[subprocess.Popen], list[subprocess.Popen]]]:
    """The spec's routers (``hera router``, each listening before the peers start) and one
    peer per node; all stopped on the way out."""
    from hera.launcher import module_command, node_command

    quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    procs: list[subprocess.Popen] = []
    try:
        for r in spec.routers:
            procs.append(
                subprocess.Popen(node_command("router", str(path), "--name", r.name), **quiet)
            )
        for r in spec.routers:  # a client whose router does not listen yet gives up
            _wait_listening(r.port, procs, time.monotonic() + 30)
        peers = [
            subprocess.Popen(
                module_command("hera.bench.peer", str(path), node.name),
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=subprocess.DEVNULL,
                text=True,
            )
            for node in spec.nodes
        ]
        routers = procs[:]
        procs += peers
        yield routers, peers
    finally:
        for p in procs:
            if p.poll() is None:
                p.terminate()
        for p in procs:
            try:
                p.wait(30)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


def measure(spec: ClusterSpec, folder: Path, seconds: float) -> Measured:
    """Run the peers of every node of ``spec`` (its listeners need ports; ``folder`` takes
    its resolved copy) and measure them over ``seconds``, from :data:`WARMUP` s after every
    peer said it publishes. RuntimeError when a peer or router does not come up or end."""
    path = folder / "cluster.json"
    path.write_text(spec.with_security(auth=False, tls=False, access_control=False).to_json())
    with _processes(spec, path) as (routers, peers):
        for p in peers:  # EOF when it failed (its exit code says so)
            if p.stdout.readline().strip() != "ready":
                raise RuntimeError(f"a zenoh peer exited with code {p.wait(10)}")
        start = time.time() + WARMUP
        for p in peers:
            p.stdin.write(f"{start!r} {start + seconds!r}\n")
            p.stdin.flush()
        time.sleep(max(0.0, start - time.time()))
        window = MachineWindow()
        c0, t0 = sum(cpu_seconds(p.pid) for p in peers), time.monotonic()
        window.sleep(seconds)
        c1, t1 = sum(cpu_seconds(p.pid) for p in peers), time.monotonic()
        rss = [rss_mb(p.pid) for p in peers]
        router_rss = [rss_mb(p.pid) for p in routers]
        readers = []
        for p in peers:
            try:
                out, _ = p.communicate(timeout=30)
            except subprocess.TimeoutExpired:
                raise RuntimeError("a zenoh peer did not end after its window") from None
            if p.returncode != 0 or not out.strip():
                raise RuntimeError(f"a zenoh peer exited with code {p.returncode}")
            r = json.loads(out.splitlines()[-1])
            r["bins"] = {int(k): int(v) for k, v in r["bins"].items()}
            readers.append(r)
    return Measured(readers, c1 - c0, t1 - t0, rss, window, router_rss)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main(sys.argv[1:]))
