"""The lab-2 tracker of seed 000: an EKF on [d, d_dot] that fuses raw Sharp IR voltages.

State x = [d (cm), v (cm/s)], constant-velocity model A = [[1, dt], [0, 1]] with dt from
the samples' measurement times, Q(dt) = diag(q) dt / q_step (the seed's Q is per lab-2
step of 0.1 s). Each sensor sample is one scalar measurement in **voltage space**:
z = V, h(d) = a d^b + c, H = [a b d^(b-1), 0] (the seed's Jacobian), R = the sensor's
variance; Joseph-form update with chi-square gating (``hera.estimation``), linearised
where the update lands rather than at the prediction: the iterated EKF (Bell & Cathey 1993,
"The iterated Kalman filter update as a Gauss-Newton method"; ``iterations`` Gauss-Newton
steps, 1 = the plain EKF). The voltage curve is steep near and flat far, so an estimate 20 cm
short (the seed's poor initial guess) linearised at the prediction takes a reading for far
more information than it holds: the plain EKF then reported 1.4 cm of sigma 6 cm off the
target, and the slow pull-in that followed wound up a velocity of 5-9 cm/s. Samples are
fused one by one at their own times, which is the seed's sequential scalar update with
asynchronous sensors.

A sensor is used only while the estimate lies in its range (the fit folds back below
it), a saturated reading (0 or 3.3 V) is skipped, and a sample older than the estimate is
counted as late and skipped. When half of the last ``lost_window`` samples were gated out
(the sensors disagree with the estimate: the target moved faster than the model allows),
the filter is lost and re-acquires: P gets ``p0`` added, so the next readings pull it
back instead of being gated out for ever. Counters (``counters()``): per sensor
``<name>_used``, ``<name>_gated`` (rejected by the gate: the short sensor's second spike,
heavy tails) and ``<name>_out_of_range``; ``late``, ``saturated``, ``reacquired``,
``merged`` (the start hypotheses became one, below).

The start's velocity is not known: the block may be at rest or already moving. A single
Gaussian prior must pick one spread, and both picks fail a case: a wide one (5 cm/s) lets
the first second's noise wind up a velocity of 4-6 cm/s on a block at rest, so the estimate
wanders 2 cm; a narrow one (1 cm/s) takes up to 1.8 s to catch a block that starts moving.
The prior is therefore a mixture of the two, run exactly as a static multiple-model
estimator (Magill 1965; Bar-Shalom, Li & Kirubarajan 2001, sec. 11.6.2): one EKF per
hypothesis, each weighted by the likelihood of the readings it was given (a reading its gate
refused counts as one on the gate's edge, so one outlier cannot decide), the estimate their
moment-matched mean and covariance. A hypothesis whose weight falls under ``PRUNE`` is
dropped; the two are merged into one when they have become the same Gaussian (Bhattacharyya
distance under ``MERGE``), which happens once the readings outweigh the priors.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from hera.estimation import (
    ExtendedKalmanFilter,
    NoiseRate,
    Observations,
    bhattacharyya,
    gate_threshold,
    mixture,
)
from hera.models.ir.calibration import PowerLaw, sensor_fits
from hera.store import Sample

DEFAULT_SENSORS = {"ir_medium": "GP2Y0A21YK0F", "ir_long": "GP2Y0A02YK0F"}
SATURATED = (1e-3, 3.3 - 1e-3)
MIN_D = 1.0
"""The state's distance is kept >= 1 cm, where the fits are still defined (the seed's
firmware clamps the same way)."""
PRUNE = 1e-4
"""A start hypothesis whose weight falls under this is dropped."""
MERGE = 1e-3
"""Two start hypotheses this close (Bhattacharyya distance) are merged into one."""


def _cv(x: np.ndarray, dt: float, u: Any = None) -> np.ndarray:
    """The constant-velocity model: [d + dt v, v]."""
    return np.array([x[0] + dt * x[1], x[1]])


def _cv_jacobian(x: np.ndarray, dt: float, u: Any = None) -> np.ndarray:
    return np.array([[1.0, dt], [0.0, 1.0]])


class _Hypothesis:
    """One start hypothesis: its EKF and the log of its (unnormalised) weight."""

    __slots__ = ("ekf", "log_w")

    def __init__(self, ekf: ExtendedKalmanFilter, log_w: float) -> None:
        self.ekf = ekf
        self.log_w = log_w


def _pair(value: Any, what: str) -> tuple[float, float]:
    if (
        not isinstance(value, Sequence)
        or len(value) != 2
        or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in value)
    ):
        raise ValueError(f"{what} must be two numbers, got {value!r}")
    return float(value[0]), float(value[1])


class IrTracker:
    """The EKF of the module docstring. Settings: ``sensors`` (publication name ->
    variant), ``fits`` (name -> [a, b, c]) and ``r`` (name -> V^2) to override the lab-1
    calibration, ``q`` ([cm^2, (cm/s)^2] per ``q_step`` s), ``x0`` ([cm, cm/s]; None:
    start from the first reading inverted), ``p0`` (variances: the start's, for a block
    that may be moving, and what a lost filter's covariance gets added), ``v0_still``
    ((cm/s)^2: the start's second hypothesis, a block at rest, with p0's distance variance
    and this velocity variance; 0: p0 alone), ``gate`` (chi-square probability; 0: no
    gate), ``lost_window`` (samples over which half gated out means "lost"),
    ``iterations`` (Gauss-Newton steps of the update; 1: the plain EKF)."""

    columns = ("distance [cm]", "velocity [cm/s]", "sigma [cm]", "gated")

    def __init__(
        self,
        sensors: Mapping[str, str] | None = None,
        fits: Mapping[str, Any] | None = None,
        r: Mapping[str, float] | None = None,
        q: Sequence[float] = (0.002, 0.03),
        q_step: float = 0.1,
        x0: Sequence[float] | None = None,
        p0: Sequence[float] = (100.0, 25.0),
        v0_still: float = 1.0,
        gate: float = 0.999,
        lost_window: int = 20,
        iterations: int = 3,
    ) -> None:
        self.laws: dict[str, PowerLaw] = sensor_fits(sensors or DEFAULT_SENSORS, fits, r)
        self.inputs = tuple(self.laws)
        qd, qv = _pair(q, "q")
        if qd < 0 or qv < 0 or not q_step > 0:
            raise ValueError(f"q must be two variances >= 0 and q_step > 0, got {q!r}, {q_step!r}")
        self.q = np.array([qd, qv]) / float(q_step)
        self.x0 = None if x0 is None else _pair(x0, "x0")
        p = _pair(p0, "p0")
        if not (p[0] > 0 and p[1] > 0):
            raise ValueError(f"p0 must be two variances > 0, got {p0!r}")
        self.p0 = np.diag(p)
        if not (
            isinstance(v0_still, (int, float))
            and not isinstance(v0_still, bool)
            and 0 <= v0_still < math.inf
        ):
            raise ValueError(f"v0_still must be a variance >= 0 (0: p0 alone), got {v0_still!r}")
        self.v0_still = float(v0_still)
        if not 0 <= gate < 1:
            raise ValueError(f"gate must be a probability in [0, 1) (0: no gate), got {gate!r}")
        self.gate = float(gate) or None
        self._threshold = None if self.gate is None else gate_threshold(self.gate, 1)
        if isinstance(lost_window, bool) or not isinstance(lost_window, int) or lost_window < 2:
            raise ValueError(f"lost_window must be an integer >= 2, got {lost_window!r}")
        self._recent: deque[bool] = deque(maxlen=lost_window)
        if isinstance(iterations, bool) or not isinstance(iterations, int) or iterations < 1:
            raise ValueError(f"iterations must be an integer >= 1, got {iterations!r}")
        self.iterations = iterations
        self.hypotheses: list[_Hypothesis] = []
        self.t: float | None = None
        self._counts: dict[str, int] = {"late": 0, "saturated": 0, "reacquired": 0, "merged": 0}
        for name in self.inputs:
            for what in ("used", "gated", "out_of_range"):
                self._counts[f"{name}_{what}"] = 0
        self.gated = 0

    @property
    def ekf(self) -> ExtendedKalmanFilter | None:
        """The EKF of the likeliest start hypothesis (the only one once they merged)."""
        if not self.hypotheses:
            return None
        return max(self.hypotheses, key=lambda h: h.log_w).ekf

    def _start(self, law: PowerLaw, volts: float) -> bool:
        if self.x0 is not None:
            d0, v0 = self.x0
        else:
            d0 = law.distance(volts)
            if not law.d_min <= d0 <= law.d_max:
                return False  # wait for a reading the fit can invert
            v0 = 0.0
        priors = [self.p0]
        if self.v0_still > 0:
            priors.append(np.diag([self.p0[0, 0], self.v0_still]))
        log_w = -math.log(len(priors))
        self.hypotheses = [
            _Hypothesis(
                ExtendedKalmanFilter([d0, v0], p, _cv, NoiseRate(self.q), _cv_jacobian), log_w
            )
            for p in priors
        ]
        return True

    def process(self, sample: Sample) -> bool:
        law = self.laws.get(sample.name)
        if law is None or not sample.values:
            return False
        volts = float(sample.values[0])
        if not SATURATED[0] < volts < SATURATED[1]:
            self._counts["saturated"] += 1
            return False
        if not self.hypotheses:
            if not self._start(law, volts):
                return False
            self.t = sample.t
            if self.x0 is None:
                self._counts[f"{sample.name}_used"] += 1
                return True
        elif sample.t < self.t:
            self._counts["late"] += 1
            return False
        lead = self.ekf
        verdict: bool | None = None  # the likeliest hypothesis's: gated out or not
        for hyp in self.hypotheses:
            rejected = self._fuse(hyp, law, sample, volts)
            if hyp.ekf is lead:
                verdict = rejected
        if sample.t > self.t:
            self.t = sample.t
        if verdict is None:
            self._counts[f"{sample.name}_out_of_range"] += 1
            return True
        if verdict:
            self._counts[f"{sample.name}_gated"] += 1
            self.gated += 1
        else:
            self._counts[f"{sample.name}_used"] += 1
        recent = self._recent
        recent.append(verdict)
        if len(recent) == recent.maxlen and 2 * sum(recent) >= len(recent):
            for hyp in self.hypotheses:
                hyp.ekf.P = hyp.ekf.P + self.p0
                self._floor(hyp.ekf)
            self._counts["reacquired"] += 1
            recent.clear()
        if len(self.hypotheses) > 1:
            self._prune_or_merge()
        return True

    def _fuse(self, hyp: _Hypothesis, law: PowerLaw, sample: Sample, volts: float) -> bool | None:
        """One hypothesis takes the reading: predicted to its time, then updated and
        weighted by the reading's likelihood. Returns whether its gate refused the reading,
        None when the estimate is outside the sensor's range (no update, no weight)."""
        ekf = hyp.ekf
        assert self.t is not None
        if sample.t > self.t:
            ekf.predict(sample.t - self.t)
        d = float(ekf.x[0])
        if not law.d_min <= d <= law.d_max:
            self._floor(ekf)
            return None
        at = self._linearisation_point(ekf, law, volts)
        va, slope = law.volts(at), law.slope(at)
        if len(self.hypotheses) > 1:
            # the reading's likelihood under this hypothesis, N(volts; h(x), S) (the
            # Gaussian sum's weight update), a refused reading counted at the gate's edge
            s = slope * slope * float(ekf.P[0, 0]) + law.var
            y = volts - (va + slope * (d - at))
            nis = y * y / s
            if self._threshold is not None:
                nis = min(nis, self._threshold)
            hyp.log_w -= 0.5 * (nis + math.log(2.0 * math.pi * s))
        obs = Observations().add(  # h linearised at ``at``: the iterated EKF's last step
            sample.name,
            [volts],
            h=lambda x: np.array([va + slope * (x[0] - at)]),
            jacobian=lambda x: np.array([[slope, 0.0]]),
            R=law.var,
        )
        result = ekf.update(obs, gate=self.gate)
        self._floor(ekf)
        return bool(result.rejected)

    def _prune_or_merge(self) -> None:
        """Normalise the weights; drop a hypothesis under ``PRUNE``; merge two that have
        become the same Gaussian (moment matching)."""
        hyps = self.hypotheses
        top = max(h.log_w for h in hyps)
        for h in hyps:
            h.log_w -= top
        total = math.log(sum(math.exp(h.log_w) for h in hyps))
        for h in hyps:
            h.log_w -= total
        hyps = [h for h in hyps if h.log_w >= math.log(PRUNE)]
        if len(hyps) == 2:
            a, b = hyps[0].ekf, hyps[1].ekf
            if bhattacharyya(a.x, a.P, b.x, b.P) < MERGE:
                w = [math.exp(h.log_w) for h in hyps]  # normalised above
                x, P = mixture([a.x, b.x], [a.P, b.P], w)
                a.reset(x, P)
                hyps = [_Hypothesis(a, 0.0)]
                self._counts["merged"] += 1
        if len(hyps) == 1:
            hyps[0].log_w = 0.0
        self.hypotheses = hyps

    def _linearisation_point(self, ekf: ExtendedKalmanFilter, law: PowerLaw, volts: float) -> float:
        """The distance (cm) to linearise the reading ``volts`` at: the predicted one moved by
        ``iterations - 1`` Gauss-Newton steps of the update (Bell & Cathey 1993, eq. 9:
        ``x_{i+1} = x + K_i (z - h(x_i) - H_i (x - x_i))``, ``K_i`` the gain with ``H_i``
        linearised at ``x_i``), kept within the fit's range; the filter's own update then
        makes the last step, so its gate and covariance use the final linearisation."""
        d, p_dd = float(ekf.x[0]), float(ekf.P[0, 0])
        at = d
        for _ in range(self.iterations - 1):
            slope = law.slope(at)
            gain = p_dd * slope / (slope * slope * p_dd + law.var)  # K_i's distance row
            nxt = d + gain * (volts - law.volts(at) - slope * (d - at))
            nxt = min(max(nxt, law.d_min), law.d_max)
            if abs(nxt - at) < 1e-6:
                return nxt
            at = nxt
        return at

    @staticmethod
    def _floor(ekf: ExtendedKalmanFilter) -> None:
        if ekf.x[0] < MIN_D:
            ekf.x[0] = MIN_D

    def estimate(self) -> tuple[float, list[float]] | None:
        if not self.hypotheses or self.t is None:
            return None
        hyps = self.hypotheses
        if len(hyps) == 1:
            x, P = hyps[0].ekf.x, hyps[0].ekf.P
        else:
            log_w = np.array([h.log_w for h in hyps])  # unnormalised after an out-of-range
            w = np.exp(log_w - log_w.max())  # reading: no overflow
            x, P = mixture([h.ekf.x for h in hyps], [h.ekf.P for h in hyps], w / w.sum())
        return self.t, [float(x[0]), float(x[1]), math.sqrt(max(P[0, 0], 0.0)), float(self.gated)]

    def counters(self) -> dict[str, int]:
        return dict(self._counts)
