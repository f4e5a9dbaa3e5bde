"""The measure's side of the sync service: ask for a slot, check it, fire, give it back.

:class:`SyncClient` implements :class:`hera.measure.SlotClient`; :func:`run_in_slot` is the
whole step of a synchronised worker.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import zenoh
from hera.sync.election import Timing
from hera.sync.protocol import AcquireRequest, GrantReply, ProtocolError, Release

from hera.keys import Keys

log = logging.getLogger("hera.sync")

RETRY_PAUSE = 0.01
"""Pause before asking again when no host is granting (no leader, or a leader change)."""


@dataclass(frozen=True, slots=True)
class Grant:
    """A slot granted to ``holder`` (implements :class:`hera.measure.SlotGrant`).

    - ``epoch``, ``token``: the term and the fencing token (strictly increasing) it was
      granted under; samples taken in the slot carry them;
    - ``duration``: seconds of lease, counted from ``asked_at``;
    - ``asked_at``: this process's ``time.monotonic()`` just before the request was sent.
    """

    group: str
    holder: str
    epoch: int
    token: int
    duration: float
    asked_at: float
    leader: str

    @property
    def deadline(self) -> float:
        """When the lease runs out, on this process's monotonic clock."""
        return self.asked_at + self.duration

    def fits(self, seconds: float, now: float | None = None) -> bool:
        """True if something lasting ``seconds`` started ``now`` ends within the lease."""
        t = time.monotonic() if now is None else now
        return t + seconds <= self.deadline

    def require(self, seconds: float, now: float | None = None) -> None:
        """The trigger-time check (see :func:`run_in_slot`): raise :class:`SlotLost` unless
        something lasting ``seconds`` started ``now`` ends within the lease."""
        if not self.fits(seconds, now):
            raise SlotLost


class SlotLost(Exception):
    """Raised by a firing function that finds, at its trigger instant, that its step no
    longer fits the lease (a thread switch or a pause between :func:`run_in_slot`'s check
    and the trigger ate the slack): :func:`run_in_slot` then gives the slot back unused."""


def slot_duration(slot_s: float) -> float:
    """The lease to ask for a step of ``slot_s`` s: the step plus a slack for latency.

    The slack (25 % of the step, at least 5 ms) absorbs the grant's trip back and the
    scheduling delay before firing; a grant that arrives later than that is given back.
    """
    return slot_s + max(0.005, 0.25 * slot_s)


class SyncClient:
    """Ask the leader of a group for slots (any node, hosting or not)."""

    def __init__(self, session: zenoh.Session, keys: Keys, timing: Timing) -> None:
        self.session = session
        self.keys = keys
        self.timing = timing
        self._lock = threading.Lock()
        self._stats: dict[str, dict[str, dict[str, float]]] = {}
        self._epochs: dict[str, int] = {}

    def _stat(self, group: str, holder: str) -> dict[str, float]:
        return self._stats.setdefault(group, {}).setdefault(
            holder,
            {
                "acquired": 0,
                "timeouts": 0,
                "late": 0,
                "stale": 0,
                "last_wait_ms": 0.0,
                "mean_wait_ms": 0.0,
                "max_wait_ms": 0.0,
            },
        )

    def acquire(self, group: str, holder: str, duration: float, timeout: float) -> Grant | None:
        """Block until a slot of ``duration`` s is granted (a :class:`Grant`) or ``timeout``
        s pass (None). ValueError if ``duration`` exceeds the service's longest slot."""
        if not 0 < duration <= self.timing.max_slot:
            raise ValueError(
                f"sync {group!r}: slot lease {duration:.4f} s is not in (0, "
                f"{self.timing.max_slot} s]; shorten the slot or raise max_slot_ms"
            )
        start = time.monotonic()
        end = start + timeout
        key = self.keys.sync(group, "acquire")
        while True:
            asked_at = time.monotonic()
            left = end - asked_at
            if left <= 0:
                with self._lock:
                    self._stat(group, holder)["timeouts"] += 1
                return None
            # One attempt waits at most a lease: a host that stopped without its link
            # being declared dead yet would otherwise hold the reply stream open.
            grant = self._ask(group, key, holder, duration, min(left, self.timing.lease), asked_at)
            if grant is not None:
                wait = time.monotonic() - start
                with self._lock:
                    st = self._stat(group, holder)
                    st["acquired"] += 1
                    st["last_wait_ms"] = round(wait * 1e3, 3)
                    st["mean_wait_ms"] += (st["last_wait_ms"] - st["mean_wait_ms"]) / st["acquired"]
                    st["max_wait_ms"] = max(st["max_wait_ms"], st["last_wait_ms"])
                return grant
            time.sleep(min(RETRY_PAUSE, max(0.0, end - time.monotonic())))

    def _ask(
        self, group: str, key: str, holder: str, duration: float, left: float, asked_at: float
    ) -> Grant | None:
        got: Grant | None = None
        try:
            replies = self.session.get(
                key,
                payload=AcquireRequest(holder, duration, left).encode(),
                target=zenoh.QueryTarget.ALL,
                consolidation=zenoh.ConsolidationMode.NONE,
                timeout=left,
            )
            for r in replies:
                if not r.ok:
                    continue
                try:
                    rep = GrantReply.decode(r.ok.payload.to_bytes())
                except ProtocolError as e:
                    log.warning("sync %s: bad grant: %s", group, e)
                    continue
                g = Grant(group, holder, rep.epoch, rep.token, rep.duration, asked_at, rep.leader)
                with self._lock:
                    stale = rep.epoch < self._epochs.get(group, 0)
                    if not stale:
                        self._epochs[group] = rep.epoch
                    if stale:
                        self._stat(group, holder)["stale"] += 1
                if stale or got is not None:
                    self.release(g, used=False)  # an older term's or a second grant
                    continue
                got = g
                break
        except Exception as e:  # session closed or cut off: no grant
            log.debug("sync %s: acquire failed: %s", group, e)
        return got

    def release(self, grant: Grant, used: bool) -> None:
        """Give the slot back (best effort: a lost release frees at lease expiry)."""
        msg = Release(grant.epoch, grant.token, grant.holder, bool(used)).encode()
        try:
            self.session.put(
                self.keys.sync(grant.group, "release"),
                msg,
                congestion_control=zenoh.CongestionControl.BLOCK,
                express=True,
            )
        except Exception as e:
            log.debug("sync %s: release failed: %s", grant.group, e)

    def note_late(self, grant: Grant) -> None:
        with self._lock:
            self._stat(grant.group, grant.holder)["late"] += 1

    def status(self) -> dict[str, Any]:
        """Per group and measure: slots acquired, timeouts, late grants given back, waits."""
        with self._lock:
            return {g: {h: dict(s) for h, s in hs.items()} for g, hs in self._stats.items()}


def run_in_slot(
    client: Any,
    group: str,
    holder: str,
    slot_s: float,
    fn: Callable[[Grant], Any],
    timeout: float,
) -> tuple[bool, Any, Grant | None]:
    """One synchronised step: acquire a slot, call ``fn(grant)`` in it if it fits, release it.

    Returns ``(fired, result, grant)``. ``fn`` is called only if, by this process's
    monotonic clock, a step of ``slot_s`` s started now ends before the lease (counted
    from before the request was sent) runs out; otherwise the slot is given back unused
    and ``(False, None, grant)`` returned. ``(False, None, None)``: no slot within
    ``timeout``. The slot is released even if ``fn`` raises (the exception propagates).

    The check happens just before ``fn`` is called, but in CPython another thread can hold
    the GIL for a switch interval (5 ms) in between: a ``fn`` whose trigger must fall in
    the lease calls ``grant.require(slot_s)`` at its trigger, which raises :class:`SlotLost`
    if it no longer fits; that counts as a late grant, as if the first check had failed.
    """
    grant = client.acquire(group, holder, slot_duration(slot_s), timeout)
    if grant is None:
        return False, None, None
    if grant.fits(slot_s):
        try:
            result = fn(grant)
        except SlotLost:
            pass
        except BaseException:
            client.release(grant, used=True)
            raise
        else:
            client.release(grant, used=True)
            return True, result, grant
    client.release(grant, used=False)
    if hasattr(client, "note_late"):
        client.note_late(grant)
    return False, None, grant
