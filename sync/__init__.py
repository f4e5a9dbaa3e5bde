"""Leader-elected synchronisation service (sonar cross-talk).

Measures of a sync group (sonars) ask the group's leader for a time slot; the leader grants
one slot at a time, round-robin. Leaders are elected among the group's host nodes with
epochs, majority-confirmed leases on the monotonic clock and fencing tokens, so no two
measures of a group fire at once, even while the leader changes. Protocol and safety
argument: ``sync/README.md``.

Public API: :class:`SyncService` (one per node), :class:`SyncClient` and :class:`Grant`,
:func:`run_in_slot` (one synchronised step), :class:`SlotLost` and :func:`slot_duration`.
"""

from hera.sync.client import Grant, SlotLost, SyncClient, run_in_slot, slot_duration
from hera.sync.election import Timing
from hera.sync.service import SyncService

__all__ = [
    "Grant",
    "SlotLost",
    "SyncClient",
    "SyncService",
    "Timing",
    "run_in_slot",
    "slot_duration",
]
