"""Rendering a cluster's status as a text table (the live screen of ``hera up``)."""

from __future__ import annotations

from typing import Any


def _fmt_rate(x: float) -> str:
    return f"{x:7.1f}"


def render_status(
    cluster: str,
    status: dict[str, dict[str, Any]],
    launcher: dict[str, dict[str, Any]] | None = None,
    uptime: float | None = None,
    run_dir: str | None = None,
) -> str:
    """A table of nodes and their measures from node status replies and launcher state."""
    launcher = launcher or {}
    names = sorted(set(status) | set(launcher))
    up = sum(1 for n in names if n in status)
    head = f"cluster {cluster}: {up}/{len(names)} nodes answering"
    if uptime is not None:
        head += f", up {uptime:.0f} s"
    if run_dir:
        head += f", run dir {run_dir}"
    lines = [
        head,
        f"{'node':<10} {'pid':>7} {'state':<10} {'node restarts':>13} {'measures':>9} "
        f"{'msg/s':>7} {'jitter p99':>10} {'measure restarts':>16} {'rejected':>8} "
        f"{'peers':>5}",
    ]
    for n in names:
        st = status.get(n, {})
        la = launcher.get(n, {})
        ms = st.get("measures", {})
        running = sum(1 for m in ms.values() if m.get("state") == "running")
        rate = sum(m.get("rate_hz", 0.0) for m in ms.values())
        p99 = max((m.get("jitter_ms", {}).get("p99", 0.0) for m in ms.values()), default=0.0)
        restarts = sum(m.get("restarts", 0) for m in ms.values())
        state = (
            la.get("state", "?")
            if n not in status
            else ("escalated" if st.get("escalated") else la.get("state", "up"))
        )
        lines.append(
            f"{n:<10} {st.get('pid', la.get('pid')) or '-':>7} {state:<10} "
            f"{la.get('restarts', 0):>13} {f'{running}/{len(ms)}':>9} {_fmt_rate(rate)} "
            f"{p99:>7.2f} ms {restarts:>16} {sum(st.get('rejected', {}).values()):>8} "
            f"{len([p for p in st.get('peers', []) if p != n]):>5}"
        )
    details = []
    for n in names:
        for m, info in sorted(status.get(n, {}).get("measures", {}).items()):
            if info.get("state") != "running" or info.get("last_error") or info.get("counters"):
                extra = " ".join(f"{k}={v:g}" for k, v in info.get("counters", {}).items())
                err = f" last error: {info['last_error']}" if info.get("last_error") else ""
                details.append(f"  {n}/{m}: {info.get('state')} seq={info.get('seq')} {extra}{err}")
    if details:
        lines.append("measures:")
        lines.extend(details[:20])
        if len(details) > 20:
            lines.append(f"  ... {len(details) - 20} more")
    return "\n".join(lines)
