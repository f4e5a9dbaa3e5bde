"""Which nodes of the cluster are up, from their liveliness tokens.

A node declares ``alive/<node>``; every node subscribes to ``alive/**`` (with history, so
it learns who is already up) and keeps the set of live peers and a short log of up/down
events for the status. A DELETE means "lost connectivity" (ZENOH-NOTES), not "crashed".
"""

from __future__ import annotations

import time
from collections import deque

import zenoh

from hera.keys import Keys


class Peers:
    """Live nodes of the cluster and their recent up/down events."""

    EVENTS = 64

    def __init__(self, keys: Keys) -> None:
        self.keys = keys
        self.up: dict[str, float] = {}
        self.events: deque[tuple[float, str, str]] = deque(maxlen=self.EVENTS)

    def on_alive(self, sample: zenoh.Sample) -> None:
        """Liveliness callback: a node token appeared or disappeared."""
        try:
            node, worker = self.keys.parse_alive(str(sample.key_expr))
        except ValueError:
            return
        if worker is not None:
            return
        now = time.time()
        if sample.kind == zenoh.SampleKind.PUT:
            self.up[node] = now
            self.events.append((now, node, "up"))
        else:
            self.up.pop(node, None)
            self.events.append((now, node, "down"))

    def wait_for(self, expected: set[str], timeout: float) -> None:
        """Block until every node of ``expected`` is up or ``timeout`` s pass: liveliness
        history arrives asynchronously after connecting, within milliseconds on loopback."""
        deadline = time.monotonic() + timeout
        while not expected <= set(self.up) and time.monotonic() < deadline:
            time.sleep(0.005)

    def names(self) -> list[str]:
        return sorted(self.up)

    def event_log(self) -> list[dict[str, object]]:
        return [{"t": t, "node": n, "event": e} for t, n, e in list(self.events)]
