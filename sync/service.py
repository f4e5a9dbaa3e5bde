"""The per-node entry point of the sync service: :class:`SyncService`."""

from __future__ import annotations

import logging
import os
import threading
from collections.abc import Callable, Iterable, Mapping
from typing import Any

import zenoh

from hera.keys import Keys, check_chunk
from hera.measure import MeasureContext, MeasureSpec
from hera.services import ServiceContext, SlotRunner
from hera.sync import clock as sync_clock
from hera.sync.client import SyncClient, run_in_slot
from hera.sync.election import Timing
from hera.sync.group import GroupHost

log = logging.getLogger("hera.sync")

DEFAULT_LEASE_MS = 300


def _normalise(host_groups: Mapping[str, Iterable[str]] | Iterable[Any]) -> dict[str, list[str]]:
    if isinstance(host_groups, Mapping):
        items = list(host_groups.items())
    else:
        items = []
        for entry in host_groups:
            if isinstance(entry, Mapping):
                items.append((entry["group"], entry["hosts"]))
            else:
                group, hosts = entry
                items.append((group, hosts))
    out: dict[str, list[str]] = {}
    for group, hosts in items:
        check_chunk(group, "sync group")
        if isinstance(hosts, str):
            raise ValueError(f"sync group {group!r}: hosts must be a list of node names")
        names = [check_chunk(h, "node name") for h in hosts]
        if not names or len(set(names)) != len(names):
            raise ValueError(f"sync group {group!r}: hosts must be non-empty and distinct")
        if group in out:
            raise ValueError(f"sync group {group!r} listed twice")
        out[group] = names
    return out


class SyncService:
    """The sync service of one node: hosts its groups, and is every local measure's client.

    ``host_groups`` maps each group this node hosts to the full list of the group's host
    nodes (the majority is counted over that list), e.g. ``{"sonar": ["s1", "s2", "s3"]}``;
    a list of ``(group, hosts)`` pairs is accepted too, and an empty one for a node that
    hosts nothing. ``lease_ms`` is the leader lease L (how long a majority confirmation
    lets a leader grant); ``max_slot_ms`` the longest slot lease (default L / 2, the most
    allowed); ``margin_ms`` the margin m. A new leader grants nothing for L + max_slot + m
    after its election. ``state_dir``: where each hosted group's voter keeps its promise
    (durable across restarts; without it, promises live in memory and a restart is covered
    only by the quiet period, outside the guarantee of ``sync/README.md``).
    """

    def __init__(
        self,
        session: zenoh.Session,
        keys: Keys,
        node: str,
        host_groups: Mapping[str, Iterable[str]] | Iterable[Any] = (),
        lease_ms: int = DEFAULT_LEASE_MS,
        max_slot_ms: int | None = None,
        margin_ms: int = 50,
        state_dir: str | os.PathLike[str] | None = None,
    ) -> None:
        check_chunk(node, "node name")
        lease = lease_ms / 1000.0
        max_slot = (max_slot_ms / 1000.0) if max_slot_ms is not None else lease / 2
        self.timing = Timing(lease=lease, max_slot=max_slot, margin=margin_ms / 1000.0)
        self.state_dir = state_dir
        self.node = node
        self.keys = keys
        self.session = session
        groups = _normalise(host_groups)
        for group, hosts in groups.items():
            if node not in hosts:
                raise ValueError(f"sync group {group!r}: node {node!r} not among hosts {hosts}")
        if groups and state_dir is None:
            log.warning(
                "sync on %s: no state directory, promises kept in memory only: a restart is "
                "covered by the quiet period, not by the guarantee (sync/README.md)",
                node,
            )
        self.hosts: dict[str, GroupHost] = {
            g: GroupHost(session, keys, g, node, hosts, self.timing, state_dir=state_dir)
            for g, hosts in groups.items()
        }
        self._client = SyncClient(session, keys, self.timing)
        self._lock = threading.Lock()
        self._started = False
        self._closed = False

    def start(self) -> None:
        """Start hosting every group (idempotent)."""
        with self._lock:
            if self._started or self._closed:
                return
            self._started = True
            for h in self.hosts.values():
                h.start()

    def close(self) -> None:
        """Stop hosting; call before closing the session (idempotent)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        for h in self.hosts.values():
            h.close()

    def client(self) -> SyncClient:
        """The :class:`hera.measure.SlotClient` for this node's measures."""
        return self._client

    def slot_runner(self, spec: MeasureSpec, ctx: MeasureContext) -> SlotRunner:
        """What the worker of synchronised measure ``spec`` calls for each step
        (:class:`hera.services.SlotService`): acquire a slot of ``spec.group`` for
        ``spec.slot`` s, run the step in it with ``ctx.grant`` set (the measure announces
        the turn it runs under; its driver checks the turn right at the trigger), release
        it once the step has ended."""
        client = self._client
        holder = f"{self.node}/{spec.name}"

        def in_slot(step: Callable[[], Any]) -> tuple[bool, Any, Any]:
            def fire(turn: Any) -> Any:
                # the measure hands the turn to its driver, which checks it at the trigger
                ctx.grant = turn
                try:
                    return step()
                finally:
                    ctx.grant = None

            return run_in_slot(client, spec.group, holder, spec.slot, fire, spec.period)

        return in_slot

    def status(self) -> dict[str, Any]:
        """JSON-able: timing, each hosted group's state, and this node's measures' waits."""
        t = self.timing
        return {
            "node": self.node,
            "lease_ms": round(t.lease * 1e3, 3),
            "max_slot_ms": round(t.max_slot * 1e3, 3),
            "new_leader_wait_ms": round(t.wait * 1e3, 3),
            "margin_ms": round(t.margin * 1e3, 3),
            "trigger_pause_ms": round(t.trigger_pause * 1e3, 3),
            "clock": sync_clock.NAME,
            "durable_promises": self.state_dir is not None,
            "groups": {g: h.status() for g, h in self.hosts.items()},
            "client": self._client.status(),
        }


def node_service(ctx: ServiceContext) -> SyncService:
    """The ``hera.services`` factory: the sync service of node ``ctx.node``, hosting the
    groups its ``sync_hosts`` name (each with the spec's full host list) with the spec's
    ``sync_lease_ms``, and the slot client of its synchronised measures; each hosted
    group's voter persists its promises in the node's state directory."""
    groups = ctx.spec.sync_groups()
    hosts = {g: groups[g] for g in ctx.spec.node(ctx.node).sync_hosts}
    return SyncService(
        ctx.session, ctx.keys, ctx.node, hosts, ctx.spec.sync_lease_ms, state_dir=ctx.state_dir
    )
