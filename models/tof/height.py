"""The ToF height models (seed 001) as fusion models: one class, four kinds.

=========  ===================  ==================  =========================================
kind       state                sensors             seed
=========  ===================  ==================  =========================================
``cv``     [v, x]               the centre one      task 2: constant velocity
``ca``     [a, v, x]            the centre one      task 3: constant acceleration
``fused``  [a, v, x]            all, H = [0 0 1]    task 4: three sensors, R = sigma^2 I
``plane``  [a, v, h, p, r]      all, d(h, p, r)     beyond the seed: height, pitch and roll
=========  ===================  ==================  =========================================

As in the seed, the filter predicts on a fixed step ``dt`` (0.01 s: 100 Hz) and updates when
a reading arrives; a reading is fused at its own measurement time (the last predict step is
shortened to reach it), one sensor at a time (for one time, the same as the seed's stacked
z and diagonal R). The centre sensor is the one at the board's origin (its payload says
where it sits); heights are of that point, in m; angles in rad. The ``plane`` kind takes
each range as d = h / (cos r cos p) - x tan p / cos r + y tan r (:mod:`.plane`); pitch and
roll revert to level with the time constant ``tilt_tau`` (the seed's board is "held
approximately parallel to the desk"; it also bounds the angle two sensors cannot see),
driven by ``q_tilt`` (rad^2/s, per mode). A held board's tilt drifts a little (1e-3 in the
still mode: roll, seen over the 2 cm between the satellites' row and the centre, changes a
range by 2 mm at 6 deg, too little for the tilted mode's likelihood to win, so the still mode
must learn it itself), and a board moved fast stays roughly level (3e-3: about 2.6 deg over a
0.7 s move; a freer tilt there lets the tilt wander on every move and the still segments
after it inherit the wrong tilt). Measured over 40 noise draws of one world (``python
tests/support/appsim.py draws 40``): the still RMSE's worst 1.39 mm, 3.68 mm with the
earlier (1e-7, 0.02, 1e-3, 0.05).

``sigma_j`` may be one value or one per mode, 0 meaning a board held still (velocity and
acceleration zero, the height drifting by ``q_still`` m^2/s): with several modes the filter
is an interacting multiple model (:mod:`.imm`) switching between them (leaving rates
``switch_rates``, 1/s, and ``q_tilt``, one per mode). The seed's kinds default to the seed's
single values; ``plane`` to four modes: held still, tilted (height still), moved slowly
(sigma_j 2) and moved fast (30: a hand's jerk). A single sigma_j cannot be both quiet when
the board is still and quick when it is moved; the modes can, and when still the estimate
averages the readings as a still board allows.

Beyond the seed, every kind:

- fuses only readings whose status is valid (``valid_statuses``, default [0]);
- gates each reading with a chi-square test (``gate``, probability, one degree of freedom);
  when ``relock`` readings in a row are gated out the filter itself has lost the board (a
  move faster than its model): it restarts from the reading with the board's motion unknown
  (``plane``: :data:`RELOCK_SPREAD`; counted in ``relocks``);
- with a still mode (``plane``), tells a move's start from an outlier: one reading refused
  by every mode may be either and is refused; when the next is refused too, both are fused
  again from the state before them, the still modes entering the moving ones with the
  ``onset`` spread (:mod:`.imm`: mixing for modes that lack states), and kept when both pass
  the gate (counted ``onsets``): 33 ms before a relock, where the moving modes, restarted
  from the still one's certain zero motion at every reading, refused a move's first
  readings (a live run's: 52 mm off for 0.13 s, RMSE 3.5 mm; 40 mm and 2.8 mm with it);
- notices a sensor that is stuck, dead, or keeps failing the gate, stops fusing it and says
  so (:mod:`.health`): the output's ``faulty`` mask and the counters;
- starts from the first valid reading (the seed starts at 0.05 m whatever the height).

Between readings, :meth:`TofHeight.forecast` gives the state predicted to any later time
(what the seed's filter outputs on its predict-only steps) without changing the filter.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from hera.estimation import KalmanFilter
from hera.models.tof.health import SensorHealth
from hera.models.tof.imm import Imm
from hera.models.tof.kinematics import ca_matrices, cv_matrices
from hera.models.tof.plane import range_jacobian, range_of
from hera.store import Sample

KINDS = ("cv", "ca", "fused", "plane")
CENTRE_TOL_M = 0.001
"""A sensor within this distance of the board's origin is the centre sensor."""
MAX_STEPS = 500
"""Predict steps at most per gap; a longer gap is bridged by one step."""
STILL_VAR = 1e-12
"""Variance left on a still board's velocity and acceleration (the filter keeps P positive
definite)."""
RELOCK_SPREAD = {"plane": (0.5, 3.0)}
"""(m/s, m/s^2): the velocity and acceleration spread of ``plane`` after a relock (a hand's
move: the filter lost the board because it moved faster than modelled, so its motion is
unknown; its fast mode then learns it). The seed's single-model kinds restart from ``var0``
as before: with the seed's stiff sigmas a wide spread leaves them wild (measured: ``ca``
overshooting by 0.5 m on 10 Hz readings)."""
DEFAULT_SIGMA_J = {"ca": 0.1, "fused": 1.0, "plane": (0.0, 0.0, 2.0, 30.0)}
"""m/s^3: the seed's task 3 and task 4 values; four modes for ``plane`` (0: still)."""
DEFAULT_ONSET = {"plane": ((0.0, 0.0), (0.0, 0.0), (0.3, 0.05), (3.0, 0.5))}
"""(m/s^2, m/s) per mode: the acceleration and velocity spread with which a still mode (no
motion states) enters a moving one when two refused readings are tried as a move's start: a
hand's fast move reaches about 2 m/s^2 and, by the time two readings have been refused, a
few tenths of a m/s (the relock's spread, :data:`RELOCK_SPREAD`); the slow mode a tenth of
it. Kinds without a still mode have none."""


def columns_of(kind: str) -> tuple[str, ...]:
    """The output columns of a kind."""
    head = ("height [m]", "v [m/s]")
    if kind != "cv":
        head += ("a [m/s^2]",)
    if kind == "plane":
        head += ("pitch [rad]", "roll [rad]")
    return (*head, "sensors ok", "faulty [mask]")


def _per_mode(value: float | Sequence[float], what: str) -> tuple[float, ...]:
    values = (value,) if isinstance(value, (int, float)) else tuple(value)
    if not values or not all(isinstance(v, (int, float)) and v >= 0 for v in values):
        raise ValueError(f"{what} must be a number >= 0 or a list of them, got {value!r}")
    return tuple(float(v) for v in values)


def _onsets(onset: Sequence[Sequence[float]], modes: int) -> tuple[tuple[float, float], ...]:
    """``onset`` checked: one [a, v] pair (>= 0) per mode."""
    try:
        pairs = tuple((float(a), float(v)) for a, v in onset)
    except (TypeError, ValueError):
        raise ValueError(f"onset must be one [a, v] pair per mode, got {onset!r}") from None
    if len(pairs) != modes or not all(a >= 0 and v >= 0 for a, v in pairs):
        raise ValueError(f"onset needs one [a, v] pair (>= 0) per mode ({modes}), got {onset!r}")
    return pairs


class TofHeight:
    """A ToF height filter of one kind (see the module docstring).

    Settings: ``kind``; ``names`` (input names, ["vl53l1"]); ``sigma`` (m, range noise: R =
    sigma^2, seed 0.003); ``sigma_a`` (m/s^2, cv: seed task 2's 0.1); ``sigma_j`` (m/s^3,
    one or one per mode, 0 a still mode; default :data:`DEFAULT_SIGMA_J`); ``q_still``
    (m^2/s); ``q_tilt`` (rad^2/s, plane, one or one per mode: [1e-3, 0.02, 1e-3, 3e-3]);
    ``tilt_tau`` (s, 10); ``switch_rates`` (1/s, one per mode: [0.5, 0.5, 0.5, 3.0]);
    ``onset`` (one [a m/s^2, v m/s] per mode: the motion spread on entering a moving mode
    from a still one; default :data:`DEFAULT_ONSET`, none for kinds without it); ``dt``
    (s, predict step, 0.01); ``var0`` (initial variances of a and v: the seed's 1e-3);
    ``tilt_var0`` (rad^2); ``gate`` (probability, None: no gate); ``relock``;
    ``valid_statuses``; ``stuck_repeats``, ``dead_s``, ``invalid_run``, ``gated_run``
    (:class:`~hera.models.tof.health.SensorHealth`); ``max_lag`` (s: a reading older than the
    state by more is dropped, counted ``late``).
    """

    def __init__(
        self,
        kind: str = "plane",
        names: Sequence[str] = ("vl53l1",),
        sigma: float = 0.003,
        sigma_a: float = 0.1,
        sigma_j: float | Sequence[float] | None = None,
        q_still: float = 1e-8,
        q_tilt: float | Sequence[float] = (1e-3, 0.02, 1e-3, 3e-3),
        tilt_tau: float = 10.0,
        switch_rates: Sequence[float] = (0.5, 0.5, 0.5, 3.0),
        onset: Sequence[Sequence[float]] | None = None,
        dt: float = 0.01,
        var0: float = 1e-3,
        tilt_var0: float = 0.01,
        gate: float | None = 0.999,
        relock: int = 3,
        valid_statuses: Sequence[int] = (0,),
        stuck_repeats: int = 4,
        dead_s: float = 0.5,
        invalid_run: int = 3,
        gated_run: int = 5,
        max_lag: float = 0.05,
    ) -> None:
        if kind not in KINDS:
            raise ValueError(f"unknown kind {kind!r}: use one of {', '.join(KINDS)}")
        for key, v in (("sigma", sigma), ("sigma_a", sigma_a), ("dt", dt), ("var0", var0)):
            if not (isinstance(v, (int, float)) and v > 0):
                raise ValueError(f"{key} must be > 0, got {v!r}")
        if gate is not None and not 0.0 < gate < 1.0:
            raise ValueError(f"gate must be a probability in (0, 1) or None, got {gate!r}")
        if isinstance(names, str) or not names:
            raise ValueError(f"names must be a list of input names, got {names!r}")
        self.kind = kind
        self.inputs = tuple(str(n) for n in names)
        self.columns = columns_of(kind)
        self.var = float(sigma) ** 2
        if kind == "cv":
            jerks = (float(sigma_a),)
        else:
            jerks = _per_mode(DEFAULT_SIGMA_J[kind] if sigma_j is None else sigma_j, "sigma_j")
        modes = len(jerks)
        tilts = _per_mode(q_tilt, "q_tilt") if kind == "plane" else (0.0,)
        if len(tilts) not in (1, modes):
            raise ValueError(f"q_tilt needs one value or one per mode ({modes}), got {tilts}")
        rates = _per_mode(switch_rates, "switch_rates")
        if modes > 1 and len(rates) != modes:
            raise ValueError(f"switch_rates needs one rate per mode ({modes}), got {rates}")
        if not q_still >= 0:
            raise ValueError(f"q_still must be >= 0, got {q_still!r}")
        if onset is None:
            onset = DEFAULT_ONSET.get(kind, ((0.0, 0.0),) * modes)
            if len(onset) != modes:  # the kind's default is for its default modes
                onset = ((0.0, 0.0),) * modes
        spreads = _onsets(onset, modes)
        self.jerks = jerks
        self.onset = spreads
        self.tilts = tilts * (modes // len(tilts))
        self.rates = rates if modes > 1 else (0.0,)
        self.q_still = float(q_still)
        if not tilt_tau > 0:
            raise ValueError(f"tilt_tau must be > 0 s, got {tilt_tau!r}")
        self.tilt_tau = float(tilt_tau)
        self.dt, self.var0, self.gate = float(dt), float(var0), gate
        self.relock_after, self.max_lag, self.tilt_var0 = int(relock), float(max_lag), tilt_var0
        self.n = 2 if kind == "cv" else (5 if kind == "plane" else 3)
        self.ix = 1 if kind == "cv" else 2  # index of the height in the state
        self._grid = [self._matrices(j, self.dt) for j in range(modes)]
        self.health = SensorHealth(stuck_repeats, dead_s, invalid_run, gated_run, valid_statuses)
        self.imm: Imm | None = None
        self.t: float | None = None
        self._gated_in_row = 0
        self._onset_entry = self._entry()
        self._pending: tuple | None = None  # the last reading, refused: a move's start?
        self.counts = {
            "fused": 0,
            "gated": 0,
            "invalid": 0,
            "relocks": 0,
            "onsets": 0,
            "late": 0,
        }

    # -- process --------------------------------------------------------------------------------
    def _matrices(self, mode: int, step: float) -> tuple[np.ndarray, np.ndarray]:
        """(F, Q) of ``mode`` over ``step`` s (seed tasks 2-4, or still; tilt reverting to
        level, Ornstein-Uhlenbeck)."""
        jerk = self.jerks[mode]
        m = 2 if self.kind == "cv" else 3
        if jerk == 0.0:  # still: a and v are zero, the height drifts slowly
            F, Q = np.zeros((m, m)), np.eye(m) * STILL_VAR
            F[-1, -1], Q[-1, -1] = 1.0, self.q_still * step
        elif self.kind == "cv":
            F, Q = cv_matrices(step, jerk)
        else:
            F, Q = ca_matrices(step, jerk)
        if self.kind != "plane":
            return F, Q
        Fp, Qp = np.eye(5), np.zeros((5, 5))
        Fp[:3, :3], Qp[:3, :3] = F, Q
        Fp[3, 3] = Fp[4, 4] = math.exp(-step / self.tilt_tau)
        Qp[3, 3] = Qp[4, 4] = self.tilts[mode] * step
        return Fp, Qp

    def _advance(self, t: float) -> None:
        """Mix the modes, then predict each on the grid of ``dt`` steps up to ``t``."""
        imm = self.imm
        assert imm is not None and self.t is not None
        gap = t - self.t
        if gap <= 0.0:
            return
        imm.mix(gap)
        steps = int(gap / self.dt + 1e-9)
        rest = gap - steps * self.dt

        def step(j: int, kf: KalmanFilter) -> None:
            if steps > MAX_STEPS:
                F, Q = self._matrices(j, gap)
                kf.predict(gap, F=F, Q=Q)
                return
            F, Q = self._grid[j]
            for _ in range(steps):
                kf.predict(self.dt, F=F, Q=Q)
            if rest > 1e-9:
                F, Q = self._matrices(j, rest)
                kf.predict(rest, F=F, Q=Q)

        imm.predict(step)
        self.t = t

    def _entry(self) -> dict[tuple[int, int], np.ndarray]:
        """The IMM's entry covariances: still mode i into moving mode j gets j's onset
        spread on a (state 0) and v (state 1); none for ``cv`` (one mode, no acceleration)."""
        out: dict[tuple[int, int], np.ndarray] = {}
        if self.kind == "cv":
            return out
        still = [i for i, jerk in enumerate(self.jerks) if jerk == 0.0]
        for j, (a, v) in enumerate(self.onset):
            if self.jerks[j] == 0.0 or (a == 0.0 and v == 0.0):
                continue
            E = np.zeros((self.n, self.n))
            E[0, 0], E[1, 1] = a * a, v * v
            out.update({(i, j): E for i in still})
        return out

    def _start(self, t: float, x: np.ndarray, P: np.ndarray) -> None:
        filters = []
        for j in range(len(self.jerks)):
            F, Q = self._grid[j]
            filters.append(KalmanFilter(x, P, F, Q))
        mu0 = [1.0] + [0.0] * (len(filters) - 1)
        self.imm = Imm(filters, mu0, self.rates)
        self.t = t

    def _initial(self, h: float, tilt: tuple[float, float] = (0.0, 0.0)):
        n = self.n
        x = np.zeros(n)
        x[self.ix] = h
        P = np.eye(n) * self.var0
        P[self.ix, self.ix] = self.var
        if self.kind == "plane":
            x[3], x[4] = tilt
            P[3, 3] = P[4, 4] = self.tilt_var0
        return x, P

    def _uses(self, mount: tuple[float, float]) -> bool:
        if self.kind in ("fused", "plane"):
            return True
        return math.hypot(*mount) <= CENTRE_TOL_M

    # -- FusionModel ----------------------------------------------------------------------------
    def process(self, sample: Sample) -> bool:
        """Fuse one reading (time order); True when the estimate changed."""
        v = sample.values
        if len(v) != 6:  # not a vl53l1 sample
            self.counts["invalid"] += 1
            return False
        s = self.health.observe((sample.name, sample.node), sample.t, v)
        self.health.tick(sample.t)
        if not self._uses(s.mount):
            return False
        if not self.health.usable(s):
            self.counts["invalid"] += 1
            return False
        d = float(v[0])
        if self.imm is None:
            self._start(sample.t, *self._initial(d))
            self.health.fused(s, True)
            self.counts["fused"] += 1
            return True
        assert self.t is not None
        if sample.t < self.t - self.max_lag:
            self.counts["late"] += 1
            return False
        before = self._snapshot() if self._onset_entry else None
        self._advance(sample.t)
        h, jac = self._measurement(s.mount)
        assert self.imm is not None
        accepted, _ = self.imm.update(s.label, d, h, jac, self.var, self.gate)
        pending, self._pending = self._pending, None
        if not accepted and pending is not None and self._onset(pending, sample, s, d):
            return True
        self.health.fused(s, accepted, blame=self.kind in ("fused", "plane"))
        if accepted:
            self._gated_in_row = 0
            self.counts["fused"] += 1
            return True
        self.counts["gated"] += 1
        self._gated_in_row += 1
        if self._gated_in_row >= self.relock_after:
            self._relock(sample.t, d, s.mount)
            return True
        if before is not None:
            self._pending = (before, sample.t, (sample.name, sample.node), d)
        return False

    def _measurement(self, mount: tuple[float, float]):
        """(h, Jacobian) of a reading from the sensor at ``mount`` (m, on the board)."""
        if self.kind == "plane":
            x, y = mount

            def h(st: np.ndarray) -> float:
                return range_of(st[2], st[3], st[4], x, y)

            def jac(st: np.ndarray) -> np.ndarray:
                return np.array([0.0, 0.0, *range_jacobian(st[2], st[3], st[4], x, y)])

            return h, jac
        row = np.zeros(self.n)
        row[self.ix] = 1.0
        ix = self.ix

        def h_lin(st: np.ndarray) -> float:
            return float(st[ix])

        def jac_lin(st: np.ndarray) -> np.ndarray:
            return row

        return h_lin, jac_lin

    def _snapshot(self) -> tuple:
        """The filter's time and its IMM's state."""
        assert self.imm is not None
        return self.t, self.imm.snapshot()

    def _restore(self, snap: tuple) -> None:
        assert self.imm is not None
        self.t = snap[0]
        self.imm.restore(snap[1])

    def _onset(self, pending: tuple, sample: Sample, s, d: float) -> bool:
        """Two readings in a row refused by every mode: did the board start moving? Both are
        fused again from the state before the first, the still modes entering the moving ones
        with the ``onset`` spread (:mod:`.imm`); True (both fused) when both pass the gate,
        else the state is as it was (the second stays refused). One reading cannot tell a
        move's start from an outlier; two consistent ones can, 33 ms later instead of the
        relock's 100 ms, while a lone outlier (the next reading fits) changes nothing."""
        imm = self.imm
        assert imm is not None
        before, t1, key1, d1 = pending
        s1 = self.health.sensors[key1]
        now = self._snapshot()
        self._restore(before)
        imm.entry = self._onset_entry
        try:
            ok = True
            for t, sensor, z in ((t1, s1, d1), (sample.t, s, d)):
                self._advance(t)
                h, jac = self._measurement(sensor.mount)
                ok, _ = imm.update(sensor.label, z, h, jac, self.var, self.gate)
                if not ok:
                    break
        finally:
            imm.entry = {}
        if not ok:
            self._restore(now)
            return False
        blame = self.kind in ("fused", "plane")
        self.health.fused(s1, True, blame=blame)  # refused a moment ago: forgiven
        self.health.fused(s, True, blame=blame)
        self._gated_in_row = 0
        self.counts["gated"] -= 1  # the first one, fused after all
        self.counts["fused"] += 2
        self.counts["onsets"] += 1
        return True

    def _relock(self, t: float, d: float, mount: tuple[float, float]) -> None:
        """Start again from a reading: the model lost the board (tilt kept)."""
        assert self.imm is not None
        x = self.imm.x
        tilt = (float(x[3]), float(x[4])) if self.kind == "plane" else (0.0, 0.0)
        h = d
        if self.kind == "plane":
            h = (d - range_of(0.0, *tilt, *mount)) * math.cos(tilt[0]) * math.cos(tilt[1])
        x0, P0 = self._initial(h, tilt)
        if self.kind in RELOCK_SPREAD:
            spread_v, spread_a = RELOCK_SPREAD[self.kind]
            P0[0, 0], P0[1, 1] = spread_a**2, spread_v**2
        if self.kind == "plane":
            P = self.imm.P
            P0[3:, 3:] = P[3:, 3:]
        self._start(t, x0, P0)
        self.imm.mu = np.full(len(self.jerks), 1.0 / len(self.jerks))
        self._gated_in_row = 0
        self.health.forgive()
        self.counts["relocks"] += 1

    def _values(self, x: np.ndarray) -> list[float]:
        if self.kind == "cv":
            head = [x[1], x[0]]
        else:
            head = [x[2], x[1], x[0]]
            if self.kind == "plane":
                head += [x[3], x[4]]
        return [float(v) for v in head] + [float(self.health.healthy()), float(self.health.mask())]

    def estimate(self) -> tuple[float, list[float]] | None:
        """(time, values) of the current estimate, None before the first reading."""
        if self.imm is None or self.t is None:
            return None
        return self.t, self._values(self.imm.x)

    def forecast(self, t: float) -> tuple[float, list[float]] | None:
        """The estimate predicted to ``t`` (no earlier than the state's time) without changing
        the filter: each mode's state carried forward by its own model (a still board stays,
        a moving one keeps its velocity and acceleration), mixed by the mode probabilities."""
        if self.imm is None or self.t is None:
            return None
        tau = max(0.0, t - self.t)
        imm = self.imm
        x = sum(
            mu * (self._matrices(j, tau)[0] @ f.x if tau > 0 else f.x)
            for j, (mu, f) in enumerate(zip(imm.mu, imm.filters, strict=True))
        )
        return self.t + tau, self._values(x)

    def mode_probabilities(self) -> list[float]:
        """The IMM's current mode probabilities (one 1.0 for a single mode)."""
        return [] if self.imm is None else [float(m) for m in self.imm.mu]

    def counters(self) -> dict[str, int]:
        """Readings fused, gated, invalid (or from faulty sensors), relocks, onsets, late; the
        sensors' fault events, recoveries and current codes."""
        return {**self.counts, **self.health.counters()}
