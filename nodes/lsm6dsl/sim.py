"""A simulated LSM6DSL on a body moved by the world's scenario (error model:
:mod:`hera.nodes.lsm6dsl.model`).

It implements :class:`hera.nodes.lsm6dsl.driver.Lsm6dslDriver` and
:class:`hera.nodes.driver.SimulatedBoard`, and takes the board faults of
:mod:`hera.nodes.fault_model` (sensors ``acc`` and ``gyro``). Readings are a pure function of
(seed, scenario, sample times).

Sample times (``stamps``): ``"read"`` makes a sample at each read, stamped then (what a
fake clock in a test steps through); ``"chip"`` samples on the chip's own clock, as a real
LSM6DSL does: at epoch + phase + k / ODR, the phase drawn from the seed. A read then gives
the oldest sample not read yet and says in ``pending`` how many more are made (a FIFO of
``FIFO_SAMPLES``; older ones are lost); a read before the next sample waits for it when it
is due within half a period (``sleep``), as the I2C driver waits for data-ready, and is a
dropout otherwise. So the samples a live run gets do not depend on when its node got round
to reading them.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

from hera.nodes import geometry as gm
from hera.nodes.driver import NoReading
from hera.nodes.fault_model import FaultState
from hera.nodes.geometry import IDENTITY, Vec3
from hera.nodes.imu_model import ideal_acc
from hera.nodes.lsm6dsl.driver import ODRS_HZ, ImuReading
from hera.nodes.lsm6dsl.model import ImuModel
from hera.nodes.noise import KeyedRandom, RandomWalk
from hera.nodes.world import G, Scenario, State, state_at, state_of

SENSORS = {"acc": 3, "gyro": 3}
FIFO_SAMPLES = 64
"""Samples the simulated chip keeps for a late reader (``stamps = "chip"``)."""
STAMPS = ("read", "chip")


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
        stamps: str = "read",
        sleep: Callable[[float], None] | None = None,
    ) -> None:
        if odr_hz not in ODRS_HZ:
            raise ValueError(f"LSM6DSL output data rate must be one of {ODRS_HZ} Hz, got {odr_hz}")
        if stamps not in STAMPS:
            raise ValueError(f"LSM6DSL stamps must be one of {STAMPS}, got {stamps!r}")
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
        self.stamps, self.sleep = stamps, sleep
        self.phase = self.rand.constant("odr_phase").uniform(0.0, 1.0 / self.odr_hz)
        self.pending = 0
        self.lost = 0
        """Samples the chip's FIFO overran (``stamps = "chip"``)."""
        self._next: int | None = None

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
    def _chip_time(self, now: float) -> float:
        """The time of the oldest sample not read yet (``stamps = "chip"``); see the module
        docstring. NoReading when none is made and none is due within half a period."""
        period = 1.0 / self.odr_hz
        base = self.epoch + self.phase
        made = math.floor((now - base) / period + 1e-9)
        if self._next is None:
            self._next = made
        if made < self._next:
            wait = base + self._next * period - now
            if self.sleep is None or wait > period / 2.0:
                raise NoReading(f"no new sample: the next is due in {wait * 1e3:.1f} ms")
            self.sleep(max(0.0, wait))
            made = self._next
        if made - self._next >= FIFO_SAMPLES:
            self.lost += made - self._next - FIFO_SAMPLES + 1
            self._next = made - FIFO_SAMPLES + 1
        k = self._next
        self._next = k + 1
        self.pending = made - k
        return base + k * period

    def read_imu(self) -> ImuReading:
        t = self.clock()
        if self.stamps == "chip":
            t = self._chip_time(t)
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
            "stamps": self.stamps,
            "fifo_lost": self.lost,
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
