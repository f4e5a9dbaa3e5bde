"""A filter's steps, kept for smoothing and post-processing; batch filtering over arrays.

``record(filt)`` attaches a :class:`StepHistory` to a filter (KF, EKF or UKF). From then on
every ``predict`` starts a new step and every ``update`` (or ``reset``) sets that step's
posterior. Step k holds:

* ``t[k]``: seconds since the start (``t0`` plus the sum of the predicts' dt);
* ``F[k]``: the transition of the predict that began step k (the KF's F, the EKF's
  Jacobian at the previous posterior; None for the UKF and for step 0);
* ``x_prior[k]``, ``P_prior[k]``: the state after that predict;
* ``x_post[k]``, ``P_post[k]``: after the step's last update or reset (the prior when
  nothing was fused);
* ``log_likelihood[k]``: the sum over the step's updates made with ``details=True``.

Step 0 is the state when recording began (prior = posterior). The arrays are references to
the filter's own (never modified in place), so recording costs a few list appends per step.

``batch_filter`` runs a filter over a whole sequence of measurements and returns this
history, as FilterPy's ``batch_filter`` returns means and covariances.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from .observations import Block, Observations
from .state import FilterState

__all__ = ["StepHistory", "batch_filter", "record"]


class StepHistory:
    """The per-step record of one filter (see the module docstring). Lists grow as the
    filter steps; the properties stack them into arrays."""

    def __init__(self, filt: FilterState, t0: float = 0.0) -> None:
        self.n = filt.n
        self.t0 = t0
        self.residual_x = getattr(filt, "residual_x", None)
        self.dts: list[float] = [0.0]
        self.Fs: list[np.ndarray | None] = [None]
        self.priors: list[tuple[np.ndarray, np.ndarray]] = [(filt._x, filt._P)]
        self.posts: list[tuple[np.ndarray, np.ndarray]] = [(filt._x, filt._P)]
        self.lls: list[float] = [0.0]

    def __len__(self) -> int:
        return len(self.dts)

    def _predicted(self, filt: FilterState, dt: float, F: np.ndarray | None) -> None:
        state = (filt._x, filt._P)
        self.dts.append(float(dt))
        self.Fs.append(F)
        self.priors.append(state)
        self.posts.append(state)
        self.lls.append(0.0)

    def _updated(self, filt: FilterState, result: Any) -> None:
        self.posts[-1] = (filt._x, filt._P)
        ll = None if result is None else result.log_likelihood
        if ll is not None:
            self.lls[-1] += ll

    @property
    def t(self) -> np.ndarray:
        """(N,) step times in seconds: t0 + the cumulative sum of the predicts' dt."""
        return self.t0 + np.cumsum(self.dts)

    @property
    def x_prior(self) -> np.ndarray:
        """(N, n) state after each step's predict."""
        return np.array([p[0] for p in self.priors])

    @property
    def P_prior(self) -> np.ndarray:
        """(N, n, n) covariance after each step's predict."""
        return np.array([p[1] for p in self.priors])

    @property
    def x_post(self) -> np.ndarray:
        """(N, n) state after each step's updates."""
        return np.array([p[0] for p in self.posts])

    @property
    def P_post(self) -> np.ndarray:
        """(N, n, n) covariance after each step's updates."""
        return np.array([p[1] for p in self.posts])

    @property
    def F(self) -> list[np.ndarray | None]:
        """The transition matrix of each step's predict (None for step 0 and the UKF)."""
        return list(self.Fs)

    @property
    def log_likelihood(self) -> np.ndarray:
        """(N,) log-likelihood of each step's updates made with ``details=True``."""
        return np.array(self.lls)


def record(filt: FilterState, t0: float = 0.0) -> StepHistory:
    """Start recording ``filt``'s steps (replacing any history it had); returns the
    :class:`StepHistory`, also kept as ``filt.history``. ``t0``: the time of the current
    state, in seconds (step times are t0 plus the predicts' dt; ``history.t0`` may also
    be set later, before the times are read)."""
    h = StepHistory(filt, t0)
    filt.history = h
    return h


def batch_filter(
    filt: Any,
    dt: Any,
    observations: Any,
    *,
    us: Any = None,
    H: Any = None,
    h: Any = None,
    jacobian: Any = None,
    R: Any = None,
    residual: Any = None,
    label: str = "z",
    gate: Any = ...,
    t0: float = 0.0,
) -> StepHistory:
    """Run ``filt`` over N steps: ``predict(dt[k], us[k])`` then ``update(observations[k],
    details=True)``; returns the :class:`StepHistory` (N + 1 steps: step 0 is the initial
    state, so ``x_post[1:]`` are the N filtered estimates; ``log_likelihood`` per step).

    ``dt``: seconds, one number or N. ``observations``: N entries, each an Observations, a
    Block, a list of blocks or None (predict only); or an (N, m) array of measurements z,
    with ``H`` or ``h`` (and ``jacobian``), ``R`` and ``residual`` as in
    ``Observations.add`` (a row with NaN is a missing measurement: predict only). The
    filter keeps its final state; its previous history (if any) is replaced."""
    obs_seq = _observation_sequence(observations, H, h, jacobian, R, residual, label)
    steps = len(obs_seq)
    dts = np.broadcast_to(np.asarray(dt, dtype=np.float64), (steps,))
    if us is not None and len(us) != steps:
        raise ValueError(f"batch_filter: {len(us)} control inputs for {steps} steps")
    hist = record(filt, t0)
    for k in range(steps):
        filt.predict(float(dts[k]), None if us is None else us[k])
        o = obs_seq[k]
        if o is not None:
            filt.update(o, gate, details=True)
    return hist


def _observation_sequence(
    observations: Any, H: Any, h: Any, jacobian: Any, R: Any, residual: Any, label: str
) -> Sequence[Any]:
    if isinstance(observations, np.ndarray) and observations.dtype != object:
        zs = observations.astype(np.float64)
        if zs.ndim == 1:
            zs = zs.reshape(-1, 1)
        if R is None:
            raise ValueError("batch_filter: measurements as an array need R")
        out: list[Any] = []
        for z in zs:
            if np.isnan(z).any():
                out.append(None)
            else:
                out.append(Block(label, z, R, H=H, h=h, jacobian=jacobian, residual=residual))
        return out
    if any(v is not None for v in (H, h, jacobian, R, residual)):
        raise ValueError("batch_filter: H, h, jacobian, R, residual go with an array of z")
    seq = list(observations)
    for i, o in enumerate(seq):
        if o is not None and not isinstance(o, Observations | Block | list | tuple):
            raise ValueError(f"batch_filter: observation {i} is {type(o).__name__}")
    return seq
