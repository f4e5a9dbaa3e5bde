"""Variants of the tilt ``bias`` filter tried against issue 12's drift target, offline.

The target: with the gyroscope bias drifting by 0.5 deg/s over a minute, the bias filter's
tilt within 1 deg over the whole run. ``python tests/support/tilt_variants.py [SEEDS]``
prints each variant's largest error (deg) in each world of the drift scenario (the test's
``DRIFT``) and the worst; ``python tests/support/tilt_variants.py search N [SEEDS]`` draws
N settings of the filter (and of the variants' extra states) at random and prints the best
worst world found; ``python tests/support/tilt_variants.py worlds [SEEDS [NAME]]`` prints the
application's bias filter and the EKF told the true bias (``true_b``) in other drift worlds
(sample rates, accelerometer offsets and scale errors, wheels whose motor torque pushes
back on the body; NAME: only the worlds whose name holds it). The figures are quoted in
the README ("2-D tilt of a self-balancing robot"); none of these variants is the
application's filter (:mod:`hera.models.tilt`).

Variants (all on eqs. 25-26 with the bias a state, R scaled with the rate and angular
acceleration as in :class:`hera.models.tilt.tilt.Tilt2D`; SI units):

- ``lever``: the board's own acceleration about the axle taken out of the reading first,
  a_X + s theta'', a_Z + s theta'^2 (s the board's height over the axle, m; theta' the
  bias-corrected rate, theta'' its difference over the sample interval);
- ``singer``: the wheels' horizontal acceleration a_w a state, a first-order Gauss-Markov
  process (Singer) of spread sigma_a (m/s^2) and time constant tau (s); the reading is
  a_X = g sin(theta) - a_w cos(theta), a_Z = g cos(theta) + a_w sin(theta);
- ``velocity``: a_w the derivative of a bounded velocity v: v' = a_w,
  a_w' = -a_w / tau_a - v / (tau_a tau_v) + w (a robot that keeps its station);
- ``drift``: the bias's rate of drift c a fourth state, b' = c (an integrated random walk);
- ``complementary``: fixed gains instead of a Kalman filter on the accelerometer's angle,
  type 2 (theta, b: natural frequency w_n, damping zeta) or type 3 (theta, b, c: a triple
  pole at -w_n), each correction weighted by 1 / the same R scale.
"""

from __future__ import annotations

import math
import random
import sys
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from appsim import imu_samples, run_model, with_true_bias

from hera.application import EvalOptions
from hera.models.tilt.app import robot_truth, score_tilt
from hera.store import Sample

DRIFT = {"gyro_ramp_dps_s": 0.5 / 60.0, "ramp_start_s": 12.0, "ramp_s": 60.0}
COLUMNS = ("theta [rad]", "g_xz [m/s^2]", "b_gyro [rad/s]")


class Variant:
    """The bias EKF with the optional states of the module docstring."""

    columns = COLUMNS

    def __init__(
        self,
        sigma_acc: float = 1.0,
        q_theta: float = 3e-6,
        q_g: float = 1e-4,
        q_bias: float = 1e-6,
        q_drift: float = 0.0,
        r_rate: float | None = 0.2,
        r_accel: float | None = 0.5,
        lever_m: float = 0.0,
        singer: tuple[float, float] | None = None,
        velocity: tuple[float, float, float] | None = None,
    ) -> None:
        self.r = sigma_acc**2
        self.q = [q_theta, q_g, q_bias]
        self.q_drift, self.r_rate, self.r_accel = q_drift, r_rate, r_accel
        self.lever, self.singer, self.velocity = lever_m, singer, velocity
        self.x: np.ndarray | None = None
        self.t = 0.0
        self.last: float | None = None

    def _begin(self, t: float, v: Sequence[float]) -> None:
        x = [math.atan2(v[0], v[1]), math.hypot(v[0], v[1]), v[3]]
        var, q = [0.03, 0.25, 1e-4], list(self.q)
        self.i_c = self.i_a = self.i_v = None
        if self.q_drift > 0:
            self.i_c = len(x)
            x, var, q = x + [0.0], var + [self.q_drift * 100.0], q + [self.q_drift]
        if self.singer:
            self.i_a = len(x)
            x, var, q = x + [0.0], var + [self.singer[0] ** 2], q + [0.0]
        if self.velocity:
            sa, ta, tv = self.velocity
            self.i_v = len(x)
            x += [0.0, 0.0]
            var += [sa * sa * ta * tv, sa * sa]
            q += [0.0, 2.0 * sa * sa / ta]
        self.x, self.P, self.qd = np.array(x), np.diag(var), np.array(q)
        self.t, self.last = t, None

    def process(self, s: Sample) -> bool:
        v = s.values
        if self.x is None:
            if v[4] < 2:
                return False
            self._begin(s.t, v)
            return True
        dt, self.t = s.t - self.t, s.t
        x, n = self.x, len(self.x)
        rate = v[2] - x[2]
        alpha = 0.0 if self.last is None else (rate - self.last) / dt
        scale = 1.0 if self.r_rate is None else 1.0 + (rate / self.r_rate) ** 2
        if self.r_accel is not None and self.last is not None:
            scale += (alpha / self.r_accel) ** 2
        self.last = rate
        F, xn, Q = np.eye(n), x.copy(), np.diag(self.qd * dt)
        F[0, 2], xn[0] = -dt, x[0] + rate * dt
        if self.i_c is not None:
            xn[2] += x[self.i_c] * dt
            F[2, self.i_c] = dt
        if self.i_a is not None and self.singer:
            sa, tau = self.singer
            ph = math.exp(-dt / tau)
            xn[self.i_a], F[self.i_a, self.i_a] = ph * x[self.i_a], ph
            Q[self.i_a, self.i_a] = sa * sa * (1.0 - ph * ph)
        if self.i_v is not None and self.velocity:
            _, ta, tv = self.velocity
            i = self.i_v
            xn[i] = x[i] + x[i + 1] * dt
            xn[i + 1] = x[i + 1] - dt * x[i + 1] / ta - dt * x[i] / (ta * tv)
            F[i, i + 1], F[i + 1, i + 1], F[i + 1, i] = dt, 1.0 - dt / ta, -dt / (ta * tv)
        P, x = F @ self.P @ F.T + Q, xn
        a_x, a_z = v[0] + self.lever * alpha, v[1] + self.lever * rate * rate
        th, g = x[0], x[1]
        sn, cs = math.sin(th), math.cos(th)
        hx = np.array([g * sn, g * cs])
        H = np.zeros((2, n))
        H[0, 0], H[0, 1], H[1, 0], H[1, 1] = g * cs, sn, -g * sn, cs
        j = self.i_a if self.i_a is not None else (None if self.i_v is None else self.i_v + 1)
        if j is not None:
            a = x[j]
            hx += np.array([-a * cs, a * sn])
            H[0, j], H[1, j] = -cs, sn
            H[0, 0] += a * sn
            H[1, 0] += a * cs
        R = np.eye(2) * self.r * scale
        K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
        self.x = x + K @ (np.array([a_x, a_z]) - hx)
        M = np.eye(n) - K @ H
        self.P = M @ P @ M.T + K @ R @ K.T  # Joseph form
        return True

    def estimate(self) -> tuple[float, list[float]] | None:
        if self.x is None:
            return None
        return self.t, [float(self.x[0]), float(self.x[1]), float(self.x[2])]


class Complementary:
    """A fixed-gain tilt and bias loop (module docstring), type 2 or 3, natural frequency
    ``wn`` (rad/s)."""

    columns = COLUMNS

    def __init__(self, wn: float = 0.3, type3: bool = False, zeta: float = 0.707) -> None:
        self.wn, self.type3, self.zeta = wn, type3, zeta
        self.th: float | None = None
        self.last: float | None = None

    def process(self, s: Sample) -> bool:
        v = s.values
        if self.th is None:
            if v[4] < 2:
                return False
            self.th, self.b, self.c, self.t = math.atan2(v[0], v[1]), v[3], 0.0, s.t
            return True
        dt, self.t = s.t - self.t, s.t
        rate = v[2] - self.b
        scale = 1.0 + (rate / 0.2) ** 2
        if self.last is not None:
            scale += ((rate - self.last) / dt / 0.5) ** 2
        self.last = rate
        self.th += rate * dt
        e = (math.atan2(v[0], v[1]) - self.th) * dt / scale
        w = self.wn
        if self.type3:
            self.th += 3.0 * w * e
            self.b -= 3.0 * w * w * e
            self.c -= w**3 * e
            self.b += self.c * dt
        else:
            self.th += 2.0 * self.zeta * w * e
            self.b -= w * w * e
        return True

    def estimate(self) -> tuple[float, list[float]] | None:
        return None if self.th is None else (self.t, [self.th, 9.81, self.b])


VARIANTS: dict[str, Mapping[str, Any]] = {
    "bias (the application's)": {},
    "drift state, chip's walk": {"q_bias": 1e-8, "q_drift": 3.5e-10},
    "lever 0.18 m": {"lever_m": 0.18},
    "singer 0.15 m/s^2, 1 s": {"singer": (0.15, 1.0)},
    "singer 0.3 m/s^2, 5 s": {"singer": (0.3, 5.0)},
    "singer + drift state": {"singer": (0.15, 3.0), "q_bias": 1e-7, "q_drift": 3.5e-10},
    "velocity 0.5, 0.5 s, 5 s": {"velocity": (0.5, 0.5, 5.0)},
    "velocity 0.3, 1 s, 10 s": {"velocity": (0.3, 1.0, 10.0)},
}
COMPLEMENTARY = {
    "complementary type 2, 0.3": {"wn": 0.3},
    "complementary type 2, 0.4": {"wn": 0.4},
    "complementary type 3, 0.2": {"wn": 0.2, "type3": True},
}


OTHER_WORLDS: dict[str, tuple[float, Mapping[str, Any], Mapping[str, Any]]] = {
    # name: (output data rate Hz, world keys, IMU model keys besides DRIFT)
    "26 Hz (the test's)": (26.0, {}, {}),
    "52 Hz": (52.0, {}, {}),
    "12.5 Hz, 10 s on the stand": (12.5, {"still_s": 10.0}, {}),
    "acc offset 5 mg, scale 2 %": (26.0, {}, {"acc_bias_sigma": 0.005, "acc_scale_sigma": 0.02}),
    "acc trimmed (no offset)": (26.0, {}, {"acc_bias": [0.0, 0.0, 0.0]}),
    "wheels k 0.25, r 4 cm": (26.0, {"reaction_k": 0.25, "wheel_radius_m": 0.04}, {}),
    "wheels k 0.5, r 4 cm": (26.0, {"reaction_k": 0.5, "wheel_radius_m": 0.04}, {}),
}
"""At 12.5 Hz the 100 calibration samples take 8 s: the default 8 s stand is too short."""


def worlds(
    seeds: Sequence[int],
    odr: float = 26.0,
    keys: Mapping[str, Any] | None = None,
    model: Mapping[str, Any] | None = None,
    true_bias: bool = False,
) -> list[tuple[list[tuple[float, Sample]], Any]]:
    """(stream, truth) of the drift world for each seed; with ``true_bias`` the samples
    carry the board's true bias (see :func:`appsim.with_true_bias`)."""
    out = []
    for seed in seeds:
        world = {"scenario": "balancing", "seed": seed, **dict(keys or {})}
        samples, board = imu_samples(world, 80.0, seed, odr, {**DRIFT, **dict(model or {})})
        if true_bias:
            samples = with_true_bias(samples, board)
        out.append(([(s.t, s) for s in samples], robot_truth(world)))
    return out


def max_errors(make: Any, data: Sequence[tuple[list[tuple[float, Sample]], Any]]) -> list[float]:
    """The largest tilt error (deg) of a fresh ``make()`` in each world."""
    out = []
    for stream, truth in data:
        got = score_tilt(run_model(make(), stream, None), truth, EvalOptions(after=0.0))
        out.append(float(got["max_deg"] or math.nan))
    return out


def main(argv: Sequence[str]) -> int:
    if argv and argv[0] == "search":
        count = int(argv[1]) if len(argv) > 1 else 50
        data = worlds(range(int(argv[2]) if len(argv) > 2 else 10))
        rng, best = random.Random(1), (math.inf, {})
        for _ in range(count):
            cfg: dict[str, Any] = {
                "sigma_acc": 10 ** rng.uniform(-0.5, 0.5),
                "q_theta": 10 ** rng.uniform(-7.0, -4.5),
                "q_bias": 10 ** rng.uniform(-9.0, -5.0),
                "q_drift": rng.choice([0.0, 10 ** rng.uniform(-11.0, -8.5)]),
            }
            if rng.random() < 0.5:
                cfg["singer"] = (10 ** rng.uniform(-1.3, -0.3), 10 ** rng.uniform(-0.5, 1.0))
            worst = max(max_errors(lambda c=cfg: Variant(**c), data))
            if worst < best[0]:
                best = (worst, cfg)
                print(f"{worst:.3f} {cfg}", flush=True)
        print(f"best worst world of {count}: {best[0]:.3f} deg")
        return 0
    if argv and argv[0] == "worlds":
        from hera.models.tilt.tilt import Tilt2D

        seeds = range(int(argv[1]) if len(argv) > 1 else 10)
        print(f"{'world':>28} {'filter':>6} " + " ".join(f"{s:>5}" for s in seeds) + "  worst")
        for name, (odr, keys, model) in OTHER_WORLDS.items():
            if len(argv) > 2 and argv[2] not in name:
                continue
            for label, kind, true_bias in (("bias", "bias", False), ("true_b", "ekf", True)):
                data = worlds(seeds, odr, keys, model, true_bias)
                errs = max_errors(lambda k=kind: Tilt2D(kind=k), data)
                cells = " ".join(f"{e:5.2f}" for e in errs)
                print(f"{name:>28} {label:>6} {cells}  {max(errs):5.2f}")
        return 0
    seeds = range(int(argv[0]) if argv else 10)
    data = worlds(seeds)
    print(f"{'variant':>28} " + " ".join(f"{s:>5}" for s in seeds) + "  worst")
    rows = [(k, lambda c=c: Variant(**c)) for k, c in VARIANTS.items()]
    rows += [(k, lambda c=c: Complementary(**c)) for k, c in COMPLEMENTARY.items()]
    for name, make in rows:
        errs = max_errors(make, data)
        print(f"{name:>28} " + " ".join(f"{e:5.2f}" for e in errs) + f"  {max(errs):5.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
