"""The simulated boards as an application: they add the ``board`` control verb.

Registered as the ``simulator`` entry point of ``hera.apps``; the runtime asks it for its verbs
like any application's and never imports the simulator.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from hera.application import Application, Verb


class Simulator(Application):
    """Simulated Pmod NAV and MaxSonar boards (board faults at run time)."""

    name = "simulator"
    title = "simulated boards: board faults through the 'board' control verb"
    measures = ("nav", "mag", "nav3", "sonar")

    def check_world(self, world: Mapping[str, Any]) -> list[str]:
        """The scenario, its keys and the environment must be ones the simulator knows."""
        from hera.nodes.world import world_problems

        problems = world_problems(world)
        if problems:
            return problems
        sonars = world.get("sonars", {})
        if not isinstance(sonars, Mapping) or not all(
            isinstance(v, Mapping) for v in sonars.values()
        ):
            return ["world 'sonars' must be a table of <node> = {position, direction}"]
        return []

    def verbs(self) -> Mapping[str, Verb]:
        from hera.nodes.faults import board_verb

        return {"board": board_verb}
