"""The benchmark's latency histogram reads each percentile within 1 % above the exact one."""

from __future__ import annotations

import numpy as np
import pytest

from hera.bench.latency import BINS, LOW_S, RATIO, LatencyHistogram


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_percentiles_are_the_sorted_lists_within_one_bin_above(seed):
    rng = np.random.default_rng(seed)
    lat = np.concatenate([rng.lognormal(np.log(1e-3), 1.0, 20_000), rng.uniform(0.02, 0.2, 200)])
    h = LatencyHistogram()
    for x in lat.tolist():
        h.add(x)
    ordered = np.sort(lat)
    for q in (0.0, 0.5, 0.9, 0.99, 0.999, 1.0):
        exact = ordered[min(len(lat) - 1, int(q * len(lat)))]
        got = h.percentile(q)
        assert exact <= got <= exact * RATIO * (1 + 1e-12), (q, exact, got)


def test_empty_tiny_negative_and_huge_latencies():
    h = LatencyHistogram()
    assert h.percentile(0.5) is None
    for x in (-0.002, 0.0, 1e-9):  # a clock step back, or faster than the first bin
        h.add(x)
    assert h.percentile(1.0) == LOW_S
    h.add(1e6)  # beyond the last bin: counted there, not lost
    assert h.n == 4 and h.counts[BINS - 1] == 1
    assert h.percentile(1.0) == pytest.approx(LOW_S * RATIO ** (BINS - 1))


def test_merged_sparse_bins_give_the_percentiles_of_the_pooled_samples():
    rng = np.random.default_rng(5)
    parts = [rng.lognormal(np.log(1e-3 * (k + 1)), 0.5, 3000) for k in range(4)]
    pooled = LatencyHistogram()
    for part in parts:
        h = LatencyHistogram()
        for x in part.tolist():
            h.add(x)
        pooled.merge(h.sparse())
    ordered = np.sort(np.concatenate(parts))
    assert pooled.n == len(ordered)
    for q in (0.5, 0.99):
        exact = ordered[int(q * len(ordered))]
        assert exact <= pooled.percentile(q) <= exact * RATIO * (1 + 1e-12)
    # the worst part's p99 is not the pooled one: pooling is what this is for
    assert pooled.percentile(0.99) < np.quantile(parts[3], 0.99)
