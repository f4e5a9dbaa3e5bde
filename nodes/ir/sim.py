"""Simulated boards of the seed-000 rig: a Sharp IR sensor and a thermocouple.

Both implement the protocols of :mod:`hera.nodes.ir.driver` (and the optional simulated
ones), take run-time faults through :class:`hera.nodes.fault_model.FaultState` (the
``board`` control verb: sensor ``volts`` or ``temp``), and draw their noise from a
:class:`hera.nodes.noise.KeyedRandom`: identical seeds, worlds and reading times give
identical readings.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from typing import Any

from hera.nodes.fault_model import FaultState
from hera.nodes.ir.driver import TemperatureSample, VoltageSample
from hera.nodes.ir.plate import ThermocoupleModel
from hera.nodes.ir.scenarios import PlateScene, Track
from hera.nodes.ir.sharp import SharpModel, Variant, quantise, reading
from hera.nodes.noise import KeyedRandom
from hera.nodes.world import Scenario, State, state_at, state_of

Pose = tuple[float, float, float]


class SimSharpIr:
    """A simulated Sharp IR sensor of ``variant`` at a fixed ``mount`` (x cm, y cm, heading
    deg) or on the plate's ``scanner``, seeing ``scenario``."""

    kind = "sharp_ir"
    sensors = {"volts": 1}

    def __init__(
        self,
        board_id: str,
        variant: Variant,
        model: SharpModel,
        scenario: Scenario,
        epoch: float,
        seed: int,
        *,
        mount: Pose = (0.0, 0.0, 0.0),
        scanner: str | None = None,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.id, self.variant, self.model = board_id, variant, model
        self.scenario, self.epoch = scenario, float(epoch)
        self.mount, self.clock = mount, clock
        self.scanner = None
        if scanner is not None:
            if not isinstance(scenario, PlateScene):
                raise ValueError(f"IR scanner {scanner!r} needs the ir_plate world")
            self.scanner = scenario.scanner(scanner)
        self.rand = KeyedRandom(int(seed))
        self.faults = FaultState(self.sensors)
        self.readings = 0
        self._lock = threading.Lock()

    def pose(self, t: float) -> Pose:
        """(x cm, y cm, heading deg) of the sensor at epoch time ``t``."""
        if self.scanner is not None:
            return self.scanner.pose(self.scenario.plate, t - self.epoch)  # type: ignore[attr-defined]
        return self.mount

    def true_distance(self, t: float) -> float:
        """The distance (cm) to what the beam meets at epoch time ``t``."""
        x, y, heading = self.pose(t)
        sc = self.scenario
        if isinstance(sc, PlateScene):
            return sc.beam_distance(x, y, heading)
        if isinstance(sc, Track):
            return max(0.0, sc.distance(t - self.epoch)[0] - x)
        p = sc.motion(t - self.epoch).position
        return math.dist((p[0] * 100.0, p[1] * 100.0), (x, y))

    def truth(self, t: float) -> State:
        """The true state of the world's target at epoch time ``t``."""
        return state_at(self.scenario, self.epoch, t)

    def rest_truth(self) -> State:
        return state_of(self.scenario.rest_motion(), self.epoch)

    def read_volts(self) -> float:
        return self.read_sample().volts

    def read_sample(self) -> VoltageSample:
        """Convert once (see :func:`hera.nodes.ir.sharp.reading`), faults applied."""
        with self._lock:
            t = self.clock()
            rng = self.rand.rng("volts", t)
            self.faults.before_read("volts", rng)
            v = reading(self.variant, self.model, self.true_distance(t), rng)
            v = self.faults.after_read("volts", (v,), rng)[0]
            self.readings += 1
            return VoltageSample(t, quantise(v))

    def describe(self) -> dict[str, Any]:
        """JSON-able status for the ``board`` verb's listing."""
        f = self.faults.current()
        return {
            "board": self.id,
            "kind": self.kind,
            "variant": self.variant.part,
            "sensors": sorted(self.sensors),
            "readings": self.readings,
            "scanner": None if self.scanner is None else self.scanner.name,
            "fault": None if f is None else f.describe(),
        }


class SimThermocouple:
    """A simulated type-K thermocouple under the plate at ``position`` (x, y) cm."""

    kind = "thermocouple"
    sensors = {"temp": 1}

    def __init__(
        self,
        board_id: str,
        model: ThermocoupleModel,
        scenario: Scenario,
        epoch: float,
        seed: int,
        position: tuple[float, float],
        *,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.id, self.model, self.scenario = board_id, model, scenario
        self.epoch, self.position, self.clock = float(epoch), position, clock
        self.rand = KeyedRandom(int(seed))
        self.offset = model.offset(self.rand.constant("cold_junction"))
        self.faults = FaultState(self.sensors)
        self.readings = 0
        self._lock = threading.Lock()

    def true_temperature(self, t: float, lag: bool = False) -> float:
        """The plate's temperature (degC) at the spot at epoch time ``t`` (as the bead
        sees it, through its lag, if ``lag``)."""
        sc = self.scenario
        if not isinstance(sc, PlateScene):
            return 22.0
        plate, (x, y) = sc.plate, self.position
        tau = t - self.epoch - plate.t_on
        rise = sc.heat.lagged_rise(x, y, tau, self.model.lag_s) if lag else sc.heat.rise(x, y, tau)
        return plate.ambient_c + rise

    def truth(self, t: float) -> State:
        return state_at(self.scenario, self.epoch, t)

    def rest_truth(self) -> State:
        return state_of(self.scenario.rest_motion(), self.epoch)

    def read_celsius(self) -> float:
        return self.read_sample().celsius

    def read_sample(self) -> TemperatureSample:
        """Read once (see :meth:`ThermocoupleModel.read`), faults applied."""
        with self._lock:
            t = self.clock()
            rng = self.rand.rng("temp", t)
            self.faults.before_read("temp", rng)
            value = self.model.read(self.true_temperature(t, lag=True), self.offset, rng)
            value = self.faults.after_read("temp", (value,), rng)[0]
            self.readings += 1
            return TemperatureSample(t, value)

    def describe(self) -> dict[str, Any]:
        f = self.faults.current()
        return {
            "board": self.id,
            "kind": self.kind,
            "sensors": sorted(self.sensors),
            "readings": self.readings,
            "position_cm": list(self.position),
            "fault": None if f is None else f.describe(),
        }
