"""Fixtures for the sync service tests: clusters of real harness processes on loopback."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest

from hera.sync.election import Timing
from hera.sync.harness import Cluster, Firing, check_firings

HOSTS = ["s1", "s2", "s3"]


@pytest.fixture
def make_cluster() -> Iterator[Callable[..., Cluster]]:
    """Start clusters; every process is SIGCONTed and SIGKILLed afterwards, even on failure."""
    started: list[Cluster] = []

    def make(**kw) -> Cluster:
        c = Cluster(kw.pop("hosts", HOSTS), **kw)
        started.append(c)
        c.start()
        return c

    yield make
    for c in started:
        c.close()


def _assert_exclusive(firings: list[Firing], at_least: int) -> None:
    """Zero overlaps, fencing tokens increasing in firing order, every fit check right and
    every sound within its lease plus the trigger pause the margin tolerates (condition C:
    a thread that loses the CPU for a few microseconds between the check and the trigger
    ends its sound that much past the lease, as the protocol allows)."""
    pause = Timing(lease=0.3, max_slot=0.15).trigger_pause  # the harness's lease_ms = 300
    check = check_firings(firings, pause)
    assert check.firings >= at_least
    assert check.overlaps == [], f"{len(check.overlaps)} overlaps, first {check.overlaps[:3]}"
    assert check.out_of_order == [], f"stale grants fired: {check.out_of_order[:3]}"
    assert check.past_deadline == [], f"fired past lease: {check.past_deadline[:3]}"


@pytest.fixture
def assert_exclusive() -> Callable[[list[Firing], int], None]:
    """The mutual-exclusion check of a run's firings (a fixture: no conftest imports)."""
    return _assert_exclusive
