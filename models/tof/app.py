"""The ToF height application (entry point ``tof_height`` of ``hera.apps``): truth, scores,
the comparison plot and the live panel of ``tof_cv``, ``tof_ca``, ``tof_fused`` and
``tof_plane`` (seed 001).

Scores (``hera eval``), errors counted ``after`` s past a model's first estimate:

- ``rmse_mm``: height RMSE over the whole run; ``still_mm``: over the still segments once
  the board has been still for ``STILL_SETTLE_S`` (0.5 s: the filter's settling after a move
  is in ``rmse_mm``, not here), ``settle_mm``: over all of every still segment;
  ``fast_mm``: over the fast segments; ``max_mm``: the largest height error;
- ``lag_ms``: on the fast segments, the delay tau (0 .. 300 ms) that best aligns the
  estimate with the truth (minimum RMS of h_est(t) - h_true(t - tau));
- ``tilt_deg``: pitch and roll RMSE (``tof_plane``);
- ``fault_s``: when a sensor was first reported faulty (s since the first estimate).

Segments come from the world's ``desk`` scenario (still, slow, fast, tilt).
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

HEIGHT, PITCH, ROLL, SEGMENT = "height [m]", "pitch [rad]", "roll [rad]", "segment"
AGE = "segment age [s]"
STILL_SETTLE_S = 0.5
"""A board counts as held still this long after a still segment begins."""
SEGMENTS = ("still", "slow", "fast", "tilt")
FAULTY = "faulty [mask]"
LAGS_S = np.arange(0.0, 0.3005, 0.002)


def desk_truth(world: Mapping[str, Any]) -> Truth:
    """The true height (m) of the board's origin, its pitch and roll (rad), the segment
    (index into :data:`SEGMENTS`) and its age (s) at any epoch time."""
    from hera.nodes.world import epoch_of, make_scenario

    scenario, epoch = make_scenario(world), epoch_of(world)
    phase = getattr(scenario, "phase", None)

    def at(t: float) -> dict[str, float]:
        m = scenario.motion(t - epoch)
        w, x, y, z = m.orientation
        r20 = 2.0 * (x * z - w * y)
        r21 = 2.0 * (y * z + w * x)
        r22 = 1.0 - 2.0 * (x * x + y * y)
        out = {
            HEIGHT: m.position[2],
            PITCH: -math.asin(max(-1.0, min(1.0, r20))),
            ROLL: math.atan2(r21, r22),
        }
        if phase is not None:
            kind, age = phase(t - epoch)
            out[SEGMENT], out[AGE] = float(SEGMENTS.index(kind)), age
        return out

    return FunctionTruth((HEIGHT, PITCH, ROLL, SEGMENT, AGE), at)


def _rms(x: np.ndarray) -> float | None:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else None


def best_lag(t: np.ndarray, est: np.ndarray, truth_at: Any) -> float | None:
    """The delay (s, 0 .. 0.3) minimising the RMS of est(t) - truth(t - delay)."""
    if not len(t):
        return None
    errs = [
        np.sqrt(np.mean((est - np.array([truth_at(x - lag) for x in t])) ** 2)) for lag in LAGS_S
    ]
    return float(LAGS_S[int(np.argmin(errs))])


def score_height(series: Series, truth: Truth, options: EvalOptions) -> dict[str, float | None]:
    """The scores of the module docstring for one model output."""
    since = series.t - series.t[0]
    keep = since >= options.after
    t = series.t[keep]
    rows = [truth.at(float(x)) for x in t]
    h_true = np.array([r[HEIGHT] for r in rows])
    seg = np.array([r.get(SEGMENT, -1.0) for r in rows])
    age = np.array([r.get(AGE, 0.0) for r in rows])
    h = series.column(HEIGHT)[keep]
    err = h - h_true
    fast = seg == SEGMENTS.index("fast")
    still = seg == SEGMENTS.index("still")
    out: dict[str, float | None] = {
        "rmse_mm": _mm(_rms(err)),
        "still_mm": _mm(_rms(err[still & (age >= STILL_SETTLE_S)])),
        "settle_mm": _mm(_rms(err[still])),
        "fast_mm": _mm(_rms(err[fast])),
        "max_mm": _mm(float(np.max(np.abs(err))) if len(err) else None),
        "lag_ms": None,
    }
    lag = best_lag(t[fast], h[fast], lambda x: truth.at(x)[HEIGHT])
    out["lag_ms"] = None if lag is None else 1000.0 * lag
    if series.has(PITCH, ROLL):
        p = series.column(PITCH)[keep] - np.array([r[PITCH] for r in rows])
        r = series.column(ROLL)[keep] - np.array([r[ROLL] for r in rows])
        out["tilt_deg"] = None if not len(p) else math.degrees(_rms(np.concatenate([p, r])))
    if series.has(FAULTY):
        hit = np.nonzero(series.column(FAULTY) > 0)[0]
        out["fault_s"] = float(since[hit[0]]) if len(hit) else None
    return out


class TofApp(Application):
    """Height (and tilt) of a board over a desk from three VL53L1 sensors (seed 001)."""

    name = "tof_height"
    title = "board height and tilt over a desk from three VL53L1 ToF sensors (seed 001)"
    measures = ("tof_cv", "tof_ca", "tof_fused", "tof_plane")
    metrics = (
        Metric("rmse_mm", "RMSE", "mm"),
        Metric("still_mm", "still RMSE", "mm"),
        Metric("settle_mm", "still+settle", "mm"),
        Metric("fast_mm", "fast RMSE", "mm"),
        Metric("lag_ms", "fast lag", "ms"),
        Metric("max_mm", "max err", "mm"),
        Metric("tilt_deg", "tilt RMSE", "deg"),
        Metric("fault_s", "fault at", "s"),
    )

    def label(self, name: str, measure: type | None) -> str:
        kind = getattr(measure, "model_fixed", {}).get("kind")
        seed = {"cv": "seed task 2", "ca": "seed task 3", "fused": "seed task 4"}.get(kind or "")
        return f"{name} ({seed})" if seed else name

    def truth(self, world: Mapping[str, Any]) -> Truth | None:
        return desk_truth(world) if world.get("scenario") == "desk" else None

    def score(
        self, series: Series, truth: Truth | None, options: EvalOptions
    ) -> dict[str, float | None]:
        if truth is None or not len(series) or not series.has(HEIGHT):
            return {}
        return score_height(series, truth, options)

    def plots(
        self,
        series: Sequence[Series],
        truth: Truth | None,
        out_dir: Path,
        options: EvalOptions,
    ) -> list[Path]:
        """``tof_height.png``: every model's height with the truth, the whole run above and
        the first fast segment below; ``tof_tilt.png``: pitch and roll of ``tof_plane``."""
        from hera.plotting import pyplot

        have = [s for s in series if len(s) and s.has(HEIGHT)]
        if not have or truth is None:
            return []
        plt = pyplot()
        t0 = min(float(s.t[0]) for s in have)
        t1 = max(float(s.t[-1]) for s in have)
        ts = np.arange(t0, t1, 0.02)
        rows = [truth.at(float(x)) for x in ts]
        h_true = 1000.0 * np.array([r[HEIGHT] for r in rows])
        seg = np.array([r.get(SEGMENT, -1.0) for r in rows])
        fig, (top, zoom) = plt.subplots(2, 1, figsize=(10, 8))
        for ax in (top, zoom):
            ax.plot(ts - t0, h_true, color="0.6", lw=3, label="truth", zorder=1)
            for s in have:
                ax.plot(
                    s.t - t0,
                    1000.0 * s.column(HEIGHT),
                    lw=1,
                    label=self.label(s.name, s.measure),
                    zorder=2,
                )
            ax.set_ylabel("height [mm]")
            ax.grid(alpha=0.3)
        fast = np.nonzero(seg == SEGMENTS.index("fast"))[0]
        if len(fast):
            a = ts[fast[0]] - t0
            end = fast[0]
            while end + 1 < len(seg) and seg[end + 1] == seg[fast[0]]:
                end += 1
            b = ts[end] - t0
            zoom.set_xlim(a - 0.5, b + 1.0)
            lo, hi = sorted((h_true[fast[0]], h_true[end]))
            zoom.set_ylim(lo - 15.0, hi + 15.0)
            top.axvspan(a, b, color="orange", alpha=0.2)
            zoom.set_title("the first fast segment")
        top.set_title(f"height over the desk on node {have[0].node}")
        zoom.set_xlabel("time since first estimate [s]")
        top.legend(fontsize=8)
        fig.tight_layout()
        files = [out_dir / "tof_height.png"]
        fig.savefig(files[0], dpi=100)
        plt.close(fig)
        planes = [s for s in have if s.has(PITCH, ROLL)]
        if planes:
            fig, ax = plt.subplots(figsize=(10, 4))
            for col, color in ((PITCH, "C0"), (ROLL, "C1")):
                ax.plot(
                    ts - t0,
                    np.degrees([r[col] for r in rows]),
                    color=color,
                    lw=3,
                    alpha=0.4,
                    label=f"true {col.split()[0]}",
                )
                for s in planes:
                    ax.plot(s.t - t0, np.degrees(s.column(col)), color=color, lw=1, label=s.name)
            ax.set_ylabel("angle [deg]")
            ax.set_xlabel("time since first estimate [s]")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)
            fig.tight_layout()
            files.append(out_dir / "tof_tilt.png")
            fig.savefig(files[-1], dpi=100)
            plt.close(fig)
        return files

    def panel(self, estimates: Sequence[Estimate], truth: Truth | None) -> Panel | None:
        """One row per model and node: height and its error, pitch and roll, sensors ok and
        the faulty-sensor mask; then the truth."""
        if not estimates:
            return None
        rows = []
        last = None
        for e in estimates:
            v = e.values
            tr = truth.at(e.t) if truth is not None else None
            h = v.get(HEIGHT)
            err = None if h is None or tr is None else 1000.0 * (h - tr[HEIGHT])
            rows.append(
                (
                    self.label(e.name, e.measure),
                    e.node,
                    _f(None if h is None else 1000.0 * h, ".1f"),
                    _f(err, "+.1f"),
                    _f(_deg(v.get(PITCH)), "+.1f"),
                    _f(_deg(v.get(ROLL)), "+.1f"),
                    _f(v.get("sensors ok"), ".0f"),
                    _f(v.get(FAULTY), ".0f"),
                )
            )
            last = tr if tr is not None else last
        if last is not None:
            rows.append(
                (
                    "truth",
                    "",
                    _f(1000.0 * last[HEIGHT], ".1f"),
                    "",
                    _f(_deg(last[PITCH]), "+.1f"),
                    _f(_deg(last[ROLL]), "+.1f"),
                    "",
                    "",
                )
            )
        cols = ("model", "node", "height mm", "err mm", "pitch deg", "roll deg", "ok", "faulty")
        return Panel("ToF height", cols, tuple(rows))


def _f(value: float | None, fmt: str) -> str:
    return "-" if value is None else format(value, fmt)


def _deg(x: float | None) -> float | None:
    return None if x is None else math.degrees(x)


def _mm(x: float | None) -> float | None:
    return None if x is None else 1000.0 * x
