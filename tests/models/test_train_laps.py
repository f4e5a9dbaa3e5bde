"""The lap-timing reference of runs without truth: a constant speed stays constant, a speed
that drifts (as on the thesis's E8 recording) is followed (:mod:`hera.models.train.laps`)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hera.models.train.laps import TREND_T, lap_fit


def passes_of(omega_at, t_end: float, phases: tuple[float, ...], jitter: float, seed: int):
    """Each sonar's near-pass times (s) of a train whose angular speed is ``omega_at(t)``
    (rad/s), integrated finely; a sonar at phase p sees it at theta = p + 2 pi k; each
    time off by N(0, jitter) (the sonar's slow rate), one pass in ten missed."""
    rng = np.random.default_rng(seed)
    dt = 1e-3
    t = np.arange(0.0, t_end, dt)
    theta = np.cumsum([omega_at(x) * dt for x in t])
    out = []
    for p in phases:
        k = np.arange(math.ceil((theta[0] - p) / (2 * math.pi)), (theta[-1] - p) / (2 * math.pi))
        times = np.interp(p + 2 * math.pi * k, theta, t)
        times = times[times > 2.0]
        keep = rng.random(len(times)) > 0.1
        out.append(sorted(times[keep] + rng.normal(0.0, jitter, keep.sum())))
    return out


def worst_error_pct(fit, omega_at) -> float:
    ts = np.linspace(fit.t0, fit.t1, 50)
    return max(abs(2 * math.pi / fit.lap_at(t) / omega_at(t) - 1) * 100 for t in ts)


@pytest.mark.parametrize("seed", range(8))
def test_a_constant_speed_is_fitted_constant(seed):
    """The sonars' pass times of a train at one speed (0.05 s jitter: what is left of E8's
    pass times after its fit) show no trend: the fit stays constant, within 0.3 %."""
    omega = lambda t: 0.905  # noqa: E731
    fit = lap_fit(passes_of(omega, 88.0, (0.3, 2.1), 0.05, seed))
    assert fit.trend == 0.0 and abs(fit.trend_t) < TREND_T, fit
    assert worst_error_pct(fit, omega) < 0.3, fit


@pytest.mark.parametrize("seed", range(8))
def test_a_drifting_speed_is_followed_where_a_constant_fit_is_off(seed):
    """E8's case: the train speeds up by 2.5 % over 88 s. The trend is found and omega(t)
    follows it within 0.4 % everywhere; the constant fit is off by over 0.9 % at an end."""
    omega = lambda t: 0.911 * (1 + 0.025 * t / 88.0)  # noqa: E731
    passes = passes_of(omega, 88.0, (0.3, 2.1), 0.05, seed)
    fit = lap_fit(passes)
    assert fit.trend != 0.0 and abs(fit.trend_t) >= TREND_T, fit
    assert worst_error_pct(fit, omega) < 0.4, fit
    constant = lap_fit(passes, trend=False)
    assert worst_error_pct(constant, omega) > 0.9, constant


def test_too_few_passes_give_no_lap_and_no_trend():
    assert math.isnan(lap_fit([[1.0, 8.0]]).lap)
    fit = lap_fit([[1.0, 8.0, 15.0]])  # three passes: a lap, nothing left to judge a trend
    assert fit.lap == pytest.approx(7.0) and fit.trend == 0.0 and math.isnan(fit.trend_t)
