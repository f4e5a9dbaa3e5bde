"""The "counter" observer of the thesis's fault-tolerance validation (thesis ch. 5).

Each counter publishes every cycle ``[alive]``: how many observers (publications whose
name starts with ``prefix``, on any node, itself included) recently sent a value, meaning
less than 1.5 cycles ago, and have been sending without a gap for at least 2 cycles, so a
killed and restarted observer stays visibly missing for two cycles (thesis ch. 5, "counter").
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

from hera.measure import Measure, MeasureContext
from hera.schema import STR, Setting, Table, number


class Counter(Measure):
    """Counts the recently alive observers; args: ``prefix`` (default "obs")."""

    name = "obs"
    period = 0.1
    columns = ("alive observers [count]",)
    arguments = Table(
        "counter args",
        [
            Setting("prefix", STR, "obs", "count publications whose name starts with this"),
            Setting(
                "fresh_cycles", number(above=0), 1.5, "recently sent: within this many periods"
            ),
            Setting("min_age_cycles", number(0), 2.0, "and sending without a gap this many"),
        ],
    )

    @classmethod
    def reads(cls, args: Mapping[str, Any]) -> tuple[str, ...]:
        """Every publication whose name starts with its prefix."""
        return (cls.prepare_args(args)["prefix"] + "*",)

    def init(self, args: Mapping[str, Any], ctx: MeasureContext) -> None:
        args = self.prepare_args(args)
        super().init(args, ctx)
        self.prefix = args["prefix"]
        self.fresh_cycles = args["fresh_cycles"]
        self.min_age_cycles = args["min_age_cycles"]
        self._streak: dict[tuple[str, str], float] = {}

    def measure(self) -> list[float]:
        period = self.ctx.spec.period
        now = time.monotonic()
        alive = 0
        seen: dict[tuple[str, str], float] = {}
        fresh = self.fresh_cycles * period
        for s in self.ctx.store.samples():  # one look at the store, not one per name
            if not s.name.startswith(self.prefix) or now - s.arrival > fresh:
                continue
            key = (s.name, s.node)
            # a streak starts at the first fresh sample after a gap (or at start-up)
            seen[key] = start = self._streak.get(key, s.arrival)
            if now - start >= self.min_age_cycles * period:
                alive += 1
        self._streak = seen
        return [float(alive)]
