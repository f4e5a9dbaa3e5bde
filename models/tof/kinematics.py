"""The seed's process models (seed 001, tasks 2-4), on a fixed predict step dt (0.01 s).

- Constant velocity, state [v, x] (task 2): F = [[1, 0], [dt, 1]], piecewise white
  acceleration Gamma = [dt, dt^2 / 2], Q = sigma_a^2 Gamma Gamma^T (m, m/s; sigma_a m/s^2).
- Constant acceleration, state [a, v, x] (tasks 3-4): F = [[1, 0, 0], [dt, 1, 0],
  [dt^2 / 2, dt, 1]], piecewise white jerk Gamma = [dt, dt^2 / 2, dt^3 / 6],
  Q = sigma_j^2 Gamma Gamma^T (sigma_j m/s^3). Task 3 of the seed writes Gamma = [1, dt,
  dt^2 / 2], which is not a jerk's effect over one step; task 4 (and the issue) use the one
  above, and so do we.
"""

from __future__ import annotations

import numpy as np


def cv_matrices(dt: float, sigma_a: float) -> tuple[np.ndarray, np.ndarray]:
    """(F, Q) of the constant-velocity model [v, x] over ``dt`` s."""
    F = np.array([[1.0, 0.0], [dt, 1.0]])
    gamma = np.array([dt, 0.5 * dt * dt])
    return F, sigma_a**2 * np.outer(gamma, gamma)


def ca_matrices(dt: float, sigma_j: float) -> tuple[np.ndarray, np.ndarray]:
    """(F, Q) of the constant-acceleration model [a, v, x] over ``dt`` s."""
    F = np.array([[1.0, 0.0, 0.0], [dt, 1.0, 0.0], [0.5 * dt * dt, dt, 1.0]])
    gamma = np.array([dt, 0.5 * dt * dt, dt**3 / 6.0])
    return F, sigma_j**2 * np.outer(gamma, gamma)
