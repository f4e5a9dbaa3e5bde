"""The tilt filters of seed 003 on one interface: ``step(dt, g_y, b_gyro, acc)``.

=========  ====================================================================================
filter     what
=========  ====================================================================================
split      the seed's own (Table 8): Kalman evolution (A = I: only theta is moved, P += Q)
           and EKF correction, written out on scalars the way the seed optimises it for a
           Cortex-M0 (P H^T computed once and kept)
ekf        :class:`hera.estimation.ExtendedKalmanFilter` on eqs. 25-26
ukf        :class:`hera.estimation.UnscentedKalmanFilter` on eqs. 25-26, the seed's
           appendix A parameters (alpha 1, beta 2, kappa 3 - n)
bias       an EKF with b_gyro as a third state (a random walk), the gyroscope raw as input
wheels     the bias filter with the robot's model and its wheel encoders
           (:mod:`hera.models.tilt.wheels`)
=========  ====================================================================================

split and ekf compute the same numbers (to rounding); ukf differs where the measurement's
non-linearity shows across the state's spread. Units: rad, m/s^2, rad/s, s.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from hera.estimation import (
    ExtendedKalmanFilter,
    NoiseRate,
    Observations,
    UnscentedKalmanFilter,
    gate_threshold,
)
from hera.models.tilt.equations import F2, F3, F4, H, f2, f2_batch, f3, f4, h, h_batch

FILTERS = ("split", "ekf", "ukf", "bias", "wheels")


class SplitFilter:
    """Seed 003 Table 8 on scalars: state [theta, g], P a 2x2 covariance."""

    def __init__(self, x0: Sequence[float], P0: np.ndarray, q: Sequence[float], r: float):
        self.th, self.g = float(x0[0]), float(x0[1])
        self.p00, self.p01, self.p11 = float(P0[0, 0]), float(P0[0, 1]), float(P0[1, 1])
        self.q0, self.q1, self.r = float(q[0]), float(q[1]), float(r)

    @property
    def x(self) -> np.ndarray:
        return np.array([self.th, self.g])

    @property
    def P(self) -> np.ndarray:
        return np.array([[self.p00, self.p01], [self.p01, self.p11]])

    def widen(self, var: float) -> None:
        """Add ``var`` (rad^2) to theta's variance: a rotation nobody measured."""
        self.p00 += var

    def step(
        self,
        dt: float,
        g_y: float,
        b_gyro: float,
        acc: Sequence[float],
        gate: float | None = None,
        r_scale: float = 1.0,
    ) -> bool:
        """Evolution then correction (Table 8), R scaled by ``r_scale``; False when the
        chi-square gate (a probability, 2 degrees of freedom) refuses the accelerometer (the
        evolution is kept)."""
        # Evolution: X = X + B U (only theta moves), P = A P A^T + Q = P + Q.
        self.th += (g_y - b_gyro) * dt
        self.p00 += self.q0 * dt
        self.p11 += self.q1 * dt
        p00, p01, p11 = self.p00, self.p01, self.p11
        s, c = math.sin(self.th), math.cos(self.th)
        g = self.g
        # H (eq. 26, state order [theta, g]) and the cached P H^T.
        h00, h01, h10, h11 = g * c, s, -g * s, c
        a00 = p00 * h00 + p01 * h01
        a01 = p00 * h10 + p01 * h11
        a10 = p01 * h00 + p11 * h01
        a11 = p01 * h10 + p11 * h11
        r = self.r * r_scale
        s00 = h00 * a00 + h01 * a10 + r
        s01 = h00 * a01 + h01 * a11
        s11 = h10 * a01 + h11 * a11 + r
        det = s00 * s11 - s01 * s01
        e0, e1 = acc[0] - g * s, acc[1] - g * c
        nis = (s11 * e0 * e0 - 2.0 * s01 * e0 * e1 + s00 * e1 * e1) / det
        if gate is not None and nis > gate_threshold(gate, 2):
            return False
        i00, i01, i11 = s11 / det, -s01 / det, s00 / det
        k00 = a00 * i00 + a01 * i01
        k01 = a00 * i01 + a01 * i11
        k10 = a10 * i00 + a11 * i01
        k11 = a10 * i01 + a11 * i11
        self.th += k00 * e0 + k01 * e1
        self.g += k10 * e0 + k11 * e1
        # P = (I - K H) P
        m00, m01 = 1.0 - (k00 * h00 + k01 * h10), -(k00 * h01 + k01 * h11)
        m10, m11 = -(k10 * h00 + k11 * h10), 1.0 - (k10 * h01 + k11 * h11)
        n00, n01 = m00 * p00 + m01 * p01, m00 * p01 + m01 * p11
        n11 = m10 * p01 + m11 * p11
        self.p00, self.p01, self.p11 = n00, n01, n11
        return True


class OnLibrary:
    """A filter kept in ``self.f``, a :mod:`hera.estimation` filter: its state, covariance
    and the widening of theta (state 0) after lost samples."""

    f: ExtendedKalmanFilter | UnscentedKalmanFilter

    @property
    def x(self) -> np.ndarray:
        return self.f.x

    @property
    def P(self) -> np.ndarray:
        return self.f.P

    def widen(self, var: float) -> None:
        """Add ``var`` (rad^2) to theta's variance: a rotation nobody measured."""
        P = self.f.P.copy()
        P[0, 0] += var
        self.f.reset(self.f.x, P)


class LibraryFilter(OnLibrary):
    """The EKF, UKF or bias filter on :mod:`hera.estimation` (see the module docstring)."""

    def __init__(
        self,
        kind: str,
        x0: Sequence[float],
        P0: np.ndarray,
        q: Sequence[float],
        r: float,
        ukf: Sequence[float] = (1.0, 2.0, None),
    ) -> None:
        self.kind = kind
        self.r = float(r)
        q = list(q)
        if kind == "bias":
            f, F = (f4, F4) if len(x0) == 4 else (f3, F3)
            self.f = ExtendedKalmanFilter(x0, P0, f, NoiseRate(q), F)
        elif kind == "ekf":
            self.f = ExtendedKalmanFilter(x0, P0, f2, NoiseRate(q), F2)
        elif kind == "ukf":
            alpha, beta, kappa = ukf
            self.f = UnscentedKalmanFilter(
                x0,
                P0,
                f2_batch,
                NoiseRate(q),
                alpha=alpha,
                beta=beta,
                kappa=3.0 - len(x0) if kappa is None else kappa,
                batched=True,
            )
        else:
            raise ValueError(f"unknown filter {kind!r}: use one of {', '.join(FILTERS)}")

    def step(
        self,
        dt: float,
        g_y: float,
        b_gyro: float,
        acc: Sequence[float],
        gate: float | None = None,
        r_scale: float = 1.0,
    ) -> bool:
        """Predict with the gyroscope (and the calibrated bias, but for ``bias``), then
        correct with the accelerometer (R scaled by ``r_scale``); False when the gate
        refuses it."""
        u = g_y if self.kind == "bias" else (g_y, b_gyro)
        self.f.predict(dt, u)
        obs = Observations()
        if self.kind == "ukf":
            obs.add("acc", acc, h=h_batch, R=self.r * r_scale, vectorized=True)
        else:
            obs.add("acc", acc, h=h, jacobian=H, R=self.r * r_scale)
        return bool(self.f.update(obs, gate=gate).accepted)
