"""The tilt model of seed 003, sec. 4.3 (estimation mode), on numpy arrays.

State x = [theta, g] (theta_Y rad, g = |grav_XZ| m/s^2); command u = [g_Y, b_gyro] (rad/s);
measurement y = [a_X, a_Z] (m/s^2). With the sample interval dt (the seed's 1/26 s):

- evolution (eq. 25a): theta' = theta + (g_Y - b_gyro) dt, g' = g: linear, A = I,
  B = [[dt, -dt], [0, 0]];
- measurement (eq. 25b): a_X = g sin(theta), a_Z = g cos(theta);
- its Jacobian (eq. 26): the seed prints H = [[sin(theta), g cos(theta)], [cos(theta),
  -g sin(theta)]], whose columns are d/dg, d/dtheta; in our state order [theta, g] that is
  H = [[g cos(theta), sin(theta)], [-g sin(theta), cos(theta)]].

With the bias as a third state (the seed's "future studies may consider including continuous
estimation of the gyroscope bias"): x = [theta, g, b], u = g_Y, theta' = theta + (g_Y - b) dt,
b' = b (a random walk through Q), the same measurement with a zero third column.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def f2(x: np.ndarray, dt: float, u: Any) -> np.ndarray:
    """Eq. 25a: [theta + (g_Y - b_gyro) dt, g] for u = [g_Y, b_gyro]."""
    return np.array([x[0] + (u[0] - u[1]) * dt, x[1]])


def f2_batch(X: np.ndarray, dt: float, u: Any) -> np.ndarray:
    """Eq. 25a on a batch of states (rows), for the UKF's sigma points."""
    out = X.copy()
    out[:, 0] += (u[0] - u[1]) * dt
    return out


def F2(x: np.ndarray, dt: float, u: Any) -> np.ndarray:
    """The Jacobian of eq. 25a: the identity (A of Table 8)."""
    return np.eye(2)


def f3(x: np.ndarray, dt: float, u: Any) -> np.ndarray:
    """Eq. 25a with the bias as a state: [theta + (g_Y - b) dt, g, b] for u = g_Y."""
    return np.array([x[0] + (float(u) - x[2]) * dt, x[1], x[2]])


def F3(x: np.ndarray, dt: float, u: Any) -> np.ndarray:
    """The Jacobian of :func:`f3`."""
    return np.array([[1.0, 0.0, -dt], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])


def f4(x: np.ndarray, dt: float, u: Any) -> np.ndarray:
    """:func:`f3` with the bias drifting at a rate c, a fourth state: b' = b + c dt."""
    return np.array([x[0] + (float(u) - x[2]) * dt, x[1], x[2] + x[3] * dt, x[3]])


def F4(x: np.ndarray, dt: float, u: Any) -> np.ndarray:
    """The Jacobian of :func:`f4`."""
    F = np.eye(4)
    F[0, 2], F[2, 3] = -dt, dt
    return F


def h(x: np.ndarray) -> np.ndarray:
    """Eq. 25b: [g sin(theta), g cos(theta)] (a state may carry a bias as a third value)."""
    return np.array([x[1] * math.sin(x[0]), x[1] * math.cos(x[0])])


def h_batch(X: np.ndarray) -> np.ndarray:
    """Eq. 25b on a batch of states (rows)."""
    X = np.asarray(X)
    if X.ndim == 1:
        return h(X)
    return np.column_stack((X[:, 1] * np.sin(X[:, 0]), X[:, 1] * np.cos(X[:, 0])))


def H(x: np.ndarray) -> np.ndarray:
    """Eq. 26 in the state order [theta, g] (module docstring), a zero column per extra
    state (the bias)."""
    s, c = math.sin(x[0]), math.cos(x[0])
    out = np.zeros((2, x.shape[0]))
    out[0, 0], out[0, 1] = x[1] * c, s
    out[1, 0], out[1, 1] = -x[1] * s, c
    return out
