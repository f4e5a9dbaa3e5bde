"""The simulated boards as an application: they add the ``board`` control verb.

Registered as the ``simulator`` entry point of ``hera.apps``; the runtime asks it for its verbs
like any application's and never imports the simulator.
"""

from __future__ import annotations

from collections.abc import Mapping

from hera.application import Application, Verb


class Simulator(Application):
    """Simulated Pmod NAV and MaxSonar boards (board faults at run time)."""

    name = "simulator"
    title = "simulated boards: board faults through the 'board' control verb"
    measures = ("nav", "mag", "nav3", "sonar")

    def verbs(self) -> Mapping[str, Verb]:
        from hera.nodes.faults import board_verb

        return {"board": board_verb}
