"""The balancing robot's wheel encoders as an application: they check the world they sense.

Registered as ``wheels`` in ``hera.apps``; board faults go through the simulator's ``board``
verb (the boards are in the node's board registry).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from hera.application import Application


class WheelBoards(Application):
    """Wheel encoders of the balancing robot and whether it balances (seed 003)."""

    name = "wheels"
    title = "simulated wheel encoders of the balancing robot: its travel, whether it balances"
    measures = ("wheel_encoder",)

    def check_world(self, world: Mapping[str, Any]) -> list[str]:
        """The scenario, its keys and the environment must be ones the simulator knows."""
        from hera.nodes.world import world_problems

        return world_problems(world)
