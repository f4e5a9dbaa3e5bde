"""Simulated wheel encoders on the balancing robot (:class:`hera.nodes.lsm6dsl.scenario.Balancing`).

The counter reads ``floor(x (1 + s) counts_per_m)``: x the axle's travel along the world's x
(:meth:`~hera.nodes.lsm6dsl.scenario.Balancing.axle`, + forward), s the board's wheel scale
error (the wheels' true radius off the nominal one; drawn once per board from its seed,
spread ``scale_error_sigma``). It balances when the scenario's robot does (up on its wheels).

It implements :class:`hera.nodes.wheels.driver.WheelEncoderDriver` and
:class:`hera.nodes.driver.SimulatedBoard`, and takes the board faults of
:mod:`hera.nodes.fault_model` on its one sensor ``wheels`` (values in counts): ``stuck`` (the
counter freezes), ``dropout``, ``disconnect``, ``bias`` (counts added) and ``spikes``
(default 100 counts). Readings are a pure function of (seed, scenario, reading times).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

from hera.nodes.fault_model import FaultState
from hera.nodes.noise import KeyedRandom
from hera.nodes.wheels.driver import COUNTS_PER_M, WheelReading
from hera.nodes.world import Scenario, State, state_at, state_of

SENSORS = {"wheels": 1}


class SimWheels:
    """Simulated wheel encoders (see the module docstring); ``clock`` gives the epoch time
    of each read (default ``time.time``). ValueError for a scenario whose axle's travel is
    not tracked (any but ``balancing``)."""

    kind = "wheels"
    sensors = SENSORS

    def __init__(
        self,
        board_id: str,
        scenario: Scenario,
        epoch: float,
        seed: int,
        counts_per_m: float = COUNTS_PER_M,
        clock: Callable[[], float] = time.time,
        scale_error_sigma: float = 0.01,
    ) -> None:
        if not callable(getattr(scenario, "axle", None)):
            raise ValueError(
                f"wheel encoders need a world whose robot drives on wheels (scenario "
                f"'balancing'); scenario {scenario.kind!r} does not track any wheel's travel"
            )
        if not 0.0 < counts_per_m < math.inf:
            raise ValueError(f"wheel counts_per_m must be a number > 0, got {counts_per_m!r}")
        if not 0.0 <= scale_error_sigma < math.inf:
            raise ValueError(f"wheel scale_error_sigma must be >= 0, got {scale_error_sigma!r}")
        self.id = board_id
        self.scenario, self.epoch, self.seed = scenario, float(epoch), int(seed)
        self.counts_per_m, self.clock = float(counts_per_m), clock
        self.rand = KeyedRandom(self.seed)
        self.scale_error = self.rand.constant("wheel_scale").gauss(0.0, scale_error_sigma)
        self.faults = FaultState(SENSORS)
        self.reads = 0

    # -- SimulatedBoard ------------------------------------------------------------------------
    def truth(self, t: float) -> State:
        return state_at(self.scenario, self.epoch, t)

    def rest_truth(self) -> State:
        return state_of(self.scenario.rest_motion(), self.epoch)

    def travel(self, t: float) -> float:
        """The axle's true travel (m, world x) at epoch time ``t``."""
        return self.scenario.axle(t - self.epoch)[0]  # type: ignore[attr-defined]

    # -- WheelEncoderDriver --------------------------------------------------------------------
    def read_wheels(self) -> WheelReading:
        t = self.clock()
        tau = t - self.epoch
        rng = self.rand.rng("wheels", t)
        self.faults.before_read("wheels", rng)
        x = self.scenario.axle(tau)[0]  # type: ignore[attr-defined]
        counts = float(math.floor(x * (1.0 + self.scale_error) * self.counts_per_m))
        (counts,) = self.faults.after_read("wheels", (counts,), rng)
        self.reads += 1
        balancing = getattr(self.scenario, "balancing", None)
        return WheelReading(t, round(counts), bool(balancing(tau)) if callable(balancing) else True)

    def describe(self) -> dict[str, Any]:
        """JSON-able status for the ``board`` verb's listing."""
        f = self.faults.current()
        return {
            "board": self.id,
            "kind": self.kind,
            "counts_per_m": self.counts_per_m,
            "sensors": sorted(SENSORS),
            "reads": self.reads,
            "fault": None if f is None else f.describe(),
        }
