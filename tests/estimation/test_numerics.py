"""Sequential vs joint, fast vs general paths, UKF vs KF, non-finite rejection, PD checks."""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hera.estimation import (
    Block,
    CovarianceError,
    ExtendedKalmanFilter,
    KalmanFilter,
    NonFiniteInputError,
    Observations,
    UnscentedKalmanFilter,
    assert_positive_definite,
    joseph_update,
    linearised_update,
    numerical_jacobian,
)


def _spd(rng, n, scale=1.0):
    A = rng.normal(size=(n, n))
    return scale * (A @ A.T + n * np.eye(n))


def _mixed_blocks(rng, n, sizes, full_R=False):
    obs = Observations()
    for i, m in enumerate(sizes):
        H = rng.normal(size=(m, n))
        var = rng.uniform(0.1, 1.0, size=m)
        R = np.diag(var) if full_R else var
        if i % 2:
            C = H.copy()
            obs.add(f"b{i}", rng.normal(size=m), h=lambda x, C=C: np.tanh(C @ x), R=R)
        else:
            obs.add(f"b{i}", rng.normal(size=m), H=H, R=R)
    return obs


@pytest.mark.parametrize("n", [1, 2, 4, 9])
@pytest.mark.parametrize("sizes", [(1,), (2,), (3,), (1, 2), (3, 1, 2), (4,), (2, 2, 3)])
@pytest.mark.parametrize("joseph", [True, False])
def test_sequential_equals_joint(n, sizes, joseph):
    rng = np.random.default_rng(n * 100 + sum(sizes))
    x, P = rng.normal(size=n), _spd(rng, n)
    obs = _mixed_blocks(rng, n, sizes)
    xj, Pj, rj = linearised_update(x, P, obs.blocks, joseph=joseph, method="joint")
    xs, Ps, rs = linearised_update(x, P, obs.blocks, joseph=joseph, method="sequential")
    np.testing.assert_allclose(xs, xj, rtol=1e-9, atol=1e-11)
    np.testing.assert_allclose(Ps, Pj, rtol=1e-9, atol=1e-11)
    assert rj.nis == pytest.approx(rs.nis)


@pytest.mark.parametrize("n", [1, 2, 4, 9])
@pytest.mark.parametrize("m", [1, 2, 3])
@pytest.mark.parametrize("joseph", [True, False])
def test_fast_path_equals_general_path(n, m, joseph):
    """A diagonal R given as variances takes the small fast path; the same R as a matrix
    takes the general path; and both equal the textbook formulas written out here."""
    rng = np.random.default_rng(7 * n + m)
    x, P = rng.normal(size=n), _spd(rng, n)
    H, var, z = rng.normal(size=(m, n)), rng.uniform(0.1, 1, m), rng.normal(size=m)
    fast = linearised_update(x, P, [Block("a", z, var, H=H)], joseph=joseph)
    gen = linearised_update(x, P, [Block("a", z, np.diag(var), H=H)], joseph=joseph)
    R = np.diag(var)
    S = H @ P @ H.T + R
    K = P @ H.T @ np.linalg.inv(S)
    x_ref = x + K @ (z - H @ x)
    P_ref = joseph_update(P, K, H, R) if joseph else P - K @ H @ P
    for xo, Po, res in (fast, gen):
        np.testing.assert_allclose(xo, x_ref, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(Po, P_ref, rtol=1e-9, atol=1e-11)
        y = z - H @ x
        assert res.nis["a"] == pytest.approx(float(y @ np.linalg.solve(S, y)), rel=1e-9)
        np.testing.assert_array_equal(Po, Po.T)


def test_blocks_of_mixed_sizes_stack_like_one_block():
    rng = np.random.default_rng(3)
    n = 5
    x, P = rng.normal(size=n), _spd(rng, n)
    H1, H2 = rng.normal(size=(1, n)), rng.normal(size=(3, n))
    R2 = _spd(rng, 3, 0.1)
    z1, z2 = rng.normal(size=1), rng.normal(size=3)
    two = Observations().add("a", z1, H=H1, R=0.3).add("b", z2, H=H2, R=R2)
    R = np.zeros((4, 4))
    R[0, 0], R[1:, 1:] = 0.3, R2
    one = Observations().add("ab", np.r_[z1, z2], H=np.vstack([H1, H2]), R=R)
    xa, Pa, res = linearised_update(x, P, two.blocks)
    xb, Pb, _ = linearised_update(x, P, one.blocks)
    np.testing.assert_allclose(xa, xb, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(Pa, Pb, rtol=1e-10, atol=1e-12)
    assert res.accepted == ["a", "b"] and res.rejected == []


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"R": 1.0}, "give H \\(linear\\) or h \\(function\\), got neither"),
        ({"R": 1.0, "H": [[1.0, 0.0]], "h": np.sin}, "give H .*, not both"),
        ({"R": 1.0, "H": np.ones((3, 2))}, "H has shape \\(3, 2\\), z has 2 rows"),
        ({"R": [1.0, 2.0, 3.0], "h": np.sin}, "3 variances for 2 rows"),
        ({"R": np.eye(3), "h": np.sin}, "R has shape \\(3, 3\\), expected \\(2, 2\\)"),
        ({"R": 0.0, "h": np.sin}, "variance R must be > 0"),
    ],
)
def test_bad_block_named_in_error(kwargs, message):
    """A malformed block is refused when it is added, naming the block and what is wrong;
    the observations already added stay as they were."""
    obs = Observations().add("good", [0.0, 1.0], h=np.sin, R=[1.0, 1.0])
    with pytest.raises(ValueError, match=f"block 'sonar': {message}"):
        obs.add("sonar", [1.0, 2.0], **kwargs)
    assert obs.labels == ["good"]


def test_no_blocks_means_predict_only():
    kf = KalmanFilter([1.0, 2.0], np.eye(2), F=np.eye(2), Q=np.eye(2))
    res = kf.update(Observations())
    assert not res and res.outcomes == []
    np.testing.assert_array_equal(kf.x, [1.0, 2.0])


@pytest.mark.parametrize("n,m", [(1, 1), (2, 2), (3, 1), (4, 3), (6, 4)])
def test_ukf_equals_kf_on_linear_model(n, m):
    rng = np.random.default_rng(50 + n + m)
    F = np.eye(n) + 0.1 * rng.normal(size=(n, n))
    Q, P0, R = _spd(rng, n, 0.01), _spd(rng, n), _spd(rng, m, 0.1)
    H = rng.normal(size=(m, n))
    x0 = rng.normal(size=n)
    kf = KalmanFilter(x0, P0, F=F, Q=Q)
    ukf = UnscentedKalmanFilter(x0, P0, f=lambda x, dt, u: F @ x, Q=Q, alpha=0.7, kappa=1.0)
    ukf_h = UnscentedKalmanFilter(
        x0, P0, f=lambda X, dt, u: X @ F.T, Q=Q, alpha=0.7, kappa=1.0, batched=True
    )
    for _ in range(15):
        z = rng.normal(size=m)
        for filt in (kf, ukf, ukf_h):
            filt.predict(0.1)
        kf.update(Observations().add("z", z, H=H, R=R))
        ukf.update(Observations().add("z", z, H=H, R=R))
        ukf_h.update(Observations().add("z", z, h=lambda X: X @ H.T, R=R, vectorized=True))
        for u in (ukf, ukf_h):
            np.testing.assert_allclose(u.x, kf.x, rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(u.P, kf.P, rtol=1e-9, atol=1e-9)


def _filters():
    n = 3
    P0 = np.diag([1.0, 2.0, 3.0])
    yield KalmanFilter(np.ones(n), P0, F=np.eye(n), Q=0.1 * np.eye(n))
    yield ExtendedKalmanFilter(np.ones(n), P0, f=lambda x, dt, u: x, Q=0.1 * np.eye(n))
    yield UnscentedKalmanFilter(np.ones(n), P0, f=lambda x, dt, u: x, Q=0.1 * np.eye(n))


BAD_INPUTS = [
    ("z", dict(z=[1.0, math.nan], H=np.eye(2, 3), R=1.0)),
    ("z", dict(z=[math.inf], H=np.ones((1, 3)), R=1.0)),
    ("H", dict(z=[1.0], H=[[1.0, math.nan, 0.0]], R=1.0)),
    ("H", dict(z=[1.0, 2.0, 3.0, 4.0], H=np.full((4, 3), math.inf), R=1.0)),
]


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
@pytest.mark.parametrize("what,kwargs", BAD_INPUTS)
def test_nonfinite_block_rejected_state_unchanged(what, kwargs):
    for filt in _filters():
        filt.predict(0.1)
        x0, P0 = filt.x.copy(), filt.P.copy()
        obs = Observations().add("good", [1.0], H=[[1.0, 0, 0]], R=0.5)
        obs.add("sonar-7", **kwargs)
        with pytest.raises(NonFiniteInputError, match="sonar-7") as err:
            filt.update(obs)
        assert isinstance(err.value, ValueError)
        assert err.value.label == "sonar-7"
        if not isinstance(filt, UnscentedKalmanFilter):
            assert err.value.what == what
        np.testing.assert_array_equal(filt.x, x0)
        np.testing.assert_array_equal(filt.P, P0)


def test_nonfinite_jacobian_rejected():
    ekf = next(f for f in _filters() if isinstance(f, ExtendedKalmanFilter))
    x0, P0 = ekf.x.copy(), ekf.P.copy()
    obs = Observations().add(
        "mag", [0.3], h=lambda x: x[:1], jacobian=lambda x: [[math.nan, 0, 0]], R=0.1
    )
    with pytest.raises(NonFiniteInputError, match="'mag'.*Jacobian"):
        ekf.update(obs)
    np.testing.assert_array_equal(ekf.x, x0)
    np.testing.assert_array_equal(ekf.P, P0)


def test_nonfinite_predict_rejected():
    kf = KalmanFilter(np.ones(2), np.eye(2), F=np.eye(2), Q=np.eye(2))
    with pytest.raises(NonFiniteInputError):
        kf.predict(0.1, Q=np.array([[1.0, math.nan], [math.nan, 1.0]]))
    np.testing.assert_array_equal(kf.P, np.eye(2))


def _bad_step(case):
    """The step of ``case`` on a fresh 3-state filter (n <= unrolled.MAX_N), and the filter."""
    H0, H1, big = [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]], [[1e300, 1e300, 0.0]]
    kf = KalmanFilter(np.ones(3), np.eye(3), F=np.eye(3), Q=0.1, B=np.eye(3))
    obs = Observations()
    if case == "inf H, one block":
        obs.add("b", [1.0], H=[[math.inf, 0.0, 0.0]], R=1.0)
    elif case == "inf H, two blocks":
        obs.add("a", [1.0], H=H0, R=1.0).add("b", [1.0], H=[[0.0, math.inf, 0.0]], R=1.0)
    elif case == "inf H, four rows (the general path)":
        obs.add("a", [1.0] * 3, H=np.eye(3), R=1.0).add("b", [1.0], H=[[0, 0, math.inf]], R=1.0)
    elif case == "S overflows":
        obs.add("b", [1.0], H=big, R=1.0)
    elif case == "S overflows, two blocks":
        obs.add("a", [1.0], H=H1, R=1.0).add("b", [1.0], H=big, R=1.0)
    if len(obs):
        return kf, lambda: kf.update(obs)
    if case == "F P F^T overflows":
        return kf, lambda: kf.predict(0.1, F=1e200)
    if case == "nan u":
        return kf, lambda: kf.predict(0.1, u=[0.0, math.nan, 0.0])
    ekf = ExtendedKalmanFilter(np.ones(3), np.eye(3), f=lambda x, dt, u: 1e200 * x, Q=0.1)
    if case == "nan f(x)":
        ekf.f = lambda x, dt, u: x * math.nan
    return ekf, lambda: ekf.predict(0.1)


# Each names the block or step and what was wrong, with no numpy RuntimeWarning first: at
# n <= unrolled.MAX_N and on the general path (numpy still warns above MAX_N on the
# single-block and predict paths, and in the UKF, where silencing it would cost every step).
@pytest.mark.filterwarnings("error::RuntimeWarning")
@pytest.mark.parametrize("name", ["numpy", "numba"])
@pytest.mark.parametrize(
    "case, match",
    [
        ("inf H, one block", r"^observation block 'b': H contains NaN or inf$"),
        ("inf H, two blocks", r"^observation block 'b': H contains NaN or inf$"),
        ("inf H, four rows (the general path)", r"^observation block 'b': H contains NaN"),
        ("S overflows", r"^observation block 'b': the innovation y or its covariance S = H P "),
        ("S overflows, two blocks", r"^observation blocks 'a, b': .* overflowed \(every input"),
        ("F P F^T overflows", r"^step 'predict': F x \+ B u or F P F\^T \+ Q overflowed \(every"),
        ("nan u", r"^step 'predict': the control input u contains NaN or inf$"),
        ("EKF F P F^T overflows", r"^step 'predict': F P F\^T \+ Q overflowed \(every input"),
        ("nan f(x)", r"^step 'predict': f\(x\) contains NaN or inf$"),
    ],
)
def test_bad_values_and_overflows_are_named_without_numpy_warnings(use, name, case, match):
    use(name)
    filt, step = _bad_step(case)
    x0, P0 = filt.x.copy(), filt.P.copy()
    with pytest.raises(NonFiniteInputError, match=match):
        step()
    np.testing.assert_array_equal(filt.x, x0)
    np.testing.assert_array_equal(filt.P, P0)


def test_not_positive_definite_raises_clear_error():
    with pytest.raises(CovarianceError, match="P0 is not positive definite"):
        assert_positive_definite(np.array([[1.0, 2.0], [2.0, 1.0]]), "P0")
    kf = KalmanFilter(np.zeros(2), np.eye(2), F=np.eye(2), Q=np.zeros((2, 2)))
    with pytest.raises(CovarianceError, match="'neg'"):
        kf.update(Observations().add("neg", [0.0, 0.0], H=np.eye(2), R=np.diag([-5.0, 1.0])))
    np.testing.assert_array_equal(kf.P, np.eye(2))


def test_numerical_jacobian_matches_analytic():
    rng = np.random.default_rng(0)
    x = rng.normal(size=4)

    def fun(v):
        return np.array([np.sin(v[0]) * v[1], v[2] ** 3 - v[3], np.exp(0.3 * v[0])])

    J = np.array(
        [
            [np.cos(x[0]) * x[1], np.sin(x[0]), 0, 0],
            [0, 0, 3 * x[2] ** 2, -1],
            [0.3 * np.exp(0.3 * x[0]), 0, 0, 0],
        ]
    )
    np.testing.assert_allclose(numerical_jacobian(fun, x), J, rtol=1e-7, atol=1e-8)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**31 - 1),
    n=st.sampled_from([1, 2, 3, 5, 9]),
    kind=st.sampled_from(["kf", "ekf", "ukf"]),
    method=st.sampled_from(["auto", "joint", "sequential"]),
)
def test_covariance_stays_symmetric_positive_definite(seed, n, kind, method):
    """Long random runs with random dt, random block sets (sometimes none), badly scaled
    variances: P stays exactly symmetric and positive definite."""
    rng = np.random.default_rng(seed)
    A = np.eye(n) + 0.2 * rng.normal(size=(n, n))
    Q = np.diag(rng.uniform(1e-8, 1e-1, n))
    P0 = np.diag(10.0 ** rng.uniform(-3, 3, n))
    x0 = rng.normal(size=n)
    if kind == "kf":
        filt = KalmanFilter(x0, P0, F=lambda dt: np.eye(n) + dt * (A - np.eye(n)), Q=Q)
    elif kind == "ekf":
        filt = ExtendedKalmanFilter(x0, P0, f=lambda x, dt, u: x + dt * np.tanh(A @ x), Q=Q)
    else:
        filt = UnscentedKalmanFilter(x0, P0, f=lambda x, dt, u: x + dt * np.tanh(A @ x), Q=Q)
    for step in range(120):
        filt.predict(float(rng.uniform(0.001, 0.5)))
        obs = Observations()
        for j in range(int(rng.integers(0, 4))):
            m = int(rng.integers(1, 4))
            var = 10.0 ** rng.uniform(-6, 2, m)
            obs.add(f"s{j}", rng.normal(size=m), H=rng.normal(size=(m, n)), R=var)
        if kind == "ukf":
            filt.update(obs)
        else:
            filt.update(obs, method=method)
        P = filt.P
        assert np.isfinite(P).all()
        np.testing.assert_array_equal(P, P.T)
        assert_positive_definite(P, f"P at step {step}")
