"""The simulated VL53L1 boards as an application: they check the world they sense.

Registered as ``vl53l1`` in ``hera.apps``; board faults go through the simulator's ``board``
verb (the boards are in the node's board registry).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from hera.application import Application


class Vl53l1Boards(Application):
    """VL53L1 time-of-flight sensors on a carrier board (seed 001)."""

    name = "vl53l1"
    title = "simulated VL53L1 time-of-flight sensors on a carrier board (seed 001)"
    measures = ("vl53l1",)

    def check_world(self, world: Mapping[str, Any]) -> list[str]:
        """The scenario, its keys and the environment must be ones the simulator knows."""
        from hera.nodes.world import world_problems

        return world_problems(world)
