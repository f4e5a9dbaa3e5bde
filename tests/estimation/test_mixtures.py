"""Gaussian mixtures: the moments against a large sample of the mixture, and the
Bhattacharyya distance against its closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hera.estimation import bhattacharyya, mixture


def test_the_moments_are_those_of_a_sample_of_the_mixture():
    rng = np.random.default_rng(3)
    xs = [np.array([0.0, 1.0]), np.array([2.0, -1.0]), np.array([1.0, 4.0])]
    Ps = [np.diag([1.0, 0.5]), np.array([[2.0, 0.3], [0.3, 1.0]]), 0.2 * np.eye(2)]
    w = np.array([0.5, 0.3, 0.2])
    x, P = mixture(xs, Ps, w)
    n = 400_000
    k = rng.choice(3, size=n, p=w)
    draws = np.empty((n, 2))
    for j in range(3):
        idx = k == j
        draws[idx] = rng.multivariate_normal(xs[j], Ps[j], size=int(idx.sum()))
    np.testing.assert_allclose(x, draws.mean(axis=0), atol=0.01)
    np.testing.assert_allclose(P, np.cov(draws.T), atol=0.02)
    assert np.array_equal(P, P.T)


def test_one_component_is_itself():
    x0, P0 = np.array([1.0, 2.0]), np.array([[2.0, 0.5], [0.5, 1.0]])
    x, P = mixture([x0], [P0], [1.0])
    np.testing.assert_array_equal(x, x0)
    np.testing.assert_array_equal(P, P0)


def test_the_bhattacharyya_distance_in_closed_form():
    P = np.diag([4.0, 1.0])
    assert bhattacharyya(np.zeros(2), P, np.zeros(2), P) == pytest.approx(0.0, abs=1e-15)
    # equal covariances: d^2 / (8 sigma^2) along an axis
    d = bhattacharyya(np.array([2.0, 0.0]), P, np.zeros(2), P)
    assert d == pytest.approx(4.0 / (8 * 4.0))
    # equal means, 1-D variances a and b: ln((a + b) / (2 sqrt(a b))) / 2
    a, b = 1.0, 9.0
    got = bhattacharyya(np.zeros(1), np.eye(1) * a, np.zeros(1), np.eye(1) * b)
    assert got == pytest.approx(0.5 * math.log((a + b) / (2 * math.sqrt(a * b))))
    x1, x2 = np.array([1.0, -1.0]), np.array([0.5, 2.0])
    P1, P2 = np.array([[2.0, 0.4], [0.4, 1.0]]), np.diag([0.5, 3.0])
    assert bhattacharyya(x1, P1, x2, P2) == pytest.approx(bhattacharyya(x2, P2, x1, P1))
