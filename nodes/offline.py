"""Offline simulation: a spec's simulated boards, read on a virtual clock, into a run dir.

What ``hera up`` would record, without processes, a bus or a wall clock, in a fraction of
the time: every board measure of the spec (the ``hera.nodes.measures`` ones: nav, mag,
sonar, ...) is built on its node's boards exactly as a node builds it (calibration
included), then read on its own schedule (the spec's period, each interval stretched by up
to +-``jitter`` of it, a random first reading within one period), and every reading is
written in the run layout (``measures/<name>_<node>.csv`` with its columns sidecar) beside
the resolved spec (``cluster.json``, with the world's epoch). Fusion models are not run:
``hera replay RUN --out OUT`` runs them over the recordings, ``hera eval OUT`` scores them.

Sonars of a sync group never overlap (the sync service's job), so there is no simulated
air offline. Deterministic: the same spec, seed and options give the same files.

    python -m hera.nodes.offline deploy/train_rough.toml --duration 60 --out sim --seed 3
"""

from __future__ import annotations

import argparse
import heapq
import logging
import random
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from hera import cliargs
from hera.args import ArgsStore
from hera.csvlog import CsvLog
from hera.examples import resolve_spec
from hera.keys import Keys
from hera.measure import Measure, MeasureContext, readings_of
from hera.nodes.boards import CLOCK
from hera.plugins import find_measure
from hera.resources import Resources
from hera.spec import ClusterSpec, load_spec
from hera.store import Sample

DEFAULT_EPOCH = 1_800_000_000.0
"""Epoch (s) of an offline run whose world gives none: any fixed time keeps it repeatable."""


class VirtualClock:
    """The time the simulated boards read: set by the simulation, advancing by ``tick`` s
    on every read (so the readings of a calibration, taken in a burst, differ in time)."""

    def __init__(self, t: float, tick: float = 0.0) -> None:
        self.t, self.tick = float(t), float(tick)

    def __call__(self) -> float:
        t = self.t
        self.t += self.tick
        return t


def board_measures(spec: ClusterSpec) -> list[tuple[str, Any, type[Measure]]]:
    """Every (node, measure spec, class) of ``spec`` that reads a simulated board."""
    out = []
    for node, m in spec.measures():
        try:
            cls = find_measure(m.use)
        except (LookupError, TypeError) as e:
            raise ValueError(f"{spec.source}: measure {m.use!r} of node {node!r}: {e}") from None
        if cls.__module__.startswith("hera.nodes.measures"):
            out.append((node, m.resolve(cls), cls))
    return out


def simulate(
    spec: ClusterSpec,
    out: str | Path,
    duration: float,
    *,
    world: Mapping[str, Any] | None = None,
    jitter: float = 0.1,
    seed: int = 0,
) -> Path:
    """Simulate ``duration`` s of every board measure of ``spec`` (``world``: keys added to
    its world table, e.g. a seed or a direction of travel) into the run dir ``out``; return
    it. ``seed`` draws the schedule's jitter and first readings."""
    if not duration > 0:
        raise ValueError(f"duration must be > 0 s, got {duration!r}")
    if not 0 <= jitter < 1:
        raise ValueError(f"jitter must be in [0, 1), got {jitter!r}")
    spec = spec.with_world(**dict(world or {}))
    if "epoch" not in spec.world:
        spec = spec.with_world(epoch=DEFAULT_EPOCH)
    t0 = float(spec.world["epoch"])
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "cluster.json").write_text(spec.to_json())
    measures = board_measures(spec)
    if not measures:
        raise ValueError(f"{spec.source}: no board measure to simulate")
    clock = VirtualClock(t0 - 30.0, tick=0.001)  # calibrations: 30 s before the start
    nodes: dict[str, Resources] = {}
    args: dict[str, ArgsStore] = {}
    running = []
    for node, m, cls in measures:
        res = nodes.setdefault(node, Resources())
        res.put(CLOCK, clock)
        ctx = MeasureContext(
            node=node,
            cluster=spec.name,
            spec=m,
            store=None,  # type: ignore[arg-type]  # board measures never read the store
            args=args.setdefault(node, ArgsStore(node)),
            session=None,
            keys=Keys(spec.name),
            world=spec.world,
            seed=m.seed,
            run_dir=None,
            resources=res,
            log=logging.getLogger(f"hera.offline.{node}"),
        )
        measure = cls()
        measure.init(dict(m.args), ctx)
        running.append((node, m, measure))
    rng = random.Random(f"offline|{seed}")
    queue = [(t0 + rng.uniform(0.0, m.period), i) for i, (_, m, _) in enumerate(running)]
    heapq.heapify(queue)
    columns = {str(m.name): tuple(meas.columns) for _, m, meas in running}
    log = CsvLog(out, columns)
    seqs: dict[tuple[str, str], int] = {}
    clock.tick = 0.0
    try:
        while queue:
            t, i = heapq.heappop(queue)
            if t > t0 + duration:
                continue
            node, m, measure = running[i]
            clock.t = t
            for reading in readings_of(measure.measure()):
                key = (str(m.name), node)
                seqs[key] = seqs.get(key, 0) + 1
                ts = reading.t if reading.t is not None else t
                log.write(Sample(key[0], node, seqs[key], ts, 0.0, 0.0, tuple(reading.values)))
            step = m.period * (1.0 + rng.uniform(-jitter, jitter))
            heapq.heappush(queue, (t + step, i))
    finally:
        log.close()
        for _, _, measure in running:
            measure.close()
        for res in nodes.values():
            res.close()
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m hera.nodes.offline SPEC --duration S --out DIR [--seed N] [--set K=V]``."""
    p = argparse.ArgumentParser(
        prog="python -m hera.nodes.offline",
        description="Simulate a spec's boards offline into a run dir (then: hera replay, "
        "hera eval).",
    )
    p.add_argument("spec", help="cluster spec (TOML or a cluster.json)")
    p.add_argument("--out", required=True, help="run directory to write")
    p.add_argument("--duration", type=cliargs.positive, default=60.0, help="seconds (default 60)")
    p.add_argument(
        "--seed",
        type=cliargs.non_negative_int,
        default=0,
        help="world seed (a new rig) and schedule",
    )
    p.add_argument("--omega", type=cliargs.number, help="world omega (rad/s; negative: clockwise)")
    p.add_argument(
        "--jitter", type=cliargs.non_negative, default=0.1, help="period jitter, fraction"
    )
    a = p.parse_args(argv)
    world: dict[str, Any] = {"seed": a.seed}
    if a.omega is not None:
        world["omega"] = a.omega
    try:
        simulate(
            load_spec(resolve_spec(a.spec)),
            a.out,
            a.duration,
            world=world,
            jitter=a.jitter,
            seed=a.seed,
        )
    except (ValueError, OSError) as e:
        print(f"offline: {e}", file=sys.stderr)
        return 2
    print(a.out)
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
