"""A simulated Pmod NAV board: reads the world's scenario through the NAV error model.

It implements :class:`hera.nodes.driver.NavDriver`, plus the simulator-only commands a
calibration needs: :meth:`SimNavBoard.hold_still` (the vehicle is stopped in its "0 deg"
pose) and :meth:`SimNavBoard.turn` (turn the held board, e.g. 180 deg about z).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import replace
from typing import Any

from hera import wallclock
from hera.nodes import geometry as gm
from hera.nodes.driver import ImuSample, NoReading
from hera.nodes.fault_model import FaultState
from hera.nodes.geometry import Vec3
from hera.nodes.imu_model import NavModel, ideal_acc, ideal_baro, ideal_gyro, ideal_mag
from hera.nodes.noise import KeyedRandom, RandomWalk
from hera.nodes.world import Environment, G, Motion, Scenario, State, state_at, state_of

_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


class SimNavBoard:
    """Simulated Pmod NAV. ``clock`` gives the true epoch time of each reading (default
    ``time.time``); readings are a pure function of (seed, scenario, reading times).
    ``read_imu`` stamps its sample with the node's wall clock (:mod:`hera.wallclock`: the
    reading time plus any injected clock skew)."""

    kind = "pmod_nav"
    sensors = {"acc": 3, "gyro": 3, "mag": 3, "baro": 1}

    def __init__(
        self,
        board_id: str,
        scenario: Scenario,
        env: Environment,
        epoch: float,
        model: NavModel,
        seed: int,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.id = board_id
        self.scenario, self.env, self.epoch, self.model = scenario, env, float(epoch), model
        self.seed = int(seed)
        self.clock = clock
        self.rand = KeyedRandom(self.seed)
        self.mount = model.mount
        self.acc_bias = self._const(model.acc_bias, "acc_bias", model.acc_bias_sigma, 0.0)
        self.acc_scale = self._const(model.acc_scale, "acc_scale", model.acc_scale_sigma, 0.0)
        self.gyro_bias = self._const(model.gyro_bias, "gyro_bias", model.gyro_bias_sigma, 0.0)
        self.gyro_scale = self._const(model.gyro_scale, "gyro_scale", model.gyro_scale_sigma, 0.0)
        self.acc_run_bias = self._const(
            model.acc_run_bias, "acc_run_bias", model.acc_run_bias_sigma, 0.0
        )
        self.walks = [RandomWalk(self.seed, f"gyro{i}", model.gyro_drift) for i in range(3)]
        self.faults = FaultState(self.sensors, fields=("mag",))
        self.reads = 0
        self._held: Motion | None = None
        self._lock = threading.Lock()
        # One calibration at a time holds the board: a second one (mag while nav calibrates,
        # both measures sharing this board) waits, instead of being released by the first.
        self._hold = threading.RLock()

    def _const(self, given: Vec3 | None, stream: str, sigma: float, mean: float) -> Vec3:
        if given is not None:
            return given
        r = self.rand.constant(stream)
        return (r.gauss(mean, sigma), r.gauss(mean, sigma), r.gauss(mean, sigma))

    # -- simulator commands ----------------------------------------------------------------
    @contextmanager
    def hold_still(self) -> Iterator[SimNavBoard]:
        """While inside, the board is still in the scenario's rest ("0 deg") pose. Exclusive:
        another thread's hold waits until this one ends (a nested hold in the same thread
        keeps the board held until the outermost one ends)."""
        with self._hold:
            outer = self._held is None
            if outer:
                with self._lock:
                    self._held = self.scenario.rest_motion()
            try:
                yield self
            finally:
                if outer:
                    with self._lock:
                        self._held = None

    def turn(self, axis: str, degrees: float) -> None:
        """Turn the held board by ``degrees`` about its own ``axis`` ("x", "y" or "z")."""
        if axis not in _AXES:
            raise ValueError(f"turn axis must be 'x', 'y' or 'z', got {axis!r}")
        with self._lock:
            if self._held is None:
                raise RuntimeError("turn() needs the board held still (use hold_still())")
            q = gm.quat_mul(
                self._held.orientation, gm.axis_angle(_AXES[axis], math.radians(degrees))
            )
            self._held = replace(self._held, orientation=q)

    # -- driver interface --------------------------------------------------------------------
    def motion(self, t: float) -> tuple[Motion, bool]:
        """The true motion at epoch time ``t`` and whether the board is held still."""
        held = self._held
        if held is not None:
            return held, True
        return self.scenario.motion(t - self.epoch), False

    def truth(self, t: float) -> State:
        """The true state at epoch time ``t`` (:class:`hera.nodes.driver.SimulatedBoard`)."""
        return state_at(self.scenario, self.epoch, t)

    def rest_truth(self) -> State:
        """The true state in the rest pose (:class:`hera.nodes.driver.SimulatedBoard`)."""
        return state_of(self.scenario.rest_motion(), self.epoch)

    def read_acc(self) -> Vec3:
        t = self.clock()
        m, held = self.motion(t)
        return self._read("acc", t, m, held)  # type: ignore[return-value]

    def read_gyro(self) -> Vec3:
        t = self.clock()
        m, held = self.motion(t)
        return self._read("gyro", t, m, held)  # type: ignore[return-value]

    def read_mag(self) -> Vec3:
        t = self.clock()
        m, held = self.motion(t)
        return self._read("mag", t, m, held)  # type: ignore[return-value]

    def read_baro(self) -> float:
        t = self.clock()
        m, held = self.motion(t)
        return self._read("baro", t, m, held)[0]

    def read_imu(self, mag: bool = True) -> ImuSample:
        t = self.clock()
        if self.model.miss_prob and self.rand.rng("miss", t).random() < self.model.miss_prob:
            raise NoReading(f"{self.id}: no reading (simulated miss)")
        m, held = self.motion(t)
        acc = self._read("acc", t, m, held)
        gyro = self._read("gyro", t, m, held)
        field = self._read("mag", t, m, held) if mag else None
        # the world is sensed at the true time; the reading is stamped with the node's clock
        return ImuSample(t + wallclock.offset(), acc, gyro, field)  # type: ignore[arg-type]

    # -- models ------------------------------------------------------------------------------
    def _read(self, sensor: str, t: float, m: Motion, held: bool) -> tuple[float, ...]:
        rng = self.rand.rng(sensor, t)
        self.faults.before_read(sensor, rng)
        md = self.model
        if sensor == "acc":
            a = ideal_acc(m, self.mount)
            vib = 0.0 if held else self.scenario.vibration_acc / G
            run = (0.0, 0.0, 0.0) if held else self.acc_run_bias
            vals: tuple[float, ...] = tuple(
                (1.0 + self.acc_scale[i]) * a[i]
                + self.acc_bias[i]
                + run[i]
                + rng.gauss(0.0, md.acc_noise)
                + (rng.gauss(0.0, vib) if vib else 0.0)
                for i in range(3)
            )
        elif sensor == "gyro":
            w = ideal_gyro(m, self.mount)
            tau = t - self.epoch
            vib = 0.0 if held else math.degrees(self.scenario.vibration_gyro)
            vals = tuple(
                (1.0 + self.gyro_scale[i]) * w[i]
                + self.gyro_bias[i]
                + self.walks[i](tau)
                + rng.gauss(0.0, md.gyro_noise)
                + (rng.gauss(0.0, vib) if vib else 0.0)
                for i in range(3)
            )
        elif sensor == "mag":
            extra = self.faults.field("mag")  # a disturbance fixed in the world frame
            ideal = ideal_mag(m, self.mount, self.env, extra)  # type: ignore[arg-type]
            b = gm.mat_vec(md.soft_iron, ideal)
            vals = tuple(b[i] + md.hard_iron[i] + rng.gauss(0.0, md.mag_noise) for i in range(3))
        else:
            vals = (ideal_baro(m, self.env) + md.baro_bias + rng.gauss(0.0, md.baro_noise),)
        self.reads += 1
        return self.faults.after_read(sensor, vals, rng)

    def describe(self) -> dict[str, Any]:
        """JSON-able status for ``list_boards``."""
        f = self.faults.current()
        return {
            "board": self.id,
            "kind": self.kind,
            "sensors": sorted(self.sensors),
            "reads": self.reads,
            "fault": None if f is None else f.describe(),
        }
