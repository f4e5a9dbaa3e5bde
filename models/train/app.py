"""The train application (entry point ``train`` of ``hera.apps``): truth, scores, plots and
the live panel of the e4 .. e9 ladder, through :class:`hera.application.Application`.

Scores (``hera eval``), with times counted from a model's first estimate:

- ``omega_rms_pct`` / ``omega_max_pct``: relative angular-speed error after ``after`` s;
- ``omega_settled_rms_pct``: the same RMS after ``settle`` s, once every rung has seen the
  train in the sonars' beams (what the ladder of thesis fig. 6.5 compares);
- ``pos_rmse_cm``: position RMSE after ``settle`` s; ``radius_rms_cm``: radius RMS error
  after ``settle`` s;
- ``converge_s``: the time after which the angular-speed error stays within 2 %.
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
    WebPanel,
)
from hera.models.train.measures import (
    OmegaAcc,
    TrackBilat,
    TrackGyro,
    TrackMag,
    TrackRadius,
    TrackSonar,
)

OMEGA, RADIUS, X, Y, THETA = "omega [rad/s]", "radius [m]", "x [m]", "y [m]", "theta [rad]"
RUNG_OF = {
    OmegaAcc: "e4",
    TrackBilat: "e5",
    TrackSonar: "e6",
    TrackGyro: "e7",
    TrackRadius: "e8",
    TrackMag: "e9",
}


def train_truth(world: Mapping[str, Any]) -> Truth:
    """The true x, y (m), theta (rad), omega (rad/s) and radius (m) of a target moving
    around ``world["center"]``, at any epoch time."""
    from hera.nodes.world import epoch_of, make_scenario, state_at

    scenario, epoch = make_scenario(world), epoch_of(world)
    cx, cy = (float(c) for c in world.get("center", (0.0, 0.0)))

    def at(t: float) -> dict[str, float]:
        s = state_at(scenario, epoch, t)
        dx, dy = s.position[0] - cx, s.position[1] - cy
        return {
            X: s.position[0],
            Y: s.position[1],
            THETA: math.atan2(dy, dx),
            OMEGA: s.angular_rate[2],
            RADIUS: math.hypot(dx, dy),
        }

    return FunctionTruth((X, Y, THETA, OMEGA, RADIUS), at)


def _rms(x: np.ndarray) -> float | None:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else None


def _truth_columns(series: Series, truth: Truth, *cols: str) -> list[np.ndarray]:
    rows = [truth.at(float(t)) for t in series.t]
    return [np.array([r[c] for r in rows]) for c in cols]


class TrainApp(Application):
    """Toy train on a circle (thesis ch. 6): the e4 .. e9 ladder and bilateration."""

    name = "train"
    title = "toy train on a circle: the e4 .. e9 ladder of thesis ch. 6"
    measures = (
        "bilateration",
        "omega_acc",
        "track_bilat",
        "track_sonar",
        "track_gyro",
        "track_radius",
        "track_mag",
    )
    metrics = (
        Metric("omega_rms_pct", "omega RMS", "%"),
        Metric("omega_max_pct", "omega max", "%"),
        Metric("omega_settled_rms_pct", "settled RMS", "%"),
        Metric("converge_s", "converge", "s"),
        Metric("pos_rmse_cm", "pos RMSE", "cm"),
        Metric("radius_rms_cm", "radius RMS", "cm"),
    )

    def label(self, name: str, measure: type | None) -> str:
        rung = RUNG_OF.get(measure)  # type: ignore[arg-type]
        return f"{name} ({rung})" if rung else name

    def truth(self, world: Mapping[str, Any]) -> Truth | None:
        return train_truth(world) if world.get("scenario") == "train" else None

    def score(
        self, series: Series, truth: Truth | None, options: EvalOptions
    ) -> dict[str, float | None]:
        if truth is None or not len(series):
            return {}
        since = series.t - series.t[0]
        late, settled = since >= options.after, since >= options.settle
        out: dict[str, float | None] = {}
        if series.has(OMEGA):
            (w_true,) = _truth_columns(series, truth, OMEGA)
            rel = (series.column(OMEGA) - w_true) / w_true
            out["omega_rms_pct"] = _pct(_rms(rel[late]))
            out["omega_max_pct"] = _pct(float(np.max(np.abs(rel[late]))) if late.any() else None)
            out["omega_settled_rms_pct"] = _pct(_rms(rel[settled]))
            outside = np.nonzero(np.abs(rel) > 0.02)[0]
            if not len(outside):
                out["converge_s"] = 0.0
            elif outside[-1] + 1 < len(rel):
                out["converge_s"] = float(since[outside[-1] + 1])
            else:
                out["converge_s"] = None
        if series.has(X, Y):
            x_true, y_true = _truth_columns(series, truth, X, Y)
            err = np.hypot(series.column(X) - x_true, series.column(Y) - y_true)
            out["pos_rmse_cm"] = _cm(_rms(err[settled]))
        if series.has(RADIUS):
            (r_true,) = _truth_columns(series, truth, RADIUS)
            out["radius_rms_cm"] = _cm(_rms((series.column(RADIUS) - r_true)[settled]))
        return out

    def plots(
        self,
        series: Sequence[Series],
        truth: Truth | None,
        out_dir: Path,
        options: EvalOptions,
    ) -> list[Path]:
        """One PNG per quantity with every model of the ladder on it (thesis fig. 6.5), in
        ladder order, the truth drawn under the estimates, sparse outputs as markers, the
        y-range set by the settled estimates."""
        from hera.plotting import pyplot

        plt = pyplot()
        files = []
        have = [s for s in series if len(s)]
        if not have or truth is None:
            return []
        t0 = min(float(s.t[0]) for s in have)
        for col, fname, title in (
            (OMEGA, "omega.png", "angular speed [rad/s]"),
            (RADIUS, "radius.png", "radius [m]"),
            (X, "position_error.png", "position error [cm]"),
        ):
            with_col = [s for s in have if s.has(col)]
            if not with_col:
                continue
            fig, ax = plt.subplots(figsize=(9, 5))
            settled: list[np.ndarray] = []
            if col != X:
                ts = np.unique(np.concatenate([s.t for s in with_col]))[::10]
                ax.plot(
                    ts - t0,
                    [truth.at(float(t))[col] for t in ts],
                    color="0.6",
                    lw=3,
                    label="truth",
                    zorder=1,
                )
            for s in with_col:
                if col == X:
                    x_true, y_true = _truth_columns(s, truth, X, Y)
                    y = 100 * np.hypot(s.column(X) - x_true, s.column(Y) - y_true)
                else:
                    y = s.column(col)
                sparse = len(s) < 2 * max(1.0, float(s.t[-1] - s.t[0]))  # under 2 per second
                style = {"ls": "none", "marker": ".", "ms": 4} if sparse else {"lw": 1}
                ax.plot(s.t - t0, y, label=self.label(s.name, s.measure), zorder=2, **style)
                settled.append(y[(s.t - s.t[0]) >= options.settle])
            values = np.concatenate(settled) if settled else np.array([])
            if len(values):
                lo, hi = np.percentile(values, [1, 99])
                pad = 0.15 * (hi - lo) + 1e-9
                ax.set_ylim(lo - pad if col != X else 0.0, hi + pad)
            ax.set_xlabel("time since first estimate [s]")
            ax.set_ylabel(title)
            ax.set_title(f"{title} on node {have[0].node}")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)
            fig.tight_layout()
            fig.savefig(out_dir / fname, dpi=100)
            plt.close(fig)
            files.append(out_dir / fname)
        return files

    def panel(self, estimates: Sequence[Estimate], truth: Truth | None) -> Panel | None:
        """One row per model and node: omega, radius, position and their errors against
        the truth at the estimate's time; then the truth at the last estimate's time."""
        if not estimates:
            return None
        rows = []
        last = None
        for e in estimates:
            v = e.values
            tr = truth.at(e.t) if truth is not None else None
            w, r, x, y = v.get(OMEGA), v.get(RADIUS), v.get(X), v.get(Y)
            w_err = None if w is None or tr is None else 100 * (w - tr[OMEGA]) / tr[OMEGA]
            r_err = None if r is None or tr is None else 100 * (r - tr[RADIUS])
            p_err = (
                None
                if x is None or y is None or tr is None
                else 100 * math.hypot(x - tr[X], y - tr[Y])
            )
            rows.append(
                (
                    self.label(e.name, e.measure),
                    e.node,
                    _f(w, ".4f"),
                    _f(w_err, "+.2f"),
                    _f(r, ".3f"),
                    _f(r_err, "+.1f"),
                    _f(x, ".3f"),
                    _f(y, ".3f"),
                    _f(p_err, ".1f"),
                )
            )
            last = tr if tr is not None else last
        if last is not None:
            rows.append(
                (
                    "truth",
                    "",
                    _f(last[OMEGA], ".4f"),
                    "",
                    _f(last[RADIUS], ".3f"),
                    "",
                    _f(last[X], ".3f"),
                    _f(last[Y], ".3f"),
                    "",
                )
            )
        title = "estimates" + (" (truth from the simulated world)" if truth is not None else "")
        cols = ("model", "node", "omega rad/s", "err %", "radius m", "err cm", "x m", "y m")
        return Panel(title, (*cols, "pos err cm"), tuple(rows))

    def web_panel(self, estimates: Sequence[Estimate], truth: Truth | None) -> WebPanel | None:
        """The track seen from above: the true circle and train, and every model's
        position estimate (heading: the direction of travel, theta + pi/2)."""
        points = []
        for e in estimates:
            v = e.values
            if X in v and Y in v:
                heading = v[THETA] + math.pi / 2 if THETA in v else None
                points.append(
                    {"label": f"{self.label(e.name, e.measure)} {e.node}", "x": v[X], "y": v[Y]}
                    | ({"heading": heading} if heading is not None else {})
                )
        if not points:
            return None
        shapes = []
        if truth is not None:
            tr = truth.at(max(e.t for e in estimates))
            cx = tr[X] - tr[RADIUS] * math.cos(tr[THETA])
            cy = tr[Y] - tr[RADIUS] * math.sin(tr[THETA])
            shapes.append({"circle": [cx, cy, tr[RADIUS]], "label": "track"})
            points.append({"label": "truth", "x": tr[X], "y": tr[Y], "truth": True})
        return WebPanel("train on its track", "plane", {"shapes": shapes, "points": points})


def _f(value: float | None, fmt: str) -> str:
    return "-" if value is None else format(value, fmt)


def _pct(x: float | None) -> float | None:
    return None if x is None else 100 * x


def _cm(x: float | None) -> float | None:
    return None if x is None else 100 * x
