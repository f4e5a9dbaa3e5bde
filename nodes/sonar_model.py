"""Error model of the simulated MaxSonar (MaxBotix LV-MaxSonar-EZ1 on the Pmod MAXSONAR).

A ping returns the distance to the **nearest surface** of the target inside the beam (a cone
of half-angle ``half_angle_deg`` around the pointing direction), plus white noise, rounded to
whole inches and clamped to the sensor's limits; with no target in the beam it returns the
background (or the maximum range). A real rig adds missed pings, bounces and echoes of the
track's far side (:func:`echo_range`, all off by default).
Sources of every default: the README, "Simulated boards and their error models".
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields, replace
from typing import Any

from hera.nodes import geometry as gm
from hera.nodes.world import Motion, SonarMount, Target

INCH = 0.0254
"""Metres per inch (the original converted readings with x 0.0254)."""


@dataclass(frozen=True)
class SonarModel:
    """Parameters of the sonar model."""

    # White range noise std before the 1-inch rounding (m): with the rounding, 1.24 cm RMS and
    # 95 % of readings within 2.4 cm: REFERENCE.md's "about 2.5 cm accuracy".
    noise_m: float = 0.01
    half_angle_deg: float = 20.0  # beam half-angle
    min_in: int = 6  # data sheet: objects closer than 6 in range as 6 in
    max_in: int = 254  # data sheet: 254 in (6.45 m) maximum
    ping_ms: float = 49.0  # data sheet: a reading every 49 ms (20 Hz)
    background_m: float | None = None  # what the beam hits when the target is not in it
    speed_of_sound: float = 343.0  # m/s in air at 20 C
    # A real rig's echoes (probabilities per ping):
    miss_prob: float = 0.0  # no echo heard at all: reads the maximum range
    multipath_prob: float = 0.0  # the target's echo came back by a longer path (a bounce)
    multipath_max_m: float = 1.0  # ... longer by up to this much (uniform from 0.1 m)
    clutter_prob: float = 0.0  # target out of the beam: an echo of the far side of the track

    @classmethod
    def from_args(cls, table: Mapping[str, Any] | None) -> SonarModel:
        """Build from a spec table; ValueError names an unknown key or a bad value."""
        table = dict(table or {})
        known = {f.name for f in fields(cls)}
        unknown = set(table) - known
        if unknown:
            raise ValueError(f"unknown sonar model keys {sorted(unknown)}; known: {sorted(known)}")
        out: dict[str, Any] = {}
        for key, value in table.items():
            if key == "background_m" and value is None:
                out[key] = None
                continue
            try:
                v = float(value)
            except (TypeError, ValueError):
                raise ValueError(f"sonar model {key!r} must be a number, got {value!r}") from None
            if not math.isfinite(v) or v < 0:
                raise ValueError(f"sonar model {key!r} must be finite and >= 0, got {value!r}")
            out[key] = int(v) if key in ("min_in", "max_in") else v
        model = replace(cls(), **out)
        if model.min_in >= model.max_in:
            raise ValueError("sonar model min_in must be < max_in")
        if model.ping_ms <= 0 or model.speed_of_sound <= 0:
            raise ValueError("sonar model ping_ms and speed_of_sound must be > 0")
        for key in ("miss_prob", "multipath_prob", "clutter_prob"):
            if not getattr(model, key) <= 1.0:
                raise ValueError(f"sonar model {key!r} must be a probability, got {table[key]!r}")
        return model


def nearest_surface(
    mount: SonarMount, half_angle: float, motion: Motion, target: Target, samples: int = 9
) -> float | None:
    """Distance (m) from the sonar to the nearest surface of ``target`` in the beam, or None.

    The target is a capsule: points within ``target.radius`` of a segment of
    ``target.length`` centred on the body position along the body x axis. A point of the
    axis counts as in the beam when the angle between the pointing direction and the line of
    sight is at most ``half_angle`` plus the angular radius of the capsule there.
    """
    c = motion.position
    pts = [c]
    if target.length > 0.0:
        ax = gm.rotate(motion.orientation, (1.0, 0.0, 0.0))
        half = target.length / 2.0
        # the closest point of the axis segment to the sonar, then evenly spaced points
        s = max(-half, min(half, gm.dot(gm.sub(mount.position, c), ax)))
        pts.append(gm.add(c, gm.scale(ax, s)))
        for i in range(samples):
            u = -half + target.length * i / (samples - 1)
            pts.append(gm.add(c, gm.scale(ax, u)))
    best: float | None = None
    for p in pts:
        d = gm.sub(p, mount.position)
        dist = gm.norm(d)
        if dist <= target.radius:
            return 0.0
        cosang = max(-1.0, min(1.0, gm.dot(d, mount.direction) / dist))
        if math.acos(cosang) <= half_angle + math.asin(min(1.0, target.radius / dist)):
            r = dist - target.radius
            best = r if best is None or r < best else best
    return best


def echo_range(
    true_m: float | None,
    clutter: Callable[[float], float | None],
    model: SonarModel,
    rng: random.Random,
) -> float | None:
    """The range (m) a ping's first echo gives on a real rig, None for no echo: with
    ``miss_prob`` nothing; with the target in the beam (``true_m``), its surface, or with
    ``multipath_prob`` a bounce 0.1 .. ``multipath_max_m`` m longer; without, with
    ``clutter_prob`` ``clutter(u)`` (a fixed surface along the ray at u in [-1, 1] of the
    beam). Draws nothing when every probability is 0 (the noise stays as it was)."""
    if model.miss_prob and rng.random() < model.miss_prob:
        return None
    if true_m is None:
        if model.clutter_prob and rng.random() < model.clutter_prob:
            return clutter(rng.uniform(-1.0, 1.0))
        return None
    if model.multipath_prob and rng.random() < model.multipath_prob:
        return true_m + rng.uniform(0.1, max(0.1, model.multipath_max_m))
    return true_m


def to_inches(range_m: float | None, model: SonarModel, rng: random.Random) -> int:
    """The reading (whole inches) for a true range: noise, rounding, limits, background."""
    if range_m is None:
        if model.background_m is None:
            return model.max_in
        range_m = model.background_m
    inches = round((range_m + rng.gauss(0.0, model.noise_m)) / INCH)
    return max(model.min_in, min(model.max_in, inches))
