"""A latency histogram that costs O(1) a sample and reads its percentiles in O(bins).

The scale benchmark's readers record every sample's transit time in the node process they
measure. Keeping the times in a list and sorting it for each report made the measurement
part of what it measured: every reader of a machine sorted its growing list at the same
wall-clock instant (the measures' shared grid), a burst of CPU that delayed the samples
arriving then. Bins 1 % wide on a log scale keep the cost flat: a percentile is read as
the upper edge of its bin, so it is at most 1 % above the exact one, never below.
"""

from __future__ import annotations

import math

LOW_S = 1e-5  # the first bin: up to 10 us
RATIO = 1.01  # each bin 1 % wider than the one before
BINS = 1400  # the last ends at LOW_S * RATIO**(BINS - 1), about 11 s; later ones land there
_LOG_RATIO = math.log(RATIO)


class LatencyHistogram:
    """Counts of latencies (s) in log-spaced bins; not thread-safe (its owner locks)."""

    def __init__(self) -> None:
        self.counts = [0] * BINS
        self.n = 0

    def add(self, seconds: float) -> None:
        """Count one latency (negative or tiny ones in the first bin)."""
        i = 0 if seconds <= LOW_S else 1 + int(math.log(seconds / LOW_S) / _LOG_RATIO)
        self.counts[min(i, BINS - 1)] += 1
        self.n += 1

    def sparse(self) -> dict[int, int]:
        """The non-empty bins as {bin index: count}: what a reader reports so that the
        readers' samples can be pooled (``merge``)."""
        return {i: c for i, c in enumerate(self.counts) if c}

    def merge(self, bins: dict[int, int]) -> None:
        """Add the counts of another histogram's ``sparse()`` bins to this one's."""
        for i, c in bins.items():
            self.counts[i] += c
            self.n += c

    def percentile(self, q: float) -> float | None:
        """The latency (s) below which the ``q`` share (0..1) of the samples lie, as the
        upper edge of its bin: the sample of rank ``int(q * n)`` (0-based, at most n - 1),
        as an index into the sorted list gives it, within 1 % above. None when empty."""
        if not self.n:
            return None
        rank = min(self.n - 1, int(q * self.n))
        seen = 0
        for i, c in enumerate(self.counts):
            seen += c
            if seen > rank:
                return LOW_S * RATIO**i
        raise AssertionError("unreachable: the counts sum to n")
