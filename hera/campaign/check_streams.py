"""Checkers of the recorded streams: gaps outside faults, sequences, each fault's
recovery."""

from __future__ import annotations

from typing import Any

from hera.campaign import analysis
from hera.campaign.history import History
from hera.campaign.verdict import Verdict, fmt, settings


def outside(windows: list[tuple[float, float]], lo: float, hi: float) -> list[tuple[float, float]]:
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
    cfg = settings(h, "checks")
    base_w = h.baseline()
    if base_w is None:
        return Verdict("gaps", False, "no baseline period (the cluster never settled)")
    lo, hi = base_w[0], h.time("snapshot") or h.time("stopped") or base_w[1]
    quiet = outside(h.windows(after=cfg["recovery_s"]), lo, hi)
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
        # A bursty stream (bilateration: a burst while the train is in both sonars' beams)
        # may miss one burst, two of its gaps and the burst between them: a noisy pass of
        # the train gives no fix, and a 10 s baseline may hold one gap only.
        spread = 3.0 if b.bursty else 1.5
        limit = max(cfg["max_gap_periods"] * b.period, cfg["gap_floor_s"], spread * b.max_gap)
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
                "period": fmt(b.period),
                "longest quiet-time gap": fmt(worst),
                "limit": fmt(limit),
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
    """Per stream, in arrival order: a (run, seq) seen before is a duplicate; a seq not
    above the highest of its run, or a sample of an older run (incarnation) after a newer
    one, is a regression. A new run may start its seqs again (the wire's contract: a
    restarted process takes a new incarnation); how many streams did is reported."""
    rows, regress, dups, restarted = [], 0, 0, 0
    for (name, node), s in sorted(h.streams.items()):
        seen: set[tuple[int, int]] = set()
        top: dict[int, int] = {}
        latest, r, d = 0, 0, 0
        for run, q in zip(s.run.tolist(), s.seq.tolist(), strict=True):
            if (run, q) in seen:
                d += 1
            elif run < latest or q <= top.get(run, 0):
                r += 1
            seen.add((run, q))
            top[run] = max(top.get(run, 0), q)
            latest = max(latest, run)
        regress += r
        dups += d
        restarted += latest > 0
        if r or d or latest:
            rows.append(
                {
                    "stream": f"{name}@{node}",
                    "incarnations": latest + 1,
                    "regressions": r,
                    "duplicates": d,
                }
            )
    n = sum(len(s) for s in h.streams.values())
    if not n:
        return Verdict("sequences", False, "no sample was recorded")
    return Verdict(
        "sequences",
        regress == 0 and dups == 0,
        f"{regress} seq regressions, {dups} duplicates in {n} samples of {len(h.streams)} "
        f"streams ({restarted} of them from more than one incarnation)",
        rows,
    )


def figures_of(h: History) -> list[dict[str, Any]]:
    """The per-fault figures (cached on the history)."""
    cached = h.meta.get("_figures")
    if cached is None:
        cfg = settings(h, "checks")
        cached = analysis.fault_figures(h, cfg["recover_within_s"])
        h.meta["_figures"] = cached
    return cached


def check_recovery(h: History) -> Verdict:
    cfg = settings(h, "checks")
    rows, bad = [], []
    for fig in figures_of(h):
        f = fig["fault"]
        if not f.done:
            continue
        rec = fig["recover"]
        row = {"fault": f.name, "detect": fmt(fig["detect"]), "recover": fmt(rec)}
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
