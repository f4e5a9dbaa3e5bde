"""Checkers of the firings of sync groups: overlaps, stale grants, partitions."""

from __future__ import annotations

from typing import Any

from hera.campaign import analysis
from hera.campaign.history import Firing, History
from hera.campaign.verdict import EPS, Verdict, fmt, settings


def overlapping(firings: list[Firing]) -> list[tuple[Firing, Firing]]:
    """Pairs of firings (start order) that overlap in time: on the sync clock the fire logs
    were written on when every firing has it (one machine's logs share it: see
    :class:`~hera.campaign.history.Firing`), else on the wall clock."""
    spans: list[tuple[float, float, Firing]] = []
    for f in firings:
        if f.clock_start is None or f.clock_end is None:
            spans = [(g.start, g.end, g) for g in firings]
            break
        spans.append((f.clock_start, f.clock_end, f))
    out = []
    latest: tuple[float, float, Firing] | None = None
    for cur in sorted(spans, key=lambda x: x[0]):
        if latest is not None and cur[0] < latest[1] - EPS:
            out.append((latest[2], cur[2]))
        if latest is None or cur[1] > latest[1]:
            latest = cur
    return out


def _overlap_ms(a: Firing, b: Firing) -> float:
    """How long ``b`` started before ``a`` ended (ms), on the clock :func:`overlapping`
    compared them on."""
    if a.clock_end is not None and b.clock_start is not None:
        return (a.clock_end - b.clock_start) * 1000.0
    return (a.end - b.start) * 1000.0


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
                    "overlaps": f"{b.node} {b.start:.3f} ({_overlap_ms(a, b):.1f} ms)",
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
    cfg = settings(h, "checks")
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
                row["check"] = f"longest pause {fmt(pause)}"
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
                row["check"] = f"last firing {fmt(stop)} into a cut, again {fmt(resume)} after"
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
