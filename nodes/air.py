"""The air that carries sonar pings: simulated acoustic cross-talk over the bus.

Every simulated sonar of a group announces each ping on ``hera/<cluster>/sim/air/<group>``
(msgpack map ``{"origin", "sender", "start", "end", "pos", "grant"}``; ``start``/``end`` in
epoch seconds, ``pos`` the sonar position [x, y, z] m, ``grant`` [epoch, token] or nil), and
listens to the others. A ping whose interval overlaps another sender's ping is corrupted, as
with real MaxSonars sounding together. Sonars of one process sharing an :class:`Air` see each
other directly; others arrive through Zenoh (same host or not: across hosts the wall clocks
must then agree to about 0.5 ms, the gap between consecutive synchronised pings, e.g. by
PTP, for the air to tell turns apart; NTP's few ms are not enough). ``start`` is the clock
reading of the sonar's trigger-time check (``hera.sync.client.Turn``).
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
import uuid
from collections import deque
from dataclasses import dataclass
from typing import Any

import msgpack

from hera.keys import Keys, check_chunk
from hera.nodes.geometry import Vec3

log = logging.getLogger("hera.nodes.air")


@dataclass(frozen=True, slots=True)
class Ping:
    """One ping: who sounded (``sender`` = "<node>/<board>"), when (epoch s) and from where."""

    sender: str
    start: float
    end: float
    position: Vec3

    def overlaps(self, other: Ping) -> bool:
        return other.start < self.end and other.end > self.start


class Air:
    """The pings heard by the sonars of one group (thread-safe)."""

    def __init__(self, session: Any, keys: Keys, group: str, keep_s: float = 5.0) -> None:
        check_chunk(group, "air group")
        self.key = keys.sim(f"air/{group}")
        self.group = group
        self.origin = uuid.uuid4().hex
        self.keep_s = keep_s
        self.rejected = 0
        self.heard = 0  # pings received from other processes
        self._session = session
        self._pings: deque[Ping] = deque()
        self._lock = threading.Lock()
        self._sub = None
        if session is not None:
            self._sub = session.declare_subscriber(self.key, self._on_sample)

    def announce(self, ping: Ping, grant: Any = None) -> None:
        """Record ``ping`` and tell every other sonar of the group."""
        self._add(ping)
        if self._session is not None:
            g = None if grant is None else [int(grant.epoch), int(grant.token)]
            payload = msgpack.packb(
                {
                    "origin": self.origin,
                    "sender": ping.sender,
                    "start": ping.start,
                    "end": ping.end,
                    "pos": list(ping.position),
                    "grant": g,
                },
                use_bin_type=True,
            )
            try:
                self._session.put(self.key, payload)
            except Exception as e:  # a closed session must not kill the sonar
                log.warning("cannot announce ping on %s: %s", self.key, e)

    def overlapping(self, ping: Ping) -> list[Ping]:
        """The pings of other senders that overlap ``ping`` in time."""
        with self._lock:
            return [p for p in self._pings if p.sender != ping.sender and ping.overlaps(p)]

    def close(self) -> None:
        """Stop listening (the session stays open)."""
        if self._sub is not None:
            with contextlib.suppress(Exception):
                self._sub.undeclare()
        self._sub = None
        self._session = None

    def _add(self, ping: Ping) -> None:
        horizon = time.time() - self.keep_s
        with self._lock:
            self._pings.append(ping)
            while self._pings and self._pings[0].end < horizon:
                self._pings.popleft()

    def _on_sample(self, sample: Any) -> None:
        try:
            msg = msgpack.unpackb(sample.payload.to_bytes(), raw=False)
            if msg["origin"] == self.origin:
                return
            start, end = float(msg["start"]), float(msg["end"])
            pos = tuple(float(v) for v in msg["pos"])
            if not (math.isfinite(start) and math.isfinite(end) and end >= start and len(pos) == 3):
                raise ValueError("bad times or position")
            ping = Ping(str(msg["sender"]), start, end, pos)  # type: ignore[arg-type]
        except Exception as e:
            self.rejected += 1
            log.warning("rejected malformed ping on %s: %s", self.key, e)
            return
        self.heard += 1
        self._add(ping)
