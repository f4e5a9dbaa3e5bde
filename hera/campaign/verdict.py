"""A checker's verdict, and what every checker shares (settings, formatting)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from hera.campaign.history import History

EPS = 2e-6
"""Rounding of the fire logs' times (they are written to the microsecond)."""
EDGE_S = 0.5
"""Samples this close to the ends of a silence do not count as published during it."""


@dataclass
class Verdict:
    """A checker's verdict: ``passed``, a one-line ``summary``, and details as rows."""

    name: str
    passed: bool
    summary: str
    rows: list[dict[str, Any]] = field(default_factory=list)
    skipped: bool = False

    @property
    def status(self) -> str:
        if self.skipped:
            return "skipped"
        return "pass" if self.passed else "FAIL"


def settings(h: History, table: str) -> dict[str, Any]:
    return dict(h.meta.get("campaign", {}).get(table, {}))


def fmt(x: float | None, unit: str = "s") -> str:
    if x is None:
        return "-"
    return f"{x * 1000:.0f} ms" if unit == "s" and abs(x) < 1 else f"{x:.2f} {unit}".strip()
