"""Checkers of the run and of what nodes keep: the schedule, replicated args, supervisor
restarts, leftover processes."""

from __future__ import annotations

import json
from typing import Any

from hera.campaign.history import LAUNCHER_OUT, History
from hera.campaign.verdict import Verdict


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
