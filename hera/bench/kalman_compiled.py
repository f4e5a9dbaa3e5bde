"""The EKF benchmark's model written as numba functions, for ``CompiledExtendedKalmanFilter``.

The same process and measurement as ``kalman._Model``: f(x) = F x with F = I plus dt on the
superdiagonal (a constant-velocity chain), h(x) = sin(x[idx]) with idx[i] = i mod n, and
their analytic Jacobians. h depends on the measurement size m, so there is one h and one H
per m; they live at the top level of this module so the compiled step is cached.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numba
import numpy as np

from hera.estimation.compiled import CompiledExtendedKalmanFilter, CompiledModel, compile_model


@numba.njit(cache=True)
def f(x: np.ndarray, dt: float, u: np.ndarray) -> np.ndarray:
    out = x.copy()
    for i in range(x.shape[0] - 1):
        out[i] += dt * x[i + 1]
    return out


@numba.njit(cache=True)
def F(x: np.ndarray, dt: float, u: np.ndarray) -> np.ndarray:
    n = x.shape[0]
    J = np.eye(n)
    for i in range(n - 1):
        J[i, i + 1] = dt
    return J


@numba.njit(cache=True, inline="always")
def _h(x: np.ndarray, m: int) -> np.ndarray:
    out = np.empty(m)
    for i in range(m):
        out[i] = np.sin(x[i % x.shape[0]])
    return out


@numba.njit(cache=True, inline="always")
def _H(x: np.ndarray, m: int) -> np.ndarray:
    n = x.shape[0]
    J = np.zeros((m, n))
    for i in range(m):
        J[i, i % n] = np.cos(x[i % n])
    return J


@numba.njit(cache=True)
def h1(x: np.ndarray) -> np.ndarray:
    return _h(x, 1)


@numba.njit(cache=True)
def h2(x: np.ndarray) -> np.ndarray:
    return _h(x, 2)


@numba.njit(cache=True)
def h3(x: np.ndarray) -> np.ndarray:
    return _h(x, 3)


@numba.njit(cache=True)
def H1(x: np.ndarray) -> np.ndarray:
    return _H(x, 1)


@numba.njit(cache=True)
def H2(x: np.ndarray) -> np.ndarray:
    return _H(x, 2)


@numba.njit(cache=True)
def H3(x: np.ndarray) -> np.ndarray:
    return _H(x, 3)


_MEASUREMENTS = {1: (h1, H1), 2: (h2, H2), 3: (h3, H3)}
_models: dict[int, CompiledModel] = {}


def model(m: int) -> CompiledModel:
    """The compiled model with a measurement of m values (1-3), built once per process."""
    if m not in _models:
        h, H = _MEASUREMENTS[m]
        _models[m] = compile_model(f, F, h, H)
    return _models[m]


def prepare(dims: list[int]) -> str:
    """Compile (or load) the models of measurement sizes ``dims`` and run one step of each;
    returns where the steps are kept ("cached in DIR" or "not cached")."""
    for m in dims:
        md = np.zeros(1), np.eye(1)
        ekf = CompiledExtendedKalmanFilter(*md, model(m), Q=0.0, R=np.ones(m))
        ekf.fuse(0.1, np.zeros(m))
    paths = {str(p.parent) for m in dims for p in model(m).paths.values() if p is not None}
    return f"cached in {', '.join(sorted(paths))}" if paths else "not cached"


def stepper(md: Any) -> Callable[[np.ndarray], None]:
    """One benchmark step, ``fuse(dt, z)``, of a compiled EKF of ``md`` (a
    ``kalman._Model``: its x0, P0, Q, R, dt and m)."""
    ekf = CompiledExtendedKalmanFilter(md.x0, md.P0, model(md.m), Q=md.Q, R=md.var)
    dt = md.dt
    fuse = ekf.fuse

    def step(z: np.ndarray) -> None:
        fuse(dt, z)

    return step
