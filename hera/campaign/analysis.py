"""Figures of a run, as pure functions of its :class:`~hera.campaign.history.History`.

Per stream (from the campaign's own record, arrival times on one clock):

- its **baseline**: the median interval between samples in the quiet period before the
  first fault (its period as it runs), its longest gap there, and whether it is *bursty*
  (a longest gap above five periods: a sonar publishes nothing while the target is out of
  its beam) or *sparse* (under 10 samples: not judged on gaps or rates);
- when it **flows again** after a time: the first sample produced after it (arriving more
  than :data:`IN_FLIGHT` later, so a sample in flight does not count) after which the
  stream keeps at least half its rate for a second (a bursty stream: the first sample). A
  measure that audits its firings flows again at its first firing: a sonar's data stream
  stays silent while the target is out of its beam, its firings do not.

Per fault:

- **detect**: when the cluster noticed it: the first ``peer <node> down`` another node
  logged about a killed, stopped or cut-off node; the ``crashed`` / ``hung`` line of a
  measure's crash or hang;
- **recover**: from the moment the fault stopped acting (a kill's or crash's own moment,
  a pause's SIGCONT, a partition's healing) until every stream it affected flows again;
  for a measure's crash, from the logged crash;
- **flow**: for a fault on a sync group's host or on a firing measure, from the fault until
  the group's firings flow again: the first firing of a newer epoch when the leader
  changed, else the end of the pause the fault caused (0 if they never paused);
- **gap**: the longest gap of an affected stream around the fault;
- **restart**: for a measure's crash or hang, from its crash (or hang) line to its
  supervisor's ``restarted`` line: how long the measure was not running.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from hera.campaign.history import LOG_RESOLUTION_S, FaultRecord, Firing, History, Stream

IN_FLIGHT = 0.005
"""Seconds a sample may be on its way (loopback): arrivals this soon after a fault are of
samples produced before it."""
CRASH_NODE_DELAY = 0.05
"""A node asked to crash exits this long after logging it (``hera.control``)."""
NODE_FAULTS = ("kill", "pause", "crash_node", "skew", "board")
MEASURE_FAULTS = ("crash", "hang")
LINK_FAULTS = ("partition", "loss", "delay", "reset")


@dataclass(frozen=True)
class Baseline:
    """A stream's behaviour in the quiet period: its period (median interval, s), its
    longest gap (s), and how many samples it had."""

    period: float
    max_gap: float
    samples: int

    @property
    def sparse(self) -> bool:
        return self.samples < 10

    @property
    def bursty(self) -> bool:
        return self.max_gap > 5 * self.period


def baseline_of(s: Stream, window: tuple[float, float] | None) -> Baseline | None:
    """The stream's :class:`Baseline` over ``window`` (None without one, or under 3
    samples)."""
    if window is None:
        return None
    a = s.between(*window)
    if len(a) < 3:
        return None
    d = np.diff(a)
    return Baseline(float(np.median(d)), float(d.max()), len(a))


def flows_again(s: Stream, ref: float, base: Baseline | None, horizon: float) -> float | None:
    """When stream ``s`` flows again after ``ref`` (see the module docstring), or None if
    not before ``ref + horizon``."""
    a = s.arrival
    i = int(np.searchsorted(a, ref + IN_FLIGHT, side="right"))
    if base is None or base.sparse or base.bursty:
        return float(a[i]) if i < len(a) and a[i] <= ref + horizon else None
    span = max(1.0, 5 * base.period)
    need = max(2, int(0.5 * span / base.period))
    while i < len(a) and a[i] <= ref + horizon:
        j = int(np.searchsorted(a, a[i] + span, side="right"))
        if j - i >= need or j == len(a):
            return float(a[i])
        i += 1
    return None


def longest_gap(s: Stream, lo: float, hi: float) -> float:
    """The longest time without a sample of ``s`` within [lo, hi] (edges counted)."""
    a = s.arrival
    inside = a[(a > lo) & (a < hi)]
    pts = np.concatenate([[lo], inside, [hi]])
    return float(np.diff(pts).max()) if len(pts) > 1 else hi - lo


def affected(h: History, f: FaultRecord) -> list[Stream]:
    """The streams fault ``f`` acts on directly: a measure's own stream (crash, hang),
    every stream of the node it hit (kill, pause, board, skew), every stream of the nodes on
    its links (network faults)."""
    if f.kind in MEASURE_FAULTS and f.nodes:
        key = (str(f.planned.get("measure")), f.nodes[0])
        return [h.streams[key]] if key in h.streams else []
    nodes = set(f.nodes)
    if f.kind in LINK_FAULTS:
        nodes = {n for p in f.pairs for n in p}
    return [s for k, s in sorted(h.streams.items()) if k[1] in nodes]


def effect_time(h: History, f: FaultRecord) -> float | None:
    """When the fault took effect: a measure crash's or hang's log line on its node (the
    step after the request), a node's injected exit (its log line + 50 ms), else the
    moment it struck."""
    if f.start is None:
        return None
    if f.kind == "crash_node" and f.nodes:
        for e in h.log:
            if e.t >= f.start - 0.002 and e.node == f.nodes[0] and e.kind == "crash_node":
                return e.t + CRASH_NODE_DELAY
        return f.start + CRASH_NODE_DELAY
    if f.kind in MEASURE_FAULTS and f.nodes:
        kind = "crashed" if f.kind == "crash" else "hung"
        for e in h.log:
            if (
                e.t >= f.start - 0.002
                and e.node == f.nodes[0]
                and e.kind == kind
                and e.subject == f.planned.get("measure")
            ):
                return e.t
        return None
    return f.start


def detection_expected(h: History, f: FaultRecord) -> bool:
    """Whether the cluster must notice the fault: a killed node always (its sockets close);
    a stopped node or a cut link only when it lasted a whole link lease (a shorter stall is
    no failure to the bus, by design: ``[cluster] lease_ms``)."""
    if f.start is None:
        return False
    if f.kind in ("kill", "crash_node"):
        return True
    lease = h.spec.lease_ms / 1000.0
    if f.kind == "pause":
        return (f.until or f.start) - f.start >= lease
    if f.kind == "partition":  # a flapping one: each cut on its own
        longest = f.planned.get("flap_on_s") or max((b - a for a, b in f.cuts()), default=0.0)
        return longest >= lease
    return False


def detect(h: History, f: FaultRecord) -> float | None:
    """Seconds from the fault to the cluster noticing it (module docstring), or None."""
    if f.start is None:
        return None
    if f.kind in MEASURE_FAULTS:
        t = effect_time(h, f)
        return None if t is None else max(0.0, t - f.start)
    if f.kind in ("kill", "pause", "crash_node"):
        watched = {(o, f.nodes[0]) for o in _names(h) if o != f.nodes[0]}
        t0 = effect_time(h, f)
        hi = t0 + 15.0
    elif f.kind in ("partition", "reset"):
        watched = {(a, b) for a, b in f.pairs} | {(b, a) for a, b in f.pairs}
        t0, hi = f.start, (f.until or f.start) + 15.0
    else:
        return None
    lo = t0 - LOG_RESOLUTION_S  # a line stamped in the millisecond the fault struck
    for e in h.log:
        if e.kind == "peer_down" and lo < e.t <= hi and (e.node, e.subject) in watched:
            return max(0.0, e.t - t0)
    return None


def fires_again(h: History, node: str, measure: str, ref: float, horizon: float) -> float | None:
    """The first firing of ``node``'s ``measure`` after ``ref`` (None: not before
    ``ref + horizon``)."""
    for x in h.firings:  # recorded where they happen: nothing is in flight
        if x.node == node and x.measure == measure and ref < x.start <= ref + horizon:
            return x.start
    return None


def recover(
    h: History, f: FaultRecord, bases: dict[tuple[str, str], Baseline | None], horizon: float
) -> tuple[float | None, dict[str, float | None]]:
    """Seconds from the fault's end (its effect, for an instantaneous fault) until every
    affected stream flows again; and the same per stream (None: not within ``horizon``).
    Sparse and bursty data streams (no steady rate to come back to) are listed but do not
    count, unless no other stream is affected: then each must have a sample again."""
    ref = effect_time(h, f) if f.kind in (*MEASURE_FAULTS, "crash_node") else f.until
    if ref is None:
        return None, {}
    audited = {(v["measure"], v["node"]) for v in h.meta.get("fire_logs", {}).values()}
    per: dict[str, float | None] = {}
    judged = []
    for s in affected(h, f):
        b = bases.get(s.key)
        if s.key in audited:
            t = fires_again(h, s.node, s.name, ref, horizon)
        else:
            t = flows_again(s, ref, b, horizon)
        label = f"{s.name}@{s.node}"
        per[label] = None if t is None else t - ref
        if s.key in audited or (b is not None and not b.sparse and not b.bursty):
            judged.append(label)
    judged = judged or list(per)
    if not judged or any(per[k] is None for k in judged):
        return None, per
    return max(per[k] for k in judged), per


def restart(h: History, f: FaultRecord) -> float | None:
    """Seconds from a measure's crash or hang to its restart (module docstring)."""
    if f.kind not in MEASURE_FAULTS or not f.nodes:
        return None
    t0 = effect_time(h, f)
    if t0 is None:
        return None
    for e in h.log:
        if (
            e.kind == "restarted"
            and e.node == f.nodes[0]
            and e.subject == f.planned.get("measure")
            and t0 <= e.t <= t0 + 60.0
        ):
            return e.t - t0
    return None


def fault_gap(
    h: History, f: FaultRecord, bases: dict[tuple[str, str], Baseline | None], horizon: float
) -> float | None:
    """The longest gap of an affected stream (its firings, for an auditing measure; sparse
    and bursty data streams left out) from the fault until ``horizon`` s after it."""
    if f.start is None:
        return None
    lo, hi = f.start, (f.until or f.start) + horizon
    audited = {(v["measure"], v["node"]) for v in h.meta.get("fire_logs", {}).values()}
    gaps = []
    for s in affected(h, f):
        b = bases.get(s.key)
        if s.key in audited:
            starts = [x.start for x in h.firings if x.node == s.node and x.measure == s.name]
            pts = np.array([lo, *[t for t in starts if lo < t < hi], hi])
            gaps.append(float(np.diff(pts).max()))
        elif b is not None and not b.sparse and not b.bursty:
            gaps.append(longest_gap(s, lo, hi))
    return max(gaps) if gaps else None


def touches_sync(h: History, f: FaultRecord) -> bool:
    """Whether the fault hits a host of a sync group or a firing measure."""
    hosts = {n for hs in h.spec.sync_groups().values() for n in hs}
    firing = {(v["node"], v["measure"]) for v in h.meta.get("fire_logs", {}).values()}
    nodes = set(f.nodes) | {n for p in f.pairs for n in p}
    if f.kind in MEASURE_FAULTS:
        return bool(f.nodes) and (f.nodes[0], f.planned.get("measure")) in firing
    return bool(nodes & (hosts | {n for n, _ in firing}))


def flow(h: History, f: FaultRecord, until: float) -> float | None:
    """Seconds from the fault until the firings of the sync groups flow again (module
    docstring); None when the fault does not touch a sync group, or when they do not
    resume before ``until`` (the next fault, or a horizon)."""
    if f.start is None or not h.firings or not touches_sync(h, f):
        return None
    fs = h.firings
    before = [x for x in fs if x.start < f.start]
    epochs = [x.epoch for x in before if x.epoch is not None]
    e0 = max(epochs) if epochs else None
    hi = until
    after = [x for x in fs if f.start <= x.start <= hi]
    if not after:
        return None
    newer = [x for x in after if e0 is not None and x.epoch is not None and x.epoch > e0]
    if newer:
        return newer[0].start - f.start
    # no new term: did the firings pause around the fault, beyond their usual gaps?
    starts = [x.start for x in before[-20:]]
    usual = float(np.median(np.diff(starts))) if len(starts) > 2 else 0.0
    near = [x.start for x in before[-1:]] + [
        x.start for x in after if x.start <= (f.until or f.start) + 2.0
    ]
    worst, at = 0.0, None
    for a, b in zip(near, near[1:], strict=False):
        if b - a > worst:
            worst, at = b - a, b
    if at is None or worst <= 3 * usual:
        return 0.0
    return max(0.0, at - f.start)


def _names(h: History) -> list[str]:
    return [n.name for n in h.spec.nodes]


def fault_figures(h: History, horizon: float) -> list[dict[str, Any]]:
    """detect, recover, flow and gap of every fault (None where they do not apply or
    were not seen), with the per-stream recovery."""
    base = h.baseline()
    bases = {k: baseline_of(s, base) for k, s in h.streams.items()}
    starts = sorted(f.start for f in h.faults if f.start is not None)
    out = []
    for f in h.faults:
        rec, per = recover(h, f, bases, horizon)
        later = [t for t in starts if f.start is not None and t > f.start]
        until = min([*later[:1], (f.until or f.start or 0.0) + horizon])
        out.append(
            {
                "fault": f,
                "detect": detect(h, f),
                "detect_expected": detection_expected(h, f),
                "recover": rec,
                "per_stream": per,
                "flow": flow(h, f, until),
                "gap": fault_gap(h, f, bases, min(horizon, 5.0)),
                "restart": restart(h, f),
            }
        )
    return out


def firing_groups(firings: list[Firing]) -> dict[str, list[Firing]]:
    """Firings by sync group, each in start order."""
    out: dict[str, list[Firing]] = {}
    for x in sorted(firings, key=lambda x: x.start):
        out.setdefault(x.group, []).append(x)
    return out
