"""``hera replay``: run fusion models offline over recordings, with the live model code.

Every sample of the models' inputs is fed in measurement-time order (ties broken by name,
node and seq), exactly as a fusion measure in ``arrival`` mode fuses them, so a replay is
deterministic and scores like the live run. Models fed by other models (an output name
among their inputs) run after them, on their replayed outputs. Outputs are written in the
recordings' own layout: ``<out>/measures/<model>_<node>.csv``, with each model's diagnostic
counters beside them. ``--set MODEL.SETTING=VALUE`` / ``world.KEY=VALUE`` override a model
setting or the world (checked against what the model declares).
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, replace
from itertools import pairwise
from pathlib import Path
from typing import Any

from hera.fusion import (
    Copies,
    FusionMeasure,
    model_counters,
    model_outputs,
    spec_models,
    time_order,
)
from hera.plugins import find_measure
from hera.recordings import (
    SOURCE_FILE,
    CsvWriter,
    LiveStart,
    RecordingError,
    read_recordings,
    recorded_time,
    split_stem,
)
from hera.schema import did_you_mean
from hera.smoothing import NotSmoothable, SmoothedRun, smoothed_dir
from hera.spec import ClusterSpec, load_spec, tomllib
from hera.store import Sample


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


@dataclass(frozen=True)
class LiveSchedule:
    """What a replay needs to repeat one model of a live node (``hera replay --start-like``).

    ``start``: the time (epoch s) of the first sample the live model was given;
    ``instants``: the instants (epoch microseconds) of its live estimates on this node, the
    ones the replay writes; ``published``: those of every node's replica of the model. A
    fusion measure publishes the newest estimate of each of its steps, and two replicas
    step at different moments, so each publishes estimates the other superseded; a live
    model fed by this one took every replica's (each once, :class:`hera.fusion.Copies`), so
    the replay feeds it the estimates at all of ``published``.
    """

    start: float
    instants: frozenset[int]
    published: frozenset[int]


def live_schedule(recordings: str | Path, node: str) -> dict[str, LiveSchedule]:
    """For each model that ``node`` ran live, its :class:`LiveSchedule`: the start from the
    ``.start.json`` the fusion measure wrote (else its first estimate), the instants from
    the recorded estimates of ``node`` and of every other node that ran it."""
    from hera.recordings import measures_dir, read_csv

    folder = measures_dir(recordings)
    markers = live_markers(recordings, node)
    mine = {}
    for path in folder.glob(f"*_{node}.csv"):
        name = path.stem[: -len(node) - 1]
        rows = read_csv(path, name, node)
        if rows:
            start = rows[0].t if name not in markers else markers[name].first_sample_t
            mine[name] = (start, frozenset(round(r.t * 1e6) for r in rows))
    published: dict[str, set[int]] = {name: set(instants) for name, (_, instants) in mine.items()}
    for path in folder.glob("*.csv"):
        try:
            name, other = split_stem(path.stem, mine)
        except RecordingError:  # not a <name>_<node>.csv: not an estimate of a replica
            continue
        if name in mine and other != node:
            published[name].update(round(r.t * 1e6) for r in read_csv(path, name, other))
    return {
        name: LiveSchedule(start, instants, frozenset(published[name]))
        for name, (start, instants) in mine.items()
    }


def live_markers(recordings: str | Path, node: str) -> dict[str, LiveStart]:
    """The start markers (:class:`~hera.recordings.LiveStart`) of the models ``node`` ran
    live, by model name; RecordingError naming a marker that cannot be read."""
    from hera.recordings import measures_dir, read_start

    suffix = f"_{node}.start.json"
    return {
        p.name[: -len(suffix)]: read_start(p)
        for p in sorted(measures_dir(recordings).glob(f"*{suffix}"))
    }


def why_not_exact(name: str, node: str, live: LiveStart) -> str | None:
    """One sentence on what keeps a replay of ``name`` from repeating its live estimates on
    ``node`` (None: nothing recorded does, or the marker does not say)."""
    if live.exact is not False:
        return None
    parts = []
    if live.late:
        at = ""
        if live.first_late_t is not None:
            at = f", the first {live.first_late_t - live.first_sample_t:.3f} s after its start"
        parts.append(f"was given {live.late} sample(s) out of time order{at}")
    if live.dropped:
        parts.append(f"dropped {live.dropped} sample(s) to keep up")
    if live.resumed:
        parts.append(f"resumed from a checkpoint {live.resumed} time(s)")
    return (
        f"{name}: live on {node} it {' and '.join(parts)}; the replay may differ from there"
        " (a larger reorder_s or backlog keeps every sample in its place)"
    )


def _inputs_of(models: Mapping[str, tuple[str, Mapping[str, Any]]]) -> dict[str, tuple[str, ...]]:
    """The input names of each of ``models`` (name -> (measure use, model params))."""
    return {
        name: tuple(find_measure(use).make_model(params, name).inputs)
        for name, (use, params) in models.items()
    }


def why_inputs_not_exact(
    recordings: str | Path, models: Mapping[str, tuple[str, Mapping[str, Any]]]
) -> dict[str, str]:
    """For each of ``models`` (name -> (measure use, model params), as :func:`replay` takes
    them) fed by another of them: one sentence when a live replica of that input, on any
    node, was not repeatable (:func:`why_not_exact`). Its estimates were fed live to the
    model on every node, and the replay gives other ones in their place, so the model's
    replay may differ from its live estimates although its own start marker is clean."""
    from hera.recordings import measures_dir, read_start

    inputs_of = {name: [i for i in ins if i in models] for name, ins in _inputs_of(models).items()}
    wanted = {i for ins in inputs_of.values() for i in ins}
    replicas: dict[str, list[tuple[str, LiveStart]]] = {}
    for path in sorted(measures_dir(recordings).glob("*.start.json")):
        try:
            name, node = split_stem(path.name[: -len(".start.json")], wanted)
        except RecordingError:
            continue
        if name in wanted:
            replicas.setdefault(name, []).append((node, read_start(path)))
    out = {}
    for name, inputs in inputs_of.items():
        whys = [why_not_exact(i, n, live) for i in inputs for n, live in replicas.get(i, [])]
        first = next((w for w in whys if w is not None), None)
        if first is not None:
            out[name] = f"{name} is fed by it and may differ too: {first}"
    return out


def why_recordings_incomplete(
    recordings: str | Path,
    models: Mapping[str, tuple[str, Mapping[str, Any]]],
    like: Mapping[str, LiveSchedule],
) -> dict[str, str]:
    """For each of ``models`` (as :func:`replay` takes them) replayed like a live node
    (``like``, from :func:`live_schedule`): one sentence when a recorded stream it takes,
    itself or through a model it is fed by, skips seqs after the model's live start. A node
    publishes every seq of a stream in turn, so a gap is samples the log node did not
    record (the bus dropped them on its link, under load); the model's own node may have
    fused them live, and the replay then differs from there."""
    from hera.recordings import measures_dir, read_csv

    inputs_of = {name: set(ins) for name, ins in _inputs_of(models).items()}

    def recorded(name: str, seen: frozenset = frozenset()) -> set[str]:
        out = {i for i in inputs_of[name] if i not in models}
        for i in inputs_of[name] & set(models) - seen - {name}:
            out |= recorded(i, seen | {name})
        return out

    wanted = {i for name in models for i in recorded(name)}
    gaps: dict[str, list[tuple[float, str, int]]] = {}  # name -> (time, node, missing)
    for path in sorted(measures_dir(recordings).glob("*.csv")):
        try:
            name, node = split_stem(path.stem, wanted)
        except RecordingError:
            continue
        if name not in wanted:
            continue
        rows = read_csv(path, name, node)
        for a, b in pairwise(rows):
            if b.seq > a.seq + 1:
                gaps.setdefault(name, []).append((b.t, node, b.seq - a.seq - 1))
    out = {}
    for name in models:
        schedule = like.get(name)
        if schedule is None:
            continue
        found = sorted(
            (t, i, node, n)
            for i in recorded(name)
            for t, node, n in gaps.get(i, [])
            if t >= schedule.start
        )
        if found:
            t, i, node, _ = found[0]
            missing = sum(n for *_, n in found)
            out[name] = (
                f"{name}: the recordings miss {missing} sample(s) of its inputs (seqs "
                f"skipped; the first of {i} from {node}, {t - schedule.start:.3f} s after "
                "its start) that the live model may have fused; the replay may differ from "
                "there"
            )
    return out


def dependency_order(
    instances: Mapping[str, Any],
) -> list[str]:
    """The models' names in an order where each comes after every model whose output it
    takes as input (``bilateration`` before a model with input ``bilateration``);
    ValueError naming the models of a cycle."""
    produced = set(instances)
    needs = {n: {i for i in m.inputs if i in produced and i != n} for n, m in instances.items()}
    order: list[str] = []
    while needs:
        ready = sorted(n for n, deps in needs.items() if not deps - set(order))
        if not ready:
            raise ValueError(f"models feed each other in a cycle: {', '.join(sorted(needs))}")
        order.extend(ready)
        for n in ready:
            del needs[n]
    return order


def replay(
    recordings: str | Path,
    out: str | Path,
    models: Mapping[str, tuple[str, Mapping[str, Any]]],
    node: str = "replay",
    like: Mapping[str, LiveSchedule] | None = None,
    progress: Callable[[int, int], None] | None = None,
    smooth: bool = False,
    say: Callable[[str], None] | None = None,
    world: Mapping[str, Any] | None = None,
    spec: ClusterSpec | None = None,
) -> dict[str, int]:
    """Run each model (name -> (measure use, model params)) over ``recordings``; write its
    estimates to ``out``; return the number of estimates per model.

    Chained models run in dependency order in this one call: a model whose inputs include
    another replayed model's output takes that model's replayed estimates (published by
    ``node``), not the recorded ones of the same name. The recorded estimates of a model
    that ran on several nodes are fused once (:class:`hera.fusion.Copies`), as live.

    ``like`` (model name -> :class:`LiveSchedule`) makes a replay of a live node: each model
    starts at the live model's first sample and writes estimates only at the instants of
    that node's live estimates, so the two are compared on the same estimates; a model fed
    by it is given the estimates every node's replica published, as it was live.
    ``progress(done, total)`` is told the samples fed so far (all models together).

    ``smooth``: also write each model's RTS-smoothed estimates (see :mod:`hera.smoothing`);
    a model that cannot be smoothed is said so through ``say`` (one line) and left out.

    ``world``: the world table written to ``out/cluster.json`` (default: the recordings').
    ``spec``: the spec the models come from when it is not the recordings' (``--spec``):
    written to ``out/cluster.json`` with the recordings' world, so that ``hera eval`` knows
    the models by the names this spec gives them (not when ``out`` is the recordings'
    folder: its own spec stays).
    """
    same = Path(out).resolve() == Path(recordings).resolve()
    if (
        not same
        and (Path(out) / "cluster.json").exists()
        and not (Path(out) / SOURCE_FILE).exists()
    ):
        raise ValueError(
            f"--out {out} holds a run of its own (its cluster.json, and no {SOURCE_FILE} of a "
            "replay): give a new folder, a previous replay's, or the recordings' own"
        )
    if world is not None and same:
        raise ValueError(
            f"--out {out} is the recordings' folder, whose cluster.json keeps the world the "
            "live run had: a replay with world overrides (--set world.KEY=V) needs another --out"
        )
    instances = {}
    for name, (use, params) in models.items():
        cls = find_measure(use)
        if not issubclass(cls, FusionMeasure):
            raise ValueError(f"{use!r} is not a fusion model: it cannot be replayed")
        instances[name] = cls.make_model(params, f"model {name!r} ({use})")
    say = say or (lambda _text: None)
    order = dependency_order(instances)
    inputs = {n for m in instances.values() for n in m.inputs}
    recorded = inputs - set(instances)
    known = inputs | set(instances)
    samples = read_recordings(recordings, recorded, known=known) if recorded else []
    produced: dict[str, list[Sample]] = {}
    counts = {}
    total, fed = len(samples) * len(instances), 0
    for name in order:
        model = instances[name]
        writer = CsvWriter(out, name, node, model.columns)
        schedule = (like or {}).get(name)
        t_start, instants, published = float("-inf"), None, None
        if schedule is not None:
            t_start, instants, published = schedule.start, schedule.instants, schedule.published
        t_start -= CSV_RESOLUTION_S  # the recordings' times are rounded to the microsecond
        feed = samples
        upstream = [produced[i] for i in model.inputs if i in produced]
        if upstream:
            feed = time_order([*samples, *(s for u in upstream for s in u)])
        outputs: list[Sample] = []
        smoother = _smoother(model, name, say) if smooth else None
        copies = Copies()  # recorded estimates of an upstream model's replicas: fused once
        try:
            for i, s in enumerate(feed):
                if progress is not None and i % 5000 == 0:
                    progress(fed + i, total)
                if s.t < t_start or s.name not in model.inputs or copies.is_copy(s):
                    continue
                changed = model.process(s)
                rows = model_outputs(model)
                if rows is None:
                    rows = [model.estimate()] if changed else []
                for t, values in rows:
                    us = round(t * 1e6)
                    if instants is None or us in instants:
                        writer.write(t, values)
                        if smoother is not None:
                            smoother.mark(t)
                    if published is None or us in published:
                        outputs.append(
                            Sample(
                                name,
                                node,
                                len(outputs) + 1,
                                recorded_time(t),
                                0.0,
                                0.0,
                                tuple(map(float, values)),
                            )
                        )
        finally:
            writer.close()
        fed += len(samples)
        produced[name] = outputs
        counts[name] = writer.seq
        write_counters(out, name, node, model_counters(model))
        if smoother is not None:
            written = smoother.write(out, name, node, model.columns)
            say(f"{name}: {written} smoothed estimates -> {smoothed_dir(out) / 'measures'}")
    if progress is not None:
        progress(total, total)
    _write_spec(recordings, out, world, spec)
    written_spec = Path(out) / "cluster.json"
    spec_file = written_spec if written_spec.exists() else Path(recordings) / "cluster.json"
    if spec_file.exists() and smooth and smoothed_dir(out).exists():
        shutil.copy(spec_file, smoothed_dir(out) / "cluster.json")  # the world, for hera eval
    if Path(out).resolve() != Path(recordings).resolve():
        source = {"recordings": str(Path(recordings).resolve())}
        (Path(out) / SOURCE_FILE).write_text(json.dumps(source))
    return {n: counts[n] for n in models}


def _smoother(model: Any, name: str, say: Callable[[str], None]) -> SmoothedRun | None:
    """``--smooth``: a recorder of the model's filter, or None (said) if it has none."""
    try:
        return SmoothedRun(model, f"model {name!r}")
    except NotSmoothable as e:
        say(str(e))
        return None


def _write_spec(
    recordings: str | Path,
    out: str | Path,
    world: Mapping[str, Any] | None,
    spec: ClusterSpec | None = None,
) -> None:
    """Copy the recordings' ``cluster.json`` (the world, for hera eval) to ``out``, with
    ``world`` as its world table when given; with ``spec``, write that spec (the models'
    names) with the recordings' world (its own when the recordings have none)."""
    src = Path(recordings) / "cluster.json"
    same = Path(out).resolve() == Path(recordings).resolve()
    recorded = load_spec(src) if src.exists() else None
    if spec is not None and not same:
        base = spec
        if world is None and recorded is not None:
            world = recorded.world
    elif recorded is None or (same and world is None):
        return
    else:
        base = recorded
    if world is None and base is recorded:
        shutil.copy(src, Path(out) / "cluster.json")
        return
    new = replace(base, world=dict(world if world is not None else base.world))
    (Path(out) / "cluster.json").write_text(new.to_json())


def parse_override(text: str) -> tuple[str, str, Any]:
    """``(target, key, value)`` of an override ``TARGET.KEY=VALUE`` (``--set``): the value
    is read as a TOML value (``0.57``, ``true``, ``[0, 1]``, ``"text"``), else kept as the
    bare string. ValueError saying what is wrong."""
    lhs, eq, rhs = text.partition("=")
    target, dot, key = lhs.strip().rpartition(".")
    if not eq or not dot or not target or not key:
        raise ValueError(f"--set {text!r}: expected MODEL.SETTING=VALUE or world.KEY=VALUE")
    try:
        value = tomllib.loads(f"v = {rhs.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = rhs.strip()
    return target, key.strip(), value


def apply_overrides(
    models: Mapping[str, tuple[str, Mapping[str, Any]]],
    world: Mapping[str, Any],
    overrides: Iterable[str],
    check_world: Any = None,
) -> tuple[dict[str, tuple[str, dict[str, Any]]], dict[str, Any]]:
    """The models and world with the ``--set`` overrides applied.

    ``MODEL.SETTING=VALUE`` sets a model setting of every chosen model that MODEL names
    (publication name, use or alias, as :func:`pick_models`), checked against the settings
    the model declares; ``world.KEY=VALUE`` sets a key of the world table, checked by
    ``check_world(world) -> [problems]`` when given. ValueError, one sentence, naming the
    override and what is wrong."""
    out = {n: (use, dict(params)) for n, (use, params) in models.items()}
    new_world = dict(world)
    for text in overrides:
        target, key, value = parse_override(text)
        if target == "world":
            new_world[key] = value
            problems = check_world(new_world) if check_world is not None else []
            if problems:
                raise ValueError(f"--set {text!r}: {problems[0]}")
            continue
        try:
            hits = pick_models(out, [target])
        except ValueError:
            hits = {}
        hits = {n: v for n, v in hits.items() if n in out}
        if not hits:
            raise ValueError(
                f"--set {text!r}: no model {target!r} among the replayed ones "
                f"({', '.join(out) or 'none'})"
            )
        for name, (use, params) in hits.items():
            cls = find_measure(use)
            known = cls.settings() if issubclass(cls, FusionMeasure) else None
            if known is not None and key not in known:
                raise ValueError(
                    f"--set {text!r}: model {name!r} has no setting {key!r}"
                    f"{did_you_mean(key, known)}; its settings: {', '.join(known)}"
                )
            params[key] = value
            if issubclass(cls, FusionMeasure):
                try:
                    cls.make_model(params, f"model {name!r}")
                except ValueError as e:
                    raise ValueError(f"--set {text!r}: {e}") from None
    return out, new_world


def write_counters(out: str | Path, name: str, node: str, counters: Mapping[str, int]) -> Path:
    """Write a model's diagnostic counters to ``<out>/measures/<name>_<node>.counters.json``."""
    path = Path(out) / "measures" / f"{name}_{node}.counters.json"
    path.write_text(json.dumps(dict(counters), indent=1))
    return path


def with_producers(
    chosen: Mapping[str, tuple[str, Mapping[str, Any]]],
    available: Mapping[str, tuple[str, Mapping[str, Any]]],
) -> dict[str, tuple[str, Mapping[str, Any]]]:
    """``chosen`` plus every model of ``available`` whose output a chosen model takes as
    input, recursively (replaying e5 replays the bilateration that feeds it)."""
    out = dict(chosen)
    todo = list(out)
    while todo:
        name = todo.pop()
        use, params = out[name]
        cls = find_measure(use)
        if not issubclass(cls, FusionMeasure):
            continue
        for i in cls.make_model(params, f"model {name!r} ({use})").inputs:
            if i in available and i not in out:
                out[i] = available[i]
                todo.append(i)
    return out


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
