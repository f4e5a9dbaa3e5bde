"""Cheap helpers for the compiled path: the kernels' scratch array, block layout and gate
thresholds (cached per (gate, block sizes), since the same sensor set repeats every step),
and the stacked measurement noise of several blocks."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from .gating import gate_threshold
from .observations import Block

__all__ = ["EMPTY1", "SCRATCH", "block_layout", "grow_scratch", "stack_noise"]

# Placeholder for an unused kernel argument. Writable on purpose: numba's dispatch types a
# writable C array through its fast path (a read-only one costs a slower lookup), and an
# array of size zero has nothing to write to.
EMPTY1 = np.zeros(0)

# Scratch array of the allocation-free kernels: ``SCRATCH[0]``, shared by every filter. The
# kernels hold the GIL for their whole run (no ``nogil``, no callbacks into Python) and keep
# nothing in it between calls, so sharing is safe across filters and threads. A kernel that
# finds it too short returns WS_SMALL; the caller then calls ``grow_scratch`` and retries.
SCRATCH = [np.empty(4096)]


def grow_scratch(size: int) -> np.ndarray:
    """Make ``SCRATCH[0]`` at least ``size`` values long (never shrinks); returns it."""
    if SCRATCH[0].shape[0] < size:
        SCRATCH[0] = np.empty(max(size, 2 * SCRATCH[0].shape[0]))
    return SCRATCH[0]


_LAYOUT: dict[tuple, tuple[np.ndarray, np.ndarray, list]] = {}
_LAYOUT_MAX = 4096


def block_layout(
    gate: float | None, dims: int | tuple[int, ...]
) -> tuple[np.ndarray, np.ndarray, list[float | None]]:
    """(ends, thresholds, threshold list) for blocks of sizes ``dims`` (an int for one
    block): ``ends`` the cumulative row counts (int64), ``thresholds`` each block's chi-square
    NIS gate at probability ``gate`` (inf when gate is None), and the same thresholds as
    Python values (None when gate is None) for the result objects. Cached, read-only."""
    key = (gate, dims)
    got = _LAYOUT.get(key)
    if got is not None:
        return got
    sizes = (dims,) if isinstance(dims, int) else dims
    ends = np.cumsum(np.array(sizes, dtype=np.int64))
    if gate is None:
        thr: list[float | None] = [None] * len(sizes)
        arr = np.full(len(sizes), math.inf)
    else:
        thr = [gate_threshold(gate, d) for d in sizes]
        arr = np.array(thr, dtype=np.float64)
    ends.flags.writeable = False
    arr.flags.writeable = False
    got = (ends, arr, thr)
    if len(_LAYOUT) < _LAYOUT_MAX:
        _LAYOUT[key] = got
    return got


def stack_noise(blocks: Sequence[Block], m: int) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(variances, None) when every block has a diagonal R, else (None, block-diagonal R)."""
    if all(b.var is not None for b in blocks):
        return np.concatenate([b.var for b in blocks]), None  # type: ignore[misc]
    R = np.zeros((m, m))
    o = 0
    for b in blocks:
        d = b.dim
        R[o : o + d, o : o + d] = b.cov()
        o += d
    return None, R
