"""Filter health: NIS statistics per block label, a trace(P) watch, and a reset hook.

Consistent filters have NIS ~ chi-square(m): its mean over many steps should be near m
(seed 000, "monitor normalized innovation squared"); a growing trace(P) means the filter
runs open loop or diverges (seed 000, "Monitor trace(P) and trigger failsafe").
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .results import UpdateResult

__all__ = ["HealthMonitor", "NisStats"]


@dataclass
class NisStats:
    """Running NIS statistics for one block label."""

    dim: int
    window: int
    count: int = 0
    total: float = 0.0
    rejected: int = 0
    recent: deque = field(default_factory=deque)

    @property
    def mean(self) -> float:
        """Mean NIS over all samples (expected value: ``dim``)."""
        return self.total / self.count if self.count else float("nan")

    @property
    def recent_mean(self) -> float:
        """Mean NIS over the last ``window`` samples."""
        return sum(self.recent) / len(self.recent) if self.recent else float("nan")

    def add(self, nis: float, accepted: bool) -> None:
        self.count += 1
        self.total += nis
        if not accepted:
            self.rejected += 1
        self.recent.append(nis)
        if len(self.recent) > self.window:
            self.recent.popleft()


class HealthMonitor:
    """Watches a filter (anything with ``x``, ``P`` and ``reset(x, P)``).

    ``record(result)`` accumulates NIS per label; ``check(filter)`` compares trace(P)
    (state units squared) with ``trace_limit`` and, when exceeded or when P is not finite,
    calls ``on_reset(filter)`` if given, else ``filter.reset(*reset_state)`` if given;
    it returns True when the filter was found unhealthy.
    """

    def __init__(
        self,
        *,
        window: int = 50,
        trace_limit: float | None = None,
        on_reset: Callable[[Any], None] | None = None,
        reset_state: tuple[Any, Any] | None = None,
    ) -> None:
        self.window = window
        self.trace_limit = trace_limit
        self.on_reset = on_reset
        self.reset_state = reset_state
        self.stats: dict[str, NisStats] = {}
        self.resets = 0
        self.last_trace: float | None = None

    def record(self, result: UpdateResult) -> None:
        """Add the NIS of every block of an update result."""
        for o in result.outcomes:
            st = self.stats.get(o.label)
            if st is None:
                st = self.stats[o.label] = NisStats(o.dim, self.window)
            st.add(o.nis, o.accepted)

    def check(self, filt: Any) -> bool:
        """trace(P) watch; triggers the reset hook and returns True when unhealthy."""
        tr = float(np.trace(filt.P))
        self.last_trace = tr
        bad = not np.isfinite(tr) or (self.trace_limit is not None and tr > self.trace_limit)
        if bad:
            self.reset(filt)
        return bad

    def reset(self, filt: Any) -> None:
        """Run the reset hook now."""
        self.resets += 1
        if self.on_reset is not None:
            self.on_reset(filt)
        elif self.reset_state is not None:
            filt.reset(*self.reset_state)

    def summary(self) -> dict[str, dict[str, float]]:
        """{label: {count, mean, recent_mean, rejected, dim}}."""
        return {
            k: {
                "dim": s.dim,
                "count": s.count,
                "mean": s.mean,
                "recent_mean": s.recent_mean,
                "rejected": s.rejected,
            }
            for k, s in self.stats.items()
        }
