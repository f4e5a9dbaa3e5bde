"""Interacting multiple models (Blom & Bar-Shalom 1988; Bar-Shalom, Li & Kirubarajan,
"Estimation with Applications to Tracking and Navigation", sec. 11.6) over Kalman filters
that share one state vector and differ in their process noise: a board held still and a
board being moved.

One cycle per reading (sec. 11.6.6):

1. mixing: with the mode-transition matrix Pi over the time since the last reading,
   c_j = sum_i Pi_ij mu_i, mu_i|j = Pi_ij mu_i / c_j, each filter restarts from
   x0_j = sum_i mu_i|j x_i, P0_j = sum_i mu_i|j (P_i + (x_i - x0_j)(x_i - x0_j)^T);
2. each filter predicts (its own F, Q) and is updated with the reading;
3. mode likelihoods L_j = N(y_j; 0, S_j), mu_j = L_j c_j / sum(L c);
4. the output is the mixture: x = sum mu_j x_j, P = sum mu_j (P_j + (x_j - x)(x_j - x)^T).

Modes that do not model a part of the state (a board held still has no velocity or
acceleration: its filter holds them at zero with no variance) are mixed as Granstrom,
Willett and Bar-Shalom ("Systematic approach to IMM mixing for unequal dimension states",
IEEE TAES 51(4), 2015) prescribe: a component of mode i mixed into mode j takes mode j's
prior for the states mode i lacks, here its covariance ``entry[(i, j)]`` added to P_i (the
attribute ``entry`` may change between cycles). A board that starts moving then enters the
moving modes with an unknown acceleration, as it does, and not with the still mode's certain
zero, which the moving modes, restarted from the still one at every reading, otherwise
inherit: they cannot explain a move's first readings, and the gate refuses them as
outliers. (:class:`~hera.models.tof.height.TofHeight` mixes so only when it tries two
refused readings as a move's start: at every reading it would let outliers in.)

With one mode it is a plain Kalman filter. The filters are
:class:`hera.estimation.KalmanFilter` objects (their update takes any
observation block, linear or not); the chi-square gate is applied here, before any filter
is touched: a reading is an outlier when it fails the gate of every mode (a manoeuvre the
still mode cannot explain is not an outlier).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence

import numpy as np

from hera.estimation import KalmanFilter, Observations, gate_threshold, mixture


def transition(rates: Sequence[float], dt: float) -> np.ndarray:
    """The mode-transition matrix over ``dt`` s for leaving rates ``rates`` (1/s) of each
    mode, shared evenly among the other modes (first order, each row clipped to sum 1)."""
    m = len(rates)
    Pi = np.zeros((m, m))
    for i, r in enumerate(rates):
        leave = min(0.5, max(0.0, r * dt))
        Pi[i, :] = leave / max(1, m - 1)
        Pi[i, i] = 1.0 - leave
    return Pi


class Imm:
    """IMM over ``filters`` (one per mode, same state), mode probabilities ``mu0`` and
    leaving ``rates`` (1/s); ``entry[(i, j)]``: the (n, n) covariance added to mode i's
    component when it is mixed into mode j (see the module docstring; none by default)."""

    def __init__(
        self,
        filters: Sequence[KalmanFilter],
        mu0: Sequence[float],
        rates: Sequence[float],
        entry: Mapping[tuple[int, int], np.ndarray] | None = None,
    ) -> None:
        if not len(filters) == len(mu0) == len(rates) or not filters:
            raise ValueError("an IMM needs one or more modes, each with mu0 and a rate")
        modes = range(len(filters))
        for i, j in entry or {}:
            if i not in modes or j not in modes or i == j:
                raise ValueError(f"entry ({i}, {j}): modes are 0..{len(filters) - 1}, i != j")
        self.entry = dict(entry or {})
        self.filters = list(filters)
        self.mu = np.asarray(mu0, dtype=float) / float(np.sum(mu0))
        self.rates = [float(r) for r in rates]
        self._c = self.mu.copy()

    @property
    def x(self) -> np.ndarray:
        return mixture([f.x for f in self.filters], [f.P for f in self.filters], self.mu)[0]

    @property
    def P(self) -> np.ndarray:
        return mixture([f.x for f in self.filters], [f.P for f in self.filters], self.mu)[1]

    def snapshot(self) -> tuple:
        """A copy of the mode probabilities and each filter's x and P, for :meth:`restore`."""
        return (self.mu.copy(), self._c.copy(), [(f.x.copy(), f.P.copy()) for f in self.filters])

    def restore(self, snap: tuple) -> None:
        """Back to a :meth:`snapshot` of this IMM."""
        mu, c, states = snap
        self.mu, self._c = mu.copy(), c.copy()
        for f, (x, P) in zip(self.filters, states, strict=True):
            f.reset(x, P)

    def mix(self, dt: float) -> None:
        """Step 1 over ``dt`` s: restart each filter from its mixed initial condition."""
        Pi = transition(self.rates, dt)
        c = Pi.T @ self.mu
        c = np.maximum(c, 1e-300)
        xs = [f.x for f in self.filters]
        Ps = [f.P for f in self.filters]
        entry = self.entry
        for j, f in enumerate(self.filters):
            w = Pi[:, j] * self.mu / c[j]
            Pj = Ps
            if entry:
                Pj = [P if (i, j) not in entry else P + entry[(i, j)] for i, P in enumerate(Ps)]
            x0, P0 = mixture(xs, Pj, w)
            f.reset(x0, P0)
        self._c = c

    def predict(self, step: Callable[[int, KalmanFilter], None]) -> None:
        """Step 2a: ``step(j, filter)`` predicts filter j (its own F and Q)."""
        for j, f in enumerate(self.filters):
            step(j, f)

    def update(
        self,
        label: str,
        z: float,
        h: Callable[[np.ndarray], float],
        jac: Callable[[np.ndarray], np.ndarray],
        var: float,
        gate: float | None,
    ) -> tuple[bool, float]:
        """Steps 2b-3 for one scalar reading ``z`` = h(x) + N(0, var) with Jacobian ``jac``;
        (accepted, the smallest NIS over the modes). A reading outside the gate of every
        mode is an outlier: it changes nothing (the mode probabilities keep the mixing's
        c_j)."""
        like = np.empty(len(self.filters))
        nis = np.empty(len(self.filters))
        for j, f in enumerate(self.filters):
            Jj = jac(f.x)
            Sj = float(Jj @ f.P @ Jj) + var
            yj = z - h(f.x)
            nis[j] = yj * yj / Sj
            like[j] = math.exp(-0.5 * nis[j]) / math.sqrt(2.0 * math.pi * Sj)
        best = float(np.min(nis))
        if gate is not None and best > gate_threshold(gate, 1):
            self.mu = self._c.copy()
            return False, best
        for f in self.filters:
            obs = Observations().add(
                label, [z], h=lambda s: np.array([h(s)]), jacobian=lambda s: jac(s)[None, :], R=var
            )
            f.update(obs, gate=None)
        w = like * self._c
        total = float(np.sum(w))
        self.mu = w / total if total > 0 and math.isfinite(total) else self._c.copy()
        return True, best
