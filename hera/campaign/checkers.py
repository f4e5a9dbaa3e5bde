"""The checkers: each a pure function of what a run recorded, giving a :class:`Verdict`.

Like Jepsen's, they judge the history, not the intentions: the audit of real trigger
times, the campaign's own record of the bus, the nodes' logs and persisted state, the
fault journal. Each is proved by a test in which it must fail (``tests/campaign``).

==================  ============================================================
``schedule``        every planned fault struck (and was undone), the run was not
                    cut short and the cluster settled
``overlaps``        no two firings of a sync group overlap in real time (must be 0)
``stale_firings``   no firing ends past its grant's lease, none fires under an older
                    grant after a newer one fired (tokens increase in start order)
``sync_partitions`` per partition of a sync group's hosts: the majority side keeps
                    firing (again within ``failover_s``), the minority side stops
                    within one sync lease and fires again within
                    ``resume_within_s`` of the healing
``gaps``            outside the faults (and ``recovery_s`` after each), no stream
                    pauses longer than ``max_gap_periods`` periods, ``gap_floor_s``
                    or 1.5 times its longest baseline gap
``sequences``       no seq of a stream goes back or repeats
``args``            no replicated arg is lost: every node ends with the newest value
                    of every key, in memory and on disk, and no calibration is redone
                    after a restart
``recovery``        every fault is over within ``recover_within_s``: the streams it
                    hit flow again (and a killed or stopped node was noticed)
``estimates``       after each fault (past ``settle_s``) and in the tail, each judged
                    model's error is within ``factor`` x its baseline (or ``floor``)
``agreement``       the same model on two nodes agrees within the tolerances, and no
                    node stays silent while another publishes it
``restarts``        supervisors restarted within their intensity and escalated
                    exactly when it was exceeded; no node hit the launcher's limit
``figures``         each figure of ``[[figures]]`` within its target
``leftovers``       nothing of the run is left running
==================  ============================================================
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hera.campaign import analysis, estimates
from hera.campaign.history import Firing, History
from hera.campaign.schema import CHECKERS

EPS = 2e-6
"""Rounding of the fire logs' times (they are written to the microsecond)."""
EDGE_S = 0.5
"""Samples this close to the ends of a silence do not count as published during it."""


@dataclass
class Verdict:
    """A checker's verdict: ``passed``, a one-line ``summary``, and details as rows."""

    name: str
    passed: bool
    summary: str
    rows: list[dict[str, Any]] = field(default_factory=list)
    skipped: bool = False

    @property
    def status(self) -> str:
        if self.skipped:
            return "skipped"
        return "pass" if self.passed else "FAIL"


def _cfg(h: History, table: str) -> dict[str, Any]:
    return dict(h.meta.get("campaign", {}).get(table, {}))


def _fmt(x: float | None, unit: str = "s") -> str:
    if x is None:
        return "-"
    return f"{x * 1000:.0f} ms" if unit == "s" and abs(x) < 1 else f"{x:.2f} {unit}".strip()


# -- the schedule ---------------------------------------------------------------------------


def check_schedule(h: History) -> Verdict:
    rows, bad = [], []
    if h.meta.get("error"):
        bad.append(f"the run broke: {h.meta['error']}")
    if h.meta.get("settle_error"):
        bad.append(h.meta["settle_error"])
    if h.meta.get("interrupted"):
        bad.append("the run was interrupted before its schedule ended")
    for f in h.faults:
        state = "done"
        if f.error:
            state = f"failed: {f.error}"
            bad.append(f"{f.name}: {f.error}")
        elif not f.done:
            state = "not run"
            bad.append(f"{f.name}: never struck")
        elif f.planned.duration and f.end is None:
            state = "never undone"
            bad.append(f"{f.name}: never undone")
        elif f.end_error:
            state = f"undo failed: {f.end_error}"
            bad.append(f"{f.name}: undo failed: {f.end_error}")
        rows.append({"fault": f.name, "kind": f.kind, "nodes": ",".join(f.nodes), "state": state})
    if not bad:
        return Verdict("schedule", True, f"{len(h.faults)} faults struck and undone", rows)
    return Verdict("schedule", False, f"{len(bad)} problems: {bad[0]}", rows)


# -- firings --------------------------------------------------------------------------------


def overlapping(firings: list[Firing]) -> list[tuple[Firing, Firing]]:
    """Pairs of firings (start order) that overlap in time."""
    out = []
    fs = sorted(firings, key=lambda x: x.start)
    latest: Firing | None = None
    for cur in fs:
        if latest is not None and cur.start < latest.end - EPS:
            out.append((latest, cur))
        if latest is None or cur.end > latest.end:
            latest = cur
    return out


def check_overlaps(h: History) -> Verdict:
    if not h.meta.get("fire_logs"):
        return Verdict(
            "overlaps",
            False,
            "no firing audit: no measure of the run audits its firings (nothing to check)",
        )
    groups = analysis.firing_groups(h.firings)
    rows, total = [], 0
    for g, fs in sorted(groups.items()):
        ov = overlapping(fs)
        total += len(ov)
        rows.append({"group": g, "firings": len(fs), "overlaps": len(ov)})
        for a, b in ov[:20]:
            rows.append(
                {
                    "group": g,
                    "firings": f"{a.node} {a.start:.3f}-{a.end:.3f}",
                    "overlaps": f"{b.node} {b.start:.3f} ({(a.end - b.start) * 1000:.1f} ms)",
                }
            )
    n = sum(len(fs) for fs in groups.values())
    if not n:
        return Verdict("overlaps", False, "no firing was recorded", rows)
    return Verdict("overlaps", total == 0, f"{total} overlapping firings in {n}", rows)


def check_stale(h: History) -> Verdict:
    groups = analysis.firing_groups(h.firings)
    rows, late, disorder, unsync = [], [], [], 0
    for g, fs in sorted(groups.items()):
        synced = [x for x in fs if x.token is not None]
        unsync += len(fs) - len(synced)
        g_late = [x for x in synced if x.deadline is not None and x.end > x.deadline + EPS]
        g_dis = [(a, b) for a, b in zip(synced, synced[1:], strict=False) if b.token <= a.token]
        late += g_late
        disorder += g_dis
        rows.append(
            {
                "group": g,
                "synchronised firings": len(synced),
                "past their lease": len(g_late),
                "older grant after a newer one": len(g_dis),
            }
        )
    n = sum(len(fs) for fs in groups.values())
    if not n:
        return Verdict("stale_firings", False, "no firing was recorded", rows)
    bad = len(late) + len(disorder)
    summary = (
        f"{bad} stale firings ({len(late)} past their lease, {len(disorder)} under an "
        f"older grant) in {n - unsync} synchronised firings"
    )
    if unsync:
        summary += f"; {unsync} firings without a grant"
    return Verdict("stale_firings", bad == 0, summary, rows)


def partition_sides(h: History) -> list[dict[str, Any]]:
    """For each partition fault: per sync group, its majority and minority sides (the
    hosts the fault's sides hold) and the firing nodes on each."""
    groups = h.spec.sync_groups()
    firing_nodes = {x.node for x in h.firings}
    out = []
    for f in h.faults:
        if f.kind != "partition" or not f.done or not f.groups:
            continue
        for g, hosts in groups.items():
            for side in f.groups:
                held = [x for x in hosts if x in side]
                out.append(
                    {
                        "fault": f,
                        "group": g,
                        "side": side,
                        "majority": 2 * len(held) > len(hosts),
                        "firing": sorted(n for n in side if n in firing_nodes),
                    }
                )
    return out


def check_sync_partitions(h: History) -> Verdict:
    cfg = _cfg(h, "checks")
    lease = h.spec.sync_lease_ms / 1000.0
    rows, bad = [], []
    by_node: dict[tuple[str, str], list[Firing]] = {}
    for x in h.firings:
        by_node.setdefault((x.group, x.node), []).append(x)
    sides = partition_sides(h)
    if not sides:
        return Verdict("sync_partitions", True, "no partition of sync hosts in this run", [])
    for s in sides:
        f, g = s["fault"], s["group"]
        lo, hi = f.start, f.until
        for node in s["firing"]:
            fs = [x.start for x in by_node.get((g, node), [])]
            during = [t for t in fs if lo <= t <= hi]
            row = {
                "fault": f.name,
                "group": g,
                "node": node,
                "side": "majority" if s["majority"] else "minority",
            }
            if s["majority"]:
                # keeps firing: no pause longer than the failover allowance
                pts = [lo, *during, hi]
                pause = max(b - a for a, b in zip(pts, pts[1:], strict=False))
                row["check"] = f"longest pause {_fmt(pause)}"
                if hi - lo > cfg["failover_s"] and pause > cfg["failover_s"]:
                    bad.append(f"{f.name}: {node} (majority) paused {pause:.2f} s")
                    row["check"] += " FAIL"
            else:
                # stops within one lease of every cut, fires again after the last healing
                stop = None
                for c0, c1 in f.cuts():
                    inside = [t - c0 for t in fs if c0 <= t <= c1]
                    if inside:
                        stop = max(stop or 0.0, max(inside))
                after = [t for t in fs if t > hi]
                resume = None if not after else after[0] - hi
                row["check"] = f"last firing {_fmt(stop)} into a cut, again {_fmt(resume)} after"
                if stop is not None and stop > lease + EPS:
                    bad.append(f"{f.name}: {node} (minority) fired {stop:.3f} s into a cut")
                    row["check"] += " FAIL"
                if resume is None or resume > cfg["resume_within_s"]:
                    bad.append(
                        f"{f.name}: {node} (minority) did not fire again within "
                        f"{cfg['resume_within_s']:g} s of the healing"
                    )
                    row["check"] += " FAIL"
            rows.append(row)
    if not rows:
        return Verdict("sync_partitions", True, "no firing node on the sides of a partition", [])
    return Verdict(
        "sync_partitions",
        not bad,
        f"{len(bad)} problems: {bad[0]}"
        if bad
        else f"{len(rows)} sides behaved "
        "(majority kept firing, minority stopped within one lease and came back)",
        rows,
    )


# -- streams --------------------------------------------------------------------------------


def _outside(windows: list[tuple[float, float]], lo: float, hi: float) -> list[tuple[float, float]]:
    """[lo, hi] less the windows."""
    out, t = [], lo
    for a, b in windows:
        if b <= t or a >= hi:
            continue
        if a > t:
            out.append((t, a))
        t = max(t, b)
    if t < hi:
        out.append((t, hi))
    return out


def check_gaps(h: History) -> Verdict:
    cfg = _cfg(h, "checks")
    base_w = h.baseline()
    if base_w is None:
        return Verdict("gaps", False, "no baseline period (the cluster never settled)")
    lo, hi = base_w[0], h.time("snapshot") or h.time("stopped") or base_w[1]
    quiet = _outside(h.windows(after=cfg["recovery_s"]), lo, hi)
    want = {(str(m.name), n) for n, m in h.spec.measures()}
    rows, bad, unjudged = [], [], []
    for key in sorted(want):
        s = h.streams.get(key)
        if s is None:
            bad.append(f"{key[0]}@{key[1]}: never recorded")
            rows.append({"stream": f"{key[0]}@{key[1]}", "verdict": "never recorded FAIL"})
            continue
        b = analysis.baseline_of(s, base_w)
        if b is None or b.sparse:
            unjudged.append(f"{s.name}@{s.node}")
            rows.append({"stream": f"{s.name}@{s.node}", "verdict": "too sparse to judge"})
            continue
        limit = max(cfg["max_gap_periods"] * b.period, cfg["gap_floor_s"], 1.5 * b.max_gap)
        worst, at = 0.0, None
        for a, z in quiet:
            g = analysis.longest_gap(s, a, z)
            if g > worst:
                worst, at = g, a
        ok = worst <= limit
        if not ok:
            bad.append(f"{s.name}@{s.node}: a {worst:.2f} s gap (limit {limit:.2f} s)")
        rows.append(
            {
                "stream": f"{s.name}@{s.node}",
                "period": _fmt(b.period),
                "longest quiet-time gap": _fmt(worst),
                "limit": _fmt(limit),
                "verdict": "ok" if ok else f"FAIL (at {at:.1f})",
            }
        )
    summary = (
        f"{len(bad)} streams paused too long outside faults"
        if bad
        else f"{len(rows) - len(unjudged)} streams kept flowing outside faults"
    )
    if unjudged:
        summary += f" ({len(unjudged)} too sparse to judge)"
    return Verdict("gaps", not bad, summary, rows)


def check_sequences(h: History) -> Verdict:
    rows, regress, dups = [], 0, 0
    for (name, node), s in sorted(h.streams.items()):
        seen: set[int] = set()
        top, r, d = 0, 0, 0
        for q in s.seq.tolist():
            if q in seen:
                d += 1
            elif q <= top:
                r += 1
            seen.add(q)
            top = max(top, q)
        regress += r
        dups += d
        if r or d:
            rows.append({"stream": f"{name}@{node}", "regressions": r, "duplicates": d})
    n = sum(len(s) for s in h.streams.values())
    if not n:
        return Verdict("sequences", False, "no sample was recorded")
    return Verdict(
        "sequences",
        regress == 0 and dups == 0,
        f"{regress} seq regressions, {dups} duplicates in {n} samples of {len(h.streams)} streams",
        rows,
    )


def _same(a: Any, b: Any) -> bool:
    return json.dumps(a, sort_keys=True, default=repr) == json.dumps(
        b, sort_keys=True, default=repr
    )


def check_args(h: History) -> Verdict:
    latest: dict[str, tuple[int, str, Any]] = {}
    writes: dict[str, list[dict[str, Any]]] = {}
    for w in h.args_seen:
        if "ts" not in w:
            continue
        writes.setdefault(w["key"], []).append(w)
        cur = latest.get(w["key"])
        if cur is None or (w["ts"], w["origin"]) > (cur[0], cur[1]):
            latest[w["key"]] = (w["ts"], w["origin"], w.get("value"))
    for entries in h.persisted.values():
        for key, e in entries.items():
            cur = latest.get(key)
            if cur is None or (e[0], e[1]) > (cur[0], cur[1]):
                latest[key] = (e[0], e[1], e[2])
    final = h.final.get("args", {})
    rows, lost = [], []
    if not final:
        return Verdict("args", False, "no node answered the final args query")
    starts = [e for e in h.log if e.kind == "node_up"]
    for key, (ts, origin, value) in sorted(latest.items()):
        missing = [n for n, items in sorted(final.items()) if key not in items]
        stale = [
            n for n, items in sorted(final.items()) if key in items and not _same(items[key], value)
        ]
        disk = [
            n
            for n, e in sorted(h.persisted.items())
            if key not in e or (e[key][0], e[key][1]) < (ts, origin)
        ]
        redone = []
        ws = sorted(writes.get(key, []), key=lambda w: w["t"])
        for a, b in zip(ws, ws[1:], strict=False):
            restarted = any(s.node == b["origin"] and a["t"] < s.t < b["t"] for s in starts)
            if (
                b["origin"] == a["origin"]
                and restarted
                and not _same(a.get("value"), b.get("value"))
            ):
                redone.append(b["origin"])
        problems = []
        if missing:
            problems.append(f"missing on {','.join(missing)}")
        if stale:
            problems.append(f"older value on {','.join(stale)}")
        if disk:
            problems.append(f"not persisted on {','.join(disk)}")
        if redone:
            problems.append(f"redone after a restart of {','.join(redone)}")
        if problems:
            lost.append(f"{key}: {'; '.join(problems)}")
        rows.append(
            {
                "key": key,
                "writes": len(ws),
                "origin": origin,
                "verdict": "; ".join(problems) or "ok",
            }
        )
    if not latest:
        return Verdict("args", True, "the run replicated no args", rows)
    return Verdict(
        "args",
        not lost,
        f"{len(lost)} of {len(latest)} args lost: {lost[0]}"
        if lost
        else f"0 of {len(latest)} args lost (every node holds the newest value, in memory and on "
        "disk; none redone)",
        rows,
    )


# -- faults ---------------------------------------------------------------------------------


def figures_of(h: History) -> list[dict[str, Any]]:
    """The per-fault figures (cached on the history)."""
    cached = h.meta.get("_figures")
    if cached is None:
        cfg = _cfg(h, "checks")
        cached = analysis.fault_figures(h, cfg["recover_within_s"])
        h.meta["_figures"] = cached
    return cached


def check_recovery(h: History) -> Verdict:
    cfg = _cfg(h, "checks")
    rows, bad = [], []
    for fig in figures_of(h):
        f = fig["fault"]
        if not f.done:
            continue
        rec = fig["recover"]
        row = {"fault": f.name, "detect": _fmt(fig["detect"]), "recover": _fmt(rec)}
        if fig["per_stream"] and rec is None:
            lost = [k for k, v in fig["per_stream"].items() if v is None]
            bad.append(
                f"{f.name}: {', '.join(lost[:3])} not flowing within {cfg['recover_within_s']:g} s"
            )
            row["recover"] = "never FAIL"
        if fig["detect_expected"] and fig["detect"] is None:
            bad.append(f"{f.name}: no node noticed it")
            row["detect"] = "never FAIL"
        elif fig["detect"] is None and f.kind == "pause":
            row["detect"] = "- (shorter than the link lease)"
        rows.append(row)
    return Verdict(
        "recovery",
        not bad,
        f"{len(bad)} faults not recovered: {bad[0]}"
        if bad
        else f"every fault recovered within {cfg['recover_within_s']:g} s",
        rows,
    )


def estimate_windows(h: History) -> tuple[list[tuple], tuple[float, float] | None]:
    """For each fault that struck: (fault, during from, to, after from, to), the after
    window starting ``settle_s`` past the fault's end, ``after_s`` long, cut at the next
    fault; and the tail window (``settle_s`` after the last fault to the stop; None if
    shorter than 3 s)."""
    cfg = _cfg(h, "estimates")
    base = h.baseline()
    stopped = h.time("snapshot") or h.time("stopped") or (base[1] if base else 0.0)
    done = sorted((f for f in h.faults if f.done), key=lambda f: f.start)
    out = []
    for i, f in enumerate(done):
        nxt = done[i + 1].start if i + 1 < len(done) else stopped
        a0 = f.until + cfg["settle_s"]
        out.append((f, f.start, max(f.until, f.start + 1.0), a0, min(a0 + cfg["after_s"], nxt)))
    tail0 = (done[-1].until + cfg["settle_s"]) if done else (base[1] if base else stopped)
    return out, ((tail0, stopped) if stopped - tail0 >= 3.0 else None)


def check_estimates(h: History) -> Verdict:
    cfg = _cfg(h, "estimates")
    if not cfg.get("models"):
        return Verdict(
            "estimates", True, "no model judged ([checks.estimates] models)", [], skipped=True
        )
    ms = estimates.models(h, cfg["models"])
    if not ms:
        return Verdict("estimates", False, f"no estimate of {cfg['models']} was recorded")
    base = h.baseline()
    if base is None:
        return Verdict("estimates", False, "no baseline period (the cluster never settled)")
    windows, tail_w = estimate_windows(h)
    rows, bad = [], []
    for m in ms:
        label = f"{m.key[0]}@{m.key[1]}"
        metric = estimates.metric_of(m, cfg.get("metric"))
        if metric is None or m.truth is None:
            bad.append(f"{label}: its application scores no {cfg.get('metric')}")
            continue
        b = estimates.score(m, base[0], base[1], metric)
        if b is None:
            bad.append(f"{label}: no estimates in the baseline")
            continue
        limit = max(cfg["factor"] * b, cfg["floor"])
        for f, s0, s1, a0, a1 in windows:
            during = estimates.score(m, s0, s1, metric)
            after = estimates.score(m, a0, a1, metric) if a1 - a0 >= 3.0 else None
            ok = after is None or after <= limit
            if not ok:
                bad.append(f"{label} after {f.name}: {metric} {after:.3g} > {limit:.3g}")
            rows.append(
                {
                    "model": label,
                    "fault": f.name,
                    "baseline": f"{b:.3g}",
                    "during": "-" if during is None else f"{during:.3g}",
                    "after": "-" if after is None else f"{after:.3g}",
                    "limit": f"{limit:.3g}",
                    "verdict": "ok" if ok else "FAIL",
                }
            )
        tail = estimates.score(m, *tail_w, metric) if tail_w is not None else None
        if windows and tail is None:
            bad.append(f"{label}: no estimates in the tail")
        elif tail is not None and tail > limit:
            bad.append(f"{label} in the tail: {metric} {tail:.3g} > {limit:.3g}")
        rows.append(
            {
                "model": label,
                "fault": "(tail)",
                "baseline": f"{b:.3g}",
                "during": "-",
                "after": "-" if tail is None else f"{tail:.3g}",
                "limit": f"{limit:.3g}",
                "verdict": "ok" if tail is None or tail <= limit else "FAIL",
            }
        )
    return Verdict(
        "estimates",
        not bad,
        f"{len(bad)} problems: {bad[0]}"
        if bad
        else f"{len(ms)} model outputs back within {cfg['factor']:g} x baseline (or "
        f"{cfg['floor']:g}) after every fault",
        rows,
    )


def silent_while(
    mine: np.ndarray, theirs: np.ndarray, windows: list[tuple[float, float]], longest: float
) -> tuple[float, float] | None:
    """The longest silence of stream ``mine`` (arrival times) within ``windows`` that is
    over ``longest`` s while ``theirs`` published at least twice in it (more than
    :data:`EDGE_S` from its ends: two nodes falling silent together are not one silent
    while the other publishes): (length, start); None if there is none."""
    worst = None
    for q0, q1 in windows:
        pts = np.concatenate([[q0], mine[(mine > q0) & (mine < q1)], [q1]])
        for a, b in zip(pts, pts[1:], strict=False):
            longer = worst is None or b - a > worst[0]
            inside = (theirs > a + EDGE_S) & (theirs < b - EDGE_S)
            if b - a > longest and longer and np.count_nonzero(inside) >= 2:
                worst = (float(b - a), float(a))
    return worst


def _wrap(d: np.ndarray, col: str) -> np.ndarray:
    return (d + np.pi) % (2 * np.pi) - np.pi if col.endswith("[rad]") else d


def check_agreement(h: History) -> Verdict:
    cfg = _cfg(h, "agreement")
    if not cfg.get("models"):
        return Verdict(
            "agreement", True, "no model compared ([checks.agreement] models)", [], skipped=True
        )
    ms = estimates.models(h, cfg["models"])
    by_name: dict[str, list] = {}
    for m in ms:
        by_name.setdefault(m.key[0], []).append(m)
    base = h.baseline()
    lo = base[0] if base else (h.time("settled") or 0.0)
    hi = h.time("snapshot") or h.time("stopped") or 0.0
    quiet = _outside(h.windows(after=cfg["settle_s"]), lo, hi)
    rows, bad = [], []
    for name in cfg["models"]:
        group = by_name.get(name, [])
        if len(group) < 2:
            bad.append(f"{name}: recorded on {len(group)} node(s), needs two to compare")
            continue
        ref = group[0]
        for other in group[1:]:
            a, b = ref.series, other.series
            i = np.clip(np.searchsorted(b.t, a.t), 1, max(1, len(b.t) - 1))
            near = np.where(np.abs(b.t[i - 1] - a.t) < np.abs(b.t[i] - a.t), i - 1, i)
            close = np.abs(b.t[near] - a.t) <= 0.02
            inq = np.zeros(len(a.t), bool)
            for q0, q1 in quiet:
                inq |= (a.t >= q0) & (a.t < q1)
            sel = close & inq
            pair = f"{name} {a.node}/{b.node}"
            tolerances = {k: v for k, v in cfg["columns"].items() if ":" not in k}
            for key, v in cfg["columns"].items():  # "model:column" overrides "column"
                owner, _, col = key.rpartition(":")
                if owner == name:
                    tolerances[col] = v
            for col, tol in tolerances.items():
                if col not in a.columns or col not in b.columns:
                    continue
                if not sel.any():
                    bad.append(f"{pair}: no estimates to compare")
                    break
                d = np.abs(_wrap(a.column(col)[sel] - b.column(col)[near[sel]], col))
                qv = float(np.quantile(d, cfg["quantile"]))
                ok = qv <= tol
                if not ok:
                    bad.append(
                        f"{pair} {col}: {cfg['quantile']:.0%} of differences within "
                        f"{qv:.4g} > {tol:g}"
                    )
                rows.append(
                    {
                        "pair": pair,
                        "column": col,
                        "matched": int(sel.sum()),
                        f"q{cfg['quantile'] * 100:.0f}": f"{qv:.4g}",
                        "tolerance": tol,
                        "verdict": "ok" if ok else "FAIL",
                    }
                )
            # silence: one node keeps publishing while the other does not
            for x, y in ((ref, other), (other, ref)):
                worst = silent_while(
                    h.streams[y.key].arrival, h.streams[x.key].arrival, quiet, cfg["max_silence_s"]
                )
                if worst is not None:
                    g, at = worst
                    bad.append(
                        f"{name}: {y.series.node} silent {g:.1f} s while {x.series.node} published"
                    )
                    rows.append(
                        {
                            "pair": pair,
                            "column": "(silence)",
                            "matched": "-",
                            "tolerance": cfg["max_silence_s"],
                            "verdict": f"{y.series.node} silent {g:.1f} s from {at:.1f} FAIL",
                        }
                    )
    return Verdict(
        "agreement",
        not bad,
        f"{len(bad)} problems: {bad[0]}"
        if bad
        else f"{', '.join(cfg['models'])} agree across nodes outside faults",
        rows,
    )


def check_restarts(h: History) -> Verdict:
    """A supervisor restarts a measure after each abnormal exit (a crash, a hang) and
    escalates when more than ``intensity`` exits fall within ``period`` s: judged on each
    life of each node (between two ``node ... up`` lines)."""
    spec = h.spec
    limit, period = spec.intensity, spec.intensity_period
    rows, bad = [], []
    for n in spec.nodes:
        lives: list[list] = []
        for e in h.log:
            if e.node != n.name:
                continue
            if e.kind == "node_up":
                lives.append([])
            elif e.kind in ("crashed", "hung", "restarted", "escalated") and lives:
                lives[-1].append(e)
        exits = escalations = restarts = 0
        for life in lives:
            times = [e.t for e in life if e.kind in ("crashed", "hung")]
            exits += len(times)
            restarts += sum(1 for e in life if e.kind == "restarted")
            esc = [e.t for e in life if e.kind == "escalated"]
            escalations += len(esc)
            for t in esc:
                recent = [u for u in times if t - period <= u <= t]
                if len(recent) <= limit:
                    bad.append(
                        f"{n.name} escalated after {len(recent)} measure exits within "
                        f"{period:g} s (intensity {limit})"
                    )
            for i, t in enumerate(times):
                within = [u for u in times[: i + 1] if t - u <= period]
                if len(within) > limit and not any(t <= x <= t + 1.0 for x in esc):
                    bad.append(
                        f"{n.name}: {len(within)} measure exits within {period:g} s and no "
                        "escalation"
                    )
                    break
        rows.append(
            {
                "node": n.name,
                "lives": len(lives),
                "measure exits": exits,
                "restarts": restarts,
                "escalations": escalations,
            }
        )
    from hera.campaign.history import LAUNCHER_OUT

    path = h.folder / LAUNCHER_OUT
    out = path.read_text(errors="replace") if path.exists() else ""
    if "start limit hit" in out:
        bad.append("a node hit the launcher's start limit and stayed down")
    node_restarts = sum(r["lives"] for r in rows) - len(rows)
    esc = sum(r["escalations"] for r in rows)
    return Verdict(
        "restarts",
        not bad,
        f"{len(bad)} problems: {bad[0]}"
        if bad
        else f"supervisors kept their intensity ({limit} exits in {period:g} s): "
        f"{sum(r['restarts'] for r in rows)} measure restarts, {esc} escalations, each "
        f"after more than {limit} exits; {node_restarts} node restarts by the launcher",
        rows,
    )


def check_figures(h: History) -> Verdict:
    figs = h.meta.get("campaign", {}).get("figures", [])
    if not figs:
        return Verdict("figures", True, "no figures asked for ([[figures]])", [], skipped=True)
    rows, bad, absent = [], [], []
    per = figures_of(h)
    for fig in figs:
        kinds = set(fig["faults"])
        match = [x for x in per if x["fault"].done and ({x["fault"].kind, x["fault"].name} & kinds)]
        if fig["figure"] == "detect":  # a stall shorter than the link lease is no failure
            match = [x for x in match if x["detect_expected"]]
        values = [x[fig["figure"]] for x in match]
        got = [v for v in values if v is not None]
        worst = max(got) if got else None
        target = fig.get("target_s")
        row = {
            "figure": fig["label"],
            "thesis": fig.get("thesis", ""),
            "ours": f"{_fmt(worst)} (worst of {len(got)})" if got else "-",
            "median": _fmt(float(np.median(got))) if got else "-",
            "target": "-" if target is None else f"< {_fmt(target)}",
        }
        if not match:  # the short version leaves some faults out
            absent.append(fig["label"])
            rows.append({**row, "verdict": "not in this run"})
            continue
        ok = len(got) == len(values) and (target is None or worst <= target)
        if not ok:
            why = (
                f"{len(values) - len(got)} of {len(values)} not measured"
                if len(got) < len(values)
                else f"{worst:.3f} s > {target:g} s"
            )
            bad.append(f"{fig['label']}: {why}")
        rows.append({**row, "verdict": "ok" if ok else "FAIL"})
    if len(absent) == len(figs):
        return Verdict("figures", False, "no fault of any figure ran", rows)
    summary = (
        f"{len(bad)} figures missed: {bad[0]}"
        if bad
        else f"{len(rows) - len(absent)} figures within target"
    )
    if absent:
        summary += f" ({len(absent)} not measured: their faults are not in this run)"
    return Verdict("figures", not bad, summary, rows)


def check_leftovers(h: History) -> Verdict:
    from hera.campaign.runner import processes_of

    now = processes_of(h.folder)
    left = h.leftovers
    rows = [{"pid": p["pid"], "when": "at the stop", "command": p["cmdline"][:120]} for p in left]
    rows += [{"pid": p["pid"], "when": "now", "command": p["cmdline"][:120]} for p in now]
    if h.meta.get("attach"):
        return Verdict(
            "leftovers", True, "attached to a running cluster: left running", rows, skipped=True
        )
    ok = not left and not now
    return Verdict(
        "leftovers",
        ok,
        "nothing of the run left running"
        if ok
        else f"{len(left)} processes of the run outlived its stop, {len(now)} still alive",
        rows,
    )


CHECKS: dict[str, Callable[[History], Verdict]] = {
    "schedule": check_schedule,
    "overlaps": check_overlaps,
    "stale_firings": check_stale,
    "sync_partitions": check_sync_partitions,
    "gaps": check_gaps,
    "sequences": check_sequences,
    "args": check_args,
    "recovery": check_recovery,
    "estimates": check_estimates,
    "agreement": check_agreement,
    "restarts": check_restarts,
    "figures": check_figures,
    "leftovers": check_leftovers,
}
assert tuple(CHECKS) == CHECKERS


def run_all(h: History) -> list[Verdict]:
    """Every checker's verdict, in order; those the campaign skips are reported as
    skipped (never as passed); a checker that breaks fails, saying why."""
    skip = set(_cfg(h, "checks").get("skip", []))
    out = []
    for name, fn in CHECKS.items():
        if name in skip:
            out.append(Verdict(name, True, "skipped by the campaign ([checks] skip)", skipped=True))
            continue
        try:
            out.append(fn(h))
        except Exception as e:  # a checker's bug is reported, never taken for a pass
            out.append(Verdict(name, False, f"the checker failed: {type(e).__name__}: {e}"))
    return out
