"""The observers of thesis ch. 5 as an application: their live panel.

Each ``counter`` publishes how many observers it sees alive; the panel shows, per node,
what its counters see (``20 20 20 20`` on a healthy 5 x 4 cluster), so a killed node shows
as a drop on the others and its own row disappearing, then coming back.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence

from hera.application import Application, Estimate, Panel, Truth


class Observers(Application):
    """The fault-tolerance observers (``counter``)."""

    name = "observers"
    title = "fault-tolerance observers of thesis ch. 5 (the counter measure)"
    measures = ("counter",)

    def panel(self, estimates: Sequence[Estimate], truth: Truth | None) -> Panel | None:
        seen: dict[str, list[tuple[str, float]]] = defaultdict(list)
        for e in estimates:
            seen[e.node].extend((e.name, v) for v in e.values.values())
        if not seen:
            return None
        rows = tuple(
            (node, " ".join(f"{v:.0f}" for _, v in sorted(values)))
            for node, values in sorted(seen.items())
        )
        return Panel("alive observers seen by each node's counters", ("node", "alive"), rows)
