"""Omega from lap timing: the self-consistent reference of a run without simulated truth.

The thesis measured the train's "true omega" by counting laps over 60 s (ch. 6.1). The
recordings of a run hold the same information more precisely: each sonar sees the train
pass on the near side of the track once per lap (:func:`pass_times`), successive passes
of one sonar are one lap apart, and a fit over all of them gives the lap time to a small
fraction of a sonar period (:func:`lap_fit`). A real train's speed drifts (the thesis's
E8 recording speeds up by 2.5 % over 88 s): when the pass times show a trend in the lap
time beyond doubt, the fit follows it and the reference's omega changes with time; a
constant reference would count a filter that follows the train as wrong by up to half the
drift. The direction comes from the gyroscope's sign, when the run recorded one.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
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


TREND_T = 3.0
"""The lap time's trend is followed when its fitted coefficient lies this many standard errors
from 0 (a constant speed shows one that far by chance in about 0.3 % of runs)."""


@dataclass(frozen=True)
class LapFit:
    """Pass times fitted as t = c_s + T k + a u^2 (:func:`lap_fit`): ``lap`` T (s), ``trend``
    a (s; 0 when the speed is taken as constant), ``trend_t`` a's t statistic (NaN without
    enough passes to tell), ``n`` passes used, ``t0`` and ``t1`` the first and last (s), and
    ``lap0`` the constant-speed lap time that scales u = (t - t0) / lap0 (laps since t0)."""

    lap: float
    trend: float
    trend_t: float
    n: int
    t0: float
    t1: float
    lap0: float

    def lap_at(self, t: float) -> float:
        """The lap time (s) at time t: dt/dk = T + 2 a u(t)."""
        return self.lap + 2.0 * self.trend * (t - self.t0) / self.lap0


def lap_fit(passes: Sequence[Sequence[float]], trend: bool = True) -> LapFit:
    """The lap time from each sonar's pass times: per sonar, each pass numbered k by its laps
    since the first (a missed pass skips a number; a pass too close to the previous one is
    dropped), t_k = c_s + T k fitted to every sonar's passes at once (least squares, one
    offset per sonar, one lap time T: the pass times' errors average out). With ``trend``,
    t_k = c_s + T k + a u_k^2 too, u_k the pass's laps since the first pass of all (from the
    constant fit): a lap time changing linearly, T + 2 a u; kept when a is TREND_T standard
    errors from 0, else a = 0. NaN lap if no sonar has three passes."""
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
    nan = math.nan
    if not rows:
        return LapFit(nan, 0.0, nan, 0, nan, nan, nan)
    A, y = np.array(rows), np.array(ts)
    coef = np.linalg.lstsq(A, y, rcond=None)[0]
    t0, t1, lap0 = float(y.min()), float(y.max()), float(coef[-1])
    fit = LapFit(lap0, 0.0, nan, len(ts), t0, t1, lap0)
    dof = len(y) - A.shape[1] - 1
    if not trend or dof < 2 or not lap0 > 0:
        return fit
    u = (A @ coef - t0) / lap0
    Aq = np.column_stack([A, u * u])
    coef_q = np.linalg.lstsq(Aq, y, rcond=None)[0]
    resid = y - Aq @ coef_q
    cov = float(resid @ resid) / dof * np.linalg.pinv(Aq.T @ Aq)
    se = math.sqrt(max(float(cov[-1, -1]), 0.0))
    t_stat = float(coef_q[-1]) / se if se > 0 else nan
    if not abs(t_stat) >= TREND_T:
        return LapFit(lap0, 0.0, t_stat, len(ts), t0, t1, lap0)
    return LapFit(float(coef_q[-2]), float(coef_q[-1]), t_stat, len(ts), t0, t1, lap0)


def lap_reference(recordings: Sequence[Path]) -> Reference | None:
    """The reference of a run from its sonar recordings (the first folder that has some):
    omega between the first and the last timed pass from :func:`lap_fit` (constant, or
    following the lap time's trend when the passes show one), signed by the gyroscope (the
    ``nav`` recording's second column) when there is one; None when no sonar has three
    passes."""
    for folder in recordings:
        try:
            sonar = read_recordings(folder, ["sonar"])
        except RecordingError:
            continue
        by_node: dict[str, list[Sample]] = {}
        for s in sonar:
            by_node.setdefault(s.node, []).append(s)
        fit = lap_fit([pass_times(v) for _, v in sorted(by_node.items())])
        n, t0, t1 = fit.n, fit.t0, fit.t1
        if not n >= 3 or not (fit.lap > 0 and fit.lap_at(t0) > 0 and fit.lap_at(t1) > 0):
            continue
        sign, signed_by = 1.0, "assumed counter-clockwise (no gyroscope recorded)"
        try:
            g = [s.values[1] for s in read_recordings(folder, ["nav"]) if len(s.values) > 1]
        except RecordingError:
            g = []
        if g:
            sign = 1.0 if float(np.mean(g)) >= 0 else -1.0
            signed_by = "signed by the gyroscope"

        def at(t: float, fit=fit, sign=sign) -> dict[str, float]:
            if not fit.t0 <= t <= fit.t1:
                return {}
            return {OMEGA: sign * 2 * math.pi / fit.lap_at(t)}

        w0, w1 = sign * 2 * math.pi / fit.lap_at(t0), sign * 2 * math.pi / fit.lap_at(t1)
        laps = (t1 - t0) / fit.lap0
        if fit.trend:
            what = (
                f"omega {w0:.4f} -> {w1:.4f} rad/s ({(w1 / w0 - 1) * 100:+.1f} %: the lap "
                f"time's trend, {abs(fit.trend_t):.1f} standard errors from 0)"
            )
        else:
            what = f"omega {w0:.4f} rad/s"
        source = (
            f"self-consistency (no simulated truth): {what} from lap timing of {n} sonar "
            f"passes over {t1 - t0:.0f} s ({laps:.1f} laps), {signed_by}; omega only"
        )
        return Reference(FunctionTruth((OMEGA,), at), source)
    return None
