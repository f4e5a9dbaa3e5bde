"""The train application (entry point ``train`` of ``hera.apps``): truth, scores, plots and
the live panel of the e4 .. e9 ladder, through :class:`hera.application.Application`.

Scores (``hera eval``), with times counted from a model's first estimate:

- ``omega_rms_pct`` / ``omega_max_pct``: relative angular-speed error after ``after`` s;
- ``omega_settled_rms_pct``: the same RMS after ``settle`` s, once every rung has seen the
  train in the sonars' beams (what the ladder of thesis fig. 6.5 compares);
- ``pos_rmse_cm``: position RMSE after ``settle`` s; ``radius_rms_cm``: radius RMS error
  after ``settle`` s;
- ``converge_s``: the time after which the angular-speed error stays within 2 %;
- ``omega_low_pct``: the lowest angular-speed estimate after ``after`` s (for a model of
  theta, ``after`` s past its lock), in % of the truth: an echo that knocks omega down
  shows here;
- ``lock_laps``: laps until theta stays within 30 deg of the truth (on its branch) for a lap;
  ``wrong_laps``: the longest stay on a wrong branch (theta error over 45 deg) after that;
- ``radius_std_mm``: the radius's standard deviation over the second half of the run;
  ``radius_off_mm``: how far it strays outside the rails' range over that half (0: never).
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
    Importer,
    Metric,
    Panel,
    Reference,
    Series,
    Truth,
    WebPanel,
)
from hera.models.train.erlang import import_erlang
from hera.models.train.laps import lap_reference
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


RAIL_IN, RAIL_OUT = "inner rail [m]", "outer rail [m]"
LOCK_DEG, WRONG_DEG = 30.0, 45.0
"""A model is locked once its theta error stays under LOCK_DEG for a lap; on a wrong branch
while the error is over WRONG_DEG."""


def train_truth(world: Mapping[str, Any]) -> Truth:
    """The true x, y (m), theta (rad), omega (rad/s) and radius (m) of a target moving
    around ``world["center"]``, at any epoch time; for a train (a scenario with
    ``polar(tau)``), theta, omega and radius are its polar ones (what a lap count measures:
    the heading's rate differs on rails that are not round) and the rails' radii."""
    from hera.nodes.world import epoch_of, make_scenario, state_at

    scenario, epoch = make_scenario(world), epoch_of(world)
    cx, cy = (float(c) for c in world.get("center", (0.0, 0.0)))
    polar = getattr(scenario, "polar", None)
    rails = scenario.rails() if hasattr(scenario, "rails") else None

    def at(t: float) -> dict[str, float]:
        s = state_at(scenario, epoch, t)
        dx, dy = s.position[0] - cx, s.position[1] - cy
        out = {
            X: s.position[0],
            Y: s.position[1],
            THETA: math.atan2(dy, dx),
            OMEGA: s.angular_rate[2],
            RADIUS: math.hypot(dx, dy),
        }
        if polar is not None:
            out[OMEGA] = polar(t - epoch)[1]
        if rails is not None:
            out[RAIL_IN], out[RAIL_OUT] = rails
        return out

    columns = (X, Y, THETA, OMEGA, RADIUS) + ((RAIL_IN, RAIL_OUT) if rails else ())
    return FunctionTruth(columns, at)


def _rms(x: np.ndarray) -> float | None:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else None


def _truth_columns(series: Series, truth: Truth, *cols: str) -> list[np.ndarray]:
    rows = [truth.at(float(t)) for t in series.t]
    return [np.array([r.get(c, np.nan) for r in rows]) for c in cols]


def lock_time(t: np.ndarray, ok: np.ndarray, lap: float) -> float | None:
    """The first time from which ``ok`` holds for a whole ``lap`` (s), or to the end of the
    series when less than a lap is left; None if never."""
    bad = t[~ok]
    for i in np.flatnonzero(ok):
        k = np.searchsorted(bad, t[i])
        if k == len(bad) or bad[k] - t[i] >= lap:
            return float(t[i])
    return None


def longest_span(t: np.ndarray, flag: np.ndarray) -> float:
    """The longest time (s) ``flag`` holds without a break (from its first to one sample
    past its last true estimate of each run), 0 if never."""
    best, start = 0.0, None
    for i, f in enumerate(flag):
        if f and start is None:
            start = t[i]
        if start is not None and (not f or i == len(flag) - 1):
            end = t[i] if not f else t[i]
            best = max(best, float(end - start))
            start = None
    return best


def branch_scores(
    t: np.ndarray, theta: np.ndarray, theta_true: np.ndarray, omega_true: float
) -> dict[str, float | None]:
    """``lock_laps``: laps (from the first estimate) until the theta error stays within
    LOCK_DEG for a lap; ``wrong_laps``: the longest stay after that lock with the error over
    WRONG_DEG (a wrong branch), in laps; ``lock_t``: the lock's time (None: never)."""
    lap = 2 * math.pi / abs(omega_true)
    err = np.degrees(np.abs(np.angle(np.exp(1j * (theta - theta_true)))))
    locked = lock_time(t, err < LOCK_DEG, lap)
    if locked is None:
        return {"lock_laps": None, "wrong_laps": None, "lock_t": None}
    after = t >= locked
    return {
        "lock_laps": (locked - t[0]) / lap,
        "wrong_laps": longest_span(t[after], err[after] > WRONG_DEG) / lap,
        "lock_t": locked,
    }


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
        Metric("omega_low_pct", "omega low", "%"),
        Metric("lock_laps", "lock", "laps"),
        Metric("wrong_laps", "wrong br.", "laps"),
        Metric("pos_rmse_cm", "pos RMSE", "cm"),
        Metric("radius_rms_cm", "radius RMS", "cm"),
        Metric("radius_std_mm", "r std 2nd h.", "mm"),
        Metric("radius_off_mm", "off rails", "mm"),
    )

    def label(self, name: str, measure: type | None) -> str:
        rung = RUNG_OF.get(measure)  # type: ignore[arg-type]
        return f"{name} ({rung})" if rung else name

    def truth(self, world: Mapping[str, Any]) -> Truth | None:
        from hera.nodes.world import make_scenario

        try:
            scenario = make_scenario(world)
        except ValueError:
            return None
        return train_truth(world) if hasattr(scenario, "polar") else None

    def reference(self, recordings: Sequence[Path], world: Mapping[str, Any]) -> Reference | None:
        """Omega from lap timing of the sonar passes (:mod:`.laps`)."""
        return lap_reference(recordings)

    def importers(self) -> Mapping[str, Importer]:
        """``erlang-hera``: the logs of the original Erlang Hera train (:mod:`.erlang`)."""
        return {"erlang-hera": import_erlang}

    def score(
        self, series: Series, truth: Truth | None, options: EvalOptions
    ) -> dict[str, float | None]:
        """The metrics (module docstring) that ``truth`` allows: a reference of omega only
        (lap timing) gives the omega ones; ``radius_std_mm`` needs no truth."""
        if not len(series):
            return {}
        since = series.t - series.t[0]
        second_half = since >= since[-1] / 2
        out: dict[str, float | None] = {}
        if series.has(RADIUS):
            out["radius_std_mm"] = 1000 * float(np.std(series.column(RADIUS)[second_half]))
        if truth is None:
            return out
        have = set(truth.columns)
        if series.has(OMEGA) and OMEGA in have:
            (w_true,) = _truth_columns(series, truth, OMEGA)
            known = np.isfinite(w_true)  # a reference may cover part of the run only
            late, settled = known & (since >= options.after), known & (since >= options.settle)
            rel = (series.column(OMEGA) - w_true) / np.where(known, w_true, 1.0)
            out["omega_rms_pct"] = _pct(_rms(rel[late]))
            out["omega_max_pct"] = _pct(float(np.max(np.abs(rel[late]))) if late.any() else None)
            out["omega_settled_rms_pct"] = _pct(_rms(rel[settled]))
            low = late
            outside = np.nonzero(known & (np.abs(rel) > 0.02))[0]
            if not len(outside):
                out["converge_s"] = 0.0
            elif outside[-1] + 1 < len(rel):
                out["converge_s"] = float(since[outside[-1] + 1])
            else:
                out["converge_s"] = None
            if series.has(THETA) and THETA in have:
                (th_true,) = _truth_columns(series, truth, THETA)
                w_mean = float(np.mean(w_true[known]))
                branch = branch_scores(series.t, series.column(THETA), th_true, w_mean)
                lock_t = branch.pop("lock_t")
                out.update(branch)
                if lock_t is not None:  # an echo pulling w down once the model has locked
                    low = late & (series.t >= lock_t + options.after)
            out["omega_low_pct"] = _pct(float(np.min(1 + rel[low])) if low.any() else None)
        settled = since >= options.settle
        if series.has(X, Y) and {X, Y} <= have:
            x_true, y_true = _truth_columns(series, truth, X, Y)
            err = np.hypot(series.column(X) - x_true, series.column(Y) - y_true)
            out["pos_rmse_cm"] = _cm(_rms(err[settled]))
        if series.has(RADIUS) and RADIUS in have:
            (r_true,) = _truth_columns(series, truth, RADIUS)
            r = series.column(RADIUS)
            out["radius_rms_cm"] = _cm(_rms((r - r_true)[settled]))
            if {RAIL_IN, RAIL_OUT} <= have:
                lo, hi = _truth_columns(series, truth, RAIL_IN, RAIL_OUT)
                off = np.maximum(lo - r, r - hi)[second_half]
                out["radius_off_mm"] = 1000 * max(0.0, float(np.max(off)))
        return out

    def plots(
        self,
        series: Sequence[Series],
        truth: Truth | None,
        out_dir: Path,
        options: EvalOptions,
    ) -> list[Path]:
        """One PNG per quantity with every model of the ladder on it (thesis fig. 6.5), in
        ladder order, the truth (or reference) drawn under the estimates where it has the
        quantity, sparse outputs as markers, the y-range set by the settled estimates; the
        node in the labels when the series come from several (a replay beside an original);
        the position error only against a truth of the position."""
        from hera.plotting import pyplot

        plt = pyplot()
        files = []
        have = [s for s in series if len(s)]
        if not have:
            return []
        known = set(truth.columns) if truth is not None else set()
        several = len({s.node for s in have}) > 1
        t0 = min(float(s.t[0]) for s in have)
        for col, fname, title in (
            (OMEGA, "omega.png", "angular speed [rad/s]"),
            (RADIUS, "radius.png", "radius [m]"),
            (X, "position_error.png", "position error [cm]"),
        ):
            with_col = [s for s in have if s.has(col)]
            if not with_col or (col == X and not {X, Y} <= known):
                continue
            fig, ax = plt.subplots(figsize=(9, 5))
            settled: list[np.ndarray] = []
            if col != X and col in known:
                ts = np.unique(np.concatenate([s.t for s in with_col]))[::10]
                ref = [truth.at(float(t)).get(col, np.nan) for t in ts]  # type: ignore[union-attr]
                what = "truth" if {X, Y} <= known else "reference"
                ax.plot(ts - t0, ref, color="0.6", lw=3, label=what, zorder=1)
            for s in with_col:
                if col == X:
                    x_true, y_true = _truth_columns(s, truth, X, Y)  # type: ignore[arg-type]
                    y = 100 * np.hypot(s.column(X) - x_true, s.column(Y) - y_true)
                else:
                    y = s.column(col)
                sparse = len(s) < 2 * max(1.0, float(s.t[-1] - s.t[0]))  # under 2 per second
                style = {"ls": "none", "marker": ".", "ms": 4} if sparse else {"lw": 1}
                label = self.label(s.name, s.measure) + (f" {s.node}" if several else "")
                ax.plot(s.t - t0, y, label=label, zorder=2, **style)
                settled.append(y[(s.t - s.t[0]) >= options.settle])
            values = np.concatenate(settled) if settled else np.array([])
            values = values[np.isfinite(values)]
            if len(values):
                lo, hi = np.percentile(values, [1, 99])
                pad = 0.15 * (hi - lo) + 1e-9
                ax.set_ylim(lo - pad if col != X else 0.0, hi + pad)
            ax.set_xlabel("time since first estimate [s]")
            ax.set_ylabel(title)
            nodes = ", ".join(sorted({s.node for s in have}))
            ax.set_title(f"{title} on {'nodes' if several else 'node'} {nodes}")
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
