"""A simulated VL53L1 on a carrier board moved by the world's scenario.

It implements :class:`hera.nodes.tof.driver.TofDriver` and
:class:`hera.nodes.driver.SimulatedBoard`, and takes the board faults of
:mod:`hera.nodes.fault_model` on its four values (sensors ``distance``, ``ambient``,
``signal``, ``status``: a fault without ``sensor`` hits all four, e.g. ``stuck`` freezes the
whole reading; ``{"fault": "bias", "sensor": "distance", "value": 0.02}`` offsets the range).
Readings are a pure function of (seed, scenario, reading times): see :mod:`hera.nodes.noise`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

from hera.nodes import geometry as gm
from hera.nodes.fault_model import FaultState
from hera.nodes.noise import KeyedRandom
from hera.nodes.tof import driver as d
from hera.nodes.tof.driver import TofReading
from hera.nodes.tof.model import TofModel
from hera.nodes.world import Scenario, State, state_at, state_of

SENSORS = {"distance": 1, "ambient": 1, "signal": 1, "status": 1}
_FIXED = 128.0  # the chip's rates are 9.7 fixed point: 1/128 Mcps


def true_range(state_position: gm.Vec3, q: gm.Quat, mount: tuple[float, float]) -> float | None:
    """Distance (m) along the board's -z axis from the sensor at ``mount`` (x, y on the board)
    to the desk plane z = 0, for a board at ``state_position`` with orientation ``q``; None
    when the sensor does not look down at the desk."""
    p = gm.add(state_position, gm.rotate(q, (mount[0], mount[1], 0.0)))
    u = gm.rotate(q, (0.0, 0.0, -1.0))
    if u[2] > -1e-6 or p[2] <= 0.0:
        return None
    return -p[2] / u[2]


class SimVl53l1:
    """One simulated VL53L1 at ``mount`` = (x, y) m on the carrier. ``clock`` gives the epoch
    time a ranging completes (default ``time.time``)."""

    kind = "vl53l1"
    sensors = SENSORS

    def __init__(
        self,
        board_id: str,
        scenario: Scenario,
        epoch: float,
        model: TofModel,
        mount: tuple[float, float],
        seed: int,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.id = board_id
        self.scenario, self.epoch, self.model = scenario, float(epoch), model
        self.mount = (float(mount[0]), float(mount[1]))
        self.seed = int(seed)
        self.clock = clock
        self.rand = KeyedRandom(self.seed)
        c = self.rand.constant("range")
        self.offset = model.offset if model.offset is not None else c.gauss(0, model.offset_sigma_m)
        self.scale = model.scale if model.scale is not None else c.gauss(0, model.scale_sigma)
        self.faults = FaultState(SENSORS)
        self.reads = 0

    # -- SimulatedBoard ------------------------------------------------------------------------
    def truth(self, t: float) -> State:
        return state_at(self.scenario, self.epoch, t)

    def rest_truth(self) -> State:
        return state_of(self.scenario.rest_motion(), self.epoch)

    def true_range(self, t: float) -> float | None:
        """The noise-free range (m) at epoch time ``t``."""
        m = self.scenario.motion(t - self.epoch)
        return true_range(m.position, m.orientation, self.mount)

    # -- TofDriver -------------------------------------------------------------------------------
    def read_ranging(self) -> TofReading:
        t = self.clock() - self.model.budget_ms / 2000.0  # the middle of the ranging
        rng = self.rand.rng("range", t)
        for sensor in SENSORS:
            self.faults.before_read(sensor, rng)
        dist, ambient, signal, status = self._reading(t, rng)
        values = (dist, ambient, signal, float(status))
        out = [
            self.faults.after_read(s, (v,), rng)[0] for s, v in zip(SENSORS, values, strict=True)
        ]
        self.reads += 1
        code = int(round(out[3]))
        return TofReading(t, out[0], out[1], out[2], min(255, max(0, code)))

    def _reading(self, t: float, rng: Any) -> tuple[float, float, float, int]:
        md = self.model
        m = self.scenario.motion(t - self.epoch)
        ambient = max(0.0, getattr(self.scenario, "ambient", 0.3))
        ambient = _fixed(ambient * (1.0 + rng.gauss(0.0, md.ambient_noise)))
        d_true = true_range(m.position, m.orientation, self.mount)
        if d_true is None or d_true > md.max_range_m:
            return _mm(rng.uniform(0.0, md.max_range_m)), ambient, _fixed(0.0), d.OUT_OF_BOUNDS
        u = gm.rotate(m.orientation, (0.0, 0.0, -1.0))
        refl = getattr(self.scenario, "reflectance", 0.5)
        signal = md.signal_k * refl * max(0.0, -u[2]) / (d_true * d_true)
        signal = _fixed(max(0.0, signal * (1.0 + rng.gauss(0.0, md.signal_noise))))
        sigma = md.sigma(d_true)
        dist = (1.0 + self.scale) * d_true + self.offset + rng.gauss(0.0, sigma)
        status = d.RANGE_VALID
        if signal < md.min_signal_mcps:
            status = d.SIGNAL_FAIL
        elif sigma > md.sigma_limit_m:
            status = d.SIGMA_FAIL
        elif d_true < md.min_range_m:
            status, dist = d.MIN_RANGE_CLIPPED, md.min_range_m
        draw = rng.random()
        if status == d.RANGE_VALID and draw < md.invalid_prob:
            status = rng.choice((d.SIGMA_FAIL, d.SIGNAL_FAIL, d.WRAP_TARGET_FAIL))
            dist = max(0.0, dist + rng.choice((-1.0, 1.0)) * rng.uniform(0.02, 0.5))
        elif status == d.RANGE_VALID and draw < md.invalid_prob + md.outlier_prob:
            err = rng.uniform(md.outlier_min_m, md.outlier_max_m)
            dist = max(md.min_range_m, dist + rng.choice((-1.0, 1.0)) * err)
        return _mm(dist), ambient, signal, status

    def describe(self) -> dict[str, Any]:
        """JSON-able status for the ``board`` verb's listing."""
        f = self.faults.current()
        return {
            "board": self.id,
            "kind": self.kind,
            "mount": list(self.mount),
            "sensors": sorted(SENSORS),
            "reads": self.reads,
            "fault": None if f is None else f.describe(),
        }


def _mm(x: float) -> float:
    return round(x * 1000.0) / 1000.0


def _fixed(x: float) -> float:
    return round(x * _FIXED) / _FIXED if math.isfinite(x) else x
