"""The 2-D tilt application (entry point ``tilt2d`` of ``hera.apps``): truth, scores, plots
and live panel of ``tilt_split``, ``tilt_ekf``, ``tilt_ukf``, ``tilt_bias`` and
``tilt_wheels`` (seed 003).

Scores (``hera eval``; degrees, s since a filter's first estimate):

- ``converge_s``: when the error came within +/- 1 deg to stay there for 2 s (seed Table 9:
  about 30 s);
- ``still_deg``: the error's standard deviation while the robot is still (on its stand),
  from 1 s after the first estimate (seed Table 9, "still measurement noise": < 0.1 deg);
- ``rmse_deg``: RMSE after ``after`` s; ``push_deg``: RMSE while a push is under way;
  ``max_deg``: the largest error after ``after`` s;
- ``final_deg``: the mean error over the last 10 s (what a drifting bias leaves).

The truth and the segments come from the world's ``balancing`` scenario.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hera.application import (
    Application,
    Estimate,
    EvalOptions,
    FunctionTruth,
    Metric,
    Panel,
    Series,
    Truth,
)

THETA, SEGMENT = "theta [rad]", "segment"
SEGMENTS = ("still", "rise", "sway", "push")
CONVERGED_DEG, HOLD_S = 1.0, 2.0


def robot_truth(world: Mapping[str, Any]) -> Truth:
    """The robot's true tilt theta (rad, rotation about the body y axis) and the segment
    (index into :data:`SEGMENTS`) at any epoch time."""
    from hera.nodes.world import epoch_of, make_scenario

    scenario, epoch = make_scenario(world), epoch_of(world)
    segment = getattr(scenario, "segment", None)

    def at(t: float) -> dict[str, float]:
        w, _, y, _ = scenario.motion(t - epoch).orientation
        out = {THETA: 2.0 * math.atan2(y, w)}
        if segment is not None:
            out[SEGMENT] = float(SEGMENTS.index(segment(t - epoch)))
        return out

    return FunctionTruth((THETA, SEGMENT), at)


def _rms(x: np.ndarray) -> float | None:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else None


def converge_time(since: np.ndarray, err_deg: np.ndarray) -> float | None:
    """The first time (s) from which |err| <= 1 deg for ``HOLD_S`` s (or to the end)."""
    bad = np.abs(err_deg) > CONVERGED_DEG
    n = len(since)
    j = 0
    for i in range(n):
        if bad[i]:
            continue
        j = max(j, i)
        while j + 1 < n and not bad[j + 1] and since[j + 1] - since[i] < HOLD_S:
            j += 1
        if j + 1 >= n or since[j + 1] - since[i] >= HOLD_S:
            return float(since[i])
    return None


def score_tilt(series: Series, truth: Truth, options: EvalOptions) -> dict[str, float | None]:
    """The scores of the module docstring for one filter's output."""
    since = series.t - series.t[0]
    rows = [truth.at(float(t)) for t in series.t]
    err = np.degrees(series.column(THETA) - np.array([r[THETA] for r in rows]))
    seg = np.array([r.get(SEGMENT, -1.0) for r in rows])
    late = since >= options.after
    still = (seg == SEGMENTS.index("still")) & (since >= 1.0)
    push = (seg == SEGMENTS.index("push")) & late
    end = series.t >= series.t[-1] - 10.0
    return {
        "converge_s": converge_time(since, err),
        "still_deg": float(np.std(err[still])) if still.sum() > 2 else None,
        "rmse_deg": _rms(err[late]),
        "push_deg": _rms(err[push]),
        "max_deg": float(np.max(np.abs(err[late]))) if late.any() else None,
        "final_deg": float(np.mean(np.abs(err[end]))),
    }


class TiltApp(Application):
    """2-D tilt of a self-balancing robot, gyroscope bias calibrated or estimated (seed 003)."""

    name = "tilt2d"
    title = "2-D tilt of a self-balancing robot: split filter, EKF, UKF, bias EKFs (seed 003)"
    measures = ("tilt_split", "tilt_ekf", "tilt_ukf", "tilt_bias", "tilt_wheels")
    metrics = (
        Metric("converge_s", "converge", "s"),
        Metric("still_deg", "still noise", "deg"),
        Metric("rmse_deg", "RMSE", "deg"),
        Metric("push_deg", "push RMSE", "deg"),
        Metric("max_deg", "max err", "deg"),
        Metric("final_deg", "last 10 s", "deg"),
    )

    def label(self, name: str, measure: type | None) -> str:
        kind = getattr(measure, "model_fixed", {}).get("kind")
        return f"{name} (seed Table 8)" if kind == "split" else name

    def truth(self, world: Mapping[str, Any]) -> Truth | None:
        return robot_truth(world) if world.get("scenario") == "balancing" else None

    def score(
        self, series: Series, truth: Truth | None, options: EvalOptions
    ) -> dict[str, float | None]:
        if truth is None or not len(series) or not series.has(THETA):
            return {}
        return score_tilt(series, truth, options)

    def plots(
        self,
        series: Sequence[Series],
        truth: Truth | None,
        out_dir: Path,
        options: EvalOptions,
    ) -> list[Path]:
        """``tilt.png``: every filter's theta with the truth (above) and its error (below)."""
        from hera.plotting import pyplot

        have = [s for s in series if len(s) and s.has(THETA)]
        if not have or truth is None:
            return []
        plt = pyplot()
        t0 = min(float(s.t[0]) for s in have)
        t1 = max(float(s.t[-1]) for s in have)
        ts = np.arange(t0, t1, 0.02)
        fig, (top, bottom) = plt.subplots(2, 1, figsize=(10, 8), sharex=True)
        top.plot(
            ts - t0,
            np.degrees([truth.at(float(t))[THETA] for t in ts]),
            color="0.6",
            lw=3,
            label="truth",
        )
        for s in have:
            true = np.array([truth.at(float(t))[THETA] for t in s.t])
            label = self.label(s.name, s.measure)
            top.plot(s.t - t0, np.degrees(s.column(THETA)), lw=1, label=label)
            bottom.plot(s.t - t0, np.degrees(s.column(THETA) - true), lw=1, label=label)
        top.set_ylabel("theta [deg]")
        bottom.set_ylabel("error [deg]")
        bottom.set_xlabel("time since first estimate [s]")
        bottom.set_ylim(-3.0, 3.0)
        for ax in (top, bottom):
            ax.grid(alpha=0.3)
        top.legend(fontsize=8)
        top.set_title(f"tilt of the robot on node {have[0].node}")
        fig.tight_layout()
        path = out_dir / "tilt.png"
        fig.savefig(path, dpi=100)
        plt.close(fig)
        return [path]

    def panel(self, estimates: Sequence[Estimate], truth: Truth | None) -> Panel | None:
        """One row per filter and node: theta, its error, |g_XZ|, the bias estimate."""
        if not estimates:
            return None
        rows = []
        last = None
        for e in estimates:
            v = e.values
            th = v.get(THETA)
            tr = truth.at(e.t) if truth is not None else None
            err = None if th is None or tr is None else math.degrees(th - tr[THETA])
            b = v.get("b_gyro [rad/s]")
            rows.append(
                (
                    self.label(e.name, e.measure),
                    e.node,
                    _f(None if th is None else math.degrees(th), "+.2f"),
                    _f(err, "+.2f"),
                    _f(v.get("g_xz [m/s^2]"), ".3f"),
                    _f(None if b is None else math.degrees(b), "+.3f"),
                )
            )
            last = tr if tr is not None else last
        if last is not None:
            rows.append(("truth", "", _f(math.degrees(last[THETA]), "+.2f"), "", "", ""))
        cols = ("model", "node", "theta deg", "err deg", "g m/s^2", "b_gyro deg/s")
        return Panel("tilt", cols, tuple(rows))


def _f(value: float | None, fmt: str) -> str:
    return "-" if value is None else format(value, fmt)
