"""The thesis's AHRS (e11, thesis ch. 7.1.2): a Kalman filter whose state is the quaternion.

- state q (scalar first, body -> reference), P;
- predict with the gyroscope in the transition (eqs. 7.3-7.4): ``F = I + dt/2 Omega(w)``
  (``hera.estimation.quat_omega``, the body-rate form for our quaternion convention; the
  thesis writes the transposed matrix for its convention), ``Q = q_var I`` per step;
- observe ``z = q_am``, the quaternion the accelerometer and magnetometer give together
  (eqs. 7.1-7.2, :func:`.frames.triad_quat`), ``H = I``, ``R = r_var I`` per step;
- the predicted quaternion's sign is flipped so that ``q_am . q^- > 0`` (eq. 7.5), and the
  estimate is normalised after each step (the Taylor expansion of F does not keep its
  norm).

Its variances are the thesis's (sigma_Q^2 = 1e-3, sigma_R^2 = 1e-2, "defined by
trial-and-error"). It has no bias state and no gating: a linear acceleration or a magnetic
disturbance goes straight into ``z``. Units: rad/s, m/s^2, any magnetometer unit.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hera.estimation import ExtendedKalmanFilter, Observations, align_sign, quat_omega
from hera.models.ahrs.frames import Reference, triad_quat

_H = np.eye(4)


def _f(x: np.ndarray, dt: float, w: Any) -> np.ndarray:
    return _F(x, dt, w) @ x


def _F(x: np.ndarray, dt: float, w: Any) -> np.ndarray:
    return np.eye(4) + 0.5 * dt * quat_omega(w)


class ThesisAhrs:
    """The filter of thesis eqs. 7.1-7.5 (see module docstring)."""

    def __init__(self, ref: Reference, q_var: float = 1e-3, r_var: float = 1e-2) -> None:
        if not (q_var > 0 and r_var > 0):
            raise ValueError(f"q_var and r_var must be > 0, got {q_var!r}, {r_var!r}")
        self.ref = ref
        self.q_var, self.r_var = float(q_var), float(r_var)
        self.ekf: ExtendedKalmanFilter | None = None
        self.t: float | None = None
        self._w = np.zeros(3)
        self.skipped = 0

    @property
    def q(self) -> np.ndarray:
        """The estimate (unit quaternion); identity before the first sample."""
        return np.array((1.0, 0.0, 0.0, 0.0)) if self.ekf is None else self.ekf.x

    def step(self, t: float, acc: Any, gyro: Any, mag: Any) -> bool:
        """One predict (with the previous sample's rate over the time since it) and update
        (with this sample's q_am); False if the sample was not used."""
        z = triad_quat(acc, mag, self.ref) if mag is not None else None
        if z is None:
            self.skipped += 1
            return False
        if self.ekf is None:
            self.ekf = ExtendedKalmanFilter(
                z, np.eye(4) * self.r_var, _f, np.eye(4) * self.q_var, _F
            )
            self.t, self._w = t, np.asarray(gyro, dtype=np.float64)
            return True
        dt = t - self.t  # type: ignore[operator]
        if dt < 0:
            self.skipped += 1
            return False
        ekf = self.ekf
        ekf.predict(dt, self._w)
        self.t, self._w = t, np.asarray(gyro, dtype=np.float64)
        x = ekf.x
        if float(z @ x) < 0.0:  # eq. 7.5: the prediction on the measurement's side
            ekf.reset(-x, ekf.P)
        obs = Observations()
        obs.add("q_am", align_sign(z, ekf.x), H=_H, R=self.r_var)
        ekf.update(obs)
        x = ekf.x
        ekf.reset(x / np.linalg.norm(x), ekf.P)
        return True
