"""Node services: long-running parts a node starts beside its measures.

A service is registered in the entry-point group ``hera.services`` as a factory
``factory(ctx: ServiceContext) -> NodeService``; every node calls each factory once at
start-up (after it joined the bus and recovered its state, before its measures start) and
closes the services when it stops. The sync service (``hera.sync``) is one: it hosts the
leader election of the node's sync groups and runs synchronised measures in their slots.

The runtime knows services only through these protocols: :class:`NodeService` (start,
close, status) and, for a service that runs measures' steps in time slots,
:class:`SlotService`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

if TYPE_CHECKING:  # pragma: no cover
    import zenoh

    from hera.keys import Keys
    from hera.measure import MeasureContext, MeasureSpec
    from hera.spec import ClusterSpec

SlotRunner = Callable[[Callable[[], Any]], "tuple[bool, Any, Any]"]
"""Runs one step in a slot: ``runner(step) -> (fired, result, grant)``."""


@dataclass(frozen=True)
class ServiceContext:
    """What a service factory is given: the node's session, keys, name and the spec, and
    the folder where the node persists its state (None: keep everything in memory)."""

    session: zenoh.Session
    keys: Keys
    node: str
    spec: ClusterSpec
    state_dir: Path | None = None


@runtime_checkable
class NodeService(Protocol):
    """A service of one node."""

    def start(self) -> None:
        """Start serving (idempotent)."""
        ...

    def close(self) -> None:
        """Stop; called before the node closes its session (idempotent)."""
        ...

    def status(self) -> dict[str, Any]:
        """JSON-able state for the node's status reply."""
        ...


@runtime_checkable
class SlotService(Protocol):
    """A service that runs a measure's steps in exclusive time slots (``sync = true``)."""

    def slot_runner(self, spec: MeasureSpec, ctx: MeasureContext) -> SlotRunner:
        """The function the worker of ``spec`` calls for each step (see :data:`SlotRunner`):
        it waits for a slot, runs the step in it if it still fits, and gives it back."""
        ...


ServiceFactory = Callable[[ServiceContext], NodeService]
