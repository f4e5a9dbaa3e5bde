"""Leader-elected synchronisation service (sonar cross-talk).

Measures of a sync group (sonars) ask the group's leader for a time slot; the leader grants
one slot at a time, round-robin. Leaders are elected among the group's host nodes with
durable epochs; each grant is backed by a majority round made after the request arrived,
and the driver checks its slot at the physical trigger, so no two measures of a group
sound at once, even while the leader changes. Assumptions, theorem and proof:
``sync/README.md``.

Public API: :class:`SyncService` (one per node), :class:`SyncClient`, :class:`Grant`,
:func:`run_in_slot` (one synchronised step), :class:`Turn` (what a driver checks at its
trigger), :class:`SlotLost`, :func:`slot_duration` and :class:`Timing`.
"""

from hera.sync.client import (
    Grant,
    SlotLost,
    SyncClient,
    TriggerTime,
    Turn,
    run_in_slot,
    slot_duration,
)
from hera.sync.election import Timing
from hera.sync.service import SyncService

__all__ = [
    "Grant",
    "SlotLost",
    "SyncClient",
    "SyncService",
    "Timing",
    "TriggerTime",
    "Turn",
    "run_in_slot",
    "slot_duration",
]
