"""The state every filter keeps: (x, P) behind checked properties, the prior and posterior
of the last step, an optional step history, and the checks of predict's inputs.

``x`` and ``P`` are properties: assigning converts and checks (``kf.x = [1.0, 2.0]``
gives the same float64 vector on every backend; a new P must be symmetric and positive
semi-definite - P0 = 0, a state known exactly, is allowed - see
``numerics.as_covariance``). The filters replace x and P by new arrays on every step and
never write into them, so a reference taken earlier (``x_prior``, a history entry) keeps
its values; edit the state by assignment or ``reset``, not in place.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, NoReturn

import numpy as np

from .backend import active_kernels
from .numerics import NonFiniteInputError, as_covariance, finite

__all__ = ["FilterState", "check_dt", "process_noise", "state_vector"]

_INF = math.inf


def state_vector(x: Any, n: int | None, what: str) -> np.ndarray:
    """A finite state vector as a new C-contiguous float64 array (of n values if given)."""
    try:
        v = np.array(x, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a vector of numbers, got {x!r}") from None
    if n is not None and v.shape != (n,):
        raise ValueError(f"{what} has {v.shape[0]} values, the state has {n}")
    if not v.shape[0]:
        raise ValueError(f"{what} is empty")
    if not finite(v):
        raise NonFiniteInputError(what, "the state", "state")
    return v


def check_dt(dt: Any) -> float:
    """dt as given when it is a number of seconds in [0, inf); ValueError otherwise (a
    negative dt would run the model backwards and make Q(dt) negative)."""
    try:
        ok = 0.0 <= dt < _INF
    except TypeError:
        ok = False
    if not ok:
        raise ValueError(f"predict: dt must be a finite number of seconds >= 0, got {dt!r}")
    return dt


def process_noise(Q: Any, n: int, what: str) -> np.ndarray:
    """A process noise covariance from a scalar (Q I), a vector (its diagonal) or an (n, n)
    matrix, checked symmetric and positive semi-definite (Q may be singular)."""
    return as_covariance(Q, n, what, semidefinite=True)


class NoiseRate:
    """Process noise that grows linearly with the step: ``Q(dt) = Qc dt``, Qc the noise's
    rate (its continuous-time spectral density; units of the state squared per second), as
    a scalar (Qc I), a vector (its diagonal) or a matrix. Give it as a filter's ``Q``; unlike
    a lambda it can be pickled, so the filter can be (a model's checkpoint on disk)."""

    __slots__ = ("rate",)

    def __init__(self, rate: Any) -> None:
        r = np.asarray(rate, dtype=np.float64)
        if r.ndim > 2 or not np.isfinite(r).all() or (r.ndim < 2 and (r < 0).any()):
            raise ValueError(
                f"NoiseRate: the rate must be variances >= 0 or a matrix, got {rate!r}"
            )
        self.rate: Any = float(r) if r.ndim == 0 else np.diag(r) if r.ndim == 1 else r

    def __call__(self, dt: float) -> float | np.ndarray:
        """Q(dt): the rate times dt (a number when the rate is one, else a matrix)."""
        return self.rate * dt

    def __repr__(self) -> str:
        return f"NoiseRate({np.asarray(self.rate).tolist()!r})"


class FilterState:
    """(x, P) with checked assignment, ``x_prior``/``P_prior`` (after the last predict),
    ``x_post``/``P_post`` (after the last update or reset; both start at x0, P0) and
    ``history`` (a :class:`~hera.estimation.history.StepHistory` or None)."""

    def __init__(self, x0: Any, P0: Any) -> None:
        active_kernels()  # resolve the backend now: the steps read backend._active directly
        x = state_vector(x0, None, "x0")
        self.n = x.shape[0]
        self._nn = (self.n, self.n)  # the shape of P, for the steps' np.empty
        self._P = as_covariance(P0, self.n, "P0", semidefinite=True)
        self._x = x
        self.x_prior = self.x_post = x
        self.P_prior = self.P_post = self._P
        self.history: Any = None

    @property
    def x(self) -> np.ndarray:
        """The state estimate (n,)."""
        return self._x

    @x.setter
    def x(self, value: Any) -> None:
        self._x = state_vector(value, self.n, "x")

    @property
    def P(self) -> np.ndarray:
        """The state covariance (n, n), symmetric positive semi-definite."""
        return self._P

    @P.setter
    def P(self, value: Any) -> None:
        self._P = as_covariance(value, self.n, "P", semidefinite=True)

    def reset(self, x: Any, P: Any) -> None:
        """Re-initialise the state (e.g. from a health monitor's reset hook). Checked as at
        construction; recorded as the current step's posterior when a history is kept."""
        xv = state_vector(x, self.n, "reset: x")
        Pv = as_covariance(P, self.n, "reset: P", semidefinite=True)
        self._x = self.x_post = xv
        self._P = self.P_post = Pv
        if self.history is not None:
            self.history._updated(self, None)

    def _commit_predict(
        self, x: np.ndarray, P: np.ndarray, F: np.ndarray | None, dt: float
    ) -> None:
        """Store a predicted state (the prior) and record the step."""
        self._x = self.x_prior = x
        self._P = self.P_prior = P
        if self.history is not None:
            self.history._predicted(self, dt, F)

    def _commit_update(self, x: np.ndarray, P: np.ndarray, result: Any) -> None:
        """Store an updated state (the posterior) and record it."""
        self._x = self.x_post = x
        self._P = self.P_post = P
        if self.history is not None:
            self.history._updated(self, result)

    def _diagnose_predict(self, inputs: Sequence[tuple[str, Any]], result: str) -> NoReturn:
        """Raise the precise error of a predict whose result is not finite (the state is
        unchanged): the state itself (NaN put in before this predict), else the first of
        ``inputs`` ((name, array or None) pairs) that is not finite, else ``result``, which
        then overflowed from finite inputs (values past 1.8e308: an unstable F, a huge P)."""
        if not finite(self._x):
            raise NonFiniteInputError("predict", "the state x (set before this predict)", "step")
        if not finite(self._P):
            raise NonFiniteInputError("predict", "the covariance P", "step")
        for name, value in inputs:
            if value is not None and not finite(np.asarray(value, dtype=np.float64)):
                raise NonFiniteInputError("predict", name, "step")
        raise NonFiniteInputError(
            "predict", result, "step", problem="overflowed (every input is finite)"
        )

    def __repr__(self) -> str:
        return f"{type(self).__name__}(n={self.n}, x={self._x!r})"
