"""The node's wall clock: the epoch time it stamps what it publishes with.

``now()`` is ``time.time()`` plus an offset, 0 unless someone sets it: the ``clock``
control verb does (``hera inject NODE clock SECONDS``, fault campaigns), to make one node
behave like a host whose clock is off by that much. What reads this clock, and so is
skewed: the default measurement time of a sample (a measure that returns no time), the
stamps of the board drivers' readings (simulated or real, :mod:`hera.nodes.driver`), the
last-writer-wins stamps of the replicated args, and a store's arrival stamps (so the
transit figures of a skewed node show its skew, as they would on a real host).

Limits (what a real skewed host would also do, but this does not): the simulated world
itself runs on the true time (a skewed board senses the world as it is and stamps the
reading with its own clock), log lines and the sync service keep the true clocks (the
sync service only measures lengths of time on monotonic clocks, so an offset never
matters to it), a measure that calls ``time.time()`` itself is not skewed, and the offset
lives in the process: a restarted node starts on the true clock again.
"""

from __future__ import annotations

import math
import threading
import time

MAX_SKEW_S = 3600.0
"""The largest offset accepted (s), either way."""

_lock = threading.Lock()
_offset = 0.0


def now() -> float:
    """This node's wall clock (epoch seconds): the true time plus the offset."""
    return time.time() + _offset


def now_ns() -> int:
    """:func:`now` in integer nanoseconds."""
    return time.time_ns() + round(_offset * 1e9)


def offset() -> float:
    """The current offset (s) of this node's clock from the true time."""
    return _offset


def set_offset(seconds: float) -> float:
    """Set the offset (s, within +/- :data:`MAX_SKEW_S`); return the previous one.
    ValueError naming the value otherwise."""
    global _offset
    if (
        isinstance(seconds, bool)
        or not isinstance(seconds, (int, float))
        or not math.isfinite(seconds)
        or abs(seconds) > MAX_SKEW_S
    ):
        raise ValueError(
            f"clock skew must be a number of seconds within +/-{MAX_SKEW_S:g}, got {seconds!r}"
        )
    with _lock:
        before, _offset = _offset, float(seconds)
    return before
