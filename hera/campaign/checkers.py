"""The checkers: each a pure function of what a run recorded, giving a :class:`Verdict`.

Like Jepsen's, they judge the history, not the intentions: the audit of real trigger
times, the campaign's own record of the bus, the nodes' logs and persisted state, the
fault journal. Each is proved by a test in which it must fail (``tests/campaign``).

==================  ============================================================
``schedule``        every planned fault struck (and was undone), the run was not
                    cut short and the cluster settled
``overlaps``        no two firings of a sync group overlap in real time (must be 0)
``stale_firings``   no firing ends past its grant's lease, none fires under an older
                    grant after a newer one fired (tokens increase in start order)
``sync_partitions`` per partition of a sync group's hosts: the majority side keeps
                    firing (again within ``failover_s``), the minority side stops
                    within one sync lease and fires again within
                    ``resume_within_s`` of the healing
``gaps``            outside the faults (and ``recovery_s`` after each), no stream
                    pauses longer than ``max_gap_periods`` periods, ``gap_floor_s``
                    or 1.5 times its longest baseline gap
``sequences``       no seq of a stream goes back or repeats
``args``            no replicated arg is lost: every node ends with the newest value
                    of every key, in memory and on disk, and no calibration is redone
                    after a restart
``recovery``        every fault is over within ``recover_within_s``: the streams it
                    hit flow again (and a killed or stopped node was noticed)
``estimates``       after each fault (past ``settle_s``) and in the tail, each judged
                    model's error is within ``factor`` x its baseline (or ``floor``)
``agreement``       the same model on two nodes agrees within the tolerances, and no
                    node stays silent while another publishes it
``restarts``        supervisors restarted within their intensity and escalated
                    exactly when it was exceeded; no node hit the launcher's limit
``figures``         each figure of ``[[figures]]`` within its target
``leftovers``       nothing of the run is left running
==================  ============================================================

The checkers live in :mod:`~hera.campaign.check_state` (schedule, args, restarts,
leftovers), :mod:`~hera.campaign.check_firings` (overlaps, stale firings, partitions),
:mod:`~hera.campaign.check_streams` (gaps, sequences, recovery) and
:mod:`~hera.campaign.check_estimates` (estimates, agreement, figures); this module runs
them in order.
"""

from __future__ import annotations

from collections.abc import Callable

from hera.campaign.check_estimates import (
    check_agreement,
    check_estimates,
    check_figures,
    estimate_windows,
    silent_while,
)
from hera.campaign.check_firings import (
    check_overlaps,
    check_stale,
    check_sync_partitions,
    overlapping,
    partition_sides,
)
from hera.campaign.check_state import check_args, check_leftovers, check_restarts, check_schedule
from hera.campaign.check_streams import check_gaps, check_recovery, check_sequences, figures_of
from hera.campaign.history import History
from hera.campaign.schema import CHECKERS
from hera.campaign.verdict import Verdict, settings

__all__ = [
    "CHECKS",
    "Verdict",
    "estimate_windows",
    "figures_of",
    "overlapping",
    "partition_sides",
    "run_all",
    "silent_while",
]

CHECKS: dict[str, Callable[[History], Verdict]] = {
    "schedule": check_schedule,
    "overlaps": check_overlaps,
    "stale_firings": check_stale,
    "sync_partitions": check_sync_partitions,
    "gaps": check_gaps,
    "sequences": check_sequences,
    "args": check_args,
    "recovery": check_recovery,
    "estimates": check_estimates,
    "agreement": check_agreement,
    "restarts": check_restarts,
    "figures": check_figures,
    "leftovers": check_leftovers,
}
assert tuple(CHECKS) == CHECKERS


def run_all(h: History) -> list[Verdict]:
    """Every checker's verdict, in order; those the campaign skips are reported as
    skipped (never as passed); a checker that breaks fails, saying why."""
    skip = set(settings(h, "checks").get("skip", []))
    out = []
    for name, fn in CHECKS.items():
        if name in skip:
            out.append(Verdict(name, True, "skipped by the campaign ([checks] skip)", skipped=True))
            continue
        try:
            out.append(fn(h))
        except Exception as e:  # a checker's bug is reported, never taken for a pass
            out.append(Verdict(name, False, f"the checker failed: {type(e).__name__}: {e}"))
    return out
