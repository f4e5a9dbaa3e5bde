"""A simulated LSM6DSL on a body moved by the world's scenario (error model:
:mod:`hera.nodes.lsm6dsl.model`).

It implements :class:`hera.nodes.lsm6dsl.driver.Lsm6dslDriver` and
:class:`hera.nodes.driver.SimulatedBoard`, and takes the board faults of
:mod:`hera.nodes.fault_model` (sensors ``acc`` and ``gyro``). Readings are a pure function of
(seed, scenario, reading times).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

from hera.nodes import geometry as gm
from hera.nodes.fault_model import FaultState
from hera.nodes.geometry import IDENTITY, Vec3
from hera.nodes.imu_model import ideal_acc
from hera.nodes.lsm6dsl.driver import ODRS_HZ, ImuReading
from hera.nodes.lsm6dsl.model import ImuModel
from hera.nodes.noise import KeyedRandom, RandomWalk
from hera.nodes.world import G, Scenario, State, state_at, state_of

SENSORS = {"acc": 3, "gyro": 3}


class SimLsm6dsl:
    """Simulated LSM6DSL at output data rate ``odr_hz``; ``clock`` gives the epoch time of
    each read (default ``time.time``)."""

    kind = "lsm6dsl"
    sensors = SENSORS

    def __init__(
        self,
        board_id: str,
        scenario: Scenario,
        epoch: float,
        model: ImuModel,
        seed: int,
        odr_hz: float = 26.0,
        clock: Callable[[], float] = time.time,
    ) -> None:
        if odr_hz not in ODRS_HZ:
            raise ValueError(f"LSM6DSL output data rate must be one of {ODRS_HZ} Hz, got {odr_hz}")
        self.id = board_id
        self.scenario, self.epoch, self.model = scenario, float(epoch), model
        self.seed, self.odr_hz, self.clock = int(seed), float(odr_hz), clock
        self.rand = KeyedRandom(self.seed)
        self.acc_bias = self._const(model.acc_bias, "acc_bias", model.acc_bias_sigma)
        self.acc_scale = self._const(None, "acc_scale", model.acc_scale_sigma)
        self.gyro_bias = self._const(model.gyro_bias, "gyro_bias", model.gyro_bias_sigma)
        self.gyro_scale = self._const(None, "gyro_scale", model.gyro_scale_sigma)
        self.walks = [RandomWalk(self.seed, f"gyro{i}", model.gyro_drift) for i in range(3)]
        bw = math.sqrt(self.odr_hz / 2.0)
        self.acc_noise = model.acc_density * bw
        self.gyro_noise = model.gyro_density * bw
        self.faults = FaultState(SENSORS)
        self.reads = 0

    def _const(self, given: Vec3 | None, stream: str, sigma: float) -> Vec3:
        if given is not None:
            return tuple(float(v) for v in given)  # type: ignore[return-value]
        r = self.rand.constant(stream)
        return (r.gauss(0.0, sigma), r.gauss(0.0, sigma), r.gauss(0.0, sigma))

    # -- SimulatedBoard ------------------------------------------------------------------------
    def truth(self, t: float) -> State:
        return state_at(self.scenario, self.epoch, t)

    def rest_truth(self) -> State:
        return state_of(self.scenario.rest_motion(), self.epoch)

    def bias(self, t: float) -> Vec3:
        """The true gyroscope bias (deg/s) at epoch time ``t``: zero-rate level, random walk
        and drift (what a calibration should find)."""
        tau = t - self.epoch
        r = self.model.ramp(tau)
        return tuple(self.gyro_bias[i] + self.walks[i](tau) + r for i in range(3))  # type: ignore[return-value]

    # -- Lsm6dslDriver -------------------------------------------------------------------------
    def read_imu(self) -> ImuReading:
        t = self.clock()
        tau = t - self.epoch
        rng = self.rand.rng("imu", t)
        self.faults.before_read("acc", rng)
        self.faults.before_read("gyro", rng)
        md, sc = self.model, self.scenario
        motors = getattr(sc, "motors_on", None)
        shaking = motors(tau) if callable(motors) else True
        vib_a = sc.vibration_acc / G if shaking else 0.0
        vib_g = math.degrees(sc.vibration_gyro) if shaking else 0.0
        m = sc.motion(tau)
        a = ideal_acc(m, IDENTITY)
        w = mean_rate(sc.motion(tau - 1.0 / self.odr_hz).orientation, m.orientation, self.odr_hz)
        bias = self.bias(t)
        acc = tuple(
            (1.0 + self.acc_scale[i]) * a[i]
            + self.acc_bias[i]
            + rng.gauss(0.0, self.acc_noise)
            + (rng.gauss(0.0, vib_a) if vib_a else 0.0)
            for i in range(3)
        )
        gyro = tuple(
            (1.0 + self.gyro_scale[i]) * w[i]
            + bias[i]
            + rng.gauss(0.0, self.gyro_noise)
            + (rng.gauss(0.0, vib_g) if vib_g else 0.0)
            for i in range(3)
        )
        acc = _quantise(acc, md.acc_fs_g)
        gyro = _quantise(gyro, md.gyro_fs_dps)
        acc = self.faults.after_read("acc", acc, rng)
        gyro = self.faults.after_read("gyro", gyro, rng)
        self.reads += 1
        return ImuReading(t, acc, gyro)  # type: ignore[arg-type]

    def describe(self) -> dict[str, Any]:
        """JSON-able status for the ``board`` verb's listing."""
        f = self.faults.current()
        return {
            "board": self.id,
            "kind": self.kind,
            "odr_hz": self.odr_hz,
            "sensors": sorted(SENSORS),
            "reads": self.reads,
            "fault": None if f is None else f.describe(),
        }


def mean_rate(q0: gm.Quat, q1: gm.Quat, rate_hz: float) -> Vec3:
    """The mean body rate (deg/s) that turns orientation ``q0`` into ``q1`` in 1 / ``rate_hz``
    s: the rotation vector of q0^-1 q1 times the rate (exact for a turn about a fixed axis)."""
    w, x, y, z = gm.quat_mul(gm.conj(q0), q1)
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    n = math.sqrt(x * x + y * y + z * z)
    if n < 1e-15:
        return (0.0, 0.0, 0.0)
    k = 2.0 * math.atan2(n, w) / n * rate_hz * 180.0 / math.pi
    return (k * x, k * y, k * z)


def _quantise(v: tuple[float, ...], full_scale: float) -> tuple[float, ...]:
    lsb = full_scale / 32768.0
    return tuple(round(max(-full_scale, min(full_scale - lsb, x)) / lsb) * lsb for x in v)
