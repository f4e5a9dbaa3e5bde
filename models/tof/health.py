"""Which ToF sensors to trust: invalid statuses, outliers, stuck and dead sensors.

A :class:`SensorHealth` watches every sensor (one (name, node) source) a model hears from and
gives each a code:

=====  ==============  ======================================================================
code   name            when
=====  ==============  ======================================================================
0      ok
1      invalid         its last ``invalid_run`` rangings all had a status other than valid
2      inconsistent    its last ``gated_run`` valid readings were all gated out (chi-square)
3      stuck           its last ``stuck_repeats`` readings were identical, all four values
                       (a live sensor's noisy rates never repeat exactly)
4      dead            nothing from it for ``dead_s`` s (model time: other sensors' samples)
=====  ==============  ======================================================================

Codes 2-4 are faults: the sensor's bit is set in :meth:`SensorHealth.mask` (bit i for the
i-th sensor from the left, by board x then y) and its readings are not fused (a stuck or dead
sensor at all; an inconsistent one only when a reading passes the gate again). A fault
clears when the sensor behaves again (a changing reading, a sample, a reading accepted).
Pure: time comes from the samples.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

OK, INVALID, INCONSISTENT, STUCK, DEAD = 0, 1, 2, 3, 4
CODES = ("ok", "invalid", "inconsistent", "stuck", "dead")
FAULTS = (INCONSISTENT, STUCK, DEAD)


@dataclass
class Sensor:
    """What is known of one sensor: ``mount`` (x, y) m on the board, its last reading, runs
    of identical / invalid / gated readings, its ``code`` and when it was last heard."""

    key: tuple[str, str]
    mount: tuple[float, float]
    last: tuple[float, ...] | None = None
    repeats: int = 0
    invalid_run: int = 0
    gated_run: int = 0
    code: int = OK
    last_t: float = -math.inf
    faults: dict[str, int] = field(default_factory=dict)

    @property
    def label(self) -> str:
        return f"{self.key[0]}@{self.key[1]}"


class SensorHealth:
    """Codes of every sensor (see the module docstring)."""

    def __init__(
        self,
        stuck_repeats: int = 4,
        dead_s: float = 0.5,
        invalid_run: int = 3,
        gated_run: int = 5,
        valid_statuses: Sequence[int] = (0,),
    ) -> None:
        if stuck_repeats < 2 or invalid_run < 1 or gated_run < 1 or not dead_s > 0:
            raise ValueError(
                "stuck_repeats must be >= 2, invalid_run and gated_run >= 1, dead_s > 0"
            )
        self.stuck_repeats, self.dead_s = int(stuck_repeats), float(dead_s)
        self.invalid_limit, self.gated_limit = int(invalid_run), int(gated_run)
        self.valid_statuses = frozenset(int(s) for s in valid_statuses)
        self.sensors: dict[tuple[str, str], Sensor] = {}
        self.events = {name: 0 for name in CODES[1:]}
        self.recoveries = 0
        self._order: list[tuple[str, str]] = []

    def observe(self, key: tuple[str, str], t: float, values: Sequence[float]) -> Sensor:
        """Take one reading [distance, ambient, signal, status, x, y] of sensor ``key`` at
        ``t``; returns the sensor with its code updated."""
        mount = (float(values[4]), float(values[5])) if len(values) >= 6 else (0.0, 0.0)
        s = self.sensors.get(key)
        if s is None:
            s = self.sensors[key] = Sensor(key, mount)
            self._order = sorted(self.sensors, key=lambda k: (*self.sensors[k].mount, k))
        s.mount = mount
        s.last_t = max(s.last_t, t)
        reading = tuple(values[:4])
        s.repeats = s.repeats + 1 if reading == s.last else 1
        s.last = reading
        status = int(values[3]) if math.isfinite(values[3]) else -1
        valid = status in self.valid_statuses and math.isfinite(values[0])
        s.invalid_run = 0 if valid else s.invalid_run + 1
        if s.code == DEAD:
            self._set(s, OK)
        if s.repeats >= self.stuck_repeats:
            self._set(s, STUCK)
        elif s.code == STUCK:
            self._set(s, OK)
        if s.code in (OK, INVALID):
            self._set(s, INVALID if s.invalid_run >= self.invalid_limit else OK)
        return s

    def usable(self, s: Sensor) -> bool:
        """Whether the reading just observed may be fused (valid, not stuck or dead)."""
        return s.invalid_run == 0 and s.code not in (STUCK, DEAD)

    def fused(self, s: Sensor, accepted: bool, blame: bool = True) -> None:
        """Record whether the sensor's reading passed the gate. ``blame``: the filter hears
        other sensors too, so a run of refusals is this sensor's fault (a one-sensor filter
        cannot tell a bad sensor from its own lag)."""
        if accepted:
            s.gated_run = 0
            if s.code == INCONSISTENT:
                self._set(s, OK)
        else:
            s.gated_run += 1
            if blame and s.gated_run >= self.gated_limit and s.code in (OK, INVALID):
                self._set(s, INCONSISTENT)

    def forgive(self) -> None:
        """Clear every run of refusals (the filter, not the sensors, had lost the board)."""
        for s in self.sensors.values():
            s.gated_run = 0

    def tick(self, t: float) -> None:
        """Model time is now ``t``: a sensor silent for ``dead_s`` is dead."""
        for s in self.sensors.values():
            if s.code != DEAD and t - s.last_t > self.dead_s:
                self._set(s, DEAD)

    def _set(self, s: Sensor, code: int) -> None:
        if code == s.code:
            return
        if code != OK:
            self.events[CODES[code]] += 1
        elif s.code in FAULTS:
            self.recoveries += 1
        s.code = code

    def mask(self) -> int:
        """Bit i set when the i-th sensor from the left has a fault (codes 2-4)."""
        return sum(1 << i for i, k in enumerate(self._order) if self.sensors[k].code in FAULTS)

    def healthy(self) -> int:
        """How many sensors are ok."""
        return sum(s.code == OK for s in self.sensors.values())

    def counters(self) -> dict[str, int]:
        """Events per code, recoveries, and each sensor's current code (``code <label>``)."""
        out = {f"{name} events": n for name, n in self.events.items()}
        out["recoveries"] = self.recoveries
        for k in self._order:
            s = self.sensors[k]
            out[f"code {s.label}"] = s.code
        return out
