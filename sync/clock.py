"""The clock of the sync service: monotonic, and counting the time a host was suspended.

Leases, waits and slot deadlines are lengths of time on one process's clock. A clock that
stops while the system is suspended would let a host resume believing a lease still valid
that ran out long ago, so every voter, term and client reads :func:`now`:

- Linux: ``CLOCK_BOOTTIME`` (``CLOCK_MONOTONIC`` plus the time spent in suspend);
- macOS: ``CLOCK_MONOTONIC`` of ``clock_gettime``, which keeps counting while the system
  sleeps (unlike ``time.monotonic``, which is ``mach_absolute_time`` there);
- elsewhere: ``time.monotonic``; whether it counts a suspend depends on the platform, so
  there a system suspend of a client's host is outside the guarantee (``sync/README.md``).

No clock counts a VM pause: a paused guest's clocks stop. The protocol does not rely on
the hosts' clocks for that (each grant is backed by a majority round after the request
arrived); a client's host that may be paused between its grant and its trigger is outside
the guarantee.
"""

from __future__ import annotations

import functools
import sys
import time
from collections.abc import Callable


def _pick() -> tuple[str, bool, Callable[[], float]]:
    if sys.platform.startswith("linux") and hasattr(time, "CLOCK_BOOTTIME"):
        return "CLOCK_BOOTTIME", True, functools.partial(time.clock_gettime, time.CLOCK_BOOTTIME)
    if sys.platform == "darwin" and hasattr(time, "CLOCK_MONOTONIC"):
        return "CLOCK_MONOTONIC", True, functools.partial(time.clock_gettime, time.CLOCK_MONOTONIC)
    return "time.monotonic", False, time.monotonic


NAME, COUNTS_SUSPEND, now = _pick()
"""``NAME`` of the clock in use, whether it ``COUNTS_SUSPEND``, and ``now()`` (seconds)."""
