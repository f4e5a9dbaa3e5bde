"""Quaternion and angle helpers (thesis eqs. 2.14, 2.15, 6.7, 7.5)."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hera.estimation import (
    align_sign,
    matrix_to_quat,
    nearest_branch,
    quat_multiply,
    quat_normalize,
    quat_to_matrix,
    wrap_angle,
)


def _axis_angle(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.r_[math.cos(angle / 2), math.sin(angle / 2) * axis]


def _rodrigues(axis, angle):
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


quats = st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(
    lambda v: np.linalg.norm(v) > 1e-3
)


def test_matrix_matches_rodrigues():
    for axis, angle in [([1, 0, 0], 0.3), ([0, 1, 1], -2.0), ([1, 2, 3], 3.1)]:
        np.testing.assert_allclose(
            quat_to_matrix(_axis_angle(axis, angle)), _rodrigues(axis, angle), atol=1e-14
        )


@settings(max_examples=200, deadline=None)
@given(quats)
def test_round_trip_quat_matrix_quat(q):
    q = quat_normalize(q)
    back = matrix_to_quat(quat_to_matrix(q))
    np.testing.assert_allclose(back, align_sign(q, back), atol=1e-12)


@pytest.mark.parametrize("axis", [[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [1, -2, 3]])
@pytest.mark.parametrize("eps", [0.0, 1e-9, 1e-6, 1e-3])
def test_round_trip_near_180_degrees(axis, eps):
    """1 + trace(R) -> 0 near 180 degrees: eq. 2.15 alone would divide by ~0."""
    q = _axis_angle(axis, math.pi - eps)
    back = matrix_to_quat(_rodrigues(axis, math.pi - eps))
    np.testing.assert_allclose(back, align_sign(q, back), atol=1e-12)


@settings(max_examples=100, deadline=None)
@given(quats, quats)
def test_product_is_matrix_product(p, q):
    p, q = quat_normalize(p), quat_normalize(q)
    np.testing.assert_allclose(
        quat_to_matrix(quat_multiply(p, q)), quat_to_matrix(p) @ quat_to_matrix(q), atol=1e-12
    )


def test_sign_alignment():
    pred = quat_normalize([0.9, 0.1, 0.2, 0.3])
    meas = -quat_normalize([0.88, 0.12, 0.2, 0.31])
    aligned = align_sign(meas, pred)
    assert aligned @ pred > 0
    np.testing.assert_array_equal(aligned, -meas)
    np.testing.assert_array_equal(align_sign(-meas, pred), -meas)
    np.testing.assert_allclose(quat_to_matrix(aligned), quat_to_matrix(meas), atol=1e-15)


def test_normalize_rejects_zero():
    with pytest.raises(ValueError):
        quat_normalize([0, 0, 0, 0])


@pytest.mark.parametrize(
    "a,expected",
    [
        (0.0, 0.0),
        (math.pi, math.pi),
        (-math.pi, math.pi),
        (3 * math.pi, math.pi),
        (2 * math.pi, 0.0),
        (-0.5, -0.5),
        (7.0, 7.0 - 2 * math.pi),
        (-7.0, -7.0 + 2 * math.pi),
    ],
)
def test_wrap_angle(a, expected):
    assert wrap_angle(a) == pytest.approx(expected, abs=1e-12)
    assert float(wrap_angle(np.array([a]))[0]) == pytest.approx(expected, abs=1e-12)


@settings(max_examples=200, deadline=None)
@given(st.floats(-1e3, 1e3), st.floats(-1e3, 1e3))
def test_wrap_and_nearest_branch(a, ref):
    w = wrap_angle(a)
    assert -math.pi < w <= math.pi + 1e-12
    assert math.cos(w) == pytest.approx(math.cos(a), abs=1e-9)
    b = nearest_branch(a, ref)
    assert abs(b - ref) <= math.pi + 1e-9
    k = (b - a) / (2 * math.pi)
    assert k == pytest.approx(round(k), abs=1e-9)
