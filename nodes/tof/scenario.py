"""The ``desk`` scenario: a board held over a desk, raised and lowered, tilted (seed 001).

The carrier board (the frame the ToF sensors are mounted in: x to the right, y forward, z up,
its origin at the centre sensor) starts level and still at ``height`` above the desk (the
plane z = 0), then repeats a cycle of segments, each a minimum-jerk move from one pose to the
next (Flash & Hogan's model of a hand's point-to-point motion: s(u) = 10u^3 - 15u^4 + 6u^5):

====================  ========================================================
segment               what
====================  ========================================================
still                 no motion (4 s at the start, 2-3 s between moves)
slow                  up to ``high`` (or back to ``height``) in ``slow_s`` (6 s)
fast                  down to ``low``, up, or a quick bump, each in ``fast_s``
tilt                  pitch to +``tilt_deg``, roll to -``roll_deg``, level again
====================  ========================================================

Each cycle after the first is varied by ``seed`` (heights and durations by +/- 15 %, tilt
signs), so several seeds are several worlds. ``tremor_m`` adds a hand's tremor (sum of three
sines at 7-11 Hz, that amplitude in total, default 0). ``desk_reflectance`` and
``ambient_mcps`` set the light the sensors see. Heights in m, angles in degrees.
"""

from __future__ import annotations

import bisect
import math
import random
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from hera.nodes import geometry as gm
from hera.nodes.world import Motion, Scenario, number, register_scenario

Pose = tuple[float, float, float]
"""(height m, pitch rad, roll rad)."""


@dataclass(frozen=True)
class Segment:
    """One move: ``kind`` (still, slow, fast, tilt) from pose ``a`` to pose ``b`` over
    [``start``, ``start + duration``) (s since the epoch)."""

    kind: str
    start: float
    duration: float
    a: Pose
    b: Pose


def min_jerk(u: float) -> tuple[float, float, float]:
    """s(u), s'(u), s''(u) of the minimum-jerk profile on u in [0, 1] (clamped)."""
    if u <= 0.0:
        return 0.0, 0.0, 0.0
    if u >= 1.0:
        return 1.0, 0.0, 0.0
    u2 = u * u
    return (
        u2 * u * (10.0 - 15.0 * u + 6.0 * u2),
        30.0 * u2 * (1.0 - 2.0 * u + u2),
        60.0 * u * (1.0 - 3.0 * u + 2.0 * u2),
    )


class Desk(Scenario):
    """See the module docstring."""

    kind = "desk"

    def __init__(
        self,
        height: float = 0.12,
        high: float = 0.25,
        low: float = 0.07,
        tilt_deg: float = 8.0,
        roll_deg: float = 6.0,
        slow_s: float = 6.0,
        fast_s: float = 0.7,
        tremor_m: float = 0.0,
        desk_reflectance: float = 0.5,
        ambient_mcps: float = 0.3,
        seed: int = 0,
    ) -> None:
        if not 0.0 < low < height < high:
            raise ValueError(
                f"desk heights must satisfy 0 < low < height < high, got {low}, {height}, {high}"
            )
        if slow_s <= 0 or fast_s <= 0:
            raise ValueError("desk slow_s and fast_s must be > 0 s")
        if not 0.0 < desk_reflectance <= 1.0:
            raise ValueError(f"desk_reflectance must be within (0, 1], got {desk_reflectance}")
        self.height, self.high, self.low = height, high, low
        self.tilt, self.roll = math.radians(tilt_deg), math.radians(roll_deg)
        self.slow_s, self.fast_s, self.tremor = slow_s, fast_s, tremor_m
        self.reflectance, self.ambient = desk_reflectance, ambient_mcps
        self.seed = int(seed)
        self._segments: list[Segment] = []
        self._starts: list[float] = []
        self._lock = threading.Lock()

    # -- the plan ---------------------------------------------------------------------------
    def _cycle(self, k: int, start: float) -> list[Segment]:
        """The segments of cycle ``k`` (first one unvaried) beginning at ``start``."""
        r = random.Random(f"desk|{self.seed}|{k}")

        def vary(x: float) -> float:
            return x if k == 0 else x * r.uniform(0.85, 1.15)

        h0, hi, lo = self.height, vary(self.high), max(0.05, vary(self.low))
        mid = 0.5 * (h0 + hi)
        sp = 1.0 if k == 0 else r.choice((-1.0, 1.0))
        sr = 1.0 if k == 0 else r.choice((-1.0, 1.0))
        pitch, roll = sp * vary(self.tilt), -sr * vary(self.roll)
        bump = min(0.08, hi - h0)
        plan: list[tuple[str, float, Pose]] = [
            ("still", 4.0 if k == 0 else vary(2.5), (h0, 0.0, 0.0)),
            ("slow", vary(self.slow_s), (hi, 0.0, 0.0)),
            ("still", vary(3.0), (hi, 0.0, 0.0)),
            ("fast", vary(self.fast_s), (lo, 0.0, 0.0)),
            ("still", vary(2.0), (lo, 0.0, 0.0)),
            ("fast", vary(self.fast_s) * 0.85, (mid, 0.0, 0.0)),
            ("still", vary(2.0), (mid, 0.0, 0.0)),
            ("tilt", vary(1.5), (mid, pitch, 0.0)),
            ("still", vary(2.0), (mid, pitch, 0.0)),
            ("tilt", vary(1.5), (mid, pitch, roll)),
            ("still", vary(2.0), (mid, pitch, roll)),
            ("tilt", vary(1.5), (mid, 0.0, 0.0)),
            ("slow", vary(self.slow_s) * 0.8, (h0, 0.0, 0.0)),
            ("fast", vary(self.fast_s) * 0.7, (h0 + bump, 0.0, 0.0)),
            ("fast", vary(self.fast_s) * 0.7, (h0, 0.0, 0.0)),
            ("still", vary(3.0), (h0, 0.0, 0.0)),
        ]
        out, t, pose = [], start, (h0, 0.0, 0.0)
        for kind, duration, target in plan:
            out.append(Segment(kind, t, duration, pose, target))
            t += duration
            pose = target
        return out

    def _end(self) -> float:
        last = self._segments[-1]
        return last.start + last.duration

    def _segment(self, tau: float) -> Segment:
        with self._lock:
            while not self._segments or tau >= self._end():
                k = len(self._segments) // 16
                end = self._end() if self._segments else 0.0
                for s in self._cycle(k, end):
                    self._segments.append(s)
                    self._starts.append(s.start)
            if tau < 0.0:
                return self._segments[0]
            i = bisect.bisect_right(self._starts, tau) - 1
            return self._segments[i]

    def segment(self, tau: float) -> str:
        """The kind of segment under way at ``tau`` (still, slow, fast, tilt)."""
        return self._segment(tau).kind

    def phase(self, tau: float) -> tuple[str, float]:
        """The kind of segment under way at ``tau`` and how long (s) it has been going."""
        s = self._segment(tau)
        return s.kind, max(0.0, tau - s.start)

    # -- the motion -------------------------------------------------------------------------
    def pose(self, tau: float) -> tuple[Pose, Pose, Pose]:
        """(pose, its rate, its second derivative) at ``tau``: heights in m, angles in rad."""
        s = self._segment(tau)
        u = (tau - s.start) / s.duration if s.duration > 0 else 1.0
        p, dp, ddp = min_jerk(u)
        d = [b - a for a, b in zip(s.a, s.b, strict=True)]
        pose = tuple(a + p * x for a, x in zip(s.a, d, strict=True))
        rate = tuple(dp * x / s.duration for x in d)
        acc = tuple(ddp * x / s.duration**2 for x in d)
        if self.tremor:
            h, v, a = self._tremor(tau)
            pose = (pose[0] + h, pose[1], pose[2])
            rate = (rate[0] + v, rate[1], rate[2])
            acc = (acc[0] + a, acc[1], acc[2])
        return pose, rate, acc  # type: ignore[return-value]

    def _tremor(self, tau: float) -> tuple[float, float, float]:
        h = v = a = 0.0
        for f, share, ph in ((7.3, 0.5, 0.3), (8.9, 0.3, 1.9), (11.1, 0.2, 4.0)):
            w = 2.0 * math.pi * f
            amp = self.tremor * share
            h += amp * math.sin(w * tau + ph)
            v += amp * w * math.cos(w * tau + ph)
            a -= amp * w * w * math.sin(w * tau + ph)
        return h, v, a

    def motion(self, tau: float) -> Motion:
        (h, pitch, roll), (vh, vp, vr), (ah, _, _) = self.pose(tau)
        q = gm.from_euler(roll, pitch, 0.0)
        # body rates of R = Ry(pitch) Rx(roll): (roll', pitch' cos roll, -pitch' sin roll)
        rate = (vr, vp * math.cos(roll), -vp * math.sin(roll))
        return Motion(
            position=(0.0, 0.0, h),
            velocity=(0.0, 0.0, vh),
            acceleration=(0.0, 0.0, ah),
            orientation=q,
            angular_rate=rate,
        )

    def rest_motion(self) -> Motion:
        return Motion(position=(0.0, 0.0, self.height))


def _build(w: Mapping[str, Any]) -> Desk:
    seed = w.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise ValueError(f"world 'seed' must be an integer, got {seed!r}")
    return Desk(
        number(w, "height", 0.12),
        number(w, "high", 0.25),
        number(w, "low", 0.07),
        number(w, "tilt_deg", 8.0),
        number(w, "roll_deg", 6.0),
        number(w, "slow_s", 6.0),
        number(w, "fast_s", 0.7),
        number(w, "tremor_m", 0.0),
        number(w, "desk_reflectance", 0.5),
        number(w, "ambient_mcps", 0.3),
        seed,
    )


register_scenario(
    "desk",
    {
        "height",
        "high",
        "low",
        "tilt_deg",
        "roll_deg",
        "slow_s",
        "fast_s",
        "tremor_m",
        "desk_reflectance",
        "ambient_mcps",
    },
    _build,
)
