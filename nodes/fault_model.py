"""Board faults a simulated board applies to its readings (switchable at run time).

Kinds and parameters (all optional unless said):

- ``stuck``: readings freeze at the first value read under the fault, or at ``value``;
- ``dropout``: each reading is missing (:class:`NoReading`) with probability ``prob`` (1.0);
- ``spikes``: with probability ``prob`` (0.1) one axis gets +/- ``magnitude`` (driver units;
  default per sensor: acc 2 g, gyro 200 deg/s, mag 1 gauss, baro 50 hPa, range 100 in,
  wheels 100 counts);
- ``bias``: ``value`` (required; a number or one per axis) is added to the readings;
- ``disconnect``: every read raises :class:`BoardDisconnected`;
- ``field``: an external field fixed in the **world** frame, ``value`` (required: one number
  per axis, in the sensor's units, e.g. gauss) added to what a field sensor senses *before*
  the board's own error model: the board turns in it, so what it adds to the readings
  changes with the board's orientation (steel or a magnet near a magnetometer). Only for
  the sensors a board lists as sensing an ambient field (a Pmod NAV: ``mag``); ``sensor``
  is required.

Every kind takes ``sensor`` (one of the board's sensors; default: all of them) and
``duration`` (seconds; default: until cleared).
"""

from __future__ import annotations

import math
import random
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from hera.nodes.driver import BoardDisconnected, NoReading

KINDS = ("stuck", "dropout", "spikes", "bias", "disconnect", "field")
SPIKE_DEFAULT = {
    "acc": 2.0,
    "gyro": 200.0,
    "mag": 1.0,
    "baro": 50.0,
    "range": 100.0,
    "wheels": 100.0,
}
_PARAMS = {
    "stuck": {"value"},
    "dropout": {"prob"},
    "spikes": {"prob", "magnitude"},
    "bias": {"value"},
    "disconnect": set(),
    "field": {"value"},
}


@dataclass
class Fault:
    """One active fault (validated)."""

    kind: str
    sensor: str | None = None
    params: dict[str, Any] = field(default_factory=dict)
    until: float | None = None  # time.monotonic() deadline, or None
    held: dict[str, tuple[float, ...]] = field(default_factory=dict)

    def describe(self) -> dict[str, Any]:
        """JSON-able description."""
        out: dict[str, Any] = {"fault": self.kind, **self.params}
        if self.sensor is not None:
            out["sensor"] = self.sensor
        if self.until is not None:
            out["remaining_s"] = round(max(0.0, self.until - time.monotonic()), 3)
        return out


def _number(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{what} must be a finite number, got {value!r}")
    return float(value)


def make_fault(
    kind: str, sensors: dict[str, int], fields: tuple[str, ...] = (), **params: Any
) -> Fault:
    """Validate a fault request for a board whose ``sensors`` map name -> number of axes
    (``fields``: those of them that sense an ambient field, for the ``field`` kind); raise
    ValueError with a clear message on a bad request."""
    if kind not in KINDS:
        raise ValueError(f"unknown fault {kind!r}; choose one of {(*KINDS, 'clear')}")
    sensor = params.pop("sensor", None)
    if sensor is not None and sensor not in sensors:
        raise ValueError(f"fault sensor must be one of {sorted(sensors)}, got {sensor!r}")
    if kind == "field" and sensor not in fields:
        raise ValueError(
            "fault 'field' needs 'sensor': one that senses an ambient field on this board "
            f"({', '.join(fields) or 'none'}), got {sensor!r}"
        )
    duration = params.pop("duration", None)
    until = None
    if duration is not None:
        d = _number(duration, "fault duration")
        if d <= 0:
            raise ValueError(f"fault duration must be > 0 s, got {duration!r}")
        until = time.monotonic() + d
    unknown = set(params) - _PARAMS[kind]
    if unknown:
        raise ValueError(
            f"unknown parameters for fault {kind!r}: {sorted(unknown)}; "
            f"allowed: {sorted(_PARAMS[kind] | {'sensor', 'duration'})}"
        )
    clean: dict[str, Any] = {}
    if "prob" in params:
        p = _number(params["prob"], "fault prob")
        if not 0.0 <= p <= 1.0:
            raise ValueError(f"fault prob must be within [0, 1], got {p!r}")
        clean["prob"] = p
    if "magnitude" in params:
        clean["magnitude"] = _number(params["magnitude"], "spike magnitude")
    if "value" in params:
        v = params["value"]
        if isinstance(v, (list, tuple)):
            if sensor is None or len(v) != sensors[sensor]:
                raise ValueError(
                    "a fault value given per axis needs 'sensor' and one number per axis "
                    f"({sensors}), got sensor={sensor!r}, value={v!r}"
                )
            clean["value"] = [_number(x, "fault value") for x in v]
        else:
            clean["value"] = _number(v, "fault value")
    if kind == "bias" and "value" not in clean:
        raise ValueError("fault 'bias' needs a 'value' (a number or one per axis)")
    if kind == "field" and not isinstance(clean.get("value"), list):
        raise ValueError("fault 'field' needs a 'value' with one number per axis (world frame)")
    return Fault(kind, sensor, clean, until)


class FaultState:
    """The fault currently applied by one board (at most one at a time; thread-safe)."""

    def __init__(self, sensors: dict[str, int], fields: tuple[str, ...] = ()) -> None:
        self.sensors = sensors
        self.fields = fields
        self._fault: Fault | None = None
        self._lock = threading.Lock()
        self.applied = 0

    def set(self, kind: str, **params: Any) -> Fault:
        """Replace the current fault by a new one (see :func:`make_fault`)."""
        fault = make_fault(kind, self.sensors, self.fields, **params)
        with self._lock:
            self._fault = fault
        return fault

    def clear(self) -> None:
        with self._lock:
            self._fault = None

    def current(self) -> Fault | None:
        """The active fault, or None (expired faults are cleared here)."""
        with self._lock:
            f = self._fault
            if f is not None and f.until is not None and time.monotonic() >= f.until:
                self._fault = f = None
            return f

    def field(self, sensor: str) -> tuple[float, ...] | None:
        """The external world-frame field a ``field`` fault adds to ``sensor`` now, or None.
        The board adds it to what the sensor senses before its error model."""
        f = self.current()
        if f is None or f.kind != "field" or f.sensor != sensor:
            return None
        self.applied += 1
        return tuple(f.params["value"])

    def before_read(self, sensor: str, rng: random.Random) -> None:
        """Raise for a disconnection or a dropout affecting ``sensor``."""
        f = self.current()
        if f is None or (f.sensor is not None and f.sensor != sensor):
            return
        if f.kind == "disconnect":
            self.applied += 1
            raise BoardDisconnected(f"simulated disconnection, reading {sensor}")
        if f.kind == "dropout" and rng.random() < f.params.get("prob", 1.0):
            self.applied += 1
            raise NoReading(f"no {sensor} reading (simulated dropout)")

    def after_read(
        self, sensor: str, values: tuple[float, ...], rng: random.Random
    ) -> tuple[float, ...]:
        """Apply a stuck, spikes or bias fault to the ``values`` just read from ``sensor``."""
        f = self.current()
        if f is None or (f.sensor is not None and f.sensor != sensor):
            return values
        if f.kind == "stuck":
            self.applied += 1
            if "value" in f.params:
                return _broadcast(f.params["value"], len(values))
            with self._lock:
                return f.held.setdefault(sensor, values)
        if f.kind == "bias":
            self.applied += 1
            b = _broadcast(f.params["value"], len(values))
            return tuple(v + d for v, d in zip(values, b, strict=True))
        if f.kind == "spikes" and rng.random() < f.params.get("prob", 0.1):
            self.applied += 1
            mag = f.params.get("magnitude", SPIKE_DEFAULT.get(sensor, 1.0))
            i = rng.randrange(len(values))
            out = list(values)
            out[i] += mag if rng.random() < 0.5 else -mag
            return tuple(out)
        return values


def _broadcast(value: float | list[float], n: int) -> tuple[float, ...]:
    if isinstance(value, list):
        return tuple(value)  # length checked by make_fault
    return (float(value),) * n
