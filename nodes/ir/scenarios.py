"""World scenarios of the seed-000 rig, registered with :func:`hera.nodes.world.register_scenario`.

Lab 2 (a block moved along a straight track in front of the IR sensors; the sensors sit at
the track's origin and look along +x, the block's distance is its x):

- ``ir_constant_velocity``: back and forth between ``near_cm`` (20) and ``far_cm`` (60) at
  ``speed_cm_s`` (2), constant velocity but for the turns, each a smooth reversal over
  ``turn_s`` (2 s);
- ``ir_stationary``: still at ``distance_cm`` (70) (the seed's poor-initial-guess case
  starts a filter at 50 cm);
- ``ir_back_and_forth``: random back-and-forth motion (the seed's manual moves): a new
  random goal in [``near_cm``, ``far_cm``] (30, 60) every ``hop_s`` (3) s, reached with a
  smooth (half-cosine) move; the goals come from the world's ``seed``.

Lab 3 (``ir_plate``): a ``plate_cm`` (10 x 10) plate, origin at its top-left corner, x to
the right, y down. ``blocks`` on it (tables ``{x, y, w, h, hot, visible}``, cm; default: a
cold 2 x 2 block at (2, 3) and a hot one at (6, 6)); the hot one was put down
``hot_since_s`` before the epoch (0: at the epoch) and heats the plate (see
:mod:`.plate`: ``rise_c``, ``alpha_cm2_s``, ``loss_time_s``, ``ambient_c``). Thermocouples
at ``thermocouples_cm`` (default: 0.5 cm inside the four corners, and the centre). IR
``scanners`` (default ``["left", "top"]``, also ``right``, ``bottom``): a sensor on a
carriage ``scan_offset_cm`` (5) outside that edge, looking across the plate, swept along
the edge and back every ``scan_period_s`` (6 s); its beam is ``beam_cm`` (0.4) wide and
sees the first visible block it meets, else the rig's frame ``wall_cm`` (2) past the far
edge.
"""

from __future__ import annotations

import math
import random
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from hera.nodes.ir.plate import Block, Plate, PlateHeat, blocks_from
from hera.nodes.world import Motion, Scenario, Target, number, register_scenario, vector

CM = 0.01


class Track(Scenario):
    """A block on a straight track; subclasses give its distance (cm) and speed (cm/s)."""

    target = Target(radius=0.0)

    def distance(self, tau: float) -> tuple[float, float]:
        """(distance cm, velocity cm/s) from the sensors at ``tau`` s."""
        raise NotImplementedError

    def motion(self, tau: float) -> Motion:
        d, v = self.distance(tau)
        return Motion(position=(d * CM, 0.0, 0.0), velocity=(v * CM, 0.0, 0.0))


class ConstantVelocity(Track):
    """Back and forth between ``near`` and ``far`` cm at ``speed`` cm/s, each turn a smooth
    reversal taking ``turn`` s (constant deceleration: the triangle wave averaged over a
    ``turn``-long window, so the reversal points lie ``speed * turn / 4`` inside the ends)."""

    def __init__(
        self, near: float = 20.0, far: float = 60.0, speed: float = 2.0, turn: float = 2.0
    ) -> None:
        if not 0 < near < far or speed <= 0 or turn < 0 or speed * turn > far - near:
            raise ValueError(
                "ir_constant_velocity needs 0 < near_cm < far_cm, speed_cm_s > 0 and "
                "0 <= turn_s <= (far_cm - near_cm) / speed_cm_s"
            )
        self.near, self.span, self.speed, self.turn = near, far - near, speed, turn

    def _tri(self, tau: float) -> float:
        p = (tau * self.speed) % (2.0 * self.span)
        return p if p < self.span else 2.0 * self.span - p

    def _area(self, tau: float) -> float:
        """Integral of the triangle wave from 0 to ``tau`` (cm s)."""
        s, v = self.span, self.speed
        k = math.floor(tau * v / (2.0 * s))
        p = tau * v - 2.0 * s * k
        part = p * p / 2.0 if p < s else s * s / 2.0 + 2.0 * s * (p - s) - (p * p - s * s) / 2.0
        return (k * s * s + part) / v

    def distance(self, tau: float) -> tuple[float, float]:
        w = self.turn
        if w == 0.0:
            p = (tau * self.speed) % (2.0 * self.span)
            return self.near + self._tri(tau), self.speed if p < self.span else -self.speed
        lo, hi = tau - w / 2.0, tau + w / 2.0
        d = self.near + (self._area(hi) - self._area(lo)) / w
        return d, (self._tri(hi) - self._tri(lo)) / w


class Stationary(Track):
    """Still at ``distance`` cm."""

    def __init__(self, distance: float = 70.0) -> None:
        if distance <= 0:
            raise ValueError("ir_stationary needs distance_cm > 0")
        self.d = distance

    def distance(self, tau: float) -> tuple[float, float]:
        return self.d, 0.0


class BackAndForth(Track):
    """Random goals in [``near``, ``far``] every ``hop`` s, half-cosine moves between them."""

    def __init__(self, near: float = 30.0, far: float = 60.0, hop: float = 3.0, seed: int = 0):
        if not 0 < near < far or hop <= 0:
            raise ValueError("ir_back_and_forth needs 0 < near_cm < far_cm and hop_s > 0")
        self.near, self.far, self.hop, self.seed = near, far, hop, int(seed)

    def _goal(self, k: int) -> float:
        u = random.Random(f"ir_back_and_forth|{self.seed}|{k}").random()
        return self.near + (self.far - self.near) * u

    def distance(self, tau: float) -> tuple[float, float]:
        k = math.floor(tau / self.hop)
        s = tau / self.hop - k
        a, b = self._goal(k), self._goal(k + 1)
        d = a + (b - a) * (1.0 - math.cos(math.pi * s)) / 2.0
        v = (b - a) * math.pi * math.sin(math.pi * s) / (2.0 * self.hop)
        return d, v


@dataclass(frozen=True)
class Scanner:
    """An IR sensor on a carriage beside one edge of the plate (see the module docstring):
    it sits at (x, y) cm with ``heading`` deg (0 = +x, 90 = +y) at a given time."""

    name: str
    period: float
    offset: float
    phase: float = 0.0

    def pose(self, plate: Plate, tau: float) -> tuple[float, float, float]:
        """(x cm, y cm, heading deg) at ``tau`` s."""
        along = plate.height if self.name in ("left", "right") else plate.width
        s = ((tau / self.period + self.phase) % 1.0) * 2.0
        u = (s if s < 1.0 else 2.0 - s) * along
        if self.name == "left":
            return (-self.offset, u, 0.0)
        if self.name == "right":
            return (plate.width + self.offset, u, 180.0)
        if self.name == "top":
            return (u, -self.offset, 90.0)
        return (u, plate.height + self.offset, 270.0)


SCANNERS = ("left", "top", "right", "bottom")
DEFAULT_BLOCKS = (Block(2.0, 3.0, 2.0, 2.0), Block(6.0, 6.0, 2.0, 2.0, hot=True))
DEFAULT_THERMOCOUPLES = ((0.5, 0.5), (9.5, 0.5), (0.5, 9.5), (9.5, 9.5), (5.0, 5.0))


class PlateScene(Scenario):
    """The lab-3 plate: blocks, heat, thermocouples and IR scanners (module docstring)."""

    def __init__(
        self,
        plate: Plate,
        thermocouples: Sequence[tuple[float, float]],
        scanners: Sequence[str],
        scan_period: float,
        scan_offset: float,
        beam: float,
        wall: float,
    ) -> None:
        if scan_period <= 0 or scan_offset < 0 or beam < 0 or wall < 0:
            raise ValueError(
                "ir_plate needs scan_period_s > 0, scan_offset_cm, beam_cm and wall_cm >= 0"
            )
        self.plate = plate
        self.heat = PlateHeat(plate)
        self.thermocouples = tuple(thermocouples)
        self.scanners = {
            name: Scanner(name, scan_period, scan_offset, phase=i * 0.25)
            for i, name in enumerate(scanners)
        }
        self.beam, self.wall = beam, wall

    def motion(self, tau: float) -> Motion:
        return Motion(position=(0.0, 0.0, 0.0))

    def scanner(self, name: str) -> Scanner:
        """The scanner ``name``; ValueError naming the scanners of this world."""
        try:
            return self.scanners[name]
        except KeyError:
            raise ValueError(
                f"no IR scanner {name!r} in this plate world; scanners: {sorted(self.scanners)}"
            ) from None

    def beam_distance(self, x: float, y: float, heading: float) -> float:
        """Distance (cm) from a sensor at (x, y) looking along an axis (``heading`` 0, 90,
        180 or 270 deg) to the first visible block its beam meets, else to the frame."""
        h = round(heading) % 360
        half = self.beam / 2.0
        p = self.plate
        best = None
        for b in p.blocks:
            if not b.visible:
                continue
            if h in (0, 180):
                cross_lo, cross_hi, c = b.y, b.y + b.h, y
                near = b.x - x if h == 0 else x - (b.x + b.w)
            else:
                cross_lo, cross_hi, c = b.x, b.x + b.w, x
                near = b.y - y if h == 90 else y - (b.y + b.h)
            if cross_hi > c - half and cross_lo < c + half and near >= 0:
                best = near if best is None else min(best, near)
        if best is not None:
            return best
        extent = p.width if h in (0, 180) else p.height
        edge = -x if h == 0 else x - p.width if h == 180 else -y if h == 90 else y - p.height
        return edge + extent + self.wall


def _track_cv(w: Mapping[str, Any]) -> Scenario:
    return ConstantVelocity(
        number(w, "near_cm", 20.0),
        number(w, "far_cm", 60.0),
        number(w, "speed_cm_s", 2.0),
        number(w, "turn_s", 2.0),
    )


def _track_still(w: Mapping[str, Any]) -> Scenario:
    return Stationary(number(w, "distance_cm", 70.0))


def _track_random(w: Mapping[str, Any]) -> Scenario:
    return BackAndForth(
        number(w, "near_cm", 30.0),
        number(w, "far_cm", 60.0),
        number(w, "hop_s", 3.0),
        int(number(w, "seed", 0)),
    )


def _plate(w: Mapping[str, Any]) -> Scenario:
    width, height = vector(w, "plate_cm", (10.0, 10.0))
    if width <= 0 or height <= 0:
        raise ValueError(f"world 'plate_cm' must be two sizes > 0 cm, got {[width, height]}")
    blocks = blocks_from(w["blocks"]) if "blocks" in w else DEFAULT_BLOCKS
    scanners = w.get("scanners", ["left", "top"])
    if not isinstance(scanners, (list, tuple)) or not all(s in SCANNERS for s in scanners):
        raise ValueError(
            f"world 'scanners' must be a list of {', '.join(SCANNERS)}, got {scanners!r}"
        )
    tcs = w.get("thermocouples_cm", DEFAULT_THERMOCOUPLES)
    try:
        tcs = tuple((float(p[0]), float(p[1])) for p in tcs)
    except (TypeError, ValueError, IndexError, KeyError):
        raise ValueError(
            f"world 'thermocouples_cm' must be a list of [x, y] in cm, got {tcs!r}"
        ) from None
    alpha, loss = number(w, "alpha_cm2_s", 0.3), number(w, "loss_time_s", 150.0)
    if alpha <= 0 or loss <= 0:
        raise ValueError("world 'alpha_cm2_s' and 'loss_time_s' must be > 0")
    plate = Plate(
        width,
        height,
        blocks,
        alpha=alpha,
        loss_time_s=loss,
        rise_c=number(w, "rise_c", 8.0),
        ambient_c=number(w, "ambient_c", 22.0),
        t_on=-number(w, "hot_since_s", 0.0),
    )
    return PlateScene(
        plate,
        tcs,
        tuple(scanners),
        number(w, "scan_period_s", 6.0),
        number(w, "scan_offset_cm", 5.0),
        number(w, "beam_cm", 0.4),
        number(w, "wall_cm", 2.0),
    )


register_scenario("ir_constant_velocity", {"near_cm", "far_cm", "speed_cm_s", "turn_s"}, _track_cv)
register_scenario("ir_stationary", {"distance_cm"}, _track_still)
register_scenario("ir_back_and_forth", {"near_cm", "far_cm", "hop_s"}, _track_random)
register_scenario(
    "ir_plate",
    {
        "plate_cm",
        "blocks",
        "scanners",
        "thermocouples_cm",
        "alpha_cm2_s",
        "loss_time_s",
        "rise_c",
        "ambient_c",
        "hot_since_s",
        "scan_period_s",
        "scan_offset_cm",
        "beam_cm",
        "wall_cm",
    },
    _plate,
)
