"""Offline runs of the seed-000 models: simulated boards read on a schedule, their samples
fed to the very model objects the fusion measures run, in measurement-time order.

The same boards and models as a live cluster, without processes or a bus: accuracy over
many seeds and worlds takes seconds. Imported by tests as ``ir_offline``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hera.application import EvalOptions, Series
from hera.models.ir.app import IrApp, ir_truth
from hera.models.ir.measures import IrTrack
from hera.models.ir.tracker import IrTracker
from hera.nodes.ir.plate import ThermocoupleModel
from hera.nodes.ir.scenarios import PlateScene
from hera.nodes.ir.sharp import SharpModel, variant
from hera.nodes.ir.sim import SimSharpIr, SimThermocouple
from hera.nodes.noise import stable_seed
from hera.nodes.world import make_scenario
from hera.store import Sample

EPOCH = 1_800_000_000.0
MEDIUM, LONG, SHORT = "GP2Y0A21YK0F", "GP2Y0A02YK0F", "GP2Y0A41SK0F"
PAIR = (("ir_medium", MEDIUM), ("ir_long", LONG))


class Clock:
    """A settable clock the simulated boards read."""

    def __init__(self) -> None:
        self.t = EPOCH

    def __call__(self) -> float:
        return self.t


@dataclass
class Source:
    """A board read every ``period`` s from ``start`` (plus a fixed ``phase``)."""

    name: str
    board: Any
    period: float
    values: Callable[[Any, Any], tuple[float, ...]]
    phase: float = 0.0
    skip: Callable[[float], bool] = lambda tau: False
    read: int = 0


@dataclass
class Run:
    """What an offline run produced: each model's estimates (t, values) and the truth."""

    world: Mapping[str, Any]
    outputs: dict[str, list[tuple[float, list[float]]]] = field(default_factory=dict)
    models: dict[str, Any] = field(default_factory=dict)
    samples: int = 0

    def series(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        rows = self.outputs[name]
        return np.array([r[0] for r in rows]), np.array([r[1] for r in rows])


def ir_source(
    world: Mapping[str, Any],
    clock: Clock,
    name: str,
    part: str,
    seed: int,
    *,
    scanner: str | None = None,
    model: Mapping[str, Any] | None = None,
    period: float = 0.02,
    phase: float = 0.0,
    skip: Callable[[float], bool] = lambda tau: False,
) -> Source:
    board = SimSharpIr(
        f"{name}/ir",
        variant(part),
        SharpModel.from_args(model),
        make_scenario(world),
        EPOCH,
        stable_seed("ir", name, seed),
        scanner=scanner,
        clock=clock,
    )
    return Source(name, board, period, lambda b, s: (s.volts, *b.pose(s.t)), phase=phase, skip=skip)


def tc_sources(
    world: Mapping[str, Any],
    clock: Clock,
    seed: int,
    model: Mapping[str, Any] | None = None,
    period: float = 0.2,
) -> list[Source]:
    scene = make_scenario(world)
    assert isinstance(scene, PlateScene)
    out = []
    for i, pos in enumerate(scene.thermocouples):
        board = SimThermocouple(
            f"tc{i + 1}/tc",
            ThermocoupleModel.from_args(model),
            scene,
            EPOCH,
            stable_seed("tc", i, seed),
            pos,
            clock=clock,
        )
        out.append(
            Source(
                f"tc{i + 1}",
                board,
                period,
                lambda b, s: (s.celsius, *b.position),
                phase=0.013 * i,
            )
        )
    return out


def run(
    world: Mapping[str, Any],
    sources: Iterable[Source],
    models: Mapping[str, Any],
    clock: Clock,
    duration: float,
    jitter: float = 0.002,
    seed: int = 0,
) -> Run:
    """Read every source on its schedule (each reading time jittered by up to ``jitter``
    s) for ``duration`` s and feed the samples, in time order, to every model that takes
    them; record each model's estimate (and its ``outputs()`` rows) after every sample."""
    rng = np.random.default_rng(seed)
    events = []
    for src in sources:
        n = int(duration / src.period)
        for k in range(n):
            tau = src.phase + k * src.period + float(rng.uniform(0, jitter))
            if not src.skip(tau):
                events.append((tau, src.name, src))
    events.sort(key=lambda e: (e[0], e[1]))
    out = Run(world, {name: [] for name in models}, dict(models))
    seqs: dict[str, int] = {}
    for tau, name, src in events:
        clock.t = EPOCH + tau
        s = src.board.read_sample()
        seqs[name] = seqs.get(name, 0) + 1
        sample = Sample(name, name, seqs[name], s.t, tau, s.t, src.values(src.board, s))
        out.samples += 1
        for mname, model in models.items():
            if name not in model.inputs:
                continue
            changed = model.process(sample)
            drain = getattr(model, "outputs", None)
            if callable(drain):
                out.outputs[mname].extend(drain())
            elif changed:
                est = model.estimate()
                if est is not None:
                    out.outputs[mname].append(est)
    return out


def rms(x: np.ndarray) -> float:
    return float(math.sqrt(np.mean(np.square(x)))) if len(x) else math.nan


def track(world, seed, models, duration=40.0, parts=PAIR, board_model=None, skip=None):
    """An offline tracking run of the Sharp boards ``parts`` ((name, part) pairs); returns
    (the run, {model name: the application's scores plus its "series"})."""
    world = {**world, "seed": seed, "epoch": EPOCH}
    clock = Clock()
    sources = [
        ir_source(
            world,
            clock,
            name,
            part,
            seed,
            phase=0.007 * i,
            model=(board_model or {}).get(name),
            skip=(skip or {}).get(name, lambda tau: False),
        )
        for i, (name, part) in enumerate(parts)
    ]
    out = run(world, sources, models, clock, duration, seed=seed)
    truth = ir_truth(world)
    app = IrApp()
    scores = {}
    for name in models:
        t, v = out.series(name)
        s = Series(name, "offline", IrTracker.columns, t, v, IrTrack)
        scores[name] = {**app.score(s, truth, EvalOptions()), "series": s}
    return out, scores


def errors(series, world, seed) -> np.ndarray:
    """The distance error (cm) of every estimate of ``series`` against the world's truth."""
    truth = ir_truth({**world, "seed": seed, "epoch": EPOCH})
    return series.column("distance [cm]") - np.array(
        [truth.at(t)["distance [cm]"] for t in series.t]
    )


def start_scores(world, seed, x0, seconds, parts, settings) -> tuple[float, float, float]:
    """One start of an ``IrTracker(x0=x0, **settings)``: (the RMS error over 0.3-2 s, the
    largest |velocity| then, the converge time, 9 s when it never converged)."""
    r = track(world, seed, {"e": IrTracker(x0=x0, **settings)}, seconds, parts)[1]["e"]
    ser = r["series"]
    t = ser.t - EPOCH
    m = (t >= 0.3) & (t < 2.0)
    err = errors(ser, world, seed)[m]
    speed = np.abs(ser.column("velocity [cm/s]")[m]).max()
    return rms(err), float(speed), 9.0 if r["converge_s"] is None else r["converge_s"]
