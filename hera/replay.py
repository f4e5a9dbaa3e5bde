"""``hera replay``: run fusion models offline over recordings, with the live model code.

Every sample of the models' inputs is fed in measurement-time order (ties broken by name,
node and seq), exactly as a fusion measure in ``arrival`` mode fuses them, so a replay is
deterministic and scores like the live run. Outputs are written in the recordings' own
layout: ``<out>/measures/<model>_<node>.csv``.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

from hera.fusion import FusionMeasure, model_counters, model_outputs, spec_models
from hera.plugins import find_measure
from hera.recordings import CsvWriter, read_recordings
from hera.smoothing import NotSmoothable, SmoothedRun, smoothed_dir
from hera.spec import ClusterSpec


def model_args_from_spec(spec: ClusterSpec) -> dict[str, tuple[str, dict[str, Any]]]:
    """For every fusion measure of the spec: publication name -> (use, model settings).

    The settings are checked against the model's (an unknown one is a ValueError naming
    the spec, the measure and the setting)."""
    out: dict[str, tuple[str, dict[str, Any]]] = {}
    classes = spec_models(spec)
    for node, m in spec.measures():
        cls = classes.get(str(m.name))
        if cls is None or m.name in out:
            continue
        problems = cls.check_args(m.args, f"{spec.source}: measure {m.name!r} of node {node!r}")
        if problems:
            raise ValueError(problems[0])
        out[str(m.name)] = (m.use, dict(m.args.get("model", {})))
    return out


CSV_RESOLUTION_S = 1e-6
"""Recorded timestamps are milliseconds with three decimals."""


def live_schedule(recordings: str | Path, node: str) -> dict[str, tuple[float, set[int]]]:
    """For each model that ``node`` ran live: the time of its first fused sample (from the
    ``.start.json`` the fusion measure wrote, else its first estimate) and the instants
    (epoch microseconds) of its live estimates."""
    from hera.recordings import measures_dir, read_csv, start_marker

    out = {}
    folder = measures_dir(recordings)
    for path in folder.glob(f"*_{node}.csv"):
        name = path.stem[: -len(node) - 1]
        rows = read_csv(path, name, node)
        if not rows:
            continue
        start = rows[0].t
        marker = start_marker(folder, name, node)
        if marker.exists():
            start = float(json.loads(marker.read_text())["first_sample_t"])
        out[name] = (start, {round(r.t * 1e6) for r in rows})
    return out


def replay(
    recordings: str | Path,
    out: str | Path,
    models: Mapping[str, tuple[str, Mapping[str, Any]]],
    node: str = "replay",
    like: Mapping[str, tuple[float, set[int]]] | None = None,
    progress: Callable[[int, int], None] | None = None,
    smooth: bool = False,
    say: Callable[[str], None] | None = None,
) -> dict[str, int]:
    """Run each model (name -> (measure use, model params)) over ``recordings``; write its
    estimates to ``out``; return the number of estimates per model.

    ``like`` (model name -> (start, instants), see :func:`live_schedule`) makes a replay of
    a live node: each model starts at the live model's first sample and writes estimates
    only at the live estimates' instants, so the two are compared on the same estimates.
    ``progress(done, total)`` is told the samples fed so far (all models together).

    ``smooth``: also write each model's RTS-smoothed estimates (see :mod:`hera.smoothing`);
    a model that cannot be smoothed is said so through ``say`` (one line) and left out.
    """
    instances = {}
    for name, (use, params) in models.items():
        cls = find_measure(use)
        if not issubclass(cls, FusionMeasure):
            raise ValueError(f"{use!r} is not a fusion model: it cannot be replayed")
        instances[name] = cls.make_model(params, f"model {name!r} ({use})")
    say = say or (lambda _text: None)
    inputs = {n for m in instances.values() for n in m.inputs}
    samples = read_recordings(recordings, inputs, known=inputs)
    counts = {}
    total, fed = len(samples) * len(instances), 0
    for name, model in instances.items():
        writer = CsvWriter(out, name, node, model.columns)
        t_start, instants = (like or {}).get(name, (float("-inf"), None))
        t_start -= CSV_RESOLUTION_S  # the recordings' times are rounded to the microsecond
        smoother = _smoother(model, name, say) if smooth else None
        try:
            for i, s in enumerate(samples):
                if progress is not None and i % 5000 == 0:
                    progress(fed + i, total)
                if s.t < t_start or s.name not in model.inputs:
                    continue
                changed = model.process(s)
                rows = model_outputs(model)
                if rows is None:
                    rows = [model.estimate()] if changed else []
                for t, values in rows:
                    if instants is None or round(t * 1e6) in instants:
                        writer.write(t, values)
                        if smoother is not None:
                            smoother.mark(t)
        finally:
            writer.close()
        fed += len(samples)
        counts[name] = writer.seq
        write_counters(out, name, node, model_counters(model))
        if smoother is not None:
            written = smoother.write(out, name, node, model.columns)
            say(f"{name}: {written} smoothed estimates -> {smoothed_dir(out) / 'measures'}")
    if progress is not None:
        progress(total, total)
    src = Path(recordings) / "cluster.json"
    if src.exists() and Path(out).resolve() != Path(recordings).resolve():
        shutil.copy(src, Path(out) / "cluster.json")  # the world, for hera eval
    if src.exists() and smooth and smoothed_dir(out).exists():
        shutil.copy(src, smoothed_dir(out) / "cluster.json")
    return counts


def _smoother(model: Any, name: str, say: Callable[[str], None]) -> SmoothedRun | None:
    """``--smooth``: a recorder of the model's filter, or None (said) if it has none."""
    try:
        return SmoothedRun(model, f"model {name!r}")
    except NotSmoothable as e:
        say(str(e))
        return None


def write_counters(out: str | Path, name: str, node: str, counters: Mapping[str, int]) -> Path:
    """Write a model's diagnostic counters to ``<out>/measures/<name>_<node>.counters.json``."""
    path = Path(out) / "measures" / f"{name}_{node}.counters.json"
    path.write_text(json.dumps(dict(counters), indent=1))
    return path


def pick_models(all_models: Mapping[str, tuple[str, dict]], wanted: Iterable[str] | None):
    """The subset of ``all_models`` named in ``wanted``; all if None.

    A wanted entry matches a model by its publication name, by its ``use``, or by any alias
    of the same measure class (``e7`` finds a model declared ``use = "track_gyro"``); a
    measure of the spec-less kind is replayed with its default settings.
    """
    if not wanted:
        return dict(all_models)
    out = {}
    for w in wanted:
        hits = {n: v for n, v in all_models.items() if w in (n, v[0])}
        if not hits:
            try:
                cls = find_measure(w)
            except (LookupError, TypeError) as e:
                raise ValueError(str(e)) from None
            hits = {n: v for n, v in all_models.items() if _loads(v[0]) is cls} or {w: (w, {})}
        out.update(hits)
    return out


def _loads(use: str) -> type | None:
    try:
        return find_measure(use)
    except (LookupError, TypeError):
        return None
