"""The terminal view of a cluster (``hera up``'s live screen, ``hera status``).

The compact view fits the terminal it is drawn on (80 x 24 and up): a header, one line per
node, one line per sync group (leader, epoch, who holds the slot), one line of problems
(crashed measures, measures in trouble, rejected inputs, silent nodes) when there are any,
then the applications' panels (one line per model) in the rows that are left. Lines are cut to the
width, never wrapped; rows that do not fit are counted on a last line. ``hera status NODE``
gives the details of one node (:func:`render_node`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from hera.application import Panel
from hera.panel import render_panel

STARTING_S = 10.0
"""A node the launcher started less than this long ago and that does not answer yet is
"starting", not "silent"."""


def _node_state(name: str, st: Mapping[str, Any] | None, la: Mapping[str, Any]) -> str:
    if st is not None:
        return "escalated" if st.get("escalated") else "up"
    state = la.get("state", "?")
    if state == "up":
        return "starting" if la.get("age_s", STARTING_S) < STARTING_S else "silent"
    return state


def _fit(lines: list[str], width: int) -> list[str]:
    return [line if len(line) <= width else line[: max(0, width - 1)] + "~" for line in lines]


def node_rows(
    status: Mapping[str, Mapping[str, Any]], launcher: Mapping[str, Mapping[str, Any]]
) -> list[str]:
    """The nodes table (75 columns): a header and one line per node. ``rst`` counts the
    node's restarts by the launcher, ``meas`` its measures running / declared, ``p99 ms``
    the worst step lateness, ``MB`` its resident memory, ``rej`` the inputs it rejected."""
    lines = [
        f"{'node':<12} {'pid':>7} {'state':<9} {'rst':>4} {'meas':>5} {'msg/s':>7} "
        f"{'p99 ms':>7} {'MB':>5} {'rej':>5} {'peers':>5}"
    ]
    for n in sorted(set(status) | set(launcher)):
        st, la = status.get(n), launcher.get(n, {})
        ms = (st or {}).get("measures", {})
        running = sum(1 for m in ms.values() if m.get("state") == "running")
        rate = sum(m.get("rate_hz", 0.0) for m in ms.values())
        p99 = max((m.get("jitter_ms", {}).get("p99", 0.0) for m in ms.values()), default=0.0)
        rss = (st or {}).get("rss_mb")
        lines.append(
            f"{n[:12]:<12} {(st or {}).get('pid', la.get('pid')) or '-':>7} "
            f"{_node_state(n, st, la):<9} {la.get('restarts', 0):>4} "
            f"{f'{running}/{len(ms)}' if st else '-':>5} {rate:>7.1f} {p99:>7.1f} "
            f"{'-' if rss is None else f'{rss:.0f}':>5} "
            f"{sum((st or {}).get('rejected', {}).values()):>5} "
            f"{len([p for p in (st or {}).get('peers', []) if p != n]):>5}"
        )
    return lines


def sync_rows(status: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """One line per sync group: its leader and epoch, and who holds the slot."""
    groups: dict[str, dict[str, Any]] = {}
    for node in sorted(status):
        for g, info in (status[node].get("sync") or {}).get("groups", {}).items():
            seen = groups.setdefault(g, {"leader": None, "epoch": None, "holder": None})
            if info.get("role") == "leader" or (seen["leader"] is None and info.get("leader")):
                seen.update(leader=info.get("leader"), epoch=info.get("epoch"))
            if info.get("holder"):
                seen["holder"] = info["holder"]
    return [
        f"sync {g}: leader {v['leader'] or 'none'}"
        + (f" (epoch {v['epoch']})" if v["epoch"] is not None else "")
        + (f", slot held by {v['holder']}" if v["holder"] else "")
        for g, v in sorted(groups.items())
    ]


def problem_rows(status: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """What needs attention: measures not running or restarted or in trouble (a board that
    does not answer), rejected inputs, sources whose samples are all refused, refused args
    writes."""
    items = []
    for node in sorted(status):
        for name, m in sorted(status[node].get("measures", {}).items()):
            if m.get("state") != "running" or m.get("restarts"):
                err = f" ({m['last_error']})" if m.get("last_error") else ""
                items.append(f"{node}/{name} {m.get('state')} x{m.get('restarts', 0)}{err}")
            elif m.get("trouble"):
                items.append(f"{node}/{name} {m['trouble']}")
        rejected = status[node].get("rejected") or {}
        if rejected:
            kinds = ",".join(f"{k}={v}" for k, v in sorted(rejected.items()))
            items.append(f"{node} rejected {kinds}")
        for source, r in sorted((status[node].get("refused_sources") or {}).items()):
            items.append(f"{node} refuses every sample of {source} ({r['reason']} x{r['refused']})")
        args_rejected = status[node].get("args_rejected") or {}
        if args_rejected:
            kinds = ",".join(f"{k}={v}" for k, v in sorted(args_rejected.items()))
            items.append(f"{node} refused args {kinds}")
    return ["problems: " + "; ".join(items)] if items else []


def render_view(
    cluster: str,
    status: Mapping[str, Mapping[str, Any]],
    launcher: Mapping[str, Mapping[str, Any]] | None = None,
    *,
    uptime: float | None = None,
    run_dir: str | None = None,
    panels: Sequence[Panel] = (),
    width: int = 80,
    height: int = 24,
    routers: Mapping[str, Mapping[str, Any]] | None = None,
) -> str:
    """The compact view (see the module docstring), at most ``height`` lines of at most
    ``width`` characters; ``routers``: the launcher's routers (name -> pid, state)."""
    launcher = launcher or {}
    names = sorted(set(status) | set(launcher))
    up = sum(1 for n in names if n in status)
    starting = sum(
        1 for n in names if _node_state(n, status.get(n), launcher.get(n, {})) == "starting"
    )
    head = f"cluster {cluster}: {up}/{len(names)} nodes up"
    if starting:
        head += f" ({starting} starting)"
    if uptime is not None:
        head += f", {uptime:.0f} s"
    if run_dir:
        head += f", run {run_dir}"
    top = [head, *node_rows(status, launcher)]
    if routers:
        top.append(
            "routers: "
            + ", ".join(
                f"{n} {r.get('state', '?')} (pid {r.get('pid')})"
                for n, r in sorted(routers.items())
            )
        )
    top += [*sync_rows(status), *problem_rows(status)]
    body: list[str] = []
    for p in panels:
        body += ["", *render_panel(p).splitlines()]
    lines = _fit(top, width)
    room = height - len(lines)
    if len(body) > room:
        cut = len(body) - room + 1
        body = [*body[: max(0, room - 1)], f"... {cut} more lines (hera status NODE for details)"]
    return "\n".join(lines + _fit(body, width)[: max(0, room)])


def render_status(
    cluster: str,
    status: dict[str, dict[str, Any]],
    launcher: dict[str, dict[str, Any]] | None = None,
    uptime: float | None = None,
    run_dir: str | None = None,
) -> str:
    """The view without panels, for a wide terminal (``hera status``)."""
    return render_view(
        cluster, status, launcher, uptime=uptime, run_dir=run_dir, width=160, height=10_000
    )


def render_node(status: Mapping[str, Any]) -> str:
    """Every detail of one node's status: its measures with rates, jitter, counters and
    last errors; its store, transit times and peers."""
    lines = [
        f"node {status.get('node')} of cluster {status.get('cluster')}: pid {status.get('pid')}, "
        f"up {status.get('uptime_s', 0):.0f} s"
        + (f", {status['rss_mb']:.0f} MB" if status.get("rss_mb") is not None else ""),
        f"{'measure':<16} {'state':<10} {'restarts':>8} {'seq':>8} {'rate/s':>7} "
        f"{'p99 ms':>7} {'overruns':>8} counters",
    ]
    for name, m in sorted(status.get("measures", {}).items()):
        counters = " ".join(f"{k}={v:g}" for k, v in sorted(m.get("counters", {}).items()))
        lines.append(
            f"{name:<16} {m.get('state', '?'):<10} {m.get('restarts', 0):>8} "
            f"{m.get('seq', 0):>8} {m.get('rate_hz', 0):>7.1f} "
            f"{m.get('jitter_ms', {}).get('p99', 0):>7.2f} {m.get('overruns', 0):>8} {counters}"
        )
        if m.get("trouble"):
            lines.append(f"{'':<16} now: {m['trouble']}")
        if m.get("last_error"):
            lines.append(f"{'':<16} last error: {m['last_error']}")
    store = status.get("store", {})
    lines.append(
        f"store: {store.get('entries', 0)} entries, {store.get('accepted', 0)} accepted, "
        f"{store.get('stale', 0)} stale; rejected: {status.get('rejected') or 'none'}"
    )
    if "takes" in store:
        takes = store["takes"]
        lines.append(f"takes: {'every sample' if takes is None else ', '.join(takes) or 'nothing'}")
    if status.get("last_rejection"):
        lines.append(f"last rejected: {status['last_rejection']}")
    for source, r in sorted((status.get("refused_sources") or {}).items()):
        lines.append(f"every sample of {source} refused: {r['reason']} x{r['refused']}")
    if status.get("args_rejected"):
        lines.append(f"args refused: {status['args_rejected']}")
    transit = status.get("transit_ms", {})
    if transit:
        lines.append(
            "transit ms (p50/p99): "
            + ", ".join(
                f"{n} {t.get('p50', 0):.2f}/{t.get('p99', 0):.2f}"
                for n, t in sorted(transit.items())
            )
        )
    lines.append(f"peers: {', '.join(status.get('peers', [])) or 'none'}")
    return "\n".join(lines)
