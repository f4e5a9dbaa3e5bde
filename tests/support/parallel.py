"""Independent offline runs on every core.

The accuracy fixtures simulate and score many seeds, one after the other, in the test
process: CPU-bound work of which each run is seeded and self-contained. :func:`run_each`
shares them between processes (one per core), so a 2-core machine does them in about half
the time with the same results. The processes are spawned, not forked: the test process may
hold threads (bus sessions of earlier tests) that a fork would copy half-way.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import Any, TypeVar

T = TypeVar("T")


def run_each(fn: Callable[..., T], calls: Sequence[dict[str, Any]]) -> list[T]:
    """``[fn(**kw) for kw in calls]``, in order, computed in up to one process per core;
    ``fn`` must be a module-level function of an importable module (it is sent by name). An
    exception of a run is raised here, as it would be in the loop."""
    jobs = min(os.cpu_count() or 1, len(calls))
    if jobs <= 1:
        return [fn(**kw) for kw in calls]
    with ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = [pool.submit(fn, **kw) for kw in calls]
        return [f.result() for f in futures]
