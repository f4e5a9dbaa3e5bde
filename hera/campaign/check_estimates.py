"""Checkers of the estimates (through the applications) and of the figures."""

from __future__ import annotations

import numpy as np

from hera.campaign import estimates
from hera.campaign.check_streams import figures_of, outside
from hera.campaign.history import History
from hera.campaign.verdict import EDGE_S, Verdict, fmt, settings


def estimate_windows(h: History) -> tuple[list[tuple], tuple[float, float] | None]:
    """For each fault that struck: (fault, during from, to, after from, to), the after
    window starting ``settle_s`` past the fault's end, ``after_s`` long, cut at the next
    fault; and the tail window (``settle_s`` after the last fault to the stop; None if
    shorter than 3 s)."""
    cfg = settings(h, "estimates")
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
    cfg = settings(h, "estimates")
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
    cfg = settings(h, "agreement")
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
    quiet = outside(h.windows(after=cfg["settle_s"]), lo, hi)
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
            "ours": f"{fmt(worst)} (worst of {len(got)})" if got else "-",
            "median": fmt(float(np.median(got))) if got else "-",
            "target": "-" if target is None else f"< {fmt(target)}",
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
    if len(absent) == len(figs):  # a short or random schedule may have drawn none
        return Verdict(
            "figures", True, "no fault of any figure ran in this run", rows, skipped=True
        )
    summary = (
        f"{len(bad)} figures missed: {bad[0]}"
        if bad
        else f"{len(rows) - len(absent)} figures within target"
    )
    if absent:
        summary += f" ({len(absent)} not measured: their faults are not in this run)"
    return Verdict("figures", not bad, summary, rows)
