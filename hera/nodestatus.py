"""A node's status reply (the ``status`` control verb, ``hera status``, the live view).

JSON-able: the node, its measures (state, restarts, rates, jitter, counters), its store,
rejected inputs, peers and their events, transit times, args, the recent control verbs that
changed something (faults injected, measures started, args set, code reloaded) and each
service's status.
"""

from __future__ import annotations

import os
import time
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover
    from hera.node import Node


def measures_status(node: Node) -> dict[str, dict[str, Any]]:
    """Each measure of the node's supervisor: state, restarts, rates, counters."""
    out = {}
    now = time.monotonic()
    sup = node.supervisor
    for cid, c in sup.children.items() if sup else ():
        w = c.worker
        st = w.stats if w is not None else None
        decl = node.decls.get(cid)
        out[cid] = {
            "use": decl.use if decl is not None else None,
            "state": c.state,
            "restarts": c.restarts,
            "crashes": c.crashes,
            "hangs": c.hangs,
            "last_error": c.last_error,
            "seq": node.data.seq(cid),
            "steps": st.steps if st else 0,
            "published": st.published if st else 0,
            "empty": st.empty if st else 0,
            "rate_hz": round(st.rate(now), 2) if st else 0.0,
            "jitter_ms": {k: round(v, 3) for k, v in st.jitter_ms().items()} if st else {},
            "overruns": st.overruns if st else 0,
            "skipped_slots": st.skipped_slots if st else 0,
            "counters": dict(w.ctx.counters) if w is not None else {},
            "trouble": w.ctx.trouble if w is not None else None,
            "period_s": w.spec.period if w is not None else None,
            "restart_ms": c.restart_ms,
        }
    return out


def rss_mb() -> float | None:
    """This process's resident memory (MB), from /proc (None where there is none)."""
    try:
        with open("/proc/self/statm") as f:
            pages = int(f.read().split()[1])
    except (OSError, ValueError, IndexError):
        return None
    return round(pages * os.sysconf("SC_PAGE_SIZE") / 1e6, 1)


def node_status(node: Node) -> dict[str, Any]:
    """The whole status of ``node`` (see the module docstring)."""
    data = node.data
    out: dict[str, Any] = {
        "node": node.name,
        "cluster": node.spec.name,
        "pid": os.getpid(),
        "uptime_s": round(time.time() - node.started_at, 3),
        "rss_mb": rss_mb(),
        "escalated": node.supervisor.escalated if node.supervisor else None,
        "measures": measures_status(node),
        "store": {
            "entries": len(node.store.snapshot()),
            "accepted": node.store.accepted,
            "stale": node.store.stale,
            "takes": node.data.interest,
            "refused": dict(node.store.refused),
            "incarnations": node.store.incarnations,
        },
        "incarnation": data.incarnation,
        "rejected": dict(data.rejected),
        "refused_sources": data.refused_sources(),
        "args_rejected": dict(node.args.rejected) if node.args else {},
        "last_rejection": data.last_rejection,
        "peers": node.peers.names(),
        "peer_events": node.peers.event_log(),
        "transit_ms": data.percentiles(),
        "args": len(node.args.items()) if node.args else 0,
        "log_rows": data.csv.rows if data.csv else 0,
        "log_files_open": data.csv.open_files if data.csv else 0,
        "control_events": list(node.control.events),
    }
    for name, service in node.services.items():
        try:
            out[name] = service.status()
        except Exception as e:  # a service's status must not break the node's
            out[name] = {"error": f"{type(e).__name__}: {e}"}
    return out
