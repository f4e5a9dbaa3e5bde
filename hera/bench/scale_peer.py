"""The peer of ``hera bench scale``: one node's traffic on bare zenoh-python.

``python -m hera.bench.scale_peer SPEC NODE`` opens the Zenoh session of node ``NODE`` of
the benchmark's spec exactly as a hera node opens it (:func:`hera.topology.bus_config`: the
same endpoints, mode, lease, keep-alive and scouting) and then runs nothing of hera's
runtime: one subscriber per stream the node's reader reads decodes each sample and counts
it, its seq gaps and its publish-to-receive time (wall clock); one thread publishes the
node's streams on the spec's wall-clock grid (their ``offset`` past every multiple of their
period, one wake for all; payload the msgpack of ``[seq, t, value]``). It is what a program
written straight on zenoh-python must do for the same traffic: the floor hera's rows are
compared with, in the same run and on the same Zenoh configuration.

The protocol with the benchmark, one line each way: the peer prints ``ready`` once its
session, subscribers and publishers are declared and it publishes; it then reads
``START END`` (epoch seconds) from its standard input, counts what arrives between the two,
and at ``END`` prints its figures as one JSON line (``received``, ``expected``, ``bins``: the
non-empty bins of its :class:`~hera.bench.latency.LatencyHistogram`) and exits.
"""

from __future__ import annotations

import json
import math
import sys
import threading
import time
from typing import Any

import msgpack

from hera.bench.latency import LatencyHistogram
from hera.bus import open_session
from hera.keys import Keys
from hera.spec import ClusterSpec, load_spec
from hera.topology import bus_config

STREAM = "hera.bench.scale:Stream"
READER = "hera.bench.scale:Reader"


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


def plan(spec: ClusterSpec, node: str) -> tuple[list[str], float, float, list[str]]:
    """The node's stream names, their period and offset (s), and the ``name/node`` it
    reads. ValueError when its streams do not share one period and offset."""
    spec_node = next(n for n in spec.nodes if n.name == node)
    names: list[str] = []
    timing: set[tuple[float, float]] = set()
    reads: list[str] = []
    for m in spec_node.measures:
        if m.use == STREAM:
            names.append(m.name or "s")
            timing.add((m.period or 0.0, m.offset or 0.0))
        elif m.use == READER:
            reads.extend(m.args.get("streams", ()))
    if len(timing) != 1 or min(timing)[0] <= 0:
        raise ValueError(f"node {node}: its streams need one period and offset, got {timing}")
    ((period, offset),) = timing
    return names, period, offset, reads


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
    names, period, offset, reads = plan(spec, node)
    counts = Counts()
    stop = threading.Event()
    session = open_session(bus_config(spec, node))
    try:
        for r in reads:
            name, _, source = r.partition("/")
            session.declare_subscriber(keys.data(name, source), counts.on_sample)
        pubs = [session.declare_publisher(keys.data(name, node)) for name in names]
        publisher = threading.Thread(target=publish, args=(pubs, period, offset, stop))
        publisher.start()
        try:
            print("ready", flush=True)
            start, end = (float(x) for x in sys.stdin.readline().split())
            counts.start, counts.end = start, end
            time.sleep(max(0.0, end - time.time()))
            print(json.dumps(counts.figures()), flush=True)
        finally:
            stop.set()
            publisher.join()
    finally:
        session.close()
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main(sys.argv[1:]))
