"""Our 3-D position from sonars: an EKF on the raw ranges of sonars at any pose.

Beyond the thesis's e10 (:mod:`.thesis`), which needs one sonar per axis and reads a range
as an axial coordinate:

- state [x, y, z, vx, vy, vz] (m, m/s), a velocity that persists for about ``tau_v`` s
  (an Ornstein-Uhlenbeck velocity: ``F = [[I, tau (1 - e) I], [0, e I]]``, ``e =
  exp(-dt / tau_v)``) with white acceleration noise ``Q = [[dt^3/3 A, dt^2/2 A],
  [dt^2/2 A, dt A]]`` (A the acceleration's spectral density, m^2/s^3; the constant
  velocity model's Q, Bar-Shalom, Li, Kirubarajan 2001, eq. 6.2.2-12, good for dt well
  under tau_v): a moving target is followed without lag, and a direction no sonar sees any
  more is neither extrapolated for ever at its last speed (a hand stops, turns back) nor
  claimed known: its variance grows;
- A is steered by the motion: a hand or a carriage moves along a line for a while (the
  thesis's test moves the target back and forth along one axis at a time), so along the
  estimated velocity A is ``q_along``, across it ``q_across``, blended by the speed's
  weight ``w = |v|^2 / (|v|^2 + v_ref^2)`` with the isotropic ``q_acc`` of a still target
  (which may start in any direction): ``A = (q_across + (1 - w) q_acc) I + w q_along
  u u^T``. The directions the target does not move in are smoothed hard, the one it
  moves in is followed;
- a reading is the distance from its sonar to the target's surface, ``h(p) = |p - s| -
  target_radius`` (Jacobian ``[u^T, 0]``, u the unit vector from the sonar to p), for a
  sonar at any position pointing anywhere: a target off the beam's axis is read at its
  slant range, and so modelled;
- a reading whose predicted target lies near the edge of the beam (within
  ``beam_margin_deg`` of ``half_angle_deg``) is skipped (the sonar may see only part of the
  target there) while the position is known to ``beam_std`` (a lost track must not lock
  its sonars out), and one whose innovation fails the chi-square test at ``gate`` is
  rejected (cross-talk, a hand in the beam);
- it starts once its sonars' first readings (within ``init_s``) determine a position
  (:func:`.sonars.beam_points`), or at ``x0`` when given;
- the published estimate is smoothed with the readings of the next ``lag`` s (a fixed-lag
  Rauch-Tung-Striebel smoother): it is ``lag`` s old when published, and instead of
  extrapolating each axis from its last reading (the sonars sound one at a time, an axis
  is read every 0.15 s) it interpolates between two (0 gives the real-time filter).

The estimate carries its standard deviations, so a reader sees which direction a lost sonar
leaves unobserved. dt comes from the samples' measurement times (a sonar stamps the start
of its ping); a reading older than the filter by more than ``max_lag`` s is dropped.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from hera.estimation import KalmanFilter, Observations
from hera.models.position3d.sonars import Sonar, beam_points, parse_sonars
from hera.store import Sample


@dataclass(frozen=True)
class _Step:
    """One step of the filter: its time, filtered state, the prediction it started from and
    the transition from the step before (what the smoother needs)."""

    t: float
    x: np.ndarray
    P: np.ndarray
    x_pred: np.ndarray
    P_pred: np.ndarray
    F: np.ndarray


COLUMNS = (
    "x [m]",
    "y [m]",
    "z [m]",
    "std x [m]",
    "std y [m]",
    "std z [m]",
    "vx [m/s]",
    "vy [m/s]",
    "vz [m/s]",
)


class RangeTracker:
    """Our e10 (see module docstring). Settings: ``sonars`` (required, see :mod:`.sonars`),
    ``target_radius`` (0.05 m), ``var_range`` (m^2; 0.025^2, the MaxSonar's 2.5 cm),
    ``q_acc`` (0.02 m^2/s^3), ``q_along`` (0.1), ``q_across`` (0.001), ``v_ref`` (0.05
    m/s), ``tau_v`` (2 s), ``half_angle_deg`` (20), ``beam_margin_deg`` (2), ``beam_std`` (0.03 m),
    ``gate`` (0.9999), ``init_s`` (1.0 s), ``x0`` (m, optional), ``pos_std0`` (0.1 m),
    ``vel_std0`` (0.5 m/s), ``max_lag`` (0.25 s), ``lag`` (0.2 s)."""

    inputs = ("sonar",)
    columns = COLUMNS

    def __init__(
        self,
        sonars: Any = None,
        target_radius: float = 0.05,
        var_range: float = 0.025**2,
        q_acc: float = 0.02,
        q_along: float = 0.1,
        q_across: float = 0.001,
        v_ref: float = 0.05,
        tau_v: float = 2.0,
        half_angle_deg: float = 20.0,
        beam_margin_deg: float = 2.0,
        beam_std: float = 0.03,
        gate: float | None = 0.9999,
        init_s: float = 1.0,
        x0: list[float] | None = None,
        pos_std0: float = 0.1,
        vel_std0: float = 0.5,
        max_lag: float = 0.25,
        lag: float = 0.2,
    ) -> None:
        for name, v in (
            ("var_range", var_range),
            ("q_acc", q_acc),
            ("q_along", q_along),
            ("q_across", q_across),
            ("v_ref", v_ref),
            ("tau_v", tau_v),
            ("init_s", init_s),
        ):
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a number > 0, got {v!r}")
        if not 0 < half_angle_deg - beam_margin_deg < 90:
            raise ValueError("half_angle_deg - beam_margin_deg must lie in (0, 90) deg")
        self.sonars = parse_sonars(sonars)
        self.target_radius = float(target_radius)
        self.var_range = float(var_range)
        self.q = (float(q_acc), float(q_along), float(q_across), float(v_ref) ** 2)
        self.tau_v = float(tau_v)
        self.beam_std = float(beam_std)
        self.cos_beam = math.cos(math.radians(half_angle_deg - beam_margin_deg))
        self.gate = gate
        self.init_s = float(init_s)
        self.max_lag = float(max_lag)
        if not (isinstance(lag, (int, float)) and 0.0 <= lag <= 5.0):
            raise ValueError(f"lag must be a number of seconds in [0, 5], got {lag!r}")
        self.lag = float(lag)
        self._history: deque[_Step] = deque()
        self.p0 = (float(pos_std0) ** 2, float(vel_std0) ** 2)
        self.kf: KalmanFilter | None = None
        self.t: float | None = None
        self._first: dict[str, tuple[float, float]] = {}  # node -> (t, range) at start
        self.counts = {"fused": 0, "rejected": 0, "beam_edge": 0, "late": 0, "other": 0}
        if x0 is not None:
            self._start(np.array(x0, dtype=np.float64).reshape(3), None)

    def _Q(self, dt: float) -> np.ndarray:
        """Process noise over dt, steered by the estimated velocity (module docstring)."""
        q_acc, q_along, q_across, v2_ref = self.q
        v = self.kf.x[3:6] if self.kf is not None else np.zeros(3)
        v2 = float(v @ v)
        w = v2 / (v2 + v2_ref)
        A = (q_across + (1.0 - w) * q_acc) * np.eye(3)
        if v2 > 0.0:
            A += (w * q_along / v2) * np.outer(v, v)
        Q = np.empty((6, 6))
        Q[:3, :3] = A * (dt**3 / 3.0)
        Q[:3, 3:] = Q[3:, :3] = A * (dt**2 / 2.0)
        Q[3:, 3:] = A * dt
        return Q

    def _F(self, dt: float) -> np.ndarray:
        """Transition over dt: position integrates a velocity decaying with tau_v."""
        e = math.exp(-dt / self.tau_v)
        F = np.eye(6)
        for i in range(3):
            F[i, i + 3] = self.tau_v * (1.0 - e)
            F[i + 3, i + 3] = e
        return F

    def _start(self, p: np.ndarray, t: float | None) -> None:
        pv, vv = self.p0
        self.kf = KalmanFilter(
            np.concatenate((p, np.zeros(3))), np.diag([pv] * 3 + [vv] * 3), self._F, self._Q
        )
        self.t = t

    def _initialise(self, sample: Sample) -> bool:
        """Collect first readings until they determine a position (or go stale)."""
        self._first[sample.node] = (sample.t, float(sample.values[0]))
        self._first = {n: v for n, v in self._first.items() if sample.t - v[0] <= self.init_s}
        p = beam_points(
            {n: r for n, (_, r) in self._first.items()}, self.sonars, self.target_radius
        )
        if p is None:
            return False
        self._start(p, sample.t)
        return True

    def _range_block(self, obs: Observations, sonar: Sonar, r: float) -> None:
        s = sonar.position
        rt = self.target_radius

        def h(x: np.ndarray) -> np.ndarray:
            return np.array([math.dist(x[:3], s) - rt])

        def jac(x: np.ndarray) -> np.ndarray:
            d = x[:3] - s
            H = np.zeros((1, 6))
            H[0, :3] = d / max(float(np.sqrt(d @ d)), 1e-9)
            return H

        obs.add(f"sonar@{sonar.node}", [r], h=h, jacobian=jac, R=self.var_range)

    @classmethod
    def check(cls, settings: dict[str, Any]) -> None:
        """Raise ValueError naming a bad setting (the model is cheap to build: build it)."""
        cls(**settings)

    def process(self, sample: Sample) -> bool:
        """Predict to the reading's time and fuse it; True if the estimate changed."""
        if sample.name != "sonar" or not sample.values:
            return False
        sonar = self.sonars.get(sample.node)
        if sonar is None:
            self.counts["other"] += 1
            return False
        if self.kf is None:
            return self._initialise(sample)
        if self.t is None:
            self.t = sample.t
        dt = sample.t - self.t
        if dt < -self.max_lag:
            self.counts["late"] += 1
            return False
        kf = self.kf
        if dt > 0:
            F = self._F(dt)
            kf.predict(dt, Q=self._Q(dt))
            self.t = sample.t
            x, P = kf.x.copy(), kf.P.copy()
            self._history.append(_Step(sample.t, x, P, x, P, F))
        known = float(np.max(np.diag(kf.P)[:3])) <= self.beam_std**2
        if known and not sonar.in_beam(kf.x[:3], self.cos_beam):
            self.counts["beam_edge"] += 1
            return dt > 0
        obs = Observations()
        self._range_block(obs, sonar, float(sample.values[0]))
        result = kf.update(obs, gate=self.gate)
        if result.rejected:
            self.counts["rejected"] += 1
            return dt > 0
        self.counts["fused"] += 1
        if self._history:  # the step's filtered state (same-time readings share a step)
            last = self._history[-1]
            x, P = kf.x.copy(), kf.P.copy()
            self._history[-1] = _Step(last.t, x, P, last.x_pred, last.P_pred, last.F)
        self._prune()
        return True

    def _prune(self) -> None:
        """Keep the steps a smoothed estimate ``lag`` s back needs (one before it)."""
        h = self._history
        if not h:
            return
        keep_from = h[-1].t - self.lag
        while len(h) > 2 and h[1].t <= keep_from:
            h.popleft()

    def smoothed(self) -> tuple[float, np.ndarray, np.ndarray] | None:
        """(t, x, P) at the newest step at least ``lag`` s older than the newest reading,
        smoothed by every step since (Rauch, Tung, Striebel 1965: ``C = P_f F^T
        P_pred^-1``, ``x_s = x_f + C (x_s' - x_pred')``, ``P_s = P_f + C (P_s' - P_pred')
        C^T``); the filtered state when ``lag`` is 0 or nothing is that old yet."""
        if self.kf is None or self.t is None:
            return None
        h = self._history
        if self.lag <= 0.0 or len(h) < 2 or h[0].t > h[-1].t - self.lag:
            return self.t, self.kf.x, self.kf.P
        x, P = self.kf.x, self.kf.P
        target = h[-1].t - self.lag
        k = len(h) - 1
        while k > 0 and h[k].t > target:
            f, nxt = h[k - 1], h[k]
            C = np.linalg.solve(nxt.P_pred, nxt.F @ f.P).T  # P_f F^T P_pred^-1
            x = f.x + C @ (x - nxt.x_pred)
            P = f.P + C @ (P - nxt.P_pred) @ C.T
            k -= 1
        return h[k].t, x, 0.5 * (P + P.T)

    def estimate(self) -> tuple[float, list[float]] | None:
        """(time, [x, y, z, std x, std y, std z, vx, vy, vz]): the :meth:`smoothed` state."""
        s = self.smoothed()
        if s is None:
            return None
        t, x, P = s
        std = [math.sqrt(max(float(P[i, i]), 0.0)) for i in range(3)]
        return t, [*(float(v) for v in x[:3]), *std, *(float(v) for v in x[3:])]

    def counters(self) -> dict[str, int]:
        """Readings ``fused``, ``rejected`` by the gate, skipped at the ``beam_edge``,
        ``late`` (dropped) and of sonars the model was not told of (``other``)."""
        return dict(self.counts)
