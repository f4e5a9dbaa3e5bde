"""Omega from lap timing: the self-consistent reference of a run without simulated truth.

The thesis measured the train's "true omega" by counting laps over 60 s (ch. 6.1). The
recordings of a run hold the same information more precisely: each sonar sees the train
pass on the near side of the track once per lap (:func:`pass_times`), successive passes
of one sonar are one lap apart, and a fit over all of them gives the lap time to a small
fraction of a sonar period (:func:`lap_time`). The direction comes from the
gyroscope's sign, when the run recorded one.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from hera.application import FunctionTruth, Reference
from hera.recordings import RecordingError, read_recordings
from hera.store import Sample

OMEGA = "omega [rad/s]"


def pass_times(
    samples: Sequence[Sample], near_margin: float = 0.3, split_s: float = 1.5
) -> list[float]:
    """The times (s) of the near-side passes in one sonar's readings (``[range m, ...]``,
    time-ordered): readings under a threshold ``near_margin`` m above the shortest ones
    (their 5th percentile), grouped into passes split by gaps over ``split_s`` s; a pass
    is timed by the middle of its two threshold crossings (each interpolated between the
    readings on either side of it, when the reading outside is a plain miss of the
    threshold): the range profile of a pass is symmetric about its closest approach. A
    pass cut by the start or the end of the recording is left out."""
    if len(samples) < 3:
        return []
    t = np.array([s.t for s in samples])
    r = np.array([s.values[0] for s in samples])
    thr = float(np.percentile(r, 5)) + near_margin
    idx = np.flatnonzero(r <= thr)
    if not len(idx):
        return []
    groups = np.split(idx, np.flatnonzero(np.diff(t[idx]) > split_s) + 1)
    out = []
    for g in groups:
        first, last = int(g[0]), int(g[-1])
        if t[first] - t[0] < split_s or t[-1] - t[last] < split_s:
            continue  # cut by the start or the end of the recording: not symmetric
        t_in, t_out = float(t[first]), float(t[last])
        if first > 0 and t[first] - t[first - 1] <= split_s and r[first - 1] < thr + 1.0:
            f = (r[first - 1] - thr) / (r[first - 1] - r[first])
            t_in = float(t[first - 1] + f * (t[first] - t[first - 1]))
        if last + 1 < len(t) and t[last + 1] - t[last] <= split_s and r[last + 1] < thr + 1.0:
            f = (thr - r[last]) / (r[last + 1] - r[last])
            t_out = float(t[last] + f * (t[last + 1] - t[last]))
        out.append((t_in + t_out) / 2)
    return out


def lap_time(passes: Sequence[Sequence[float]]) -> tuple[float, int, tuple[float, float]]:
    """(lap time s, passes used, (first, last) pass time) from each sonar's pass times:
    per sonar, each pass numbered by its laps since the first (a missed pass skips a
    number; a pass too close to the previous one is dropped), t_k = c_s + T k fitted to
    every sonar's passes at once (least squares, one offset per sonar, one lap time T: the
    pass times' errors average out). A constant speed over the run; NaN if no sonar has
    three passes."""
    rows, ts = [], []
    used = [np.asarray(sorted(p), dtype=float) for p in passes if len(p) >= 3]
    for j, p in enumerate(used):
        lap = float(np.median(np.diff(p)))
        k = np.round((p - p[0]) / lap)
        keep = np.concatenate([[True], np.diff(k) > 0])
        for kk, tt in zip(k[keep], p[keep], strict=True):
            row = [0.0] * (len(used) + 1)
            row[j], row[-1] = 1.0, kk
            rows.append(row)
            ts.append(tt)
    if not rows:
        return math.nan, 0, (math.nan, math.nan)
    coef = np.linalg.lstsq(np.array(rows), np.array(ts), rcond=None)[0]
    return float(coef[-1]), len(ts), (min(ts), max(ts))


def lap_reference(recordings: Sequence[Path]) -> Reference | None:
    """The reference of a run from its sonar recordings (the first folder that has some):
    a constant omega between the first and the last timed pass (:func:`lap_time`), signed
    by the gyroscope (the ``nav`` recording's second column) when there is one; None when
    no sonar has three passes."""
    for folder in recordings:
        try:
            sonar = read_recordings(folder, ["sonar"])
        except RecordingError:
            continue
        by_node: dict[str, list[Sample]] = {}
        for s in sonar:
            by_node.setdefault(s.node, []).append(s)
        passes = [pass_times(v) for _, v in sorted(by_node.items())]
        lap, n, (t0, t1) = lap_time(passes)
        if not n >= 3 or not lap > 0:
            continue
        sign, signed_by = 1.0, "assumed counter-clockwise (no gyroscope recorded)"
        try:
            g = [s.values[1] for s in read_recordings(folder, ["nav"]) if len(s.values) > 1]
        except RecordingError:
            g = []
        if g:
            sign = 1.0 if float(np.mean(g)) >= 0 else -1.0
            signed_by = "signed by the gyroscope"
        w = sign * 2 * math.pi / lap

        def at(t: float, w=w, t0=t0, t1=t1) -> dict[str, float]:
            return {OMEGA: w} if t0 <= t <= t1 else {}

        source = (
            f"self-consistency (no simulated truth): omega {w:.4f} rad/s from lap timing of "
            f"{n} sonar passes over {t1 - t0:.0f} s ({(t1 - t0) / lap:.1f} laps), "
            f"{signed_by}; omega only"
        )
        return Reference(FunctionTruth((OMEGA,), at), source)
    return None
