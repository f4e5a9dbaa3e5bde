"""Which nodes of the cluster are up, from their liveliness tokens.

A node declares ``alive/<node>``; every node subscribes to ``alive/**`` (with history, so
it learns who is already up) and keeps the set of live peers and a short log of up/down
events for the status. A DELETE means "lost connectivity" (ZENOH-NOTES), not "crashed".
Each event is also logged (``peer <node> up|down``), so a run's logs say when every node
noticed every other one come and go (fault campaigns measure detection times from them).
"""

from __future__ import annotations

import logging
import time
from collections import deque
from collections.abc import Callable

import zenoh

from hera.keys import Keys

log = logging.getLogger("hera.peers")


class Peers:
    """Live nodes of the cluster and their recent up/down events."""

    EVENTS = 64

    def __init__(self, keys: Keys, on_up: Callable[[str], None] | None = None) -> None:
        """``on_up(node)``: called (on the bus's thread: keep it short) when a node that was
        not up comes up."""
        self.keys = keys
        self.up: dict[str, float] = {}
        self.events: deque[tuple[float, str, str]] = deque(maxlen=self.EVENTS)
        self.on_up = on_up

    def on_alive(self, sample: zenoh.Sample) -> None:
        """Liveliness callback: a node token appeared or disappeared."""
        try:
            node, worker = self.keys.parse_alive(str(sample.key_expr))
        except ValueError:
            return
        if worker is not None:
            return
        now = time.time()
        event = "up" if sample.kind == zenoh.SampleKind.PUT else "down"
        if event == "up":
            new = node not in self.up
            self.up[node] = now
            if new and self.on_up is not None:
                try:
                    self.on_up(node)
                except Exception as e:  # a listener's bug must not stop liveliness
                    log.warning("peer-up listener failed for %s: %s", node, e)
        else:
            self.up.pop(node, None)
        self.events.append((now, node, event))
        log.info("peer %s %s", node, event)

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
