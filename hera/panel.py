"""The estimates part of the live view of ``hera up``: each application's panel.

The runtime collects the latest estimate of every fusion model of the spec (from one node's
store) and asks each model's application for its :class:`~hera.application.Panel`; models
of no application get a plain panel of their values. Panels are data; :func:`render_panel`
lays one out as aligned text.
"""

from __future__ import annotations

import logging
import traceback
from collections import defaultdict
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from hera.application import Estimate, Panel
from hera.plugins import AppIndex

log = logging.getLogger("hera.panel")


def estimates_panels(
    models: Mapping[str, type],
    samples: Sequence[Mapping[str, Any]],
    world: Mapping[str, Any],
    index: AppIndex,
) -> list[Panel]:
    """The panels of the latest estimates in ``samples`` (the ``store`` control verb's
    samples: name, node, t, values) of the measures ``models`` (publication name -> measure
    class): each application's own panel (none if it has none), and a plain one for the
    models of no application."""
    by_app: dict[Any, list[Estimate]] = defaultdict(list)
    for s in samples:
        cls = models.get(s["name"])
        if cls is None:
            continue
        cols = tuple(getattr(cls, "columns", ())) or tuple(
            f"v{i + 1}" for i in range(len(s["values"]))
        )
        values = dict(zip(cols, s["values"], strict=False))
        est = Estimate(s["name"], s["node"], float(s["t"]), values, cls)
        by_app[index.app_of(cls)].append(est)
    panels = []
    for app, estimates in by_app.items():
        estimates.sort(key=lambda e: (*index.rank(e.measure), e.name, e.node))
        if app is None:
            panels.append(plain_panel(estimates))
            continue
        try:
            panel = app.panel(estimates, app.truth(world))
        except Exception as e:  # an application's bug: its panel says so, the others stand
            log.warning("panel of application %s failed", app.name, exc_info=True)
            where = traceback.extract_tb(e.__traceback__)[-1]
            panel = Panel(
                f"{app.name}: panel failed ({type(e).__name__}: {e}, "
                f"{Path(where.filename).name}:{where.lineno})",
                ("",),
            )
        if panel is not None:
            panels.append(panel)
    return panels


def plain_panel(estimates: Sequence[Estimate]) -> Panel:
    """A panel of latest values for models no application describes."""
    rows = tuple(
        (
            e.name,
            e.node,
            "  ".join(f"{k}={v:.4g}" for k, v in e.values.items()),
        )
        for e in estimates
    )
    return Panel("estimates", ("model", "node", "values"), rows)


def render_panel(panel: Panel) -> str:
    """The panel as aligned text: its title, a header line and its rows (first column
    left-aligned, the others right-aligned). A ``node`` column whose rows all name the same
    node is dropped and the node named in the title instead."""
    if "node" in panel.columns and len(panel.rows) > 0:
        i = panel.columns.index("node")
        nodes = {r[i] for r in panel.rows if i < len(r) and r[i]}
        if len(nodes) == 1:
            keep = [j for j in range(len(panel.columns)) if j != i]
            panel = Panel(
                f"{panel.title} on node {nodes.pop()}",
                tuple(panel.columns[j] for j in keep),
                tuple(tuple(r[j] for j in keep if j < len(r)) for r in panel.rows),
            )
    table = [panel.columns, *panel.rows]
    widths = [
        max(len(str(row[i])) if i < len(row) else 0 for row in table)
        for i in range(len(panel.columns))
    ]

    def line(row: Sequence[str]) -> str:
        cells = [
            str(c).ljust(w) if i == 0 else str(c).rjust(w)
            for i, (c, w) in enumerate(zip(row, widths, strict=False))
        ]
        return " ".join(cells).rstrip()

    return "\n".join([f"{panel.title}:", *(line(r) for r in table)])
