"""``hera eval RUN_DIR``: score a run's model outputs through their applications.

For every fusion model of the run's spec (``cluster.json``) with a CSV log in
``<run>/measures``, the application the model belongs to (:mod:`hera.application`) gives
the truth of the run's world, the scores (the columns of the table, with units) and the
plots. A run whose world has no truth (a real rig, imported logs) is scored against a
reference series given on the command line (``--reference FILE``, a recording with its
columns sidecar), else against what the application builds from the run's own recordings
(self-consistency), and says which. Models of no installed application are listed with
their number of estimates. The runtime itself knows no application: it only asks them.
"""

from __future__ import annotations

import json
from collections import defaultdict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hera.application import (
    Application,
    EvalOptions,
    Metric,
    Reference,
    Series,
    SeriesTruth,
    Truth,
)
from hera.fusion import spec_models
from hera.plugins import AppIndex
from hera.recordings import SOURCE_FILE, measures_dir, read_columns, read_csv
from hera.rundirs import folder_problem
from hera.spec import ClusterSpec, load_spec


@dataclass
class Scored:
    """One model output with its application (None if none) and its scores."""

    series: Series
    app: Application | None
    label: str
    scores: dict[str, float | None] = field(default_factory=dict)
    source: str | None = None
    """What the scores compare with (the simulated world, a reference, self-consistency)."""
    note: str | None = None
    """Why the output has no scores although its application has metrics (too short a
    series, or the application's scoring failed), in one sentence."""


def run_spec(run_dir: str | Path) -> ClusterSpec:
    """The resolved spec of a run (its ``cluster.json``); ValueError naming what is wrong
    when the folder is not there, is not a folder, or holds no run."""
    problem = folder_problem(run_dir)
    if problem:
        raise ValueError(f"{problem}; give a run directory of 'hera up'")
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
        meta = read_columns(side)
        if meta["name"] not in classes:
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


def recording_folders(run_dir: str | Path) -> list[Path]:
    """The run dir, then the recordings it was replayed from (its ``replay.json``)."""
    folders = [Path(run_dir)]
    src = Path(run_dir) / SOURCE_FILE
    if src.exists():
        try:
            folders.append(Path(json.loads(src.read_text())["recordings"]))
        except (ValueError, KeyError, TypeError):
            raise ValueError(
                f"{src}: not a replay source (expected {{'recordings': path}})"
            ) from None
    return folders


def read_reference(path: str | Path) -> Series:
    """A reference series: one recording (``<name>_<node>.csv``) and its columns sidecar;
    ValueError naming the file when it is not one."""
    path = Path(path)
    side = path.with_name(path.name.removesuffix(".csv") + ".columns.json")
    if not path.exists() or not side.exists():
        raise ValueError(
            f"{path}: a reference is a recording <name>_<node>.csv beside its "
            f"<name>_<node>.columns.json"
        )
    meta = read_columns(side, ())
    samples = read_csv(path, meta.get("name", path.stem), meta.get("node", ""))
    return Series(
        meta.get("name", path.stem),
        meta.get("node", ""),
        tuple(meta["columns"][2:]),
        [x.t for x in samples],
        [x.values for x in samples],
    )


def truth_of(
    app: Application, spec: ClusterSpec, run_dir: str | Path, reference: str | Path | None
) -> Reference | None:
    """What ``app``'s outputs of the run are scored against: its world's truth, else the
    ``reference`` recording, else the application's own reference from the recordings."""
    truth: Truth | None = app.truth(spec.world)
    if truth is not None:
        return Reference(truth, "the simulated world's truth")
    if reference is not None:
        return Reference(SeriesTruth(read_reference(reference)), f"reference series {reference}")
    return app.reference(recording_folders(run_dir), spec.world)


def evaluate(
    run_dir: str | Path,
    options: EvalOptions | None = None,
    index: AppIndex | None = None,
    reference: str | Path | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[Scored]:
    """Every model output of the run, scored by its application, in the applications'
    order (a ladder's rungs in order). ``reference``: a recording to score against when
    the world has no truth (see the module docstring); ``progress(done, total)`` after
    each output."""
    options = options or EvalOptions()
    spec = run_spec(run_dir)
    if reference is not None:
        read_reference(reference)  # a reference given is one, if or not the world has truth
    index = index or AppIndex()
    refs: dict[str, Reference | None] = {}
    out = []
    outputs = load_outputs(run_dir, spec)
    for i, s in enumerate(outputs):
        if progress is not None:
            progress(i, len(outputs))
        app = index.app_of(s.measure)
        scores: dict[str, float | None] = {}
        source = note = None
        if app is not None:
            if app.name not in refs:
                refs[app.name] = truth_of(app, spec, run_dir, reference)
            ref = refs[app.name]
            source = ref.source if ref else None
            scores, note = _score(app, s, ref, options)
        out.append(Scored(s, app, index.label(s.name, s.measure), scores, source, note))
    if progress is not None:
        progress(len(outputs), len(outputs))
    out.sort(key=lambda r: (*index.rank(r.series.measure), r.series.name, r.series.node))
    return out


def _score(
    app: Application, series: Series, ref: Reference | None, options: EvalOptions
) -> tuple[dict[str, float | None], str | None]:
    """``app``'s scores of ``series``, or none and the reason: fewer than ``options.after``
    seconds of estimates (scores count from then), or the application's error."""
    span = float(series.t[-1] - series.t[0]) if len(series) else 0.0
    what = f"{series.name} on {series.node}"
    if span < options.after:
        return {}, (
            f"{what}: not scored: {len(series)} estimates over {span:.1f} s, and scores count "
            f"from {options.after:g} s after the first (--after)"
        )
    try:
        return dict(app.score(series, ref.truth if ref else None, options)), None
    except Exception as e:  # one application's bug must not hide the other outputs' scores
        return {}, f"{what}: not scored: application {app.name!r} failed: {e!r}"


def notes(results: list[Scored]) -> list[str]:
    """One line per output that has no scores, saying why."""
    return [r.note for r in results if r.note]


def sources(results: list[Scored]) -> list[str]:
    """One line per application: what its outputs were scored against."""
    seen: dict[str, str] = {}
    for r in results:
        if r.app is not None:
            seen.setdefault(r.app.name, r.source or "nothing (no truth, no reference)")
    return [f"{name}: scored against {src}" for name, src in seen.items()]


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
            "scored_against": r.source,
            **({"note": r.note} if r.note else {}),
            **r.scores,
        }
        for r in results
    ]


def plot(
    run_dir: str | Path,
    out_dir: str | Path,
    node: str | Sequence[str] | None = None,
    options: EvalOptions | None = None,
    index: AppIndex | None = None,
    reference: str | Path | None = None,
) -> list[Path]:
    """Each application's plots of its model outputs on ``node`` (or several nodes,
    together: a replay beside the live or an imported original; default: the first node
    with outputs); returns the files written."""
    options = options or EvalOptions()
    index = index or AppIndex()
    spec = run_spec(run_dir)
    series = load_outputs(run_dir, spec)
    if node is None and series:
        node = sorted({s.node for s in series})[0]
    nodes = [node] if isinstance(node, str) else list(node or ())
    by_app: dict[str, list[Series]] = defaultdict(list)
    apps = {}
    for s in series:
        app = index.app_of(s.measure)
        if app is not None and s.node in nodes:
            by_app[app.name].append(s)
            apps[app.name] = app
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    files: list[Path] = []
    for name, group in by_app.items():
        group.sort(key=lambda s: (index.rank(s.measure), nodes.index(s.node)))
        ref = truth_of(apps[name], spec, run_dir, reference)
        files.extend(apps[name].plots(group, ref.truth if ref else None, out_dir, options))
    return files
