"""NoiseRate: Q(dt) = Qc dt as a picklable process noise."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from hera.estimation import ExtendedKalmanFilter, NoiseRate, Observations


def test_the_rate_times_the_step_for_a_scalar_a_vector_and_a_matrix():
    assert NoiseRate(0.5)(0.1) == pytest.approx(0.05)
    np.testing.assert_array_equal(NoiseRate([1.0, 4.0])(0.5), np.diag([0.5, 2.0]))
    m = np.array([[2.0, 0.5], [0.5, 1.0]])
    np.testing.assert_array_equal(NoiseRate(m)(2.0), 2.0 * m)


@pytest.mark.parametrize("rate", [-1.0, [1.0, -0.1], [np.nan, 1.0], np.ones((2, 2, 2))])
def test_a_bad_rate_is_refused_naming_it(rate):
    with pytest.raises(ValueError, match="NoiseRate: the rate"):
        NoiseRate(rate)


def f(x, dt, u=None):
    return np.array([x[0] + dt * x[1], x[1]])


def jac(x, dt, u=None):
    return np.array([[1.0, dt], [0.0, 1.0]])


def test_a_filter_with_it_pickles_and_runs_as_with_a_lambda():
    q = [0.02, 0.3]
    a = ExtendedKalmanFilter([0.0, 1.0], np.eye(2), f, NoiseRate(q), jac)
    b = ExtendedKalmanFilter([0.0, 1.0], np.eye(2), f, lambda dt: np.diag(q) * dt, jac)
    a = pickle.loads(pickle.dumps(a))
    with pytest.raises((pickle.PicklingError, AttributeError)):
        pickle.dumps(b)
    for k in range(20):
        for filt in (a, b):
            filt.predict(0.1 + 0.01 * k)
            filt.update(Observations().add("z", [0.1 * k], H=[[1.0, 0.0]], R=0.5))
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.P, b.P)
