"""Sensor streams of the simulated boards without a cluster, in measurement-time order.

The same readings the ``nav3`` and ``sonar`` measures of a live node would publish (same
boards, error models, calibration and conversion), at the times one asks for, as
:class:`hera.store.Sample` objects a fusion model can be fed directly; the truth comes from
:func:`hera.nodes.world.state_at`. For offline checks of models over many seeds and worlds,
and for benchmarks: no clock is read, so a stream is a pure function of its arguments.

- :func:`nav3_stream`: a Pmod NAV calibrated as ``nav3`` does (held still in the rest pose),
  then read every ``1 / rate`` s (with a reproducible jitter of the reading times);
- :func:`sonar_stream`: MaxSonars of one sync group sounding in turn, one slot each
  (no two at once, as the sync service grants them).

A ``events`` list of ``(t, function(board))`` switches board faults at given times.
"""

from __future__ import annotations

import random
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from hera.nodes.calibration import calibrate_nav3
from hera.nodes.imu_model import NavModel
from hera.nodes.measures.nav import nav3_values
from hera.nodes.noise import stable_seed
from hera.nodes.sim_nav import SimNavBoard
from hera.nodes.sim_sonar import SimMaxSonar
from hera.nodes.sonar_model import INCH, SonarModel
from hera.nodes.world import SonarMount, environment, epoch_of, make_scenario
from hera.store import Sample

Event = tuple[float, Callable[[Any], None]]
"""``(t, function(board))``: called once, before the first reading at or after epoch time t."""


class _Clock:
    """The time a simulated board reads at: set by the stream before each reading."""

    def __init__(self, t: float) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


@dataclass
class Nav3Stream:
    """A calibrated Pmod NAV's samples (``name`` "nav3"), its board and calibration."""

    samples: list[Sample]
    board: SimNavBoard
    calibration: dict[str, Any]


def _fire(events: list[Event], t: float, board: Any) -> None:
    while events and events[0][0] <= t:
        events.pop(0)[1](board)


def nav3_stream(
    world: Mapping[str, Any],
    duration: float,
    *,
    rate: float = 100.0,
    start: float = 0.0,
    seed: int = 0,
    node: str = "nav",
    model: Mapping[str, Any] | None = None,
    full: bool = True,
    calib_samples: int = 300,
    jitter: float = 0.002,
    events: Sequence[Event] = (),
) -> Nav3Stream:
    """``duration`` s of ``nav3`` samples from ``start`` s after the world's epoch.

    The board (seed as the live node's: ``stable_seed("pmod_nav", node, "nav", seed)``) is
    calibrated at ``start`` as ``nav3`` would (``full``: with ``calibration = "full"``);
    each reading time is ``start + k / rate`` plus a uniform jitter of up to ``jitter`` s
    (the live schedule's lateness).
    """
    epoch = epoch_of(world)
    t0 = epoch + start
    clock = _Clock(t0)
    board = SimNavBoard(
        f"{node}/nav",
        make_scenario(world),
        environment(world),
        epoch,
        NavModel.from_args(model),
        stable_seed("pmod_nav", node, "nav", seed),
        clock=clock,
    )
    cal = calibrate_nav3(board, n_gyro=calib_samples, full=full)
    rng = random.Random(stable_seed("nav3_stream", node, seed))
    pending = sorted(events, key=lambda e: e[0])
    out = []
    for k in range(int(duration * rate)):
        t = t0 + k / rate + rng.uniform(0.0, jitter)
        _fire(pending, t, board)
        clock.t = t
        values = nav3_values(board.read_imu(mag=True), cal)
        out.append(Sample("nav3", node, k + 1, t, t, t, values))
    return Nav3Stream(out, board, cal)


def sonar_stream(
    world: Mapping[str, Any],
    mounts: Mapping[str, SonarMount],
    duration: float,
    *,
    start: float = 0.0,
    slot: float = 0.06,
    seed: int = 0,
    model: Mapping[str, Any] | None = None,
    max_range: float = 6.45,
    events: Sequence[Event] = (),
    down: Mapping[str, tuple[float, float]] | None = None,
) -> list[Sample]:
    """Samples ``sonar`` ([range m, x, y]) of the sonars ``mounts`` (node -> mount), sounding
    in turn in slots of ``slot`` s from ``start`` s after the epoch for ``duration`` s.
    ``down`` maps a node to the (from, to) epoch times it is gone (killed): it sounds no
    ping then, and its slots go to the others. Readings beyond ``max_range`` are dropped,
    as the measure does."""
    epoch = epoch_of(world)
    scenario = make_scenario(world)
    sonar_model = SonarModel.from_args(model)
    clock = _Clock(epoch + start)
    boards = {
        node: SimMaxSonar(
            f"{node}/sonar",
            f"{node}/sonar",
            scenario,
            epoch,
            mount,
            sonar_model,
            stable_seed("maxsonar", node, "sonar", seed),
            clock=clock,
            block=False,
            node=node,
        )
        for node, mount in mounts.items()
    }
    pending = sorted(events, key=lambda e: e[0])
    down = down or {}
    order = list(boards)
    seqs = dict.fromkeys(order, 0)
    out = []
    t, i, skipped, end = epoch + start, 0, 0, epoch + start + duration
    while t < end:
        node = order[i % len(order)]
        i += 1
        gone = down.get(node)
        if gone is not None and gone[0] <= t < gone[1]:
            skipped += 1
            if skipped >= len(order):  # every sonar gone: time passes all the same
                t, skipped = t + slot, 0
            continue
        skipped = 0
        _fire(pending, t, boards)
        clock.t = t
        reading = boards[node].read_sample()
        r = reading.inches * INCH
        if r <= max_range:
            seqs[node] += 1
            pos = boards[node].mount.position
            out.append(Sample("sonar", node, seqs[node], t, t, t, (r, pos[0], pos[1])))
        t += slot
    return out


def merged(*streams: Sequence[Sample]) -> list[Sample]:
    """Several streams as one, in measurement-time order (ties by name, node, seq)."""
    return sorted((s for st in streams for s in st), key=lambda s: (s.t, s.name, s.node, s.seq))
