"""The 3-D position application (entry point ``position3d`` of ``hera.apps``): truth, scores,
plots and the live panel of our sonar tracker and the thesis's e10.

Truth: the target's position in the simulated world (any scenario; thesis ch. 7.2 moves it
back and forth along x, then y, then z: ``target3d``). Scores (``hera eval``), over the
estimates from ``after`` s past a model's first one:

- ``pos_rmse_cm`` / ``pos_max_cm``: RMS and largest distance to the truth;
- ``axis_rms_cm``: the worst of the three axes' RMS errors;
- ``std_ratio``: RMS of (error / reported standard deviation) over the three axes: about 1
  for a model whose standard deviations tell the truth, well above 1 for an overconfident
  one.
"""

from __future__ import annotations

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
from hera.models.position3d.measures import Position3d, Position3dThesis

POS = ("x [m]", "y [m]", "z [m]")
STD = ("std x [m]", "std y [m]", "std z [m]")
LABELS = {Position3d: "ours", Position3dThesis: "e10"}


def position_truth(world: Mapping[str, Any]) -> Truth | None:
    """The body's true position (x, y, z in m) at any epoch time, or None when the world is
    not one the simulator knows."""
    from hera.nodes.world import epoch_of, make_scenario, state_at

    try:
        scenario, epoch = make_scenario(world), epoch_of(world)
    except ValueError:
        return None

    def at(t: float) -> dict[str, float]:
        return dict(zip(POS, state_at(scenario, epoch, t).position, strict=True))

    return FunctionTruth(POS, at)


def position_errors(series: Series, truth: Truth) -> np.ndarray:
    """(N, 3) estimate minus truth (m) at each estimate of ``series``."""
    est = np.column_stack([series.column(c) for c in POS])
    true = np.array([[truth.at(float(t))[c] for c in POS] for t in series.t])
    return est - true


def position_scores(series: Series, truth: Truth, after: float) -> dict[str, float | None]:
    """``pos_rmse_cm``, ``pos_max_cm``, ``axis_rms_cm`` and (with standard deviations)
    ``std_ratio`` over the estimates ``after`` s past the first (see module docstring)."""
    late = series.t - series.t[0] >= after
    if not late.any():
        return {}
    err = position_errors(series, truth)[late]
    dist = np.linalg.norm(err, axis=1)
    out: dict[str, float | None] = {
        "pos_rmse_cm": 100 * float(np.sqrt(np.mean(dist**2))),
        "pos_max_cm": 100 * float(dist.max()),
        "axis_rms_cm": 100 * float(np.sqrt(np.mean(err**2, axis=0)).max()),
    }
    if series.has(*STD):
        std = np.column_stack([series.column(c) for c in STD])[late]
        out["std_ratio"] = float(np.sqrt(np.mean((err / np.maximum(std, 1e-9)) ** 2)))
    return out


class Position3dApp(Application):
    """Position of a target seen by three sonars (thesis ch. 7.2): ours and e10."""

    name = "position3d"
    title = "3-D position from three sonars: ours (raw ranges, any pose) and the thesis's e10"
    measures = ("position3d", "position3d_thesis")
    metrics = (
        Metric("pos_rmse_cm", "pos RMSE", "cm"),
        Metric("pos_max_cm", "pos max", "cm"),
        Metric("axis_rms_cm", "worst axis RMS", "cm"),
        Metric("std_ratio", "err/std RMS"),
    )

    def label(self, name: str, measure: type | None) -> str:
        tag = LABELS.get(measure)  # type: ignore[arg-type]
        return f"{name} ({tag})" if tag else name

    def truth(self, world: Mapping[str, Any]) -> Truth | None:
        return position_truth(world)

    def score(
        self, series: Series, truth: Truth | None, options: EvalOptions
    ) -> dict[str, float | None]:
        if truth is None or not len(series) or not series.has(*POS):
            return {}
        return position_scores(series, truth, options.after)

    def plots(
        self,
        series: Sequence[Series],
        truth: Truth | None,
        out_dir: Path,
        options: EvalOptions,
    ) -> list[Path]:
        """``position.png``: x, y, z of every model over the truth, with the reported
        standard deviations as bands; ``position_error.png``: the distance to the truth."""
        return plot_positions(self, series, truth, out_dir)

    def panel(self, estimates: Sequence[Estimate], truth: Truth | None) -> Panel | None:
        return position_panel(self, estimates, truth)

    def web_panel(self, estimates: Sequence[Estimate], truth: Truth | None) -> WebPanel | None:
        return position_web_panel(self, estimates, truth)


def plot_positions(
    app: Application, series: Sequence[Series], truth: Truth | None, out_dir: Path
) -> list[Path]:
    """The two plots of :meth:`Position3dApp.plots` for any application's position models."""
    from hera.plotting import pyplot

    have = [s for s in series if len(s) and s.has(*POS)]
    if truth is None or not have:
        return []
    plt = pyplot()
    t0 = min(float(s.t[0]) for s in have)
    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    ts = np.unique(np.concatenate([s.t for s in have]))[::3]
    for i, (ax, col) in enumerate(zip(axes, POS, strict=True)):
        true = [truth.at(float(t))[col] for t in ts]
        ax.plot(ts - t0, true, color="0.6", lw=3, label="truth")
        ax.set_ylim(min(true) - 0.15, max(true) + 0.15)  # not the models' first guesses
        for s in have:
            y = s.column(col)
            line = ax.plot(s.t - t0, y, lw=1, label=app.label(s.name, s.measure))[0]
            if s.has(STD[i]):
                sd = s.column(STD[i])
                ax.fill_between(s.t - t0, y - sd, y + sd, color=line.get_color(), alpha=0.15)
        ax.set_ylabel(col)
        ax.grid(alpha=0.3)
    axes[0].set_title(f"position on node {have[0].node} (bands: +/- 1 reported std)")
    axes[0].legend(fontsize=8)
    axes[-1].set_xlabel("time since first estimate [s]")
    fig.tight_layout()
    files = [out_dir / "position.png"]
    fig.savefig(files[0], dpi=100)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(9, 4))
    top = 0.0
    for s in have:
        d = 100 * np.linalg.norm(position_errors(s, truth), axis=1)
        ax.plot(s.t - t0, d, lw=1, label=app.label(s.name, s.measure))
        late = d[s.t - s.t[0] >= 3.0]
        top = max(top, float(np.percentile(late, 99)) if len(late) else 0.0)
    if top > 0:
        ax.set_ylim(0.0, 1.3 * top)
    ax.set_ylabel("distance to the truth [cm]")
    ax.set_xlabel("time since first estimate [s]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    files.append(out_dir / "position_error.png")
    fig.savefig(files[1], dpi=100)
    plt.close(fig)
    return files


def position_panel(
    app: Application, estimates: Sequence[Estimate], truth: Truth | None
) -> Panel | None:
    """One row per position model and node: x, y, z, the largest reported std and the
    distance to the truth at the estimate's time; then the truth."""
    rows = []
    last = None
    for e in estimates:
        v = e.values
        if not all(c in v for c in POS):
            continue
        p = np.array([v[c] for c in POS])
        stds = [v[c] for c in STD if c in v]
        err = ""
        if truth is not None:
            tr = truth.at(e.t)
            last = tr
            err = f"{100 * float(np.linalg.norm(p - [tr[c] for c in POS])):.1f}"
        std = f"{100 * max(stds):.1f}" if stds else "-"
        rows.append((app.label(e.name, e.measure), e.node, *(f"{x:.3f}" for x in p), std, err))
    if not rows:
        return None
    if last is not None:
        rows.append(("truth", "", *(f"{last[c]:.3f}" for c in POS), "", ""))
    title = "position" + (" (truth from the simulated world)" if truth is not None else "")
    return Panel(title, ("model", "node", "x m", "y m", "z m", "max std cm", "err cm"), tuple(rows))


def position_web_panel(
    app: Application, estimates: Sequence[Estimate], truth: Truth | None
) -> WebPanel | None:
    """The target seen from above (x, y in m): every position model's estimate on each node
    and the truth at the newest estimate's time (z is in the page's plots of the columns)."""
    points = []
    for e in estimates:
        if all(c in e.values for c in POS):
            x, y = e.values[POS[0]], e.values[POS[1]]
            points.append({"label": f"{app.label(e.name, e.measure)} {e.node}", "x": x, "y": y})
    if not points:
        return None
    if truth is not None:
        tr = truth.at(max(e.t for e in estimates))
        points.append({"label": "truth", "x": tr[POS[0]], "y": tr[POS[1]], "truth": True})
    return WebPanel("position from above", "plane", {"shapes": [], "points": points})
