"""``hera eval RUN_DIR``: score the estimates of a run against the ground truth.

The truth comes from the run's own world (``cluster.json``, the scenario is a pure function
of time). For every model output found in ``<run>/measures`` (a CSV whose sidecar names
columns such as ``omega [rad/s]``) it computes, with times counted from the model's first
estimate:

- ``omega_rms_pct`` / ``omega_max_pct``: relative angular-speed error after ``omega_after``
  s (default 3 s);
- ``omega_settled_rms_pct``: the same RMS after ``settle`` s, once every rung has seen the
  train in the sonars' beams (what the ladder of thesis fig. 6.5 compares);
- ``pos_rmse_cm``: position RMSE after ``settle`` s (default 10 s, "once converged");
- ``radius_rms_cm``: radius RMS error after ``settle`` s;
- ``converge_s``: the time after which the angular-speed error stays within 2 %.

Plots (one PNG per quantity with every model on it, like thesis fig. 6.5) need matplotlib
(``pip install 'hera-fusion[plot]'``).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

from hera.recordings import measures_dir, read_csv
from hera.spec import load_spec

QUANTITIES = ("omega [rad/s]", "x [m]", "y [m]", "radius [m]", "theta [rad]")


@dataclass
class Series:
    """One model output: its name, node, columns and rows (t epoch s, values)."""

    name: str
    node: str
    columns: list[str]
    rows: list[tuple[float, tuple[float, ...]]] = field(default_factory=list)

    def column(self, col: str) -> list[tuple[float, float]]:
        i = self.columns.index(col)
        return [(t, v[i]) for t, v in self.rows]


def load_outputs(run_dir: str | Path) -> list[Series]:
    """Every fusion model output of the run (the spec's fusion measures) whose sidecar names
    a scored quantity."""
    from hera.replay import model_args_from_spec

    models = model_args_from_spec(load_spec(Path(run_dir) / "cluster.json"))
    out = []
    for side in sorted(measures_dir(run_dir).glob("*.columns.json")):
        meta = json.loads(side.read_text())
        cols = meta["columns"][2:]
        if meta["name"] not in models or not any(c in QUANTITIES for c in cols):
            continue
        csv = side.with_name(side.name.replace(".columns.json", ".csv"))
        samples = read_csv(csv, meta["name"], meta["node"])
        out.append(Series(meta["name"], meta["node"], cols, [(s.t, s.values) for s in samples]))
    return out


def _rms(xs: list[float]) -> float | None:
    return math.sqrt(sum(x * x for x in xs) / len(xs)) if xs else None


def score(series: Series, world: dict, omega_after: float = 3.0, settle: float = 10.0):
    """The metrics of one output (see module docstring); None where they do not apply."""
    from hera.models.train import truth_columns

    if not series.rows:
        return {"estimates": 0}
    t0 = series.rows[0][0]
    truth = [truth_columns(world, t) for t, _ in series.rows]
    out: dict[str, float | int | None] = {"estimates": len(series.rows)}
    cols = series.columns
    if "omega [rad/s]" in cols:
        i = cols.index("omega [rad/s]")
        rel = [
            (v[i] - tr["omega [rad/s]"]) / tr["omega [rad/s]"]
            for (t, v), tr in zip(series.rows, truth, strict=True)
        ]
        since = [t - t0 for t, _ in series.rows]
        late = [e for s, e in zip(since, rel, strict=True) if s >= omega_after]
        settled = [e for s, e in zip(since, rel, strict=True) if s >= settle]
        out["omega_rms_pct"] = None if not late else 100 * _rms(late)
        out["omega_max_pct"] = None if not late else 100 * max(abs(e) for e in late)
        out["omega_settled_rms_pct"] = None if not settled else 100 * _rms(settled)
        conv = None
        for (t, _), e in zip(reversed(series.rows), reversed(rel), strict=True):
            if abs(e) > 0.02:
                break
            conv = t - t0
        out["converge_s"] = conv
    if "x [m]" in cols and "y [m]" in cols:
        ix, iy = cols.index("x [m]"), cols.index("y [m]")
        errs = [
            math.hypot(v[ix] - tr["x [m]"], v[iy] - tr["y [m]"])
            for (t, v), tr in zip(series.rows, truth, strict=True)
            if t - t0 >= settle
        ]
        out["pos_rmse_cm"] = None if not errs else 100 * _rms(errs)
    if "radius [m]" in cols:
        i = cols.index("radius [m]")
        errs = [
            v[i] - tr["radius [m]"]
            for (t, v), tr in zip(series.rows, truth, strict=True)
            if t - t0 >= settle
        ]
        out["radius_rms_cm"] = None if not errs else 100 * _rms(errs)
    return out


def world_of(run_dir: str | Path) -> dict:
    """The world table of a run (its resolved cluster.json); ValueError if absent."""
    path = Path(run_dir) / "cluster.json"
    if not path.exists():
        raise ValueError(f"cannot score {run_dir}: no cluster.json (the run's world)")
    world = load_spec(path).world
    if world.get("scenario") != "train":
        raise ValueError(f"cannot score scenario {world.get('scenario')!r}: only 'train'")
    return world


def evaluate(run_dir: str | Path, omega_after: float = 3.0, settle: float = 10.0):
    """Score every model output of a run: {(name, node): metrics}."""
    world = world_of(run_dir)
    return {(s.name, s.node): score(s, world, omega_after, settle) for s in load_outputs(run_dir)}


def alias(name: str) -> str:
    """``track_gyro (e7)`` for a ladder model, else the name."""
    from hera.models.train import LADDER

    for rung, r in LADDER.items():
        if r.name == name:
            return f"{name} ({rung})"
    return name


def format_table(results: dict) -> str:
    """A text table of :func:`evaluate`'s results."""
    cols = [
        ("omega_rms_pct", "omega RMS %"),
        ("omega_max_pct", "omega max %"),
        ("omega_settled_rms_pct", "settled RMS %"),
        ("converge_s", "converge s"),
        ("pos_rmse_cm", "pos RMSE cm"),
        ("radius_rms_cm", "radius RMS cm"),
        ("estimates", "estimates"),
    ]
    head = f"{'model':<26} {'node':<10} " + " ".join(f"{h:>13}" for _, h in cols)
    lines = [head]
    for (name, node), m in sorted(results.items()):
        cells = []
        for k, _ in cols:
            v = m.get(k)
            cells.append(
                f"{'-':>13}" if v is None else f"{v:>13.3f}" if isinstance(v, float) else f"{v:>13}"
            )
        lines.append(f"{alias(name):<26} {node:<10} " + " ".join(cells))
    return "\n".join(lines)


def plot(run_dir: str | Path, out_dir: str | Path, node: str | None = None) -> list[Path]:
    """One PNG per quantity with every model (of ``node``, default the first) and the truth."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hera.models.train import truth_columns

    world = world_of(run_dir)
    series = load_outputs(run_dir)
    if node is None and series:
        node = sorted({s.node for s in series})[0]
    series = [s for s in series if s.node == node]
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    files = []
    for col, fname in (
        ("omega [rad/s]", "omega.png"),
        ("radius [m]", "radius.png"),
        ("x [m]", "position_error.png"),
    ):
        have = [s for s in series if col in s.columns]
        if not have:
            continue
        t0 = min(s.rows[0][0] for s in have if s.rows)
        fig, ax = plt.subplots(figsize=(9, 5))
        for s in have:
            if col == "x [m]":
                ix, iy = s.columns.index("x [m]"), s.columns.index("y [m]")
                pts = [
                    (t - t0, 100 * math.hypot(v[ix] - tr["x [m]"], v[iy] - tr["y [m]"]))
                    for t, v in s.rows
                    for tr in (truth_columns(world, t),)
                ]
            else:
                pts = [(t - t0, y) for t, y in s.column(col)]
            ax.plot([p[0] for p in pts], [p[1] for p in pts], label=alias(s.name), lw=1)
        if col != "x [m]":
            ts = sorted({t for s in have for t, _ in s.rows})[::10]
            ax.plot(
                [t - t0 for t in ts],
                [truth_columns(world, t)[col] for t in ts],
                "k--",
                label="truth",
                lw=1.5,
            )
        ax.set_xlabel("time since first estimate [s]")
        ax.set_ylabel("position error [cm]" if col == "x [m]" else col)
        ax.set_title(f"{'position error' if col == 'x [m]' else col} on node {node}")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(out_dir / fname, dpi=100)
        plt.close(fig)
        files.append(out_dir / fname)
    return files
