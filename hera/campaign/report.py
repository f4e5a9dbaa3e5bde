"""The report of a campaign run: ``report.md``, ``report.html`` and ``timeline.png``.

Both documents hold the same sections, built once as a list of blocks (headings,
paragraphs, tables, the image) and rendered twice: the verdict of every checker, the
figures beside the thesis's chapter 5, the timeline, one row per fault (when it struck,
what it hit, how long the cluster took to notice and to recover, the estimate error during
and after it), and each checker's details.

The timeline (``timeline.png``) shows the faults as shaded bands over: every stream's
rate against its baseline rate (one row per stream), the firings of each sync group by
node (one tick per sound, the leader's epoch as its colour), and each judged model's error
(the application's metric over short windows).
"""

from __future__ import annotations

import html
import time
from pathlib import Path
from typing import Any

import numpy as np

from hera.campaign import analysis, estimates
from hera.campaign.checkers import Verdict, estimate_windows, figures_of
from hera.campaign.history import History

REPORT_MD = "report.md"
REPORT_HTML = "report.html"
TIMELINE = "timeline.png"

Block = tuple[str, Any]
COLOURS = {
    "crash": "#f4a261",
    "hang": "#e9c46a",
    "kill": "#e63946",
    "crash_node": "#d62828",
    "pause": "#9d4edd",
    "board": "#2a9d8f",
    "partition": "#457b9d",
    "loss": "#8ecae6",
    "delay": "#a8dadc",
    "reset": "#1d3557",
    "skew": "#ffb703",
}


def _s(x: float | None) -> str:
    if x is None:
        return "-"
    return f"{x * 1000:.0f} ms" if abs(x) < 1 else f"{x:.2f} s"


def _t0(h: History) -> float:
    return h.time("settled") or h.time("started") or 0.0


def fault_rows(h: History) -> list[dict[str, Any]]:
    """One row per fault: what, when, and the figures."""
    t0 = _t0(h)
    cfg = h.meta.get("campaign", {}).get("estimates", {})
    ms = estimates.models(h, cfg.get("models") or []) if cfg.get("models") else []
    windows = {w[0].planned.index: w for w in estimate_windows(h)[0]} if ms else {}
    rows = []
    for fig in figures_of(h):
        f = fig["fault"]
        row = {
            "#": f.planned.index + 1,
            "fault": f.name,
            "kind": f.kind,
            "hit": " | ".join(",".join(g) for g in f.groups) or ",".join(f.nodes) or "-",
            "at s": "-" if f.start is None else f"{f.start - t0:.1f}",
            "lasted": _s(None if f.start is None else (f.until or f.start) - f.start),
            "detect": _s(fig["detect"]),
            "recover": _s(fig["recover"]),
            "sync flow": _s(fig["flow"]),
            "longest gap": _s(fig["gap"]),
        }
        if f.error:
            row["hit"] = f"FAILED: {f.error}"
        if ms and f.planned.index in windows:
            m = ms[0]
            metric = estimates.metric_of(m, cfg.get("metric"))
            _, s0, s1, a0, a1 = windows[f.planned.index]
            if metric:
                d = estimates.score(m, s0, s1, metric)
                a = estimates.score(m, a0, a1, metric) if a1 - a0 >= 3.0 else None
                row[f"{m.key[0]}@{m.key[1]} {metric}"] = (
                    f"{'-' if d is None else f'{d:.3g}'} / {'-' if a is None else f'{a:.3g}'}"
                )
        rows.append(row)
    return rows


def blocks(h: History, verdicts: list[Verdict], command: str) -> list[Block]:
    """The report's content (see the module docstring)."""
    meta = h.meta
    camp = meta.get("campaign", {})
    failed = [v for v in verdicts if not v.passed]
    verdict = "PASS" if not failed else "FAIL"
    started, stopped = h.time("started"), h.time("stopped")
    out: list[Block] = [
        ("h1", f"Campaign {camp.get('name')} on cluster {meta.get('cluster')}: {verdict}"),
    ]
    if camp.get("title"):
        out.append(("p", camp["title"]))
    facts = [
        f"command: `{command}`",
        f"seed {meta.get('seed')} (the same seed gives the same schedule)",
        f"directory: `{h.folder}`",
        f"spec: `{meta.get('spec_source')}`, campaign: `{camp.get('source')}`",
        f"{len(h.faults)} faults planned, {sum(f.done for f in h.faults)} struck"
        + (f"; {len(h.manual)} injected by hand" if h.manual else ""),
    ]
    if started and stopped:
        when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(started))
        facts.append(f"ran {stopped - started:.0f} s from {when}")
    if meta.get("interrupted"):
        facts.append("**interrupted** before the end of its schedule")
    for lo, _, stood in h.pauses:
        clock = time.strftime("%H:%M:%S", time.localtime(lo))
        at = f"{lo - started:.0f} s in" if started else f"at {clock}"
        facts.append(
            f"the machine stood still for {stood:.1f} s, {at} (its clocks stopped: a paused "
            "virtual machine); nothing is judged there"
        )
    out.append(("ul", facts))
    out.append(("h2", "Verdict"))
    out.append(
        (
            "table",
            [{"checker": v.name, "verdict": v.status, "summary": v.summary} for v in verdicts],
        )
    )
    figs = next((v for v in verdicts if v.name == "figures" and v.rows), None)
    if figs is not None:
        out.append(("h2", "Figures beside the thesis's (chapter 5)"))
        out.append(("table", figs.rows))
    out.append(("h2", "Timeline"))
    out.append(("img", TIMELINE))
    out.append(
        (
            "p",
            "Faults are shaded bands (instantaneous ones a thin band), numbered as in the "
            "table below. Streams: each row is one stream's rate against its baseline rate "
            "(dark: silent). Firings: one tick per sound, coloured by the grant's epoch. "
            "Errors: the application's metric of each judged model over short windows.",
        )
    )
    out.append(("h2", "Faults"))
    rows = fault_rows(h)
    out.append(("table", rows) if rows else ("p", "No fault was planned."))
    if rows and any(
        k.endswith(tuple(["pct", "cm", "m"])) or "/" in str(v) for k, v in rows[0].items()
    ):
        out.append(("p", "The last column is the judged model's error during / after the fault."))
    out.append(("h2", "Checkers"))
    for v in verdicts:
        out.append(("h3", f"{v.name}: {v.status}"))
        out.append(("p", v.summary))
        if v.rows:
            out.append(("table", v.rows[:60]))
            if len(v.rows) > 60:
                out.append(("p", f"... and {len(v.rows) - 60} more rows"))
    return out


def _md_table(rows: list[dict[str, Any]]) -> str:
    cols: list[str] = []
    for r in rows:
        cols += [c for c in r if c not in cols]
    cell = lambda v: str(v).replace("|", "\\|").replace("\n", " ")  # noqa: E731
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(cell(r.get(c, "")) for c in cols) + " |" for r in rows]
    return "\n".join(lines)


def markdown(content: list[Block]) -> str:
    parts = []
    for kind, x in content:
        if kind in ("h1", "h2", "h3"):
            parts.append("#" * int(kind[1]) + " " + x)
        elif kind == "p":
            parts.append(x)
        elif kind == "ul":
            parts.append("\n".join(f"- {i}" for i in x))
        elif kind == "table":
            parts.append(_md_table(x))
        elif kind == "img":
            parts.append(f"![timeline]({x})")
    return "\n\n".join(parts) + "\n"


def _inline(text: str) -> str:
    """Escape, then render `code` spans and **bold**."""
    out = html.escape(text)
    while out.count("`") >= 2:
        out = out.replace("`", "<code>", 1).replace("`", "</code>", 1)
    while out.count("**") >= 2:
        out = out.replace("**", "<b>", 1).replace("**", "</b>", 1)
    return out


def html_page(content: list[Block], title: str) -> str:
    css = (
        "body{font-family:sans-serif;max-width:1100px;margin:2em auto;padding:0 1em}"
        "table{border-collapse:collapse;margin:1em 0;font-size:90%}"
        "td,th{border:1px solid #ccc;padding:3px 8px;text-align:left}"
        "th{background:#f0f0f0}img{max-width:100%}code{background:#f4f4f4}"
        ".FAIL{color:#b00;font-weight:bold}.pass{color:#070}"
    )
    parts = [
        f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
        f"<style>{css}</style></head><body>"
    ]
    for kind, x in content:
        if kind in ("h1", "h2", "h3"):
            parts.append(f"<{kind}>{_inline(x)}</{kind}>")
        elif kind == "p":
            parts.append(f"<p>{_inline(x)}</p>")
        elif kind == "ul":
            parts.append("<ul>" + "".join(f"<li>{_inline(i)}</li>" for i in x) + "</ul>")
        elif kind == "table":
            cols: list[str] = []
            for r in x:
                cols += [c for c in r if c not in cols]
            head = "".join(f"<th>{html.escape(c)}</th>" for c in cols)
            body = ""
            for r in x:
                cells = ""
                for c in cols:
                    v = str(r.get(c, ""))
                    cls = (
                        " class='FAIL'" if "FAIL" in v else (" class='pass'" if v == "pass" else "")
                    )
                    cells += f"<td{cls}>{html.escape(v)}</td>"
                body += f"<tr>{cells}</tr>"
            parts.append(f"<table><tr>{head}</tr>{body}</table>")
        elif kind == "img":
            parts.append(f"<p><img src='{html.escape(x)}' alt='timeline'></p>")
    parts.append("</body></html>")
    return "\n".join(parts)


def timeline(h: History, path: Path, dpi: int = 80) -> Path | None:
    """Draw ``timeline.png`` (see the module docstring); None without matplotlib, or when
    the cluster never started."""
    try:
        from hera.plotting import pyplot
    except ImportError:
        return None
    try:
        plt = pyplot()
    except ImportError:
        return None
    if not _t0(h):  # the run broke before the cluster started: no time axis to draw on
        return None
    t0 = _t0(h)
    t1 = h.time("snapshot") or h.time("stopped") or t0 + 1
    base = h.baseline()
    cfg = h.meta.get("campaign", {}).get("estimates", {})
    ms = estimates.models(h, cfg.get("models") or []) if cfg.get("models") else []
    groups = analysis.firing_groups(h.firings)
    panels = ["faults", "streams"] + (["firings"] if groups else []) + (["errors"] if ms else [])
    ratios = {"faults": 0.6, "streams": 3.0, "firings": 1.2, "errors": 1.6}
    fig, axes = plt.subplots(
        len(panels),
        1,
        figsize=(12, 1.2 + 2.2 * sum(ratios[p] for p in panels) / 2),
        sharex=True,
        gridspec_kw={"height_ratios": [ratios[p] for p in panels]},
    )
    axes = dict(zip(panels, np.atleast_1d(axes), strict=True))

    def bands(ax, labels: bool = False) -> None:
        for f in h.faults:
            if f.start is None:
                continue
            a, b = f.start - t0, max((f.until or f.start) - t0, f.start - t0 + 0.25)
            ax.axvspan(a, b, color=COLOURS.get(f.kind, "0.5"), alpha=0.35, lw=0)
            if labels:
                ax.text(
                    a,
                    0.5,
                    str(f.planned.index + 1),
                    fontsize=7,
                    va="center",
                    transform=ax.get_xaxis_transform(),
                )
        for m in h.manual:
            ax.axvline(m["t"] - t0, color="k", ls=":", lw=1)

    ax = axes["faults"]
    bands(ax, labels=True)
    ax.set_ylim(0, 1)
    ax.set_yticks([])
    ax.set_ylabel("faults", rotation=0, ha="right", va="center")
    seen = sorted({f.kind for f in h.faults if f.start is not None})
    for k in seen:
        ax.plot([], [], color=COLOURS.get(k, "0.5"), lw=6, alpha=0.5, label=k)
    if seen:
        ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=7, frameon=False, ncol=2)

    ax = axes["streams"]
    keys = sorted(h.streams, key=lambda k: (k[1], k[0]))
    step = 0.5
    edges = np.arange(t0, t1 + step, step)
    img = np.zeros((len(keys), max(1, len(edges) - 1)))
    for i, k in enumerate(keys):
        s = h.streams[k]
        b = analysis.baseline_of(s, base)
        counts, _ = np.histogram(s.arrival, edges)
        rate = 1.0 / b.period if b is not None and b.period > 0 else max(1.0, counts.mean() / step)
        img[i] = np.clip(counts / (rate * step), 0, 1.5)
    if keys:
        ax.imshow(
            img,
            aspect="auto",
            cmap="viridis",
            vmin=0,
            vmax=1.2,
            interpolation="nearest",
            extent=(0, t1 - t0, len(keys) - 0.5, -0.5),
        )
        ax.set_yticks(range(len(keys)), [f"{n}@{node}" for n, node in keys], fontsize=6)
    for f in h.faults:
        if f.start is not None:
            ax.axvline(f.start - t0, color="w", lw=0.6, alpha=0.7)
    ax.set_ylabel("stream rate")

    if "firings" in axes:
        ax = axes["firings"]
        bands(ax)
        nodes = sorted({x.node for x in h.firings})
        for i, n in enumerate(nodes):
            xs = [x for x in h.firings if x.node == n]
            ax.scatter(
                [x.start - t0 for x in xs],
                [i] * len(xs),
                s=4,
                marker="|",
                c=[x.epoch or 0 for x in xs],
                cmap="tab10",
                vmin=0,
                vmax=10,
            )
        ax.set_yticks(range(len(nodes)), nodes, fontsize=7)
        ax.set_ylim(-0.7, len(nodes) - 0.3)
        ax.set_ylabel("firings")

    if "errors" in axes:
        ax = axes["errors"]
        bands(ax)
        for m in ms:
            metric = estimates.metric_of(m, cfg.get("metric"))
            if metric is None:
                continue
            xs, ys = estimates.timeline(m, metric, t0, t1, cfg.get("window_s", 2.0))
            ax.plot(
                [x - t0 for x in xs],
                [np.nan if y is None else y for y in ys],
                lw=1,
                label=f"{m.key[0]}@{m.key[1]}",
            )
            ax.set_ylabel(metric, fontsize=8)
        ax.set_yscale("log")
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0), frameon=False)
    axes[panels[-1]].set_xlabel("time since the cluster settled [s]")
    axes[panels[0]].set_xlim(0, t1 - t0)
    fig.suptitle(
        f"{h.meta.get('campaign', {}).get('name')}: seed {h.meta.get('seed')}", fontsize=10
    )
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path


def write(h: History, verdicts: list[Verdict], command: str | None = None) -> list[Path]:
    """Write report.md, report.html and timeline.png into the campaign directory."""
    command = command or h.meta.get("command") or "hera campaign ..."
    content = blocks(h, verdicts, command)
    timeline(h, h.folder / TIMELINE)
    md = h.folder / REPORT_MD
    md.write_text(markdown(content))
    page = h.folder / REPORT_HTML
    page.write_text(html_page(content, f"campaign {h.meta.get('campaign', {}).get('name')}"))
    return [md, page, h.folder / TIMELINE]
