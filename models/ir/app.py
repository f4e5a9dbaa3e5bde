"""The seed-000 application (entry point ``ir`` of ``hera.apps``): truth, scores, plots and
the live panel of the IR tracker and the plate maps.

Scores (``hera eval``), times counted from a model's first output:

- tracker: ``rmse_cm`` and ``max_err_cm`` (distance error after ``after`` s), ``lag_s``
  (the delay that best aligns the estimate with the truth), ``converge_s`` (the first time
  the error is within 1 cm and its RMS over the next second too), ``gated`` (readings the
  gate rejected);
- maps: ``map_pct`` (cells classified right in the last map: occupied when the log-odds
  exceed +0.4, free below -0.4, else unknown, which counts as wrong; a cell is truly
  occupied when its centre lies in a block), ``map60_pct`` (the same for the map made 60 s
  after the first), ``hot_err_cm`` (distance from the last map's hot-block estimate to the
  hot block's centre) and ``hot_found_s`` (when the estimate first came within one cell).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
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
from hera.models.ir.measures import OccupancyFused, OccupancyIr, OccupancyThermal
from hera.models.ir.tiles import assemble

DIST, VEL = "distance [cm]", "velocity [cm/s]"
HOT_X, HOT_Y = "hot x [cm]", "hot y [cm]"
CLASS_LOGODDS = 0.4
"""A cell is classified occupied above this log-odds (p = 0.6), free below its negative."""
MODALITY = {
    OccupancyFused: "IR + thermal",
    OccupancyIr: "IR only",
    OccupancyThermal: "thermal only",
}


@dataclass(frozen=True)
class PlateTruth:
    """The truth of the plate world: where the hot block is, and which cells are occupied."""

    columns: tuple[str, ...]
    scene: Any

    def at(self, t: float) -> Mapping[str, float]:
        hot = self.scene.plate.hot
        return {} if hot is None else {HOT_X: hot.center[0], HOT_Y: hot.center[1]}

    def occupancy(self, rows: int, cols: int, cell: float) -> np.ndarray:
        """True where a cell's centre lies in a block."""
        plate = self.scene.plate
        return np.array(
            [
                [plate.occupied((c + 0.5) * cell, (r + 0.5) * cell) for c in range(cols)]
                for r in range(rows)
            ]
        )

    def blocks(self) -> list[Any]:
        return list(self.scene.plate.blocks)


def ir_truth(world: Mapping[str, Any]) -> Truth | None:
    """The truth of a seed-000 world (a track or the plate), or None for other worlds."""
    from hera.nodes.world import epoch_of, make_scenario

    try:
        scene = make_scenario(world)
    except ValueError:
        return None
    epoch = epoch_of(world)
    if hasattr(scene, "distance"):

        def at(t: float) -> dict[str, float]:
            d, v = scene.distance(t - epoch)
            return {DIST: d, VEL: v}

        return FunctionTruth((DIST, VEL), at)
    if hasattr(scene, "plate"):
        return PlateTruth((HOT_X, HOT_Y), scene)
    return None


def _rms(x: np.ndarray) -> float | None:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else None


def classify(logodds: np.ndarray) -> np.ndarray:
    """1 occupied, 0 free, -1 unknown (see :data:`CLASS_LOGODDS`)."""
    return np.where(logodds > CLASS_LOGODDS, 1, np.where(logodds < -CLASS_LOGODDS, 0, -1))


def map_accuracy(logodds: np.ndarray, truth: np.ndarray) -> float:
    """Fraction of cells classified right (unknown counts as wrong)."""
    return float(np.mean(classify(logodds) == truth.astype(int)))


def lag(t: np.ndarray, est: np.ndarray, truth_at: Any, max_lag: float = 2.0) -> float | None:
    """The delay (s, 0 to ``max_lag`` by 10 ms) that minimises the RMS of
    est(t) - truth(t - delay); the truth is sampled every 10 ms and interpolated."""
    if len(t) < 10:
        return None
    grid = np.arange(t[0] - max_lag - 0.01, t[-1] + 0.01, 0.01)
    true = np.array([truth_at(float(x)) for x in grid])
    delays = np.arange(0.0, max_lag + 1e-9, 0.01)
    costs = [float(np.mean((est - np.interp(t - d, grid, true)) ** 2)) for d in delays]
    return float(delays[int(np.argmin(costs))])


def converge_time(since: np.ndarray, err: np.ndarray, within: float = 1.0) -> float | None:
    """The first time the error is within ``within`` and its RMS over the next second is
    too; None if never."""
    ok = np.abs(err) <= within
    for i in np.nonzero(ok)[0]:
        window = (since >= since[i]) & (since <= since[i] + 1.0)
        if since[-1] >= since[i] + 1.0 and _rms(err[window]) <= within:
            return float(since[i])
    return None


def plate_maps(series: Series) -> list[tuple[float, np.ndarray, tuple[float, float, float], float]]:
    """The complete maps of a map output (see :func:`hera.models.ir.tiles.assemble`)."""
    return assemble(series.t, series.values)


def hot_error(hot: tuple[float, float, float], truth: PlateTruth) -> float | None:
    want = truth.at(0.0)
    if hot[2] <= 0 or not want:
        return None
    return math.hypot(hot[0] - want[HOT_X], hot[1] - want[HOT_Y])


class IrApp(Application):
    """Seed 000: Sharp IR distance tracking (lab 2) and the plate occupancy grid (lab 3)."""

    name = "ir"
    title = (
        "seed 000: Sharp IR EKF in voltage space, plate occupancy grid from IR and thermocouples"
    )
    measures = (
        "sharp_ir",
        "thermocouple",
        "ir_track",
        "occupancy_grid",
        "occupancy_ir",
        "occupancy_thermal",
    )
    metrics = (
        Metric("rmse_cm", "RMSE", "cm"),
        Metric("max_err_cm", "max err", "cm"),
        Metric("lag_s", "lag", "s"),
        Metric("converge_s", "within 1 cm", "s"),
        Metric("gated", "gated"),
        Metric("map_pct", "map right", "%"),
        Metric("map60_pct", "map @60s", "%"),
        Metric("hot_err_cm", "hot err", "cm"),
        Metric("hot_found_s", "hot found", "s"),
    )

    def label(self, name: str, measure: type | None) -> str:
        kind = MODALITY.get(measure)  # type: ignore[arg-type]
        return f"{name} ({kind})" if kind else name

    def truth(self, world: Mapping[str, Any]) -> Truth | None:
        return ir_truth(world)

    def check_world(self, world: Mapping[str, Any]) -> list[str]:
        from hera.nodes.world import make_scenario

        try:
            make_scenario(world)
        except ValueError as e:
            return [str(e)]
        return []

    def score(
        self, series: Series, truth: Truth | None, options: EvalOptions
    ) -> dict[str, float | None]:
        if truth is None or not len(series):
            return {}
        if series.has(DIST) and DIST in truth.columns:
            return self._score_track(series, truth, options)
        if series.has("tile") and isinstance(truth, PlateTruth):
            return self._score_map(series, truth)
        return {}

    def _score_track(self, series: Series, truth: Truth, options: EvalOptions) -> dict[str, Any]:
        since = series.t - series.t[0]
        late = since >= options.after
        est = series.column(DIST)
        true = np.array([truth.at(float(t))[DIST] for t in series.t])
        err = est - true
        return {
            "rmse_cm": _rms(err[late]),
            "max_err_cm": float(np.max(np.abs(err[late]))) if late.any() else None,
            "lag_s": lag(series.t[late], est[late], lambda t: truth.at(t)[DIST]),
            "converge_s": converge_time(since, err),
            "gated": float(series.column("gated")[-1]) if series.has("gated") else None,
        }

    def _score_map(self, series: Series, truth: PlateTruth) -> dict[str, Any]:
        maps = plate_maps(series)
        if not maps:
            return {}
        t0 = maps[0][0]
        _, grid, hot, cell = maps[-1]
        occ = truth.occupancy(*grid.shape, cell)
        out: dict[str, Any] = {"map_pct": 100.0 * map_accuracy(grid, occ)}
        at60 = [m for m in maps if m[0] - t0 <= 60.0 + 1e-6]
        out["map60_pct"] = (
            100.0 * map_accuracy(at60[-1][1], occ) if at60[-1][0] - t0 >= 60.0 - 1e-6 else None
        )
        out["hot_err_cm"] = hot_error(hot, truth)
        found = [m[0] - t0 for m in maps if (e := hot_error(m[2], truth)) is not None and e <= m[3]]
        out["hot_found_s"] = found[0] if found else None
        return out

    def plots(
        self,
        series: Sequence[Series],
        truth: Truth | None,
        out_dir: Path,
        options: EvalOptions,
    ) -> list[Path]:
        from hera.plotting import pyplot

        have = [s for s in series if len(s)]
        if not have or truth is None:
            return []
        plt = pyplot()
        files: list[Path] = []
        tracks = [s for s in have if s.has(DIST)]
        if tracks and DIST in truth.columns:
            files.append(self._plot_track(plt, tracks, truth, out_dir))
        grids = [s for s in have if s.has("tile")]
        if grids and isinstance(truth, PlateTruth):
            files.extend(self._plot_maps(plt, grids, truth, out_dir))
        return files

    def _plot_track(self, plt: Any, tracks: list[Series], truth: Truth, out_dir: Path) -> Path:
        t0 = min(float(s.t[0]) for s in tracks)
        fig, (ax, bx) = plt.subplots(2, 1, figsize=(9, 7), sharex=True)
        ts = np.linspace(t0, max(float(s.t[-1]) for s in tracks), 2000)
        ax.plot(ts - t0, [truth.at(float(t))[DIST] for t in ts], color="0.6", lw=3, label="truth")
        for s in tracks:
            true = np.array([truth.at(float(t))[DIST] for t in s.t])
            ax.plot(s.t - t0, s.column(DIST), lw=1, label=self.label(s.name, s.measure))
            bx.plot(s.t - t0, s.column(DIST) - true, lw=1, label=self.label(s.name, s.measure))
        ax.set_ylabel("distance [cm]")
        bx.set_ylabel("error [cm]")
        bx.set_xlabel("time since first estimate [s]")
        bx.axhline(0.0, color="0.5", lw=0.5)
        for a in (ax, bx):
            a.grid(alpha=0.3)
            a.legend(fontsize=8)
        ax.set_title(f"IR tracking on node {tracks[0].node}")
        fig.tight_layout()
        path = out_dir / "ir_distance.png"
        fig.savefig(path, dpi=100)
        plt.close(fig)
        return path

    def _plot_maps(
        self, plt: Any, grids: list[Series], truth: PlateTruth, out_dir: Path
    ) -> list[Path]:
        from matplotlib.patches import Rectangle

        last = [(s, plate_maps(s)) for s in grids]
        last = [(s, maps) for s, maps in last if maps]
        if not last:
            return []
        fig, axes = plt.subplots(
            1, len(last), figsize=(3.6 * len(last) + 0.8, 3.9), squeeze=False, layout="constrained"
        )
        want = truth.at(0.0)
        for ax, (s, maps) in zip(axes[0], last, strict=True):
            t, grid, hot, cell = maps[-1]
            rows, cols = grid.shape
            p = 1.0 / (1.0 + np.exp(-grid))
            im = ax.imshow(
                p, cmap="inferno", vmin=0, vmax=1, extent=(0, cols * cell, rows * cell, 0)
            )
            for b in truth.blocks():
                ax.add_patch(
                    Rectangle(
                        (b.x, b.y),
                        b.w,
                        b.h,
                        fill=False,
                        lw=1.5,
                        ls="-" if b.visible else ":",
                        ec="tab:red" if b.hot else "tab:cyan",
                    )
                )
            if want:
                ax.plot(want[HOT_X], want[HOT_Y], "o", mfc="none", mec="tab:red", ms=12)
            if hot[2] > 0:
                ax.plot(hot[0], hot[1], "x", color="lime", ms=10, mew=2)
            acc = 100.0 * map_accuracy(grid, truth.occupancy(rows, cols, cell))
            ax.set_title(
                f"{self.label(s.name, s.measure)}\n{acc:.0f} % right at {t - maps[0][0]:.0f} s",
                fontsize=9,
            )
            ax.set_xlabel("x [cm]")
            ax.set_ylabel("y [cm]")
        fig.colorbar(im, ax=axes[0].tolist(), shrink=0.8, label="P(occupied)")
        path = out_dir / "ir_map.png"
        fig.savefig(path, dpi=100)
        plt.close(fig)
        files = [path]
        fig, ax = plt.subplots(figsize=(8, 4))
        for s, maps in last:
            pts = [
                (m[0] - maps[0][0], e) for m in maps if (e := hot_error(m[2], truth)) is not None
            ]
            if pts:
                ax.plot(*zip(*pts, strict=True), ".", ms=3, label=self.label(s.name, s.measure))
        ax.axhline(last[0][1][0][3], color="0.5", lw=0.8, ls="--", label="one cell")
        ax.set_xlabel("time since first map [s]")
        ax.set_ylabel("hot block location error [cm]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        path = out_dir / "ir_hot_error.png"
        fig.savefig(path, dpi=100)
        plt.close(fig)
        files.append(path)
        return files

    def panel(self, estimates: Sequence[Estimate], truth: Truth | None) -> Panel | None:
        tracks = [e for e in estimates if DIST in e.values]
        if tracks:
            return self._panel_track(tracks, truth)
        grids = [e for e in estimates if "tile" in e.values]
        return self._panel_map(grids, truth) if grids else None

    def _panel_track(self, estimates: list[Estimate], truth: Truth | None) -> Panel:
        rows = []
        tr = None
        for e in estimates:
            v = e.values
            tr = truth.at(e.t) if truth is not None and DIST in truth.columns else None
            err = None if tr is None else v[DIST] - tr[DIST]
            rows.append(
                (
                    self.label(e.name, e.measure),
                    e.node,
                    f"{v[DIST]:.2f}",
                    "-" if err is None else f"{err:+.2f}",
                    f"{v.get(VEL, math.nan):+.2f}",
                    f"{v.get('sigma [cm]', math.nan):.2f}",
                    f"{v.get('gated', 0):.0f}",
                )
            )
        if tr is not None:
            rows.append(("truth", "", f"{tr[DIST]:.2f}", "", f"{tr[VEL]:+.2f}", "", ""))
        cols = ("model", "node", "distance cm", "err cm", "velocity cm/s", "sigma cm", "gated")
        return Panel(
            "IR tracking" + (" (truth from the simulated world)" if tr else ""), cols, tuple(rows)
        )

    def _panel_map(self, estimates: list[Estimate], truth: Truth | None) -> Panel:
        rows: list[tuple[str, ...]] = []
        plate = truth if isinstance(truth, PlateTruth) else None
        picture = None
        for e in estimates:
            v = e.values
            hot = (v.get(HOT_X, -1.0), v.get(HOT_Y, -1.0), v.get("hot p", 0.0))
            err = hot_error(hot, plate) if plate is not None else None
            rows.append(
                (
                    self.label(e.name, e.measure),
                    e.node,
                    "-" if hot[2] <= 0 else f"{hot[0]:.1f}, {hot[1]:.1f}",
                    "-" if err is None else f"{err:.2f}",
                    f"{hot[2]:.2f}",
                )
            )
            if picture is None and e.measure is OccupancyFused and v.get("tiles") == 1:
                picture = _picture(v)
        if picture:
            rows.extend((line, "", "", "", "") for line in picture)
        return Panel("plate maps", ("model", "node", "hot x, y cm", "err cm", "hot p"), tuple(rows))


def _picture(values: Mapping[str, float]) -> list[str]:
    """The map of a one-tile estimate as text: '#' occupied, '.' free, '?' unknown."""
    r, c = int(values.get("rows", 0)), int(values.get("cols", 0))
    if not 0 < r <= 20 or not 0 < c <= 40:
        return []
    cells = np.array([values.get(f"c{i} [log-odds]", 0.0) for i in range(r * c)]).reshape(r, c)
    cls = classify(cells)
    return ["  " + " ".join("#" if x == 1 else "." if x == 0 else "?" for x in row) for row in cls]
