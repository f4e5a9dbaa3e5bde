"""``hera eval RUN_DIR``: score a run's model outputs through their applications.

For every fusion model of the run's spec (``cluster.json``) with a CSV log in
``<run>/measures``, the application the model belongs to (:mod:`hera.application`) gives
the truth of the run's world, the scores (the columns of the table, with units) and the
plots. Models of no installed application are listed with their number of estimates. The
runtime itself knows no application: it only asks them.
"""

from __future__ import annotations

import json
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hera.application import Application, EvalOptions, Metric, Series
from hera.fusion import spec_models
from hera.plugins import AppIndex
from hera.recordings import measures_dir, read_csv
from hera.spec import ClusterSpec, load_spec


@dataclass
class Scored:
    """One model output with its application (None if none) and its scores."""

    series: Series
    app: Application | None
    label: str
    scores: dict[str, float | None] = field(default_factory=dict)


def run_spec(run_dir: str | Path) -> ClusterSpec:
    """The resolved spec of a run (its ``cluster.json``); ValueError if absent."""
    path = Path(run_dir) / "cluster.json"
    if not path.exists():
        raise ValueError(f"{run_dir}: no cluster.json; is it a run directory of 'hera up'?")
    return load_spec(path)


def load_outputs(run_dir: str | Path, spec: ClusterSpec | None = None) -> list[Series]:
    """Every model output of the run (the spec's fusion measures) that has a CSV log."""
    spec = spec or run_spec(run_dir)
    classes = spec_models(spec)
    out = []
    for side in sorted(measures_dir(run_dir).glob("*.columns.json")):
        meta = json.loads(side.read_text())
        if meta.get("name") not in classes:
            continue
        csv = side.with_name(side.name.replace(".columns.json", ".csv"))
        samples = read_csv(csv, meta["name"], meta["node"])
        out.append(
            Series(
                meta["name"],
                meta["node"],
                tuple(meta["columns"][2:]),
                [s.t for s in samples],
                [s.values for s in samples],
                classes[meta["name"]],
            )
        )
    return out


def evaluate(
    run_dir: str | Path,
    options: EvalOptions | None = None,
    index: AppIndex | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[Scored]:
    """Every model output of the run, scored by its application, in the applications'
    order (a ladder's rungs in order); ``progress(done, total)`` after each output."""
    options = options or EvalOptions()
    spec = run_spec(run_dir)
    index = index or AppIndex()
    truths: dict[str, Any] = {}
    out = []
    outputs = load_outputs(run_dir, spec)
    for i, s in enumerate(outputs):
        if progress is not None:
            progress(i, len(outputs))
        app = index.app_of(s.measure)
        scores: dict[str, float | None] = {}
        if app is not None:
            if app.name not in truths:
                truths[app.name] = app.truth(spec.world)
            scores = dict(app.score(s, truths[app.name], options))
        out.append(Scored(s, app, index.label(s.name, s.measure), scores))
    if progress is not None:
        progress(len(outputs), len(outputs))
    out.sort(key=lambda r: (*index.rank(r.series.measure), r.series.name, r.series.node))
    return out


def metrics_of(results: list[Scored]) -> list[Metric]:
    """The table's columns: every metric of the applications present, in their order."""
    seen: dict[str, Metric] = {}
    for r in results:
        for m in r.app.metrics if r.app is not None else ():
            seen.setdefault(m.key, m)
    return list(seen.values())


def format_table(results: list[Scored]) -> str:
    """A text table of :func:`evaluate`'s results: one row per model output."""
    metrics = metrics_of(results)
    width = max([26, *(len(r.label) + 1 for r in results)])
    head = f"{'model':<{width}} {'node':<10} " + " ".join(
        f"{m.header:>13}" for m in [*metrics, Metric("estimates", "estimates")]
    )
    lines = [head]
    for r in results:
        cells = []
        for m in metrics:
            v = r.scores.get(m.key)
            cells.append(f"{'-':>13}" if v is None else f"{v:>13.3f}")
        cells.append(f"{len(r.series):>13}")
        lines.append(f"{r.label:<{width}} {r.series.node:<10} " + " ".join(cells))
    return "\n".join(lines)


def by_model(results: list[Scored]) -> dict[tuple[str, str], dict[str, Any]]:
    """:func:`evaluate`'s results by (model, node): its scores and ``estimates``."""
    return {
        (r.series.name, r.series.node): {**r.scores, "estimates": len(r.series)} for r in results
    }


def to_json(results: list[Scored]) -> list[dict[str, Any]]:
    """:func:`evaluate`'s results as JSON-able rows."""
    return [
        {
            "model": r.series.name,
            "node": r.series.node,
            "application": r.app.name if r.app is not None else None,
            "label": r.label,
            "estimates": len(r.series),
            **r.scores,
        }
        for r in results
    ]


def plot(
    run_dir: str | Path,
    out_dir: str | Path,
    node: str | None = None,
    options: EvalOptions | None = None,
    index: AppIndex | None = None,
) -> list[Path]:
    """Each application's plots of its model outputs on ``node`` (default: the first node
    with outputs); returns the files written."""
    options = options or EvalOptions()
    index = index or AppIndex()
    spec = run_spec(run_dir)
    series = load_outputs(run_dir, spec)
    if node is None and series:
        node = sorted({s.node for s in series})[0]
    by_app: dict[str, list[Series]] = defaultdict(list)
    apps = {}
    for s in series:
        app = index.app_of(s.measure)
        if app is not None and s.node == node:
            by_app[app.name].append(s)
            apps[app.name] = app
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    files: list[Path] = []
    for name, group in by_app.items():
        group.sort(key=lambda s: index.rank(s.measure))
        files.extend(apps[name].plots(group, apps[name].truth(spec.world), out_dir, options))
    return files
