"""Watching streams on the bus: ``hera echo``, ``hera hz`` and ``hera store`` (the
``ros2 topic echo`` / ``hz`` habits).

A stream is a ``(name, node)`` pair published on ``hera/<cluster>/data/<name>/<node>``. A
stream argument is ``NAME`` (every node), ``NAME/NODE``, or either with ``*`` wildcards
(``obs*``, ``*/n1``). :class:`RateStats` keeps what ``hz`` prints for one stream: the rate,
the jitter of the intervals (their standard deviation, on the receiver's clock and on the
measurement times) and the gaps (intervals longer than :data:`GAP_FACTOR` times the median
interval, and samples lost by seq).
"""

from __future__ import annotations

import math
import statistics
import time
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from hera import wire
from hera.keys import Keys, glob_chunk

GAP_FACTOR = 2.0
"""An interval longer than this many median intervals is a gap."""
WINDOW = 2000
"""Intervals kept per stream for the rate and jitter figures."""


def stream_selector(keys: Keys, stream: str) -> str:
    """The data key expression of a stream argument (see the module docstring);
    ValueError naming the argument when it has more than one '/'."""
    parts = stream.strip("/").split("/")
    if not stream.strip("/") or len(parts) > 2 or not all(parts):
        raise ValueError(f"stream {stream!r}: give NAME or NAME/NODE (wildcards '*' allowed)")
    node = glob_chunk(parts[1], "node") if len(parts) == 2 else "*"
    return keys.data(glob_chunk(parts[0], "stream name"), node)


def stream_note(spec: Any, stream: str) -> str | None:
    """A sentence for a stream argument that names no publication of the cluster's spec
    (a typo shows at once rather than as silence), or None (also without a spec). Only a
    note: a measure started at run time (``hera start``) may publish the name later."""
    from fnmatch import fnmatchcase

    if spec is None:
        return None

    parts = stream.strip("/").split("/")
    names = sorted({str(m.name) for _, m in spec.measures()})
    nodes = [n.name for n in spec.nodes]
    if not any(fnmatchcase(x, parts[0]) for x in names):
        return (
            f"no measure of the spec publishes {parts[0]!r} (names: {', '.join(names)}); "
            "waiting in case one is started at run time"
        )
    if len(parts) == 2 and not any(fnmatchcase(x, parts[1]) for x in nodes):
        return f"no node {parts[1]!r} in the spec (nodes: {', '.join(nodes)}); waiting anyway"
    return None


def decode_sample(keys: Keys, key: str, payload: bytes) -> dict[str, Any]:
    """One sample of the bus as a JSON-able dict: name, node, seq, t, values (and grant);
    ValueError (WireError) naming what was wrong."""
    name, node = keys.parse_data(key)
    msg = wire.decode(payload)
    out: dict[str, Any] = {
        "name": name,
        "node": node,
        "seq": msg.seq,
        "t": msg.t,
        "values": list(msg.values),
    }
    if msg.grant is not None:
        out["grant"] = list(msg.grant)
    return out


def format_sample(sample: Mapping[str, Any], columns: Sequence[str] = ()) -> str:
    """One line for ``hera echo``: stream, seq, measurement time and the values (named by
    ``columns`` when there are as many)."""
    values = sample["values"]
    if len(columns) == len(values):
        shown = "  ".join(f"{c}={v:.6g}" for c, v in zip(columns, values, strict=True))
    else:
        shown = "  ".join(f"{v:.6g}" for v in values)
    stamp = time.strftime("%H:%M:%S", time.localtime(sample["t"])) + f"{sample['t'] % 1:.3f}"[1:]
    return f"{sample['name']}/{sample['node']} seq={sample['seq']} t={stamp}  {shown}"


@dataclass
class RateStats:
    """Arrivals of one stream (see the module docstring)."""

    count: int = 0
    lost: int = 0
    last_seq: int | None = None
    last_arrival: float | None = None
    last_t: float | None = None
    arrivals: deque = field(default_factory=lambda: deque(maxlen=WINDOW))
    measured: deque = field(default_factory=lambda: deque(maxlen=WINDOW))

    def add(self, seq: int, t: float, arrival: float) -> None:
        """Count one sample: its seq, measurement time ``t`` and arrival time (s)."""
        self.count += 1
        if self.last_seq is not None and seq > self.last_seq + 1:
            self.lost += seq - self.last_seq - 1
        if self.last_arrival is not None:
            self.arrivals.append(arrival - self.last_arrival)
            self.measured.append(t - self.last_t)
        self.last_seq, self.last_arrival, self.last_t = seq, arrival, t

    def summary(self) -> dict[str, float | int | None]:
        """rate_hz, jitter_ms (std dev of the arrival intervals), t_jitter_ms (of the
        measurement-time intervals), min_ms/max_ms (shortest and longest interval), gaps
        (intervals > GAP_FACTOR x the median), lost (by seq) and count."""
        xs = list(self.arrivals)
        out: dict[str, float | int | None] = {"count": self.count, "lost": self.lost}
        if len(xs) < 2:
            return {**out, "rate_hz": None, "jitter_ms": None, "gaps": 0}
        mean = statistics.fmean(xs)
        median = statistics.median(xs)
        gaps = [x for x in xs if x > GAP_FACTOR * median]
        return {
            **out,
            "rate_hz": 1.0 / mean if mean > 0 else math.inf,
            "jitter_ms": 1e3 * statistics.pstdev(xs),
            "t_jitter_ms": 1e3 * statistics.pstdev(self.measured),
            "min_ms": 1e3 * min(xs),
            "max_ms": 1e3 * max(xs),
            "gaps": len(gaps),
        }


class RateTable:
    """:class:`RateStats` of every stream seen, fed from bus samples (thread-safe enough:
    one Zenoh callback thread per subscription adds, the printer reads copies)."""

    def __init__(self, keys: Keys) -> None:
        self.keys = keys
        self.streams: dict[tuple[str, str], RateStats] = {}
        self.rejected = 0

    def on_sample(self, sample: Any) -> None:
        """Zenoh callback: count one sample (a malformed one is counted as rejected)."""
        now = time.monotonic()
        try:
            s = decode_sample(self.keys, str(sample.key_expr), sample.payload.to_bytes())
        except ValueError:
            self.rejected += 1
            return
        stats = self.streams.setdefault((s["name"], s["node"]), RateStats())
        stats.add(s["seq"], s["t"], now)

    def render(self) -> str:
        """A table: one line per stream."""
        lines = [
            f"{'stream':<28} {'rate Hz':>8} {'jitter ms':>9} {'min ms':>7} {'max ms':>7} "
            f"{'gaps':>5} {'lost':>5} {'count':>7}"
        ]
        for (name, node), st in sorted(self.streams.items()):
            s = st.summary()
            if s["rate_hz"] is None:
                lines.append(
                    f"{name + '/' + node:<28} {'-':>8} {'':>9} {'':>7} {'':>7} "
                    f"{0:>5} {s['lost']:>5} {s['count']:>7}"
                )
                continue
            lines.append(
                f"{name + '/' + node:<28} {s['rate_hz']:>8.2f} {s['jitter_ms']:>9.2f} "
                f"{s['min_ms']:>7.1f} {s['max_ms']:>7.1f} {s['gaps']:>5} {s['lost']:>5} "
                f"{s['count']:>7}"
            )
        if self.rejected:
            lines.append(f"rejected (malformed) samples: {self.rejected}")
        return "\n".join(lines)


def stream_columns(spec: Any) -> dict[str, tuple[str, ...]]:
    """Publication name -> output columns of every measure of a cluster spec whose class
    loads here (for naming values); none without a spec (a cluster reached by ``--connect``)."""
    from hera.plugins import find_measure

    out: dict[str, tuple[str, ...]] = {}
    for _, m in spec.measures() if spec is not None else ():
        try:
            out.setdefault(str(m.name), tuple(find_measure(m.use).columns))
        except (LookupError, TypeError):
            continue
    return out


def format_store(samples: Sequence[Mapping[str, Any]], columns: Mapping[str, Sequence[str]]) -> str:
    """``hera store NODE``: one line per (name, node) the store holds, with its seq, the
    age of its arrival and its values (named by the measure's columns when known)."""
    lines = [f"{'name':<18} {'from':<12} {'seq':>8} {'age ms':>9}  values"]
    for s in sorted(samples, key=lambda s: (s["name"], s["node"])):
        cols = columns.get(s["name"], ())
        values = s["values"]
        if len(cols) == len(values):
            shown = "  ".join(f"{c}={v:.6g}" for c, v in zip(cols, values, strict=True))
        else:
            shown = "  ".join(f"{v:.6g}" for v in values)
        lines.append(
            f"{s['name']:<18} {s['node']:<12} {s['seq']:>8} {1e3 * s['age_s']:>9.1f}  {shown}"
        )
    return "\n".join(lines)
