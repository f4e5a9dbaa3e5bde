"""The thermometer (a simulated sensor) and the filter that smooths it."""

import math
import random
import time

import numpy as np

from hera.estimation import KalmanFilter, Observations
from hera.fusion import FusionMeasure
from hera.measure import Measure, Reading
from hera.schema import Setting, Table, number


def room(world, t):
    """The true room temperature (degC) at epoch time t: a slow sine."""
    mean, swing = world.get("mean_degc", 21.0), world.get("swing_degc", 2.0)
    return mean + swing * math.sin(2 * math.pi * t / world.get("cycle_s", 60.0))


class Thermo(Measure):
    """A thermometer: the room's temperature plus white noise."""

    name = "thermo"
    period = 0.1
    columns = ("temperature [degC]",)
    arguments = Table("thermo args", [Setting("noise", number(above=0), 0.3, "degC")])

    def init(self, args, ctx):
        args = self.prepare_args(args)
        super().init(args, ctx)
        self.noise = args["noise"]
        self.rng = random.Random(ctx.seed)

    def measure(self):
        t = time.time()
        return Reading([room(self.ctx.world, t) + self.rng.gauss(0, self.noise)], t)


class ThermoModel:
    """A Kalman filter on [temperature, rate]; dt from the samples' times (never a clock)."""

    inputs = ("thermo",)
    columns = ("temperature [degC]", "rate [degC/s]")

    def __init__(self, noise: float = 0.3, jerk: float = 0.01):
        self.noise, self.jerk, self.t, self.rejected = noise, jerk, None, 0
        # F(dt) and Q(dt) as methods, not lambdas: the model's checkpoint pickles it
        self.kf = KalmanFilter([20.0, 0.0], np.diag([100.0, 1.0]), self.F, self.Q)

    @staticmethod
    def F(dt):
        return np.array([[1.0, dt], [0.0, 1.0]])

    def Q(self, dt):
        return self.jerk * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])

    def process(self, sample):
        if self.t is not None and sample.t > self.t:
            self.kf.predict(sample.t - self.t)
        self.t = sample.t
        obs = Observations()
        obs.add("thermo", [sample.values[0]], H=[[1.0, 0.0]], R=self.noise**2)
        self.rejected += len(self.kf.update(obs, gate=0.9999).rejected)
        return True

    def estimate(self):
        return None if self.t is None else (self.t, [float(v) for v in self.kf.x])

    def counters(self):
        return {"rejected": self.rejected}


class ThermoFilter(FusionMeasure):
    """``thermo_filter``: the room's temperature and its rate of change."""

    name = "thermo_filter"
    model_class = ThermoModel
    columns = ThermoModel.columns
