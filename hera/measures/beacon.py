"""The "beacon" measure: publishes one constant value per step (benchmarks, smoke tests)."""

from __future__ import annotations

from hera.measure import Measure


class Beacon(Measure):
    """Publishes ``[1.0]`` every period; its cost is the runtime's, not the measure's."""

    name = "beacon"
    period = 0.01
    columns = ("one [1]",)
    inputs = ()

    def measure(self) -> list[float]:
        return [1.0]
