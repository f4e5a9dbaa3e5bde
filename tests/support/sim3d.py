"""Offline runs of the 3-D models over the simulated boards, in measurement-time order.

The very model objects the fusion measures run, fed the samples a live cluster's boards
would publish (:mod:`hera.nodes.streams`); errors against the simulated world's truth.
Imported by tests as ``sim3d`` (tests/support is on sys.path).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from hera.models.ahrs.frames import world_reference
from hera.models.ahrs.mekf import Mekf, MekfSettings
from hera.models.ahrs.scoring import attitude_error_deg, heading_error_deg, tilt_error_deg
from hera.models.ahrs.thesis import ThesisAhrs
from hera.models.imu6dof.navigator import Navigator
from hera.models.position3d.thesis import ThesisPosition
from hera.models.position3d.tracker import RangeTracker
from hera.nodes.streams import Event, merged, nav3_stream, sonar_stream
from hera.nodes.world import SonarMount, make_scenario, state_at
from hera.store import Sample

SONARS = {
    "sonar_x": ((-1.0, 1.0, 1.0), (1.0, 0.0, 0.0)),
    "sonar_y": ((1.0, -1.0, 1.0), (0.0, 1.0, 0.0)),
    "sonar_z": ((1.0, 1.0, 3.0), (0.0, 0.0, -1.0)),
}
"""The sonars of deploy/position3d.toml: 2 m from the target's centre, one per axis."""

SLOT = 0.052
"""Seconds between two pings of the sync group (a ping takes 49 ms, the grant ~2 ms)."""


def settings_of(sonars: dict) -> dict:
    """The ``sonars`` model setting for poses ``{node: (position, direction)}``."""
    return {n: {"position": list(p), "direction": list(d)} for n, (p, d) in sonars.items()}


@dataclass
class AttitudeRun:
    t: np.ndarray
    att: np.ndarray
    tilt: np.ndarray
    heading: np.ndarray
    counters: dict


def run_ahrs(
    scenario: str,
    seed: int,
    duration: float = 30.0,
    *,
    thesis: bool = False,
    settings: MekfSettings | None = None,
    events: Sequence[Event] = (),
    world: dict | None = None,
    after: float = 3.0,
    start: float = 3.0,
    node: str = "nav",
) -> AttitudeRun:
    """Our AHRS (or the thesis's) over ``duration`` s of ``nav3`` from ``start`` s after the
    epoch (the board of node ``node``); errors (deg) from ``after`` s past its first
    estimate."""
    w = {"scenario": scenario, "epoch": 0.0, **(world or {})}
    stream = nav3_stream(w, duration, seed=seed, start=start, node=node, events=events)
    f = ThesisAhrs(world_reference(90.0)) if thesis else Mekf(world_reference(90.0), settings)
    t, q = [], []
    for s in stream.samples:
        v = s.values
        if f.step(s.t, v[0:3], v[3:6], v[6:9]):
            t.append(s.t)
            q.append(np.array(f.q))
    t_arr = np.array(t)
    sc = make_scenario(w)
    true = np.array([state_at(sc, 0.0, x).orientation for x in t_arr])
    keep = t_arr - t_arr[0] >= after
    est, true = np.array(q)[keep], true[keep]
    counters = {} if thesis else dict(f.counters)
    return AttitudeRun(
        t_arr[keep],
        attitude_error_deg(est, true),
        tilt_error_deg(est, true),
        heading_error_deg(est, true),
        counters,
    )


@dataclass
class PositionRun:
    t: np.ndarray
    est: np.ndarray  # (N, 3) m
    std: np.ndarray  # (N, 3) m
    true: np.ndarray  # (N, 3) m
    counters: dict

    @property
    def err(self) -> np.ndarray:
        return self.est - self.true

    def rmse_cm(self, mask: np.ndarray | None = None) -> float:
        e = self.err if mask is None else self.err[mask]
        return 100 * float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


def run_position(
    seed: int,
    duration: float = 40.0,
    *,
    thesis: bool = False,
    sonars: dict | None = None,
    down: dict | None = None,
    world: dict | None = None,
    after: float = 3.0,
    sonar_model: dict | None = None,
    settings: dict | None = None,
    model_class: type | None = None,
) -> PositionRun:
    """Our sonar tracker (or e10, or ``model_class``: a RangeTracker variant for a
    diagnostic) over ``duration`` s of the sync group's readings (``sonar_model``: the
    simulated MaxSonars' error model's arguments; ``settings``: more model settings)."""
    sonars = sonars or SONARS
    w = world or {"scenario": "target3d", "epoch": 0.0}
    mounts = {
        n: SonarMount(p, tuple(np.array(d) / np.linalg.norm(d))) for n, (p, d) in sonars.items()
    }
    samples = sonar_stream(
        w, mounts, duration, seed=seed, start=3.0, slot=SLOT, down=down, model=sonar_model
    )
    cls = model_class or (ThesisPosition if thesis else RangeTracker)
    model = cls(sonars=settings_of(sonars), **(settings or {}))
    t, x = [], []
    for s in samples:
        if model.process(s):
            e = model.estimate()
            if e is not None:
                t.append(e[0])
                x.append(e[1])
    t_arr, x_arr = np.array(t), np.array(x)
    sc = make_scenario(w)
    true = np.array([state_at(sc, 0.0, v).position for v in t_arr])
    keep = t_arr - t_arr[0] >= after
    return PositionRun(t_arr[keep], x_arr[keep, :3], x_arr[keep, 3:6], true[keep], model.counters())


def run_imu6dof(
    seed: int, duration: float = 60.0, *, aiding: bool = True, after: float = 3.0
) -> PositionRun:
    """e13 (aided by our sonar tracker's estimates, or not) on ``target3d``."""
    w = {"scenario": "target3d", "epoch": 0.0}
    mounts = {n: SonarMount(p, d) for n, (p, d) in SONARS.items()}
    nav = nav3_stream(w, duration, seed=seed, start=3.0).samples
    son = sonar_stream(w, mounts, duration, seed=seed, start=3.0, slot=SLOT) if aiding else []
    tracker = RangeTracker(sonars=settings_of(SONARS))
    sc = make_scenario(w)
    nv = Navigator(aiding=aiding, x0=list(sc.motion(3.0).position))
    t, x, k = [], [], 0
    for s in merged(nav, son):
        if s.name == "sonar":
            if tracker.process(s) and (e := tracker.estimate()) is not None:
                k += 1
                nv.process(Sample("position3d", "computer", k, e[0], e[0], e[0], tuple(e[1])))
            continue
        if nv.process(s) and (e := nv.estimate()) is not None:
            t.append(e[0])
            x.append(e[1])
    t_arr, x_arr = np.array(t), np.array(x)
    true = np.array([state_at(sc, 0.0, v).position for v in t_arr])
    keep = t_arr - t_arr[0] >= after
    return PositionRun(t_arr[keep], x_arr[keep, 0:3], x_arr[keep, 9:12], true[keep], nv.counters())
