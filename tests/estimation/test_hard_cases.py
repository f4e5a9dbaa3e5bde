"""Regression tests of issue 18's hard cases, each on both backends, against references
computed another way: exact rational arithmetic (``exact`` fixture), analytic Jacobians, or
the same filter on a continuous branch of the angle (where no wrapping is needed).

Each numbered section is the case of the same number in the issue."""

import math

import numpy as np
import pytest

from hera.estimation import (
    Block,
    CovarianceError,
    ExtendedKalmanFilter,
    KalmanFilter,
    MerweSigmaPoints,
    NonFiniteInputError,
    Observations,
    UnscentedKalmanFilter,
    angle_residual,
    circular_mean,
    linearised_update,
    make_mean,
    make_residual,
    numerical_jacobian,
    wrap_angle,
)

BACKENDS = ["numpy", "numba"]
EPS = np.finfo(float).eps


def _bearing(x):
    return np.array([math.atan2(x[1], x[0])])


# --- 1. Numerical Jacobians difference through the residual -----------------------------


def test_numerical_jacobian_of_a_bearing_across_pi():
    """h = atan2(y, x) at [-10, 0]: h(x +- step) lands on both sides of +-pi. Through
    angle_residual the Jacobian is the analytic [0, x / (x^2 + y^2)] = [0, -0.1]; without
    it a column is ~2 pi / (2 step) (the check fails on the old behaviour)."""
    x = np.array([-10.0, 0.0])
    J = numerical_jacobian(_bearing, x, 1, residual=angle_residual)
    np.testing.assert_allclose(J, [[0.0, -0.1]], atol=1e-9)
    assert abs(numerical_jacobian(_bearing, x, 1)[0, 1]) > 1e4


@pytest.mark.parametrize("name", BACKENDS)
def test_ekf_bearing_update_across_pi(use, name, exact):
    """Issue case 1: z = pi - 0.01, R = 1e-4, P = I, numerical Jacobian. Reference: the exact
    linear update with the analytic H = [0, -0.1] and the wrapped innovation -0.01
    (x[1] = 0.0990, P11 = 0.0099)."""
    use(name)
    z = math.pi - 0.01
    ekf = ExtendedKalmanFilter([-10.0, 0.0], np.eye(2), f=lambda x, dt, u: x, Q=0.0)
    ekf.update(Observations().add("bearing", [z], h=_bearing, R=1e-4, residual=angle_residual))
    y = wrap_angle(z - math.pi)
    xr, Pr, _, _ = exact.update([-10.0, 0.0], np.eye(2), [[0.0, -0.1]], [[1e-4]], y=[y])
    np.testing.assert_allclose(ekf.x, xr, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(ekf.P, Pr, rtol=1e-8, atol=1e-12)
    assert ekf.x[1] == pytest.approx(0.0990099, rel=1e-6)
    assert ekf.P[1, 1] == pytest.approx(0.00990099, rel=1e-6)


@pytest.mark.parametrize("name", BACKENDS)
def test_ekf_predict_of_a_wrapping_heading(use, name, exact):
    """Issue case 1, predict: f wraps the heading, theta + w dt lands exactly on pi. With
    the state's residual the numerical F is the analytic [[1, dt], [0, 1]] and P the exact
    F P F^T + Q; without it P00 is ~1e9."""
    use(name)
    dt = 0.1
    x0 = [math.pi - 0.05, 0.5]
    P0 = np.diag([0.01, 0.0004])
    Q = np.diag([1e-4, 1e-6])

    def f(x, dt, u):
        return np.array([wrap_angle(x[0] + x[1] * dt), x[1]])

    ekf = ExtendedKalmanFilter(x0, P0, f=f, Q=Q, residual_x=make_residual(angles=[0]))
    ekf.predict(dt)
    _, Pr = exact.predict(x0, P0, [[1.0, dt], [0.0, 1.0]], Q)
    np.testing.assert_allclose(ekf.P, Pr, rtol=1e-8)
    plain = ExtendedKalmanFilter(x0, P0, f=f, Q=Q)
    plain.predict(dt)
    assert plain.P[0, 0] > 1e6  # the failure the residual prevents


# --- 2. The UKF averages angles -----------------------------------------------------------


@pytest.mark.parametrize("name", BACKENDS)
def test_ukf_bearing_update_with_circular_mean(use, name):
    """Issue case 2 (alpha = 1, kappa = 1): the sigma points' bearings straddle +-pi. With
    circular_mean and angle_residual the update equals the plain UKF on a continuous branch
    of the bearing, atan2 taken in [0, 2 pi) (x[1] = 0.100, P11 = 0.0101); the arithmetic
    mean is far off."""
    use(name)
    z = math.pi - 0.01

    def run(h, **kw):
        ukf = UnscentedKalmanFilter(
            [-10.0, 0.0], np.eye(2), f=lambda x, dt, u: x, Q=0.0, alpha=1.0, kappa=1.0
        )
        ukf.update(Observations().add("bearing", [z], h=h, R=1e-4, **kw))
        return ukf

    got = run(_bearing, mean=circular_mean, residual=angle_residual)
    ref = run(lambda x: np.array([math.atan2(x[1], x[0]) % (2 * math.pi)]))
    np.testing.assert_allclose(got.x, ref.x, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(got.P, ref.P, rtol=1e-12, atol=1e-14)
    assert got.x[1] == pytest.approx(0.09997, abs=1e-4)
    assert got.P[1, 1] == pytest.approx(0.0101, abs=1e-4)
    assert abs(run(_bearing).x[1] - got.x[1]) > 0.1


@pytest.mark.parametrize("name", BACKENDS)
@pytest.mark.parametrize("batched", [False, True])
def test_ukf_heading_state_near_pi(use, name, batched):
    """Issue case 2, predict: a heading state at pi - 0.15, P = 0.1, f adds 0.1 and wraps,
    so sigma points fall on both sides of pi. With the state's mean and residual the
    prediction is the continuous one (mean pi - 0.05, variance 0.1), wrapped."""
    use(name)

    def f(x, dt, u):
        return wrap_angle(x + 0.1)

    def run(fn, **kw):
        ukf = UnscentedKalmanFilter([math.pi - 0.15], [[0.1]], f=fn, Q=0.0, batched=batched, **kw)
        ukf.predict(1.0)
        return ukf

    got = run(f, x_mean=make_mean(angles=[0]), residual_x=make_residual(angles=[0]))
    ref = run(lambda x, dt, u: x + 0.1)
    assert got.x[0] == pytest.approx(wrap_angle(float(ref.x[0])), abs=1e-12)
    assert got.P[0, 0] == pytest.approx(0.1, rel=1e-12)
    assert abs(run(f).x[0] - got.x[0]) > 1.0


def test_circular_mean_keeps_the_digits_of_small_alpha_points():
    """Sigma points of alpha = 1e-3 (central weight ~ -1e6) straddling pi, symmetric about
    x = pi - 1e-6: the circular mean is x to roundoff (it is taken about the central point,
    whose huge weight multiplies a zero difference), while the plain weighted sum of the
    unwrapped points loses about six digits."""
    sp = MerweSigmaPoints(1, alpha=1e-3)
    x = math.pi - 1e-6
    sig = x + np.array([0.0, 1.0, -1.0]) * sp.scale * 0.5
    assert float(circular_mean(wrap_angle(sig), sp.Wm)) == pytest.approx(x, abs=1e-15)
    assert abs(float(sp.Wm @ sig) - x) > 1e-12
    assert sp.Wm[0] < -1e5


def test_quaternion_state_mean_and_residual():
    """The ready quaternion helpers: q and -q average to the same rotation, the residual
    of a quaternion and its negative is zero, other columns stay arithmetic."""
    q = np.array([math.cos(0.1), math.sin(0.1), 0.0, 0.0])
    X = np.array([np.r_[q, 1.0], np.r_[-q, 3.0]])
    mean = make_mean(quaternions=[0])(X, np.array([0.5, 0.5]))
    np.testing.assert_allclose(mean, np.r_[q, 2.0], atol=1e-15)
    res = make_residual(quaternions=[0])
    np.testing.assert_allclose(res(np.r_[-q, 1.0], np.r_[q, 1.0]), np.zeros(5), atol=1e-15)
    with pytest.raises(ValueError, match="overlap"):
        make_mean(angles=[1], quaternions=[0])


# --- 3. S is solved through its Cholesky factor ------------------------------------------


@pytest.mark.parametrize("name", BACKENDS)
@pytest.mark.parametrize("d", [1e-3, 1e-4, 1e-5])
@pytest.mark.parametrize("full_R", [False, True])
def test_ill_conditioned_three_row_update(use, name, d, full_R, exact):
    """Issue case 3: H = [[1,1,1],[1,1+d,1],[1,1,1+d]], P = I, R = 1e-12 I, cond(S) up to
    7e11. A backward-stable solve errs by at most a small multiple of cond(S) eps (bound:
    10 cond(S) eps); the adjugate inverse erred 1.8e-3 at d = 1e-3 (bound 2e-7 there), 1.3
    at 1e-4 and raised a false CovarianceError at 1e-5."""
    use(name)
    H = np.array([[1, 1, 1], [1, 1 + d, 1], [1, 1, 1 + d]])
    R = 1e-12 * np.eye(3)
    z = np.array([1.0, 2.0, 3.0])
    xr, Pr, S, nis = exact.update(np.zeros(3), np.eye(3), H, R, z)
    bound = 10 * np.linalg.cond(S) * EPS
    block = Block("b", z, R if full_R else np.diag(R), H=H)
    x, P, res = linearised_update(np.zeros(3), np.eye(3), [block])
    assert np.abs(x - xr).max() <= bound * np.abs(xr).max()
    assert np.abs(P - Pr).max() <= bound
    assert res.nis["b"] == pytest.approx(nis, rel=bound)


# --- 4. The true Joseph form on every path -----------------------------------------------

JOSEPH_CASES = [(1e6, 1e-10), (1e8, 1e-8), (1e8, 1e-10)]


@pytest.mark.parametrize("name", BACKENDS)
@pytest.mark.parametrize("scale,r", JOSEPH_CASES)
@pytest.mark.parametrize("R_form", ["scalar", "matrix"])
def test_joseph_form_with_a_tiny_R(use, name, scale, r, R_form, exact):
    """Issue case 4: P0 = scale [[1, .5], [.5, 1]], H = [1, 0], R << H P H^T. The expanded
    Joseph formula was 20 % / 50 % off or raised CovarianceError; the true form matches
    exact arithmetic to 1e-9 in every entry, with R as a variance or a 1x1 matrix."""
    use(name)
    P0 = scale * np.array([[1.0, 0.5], [0.5, 1.0]])
    R = r if R_form == "scalar" else np.array([[r]])
    kf = KalmanFilter([0.0, 0.0], P0, F=np.eye(2), Q=0.0)
    kf.update(Observations().add("z", [1.0], H=[[1.0, 0.0]], R=R))
    xr, Pr, _, _ = exact.update([0.0, 0.0], P0, [[1.0, 0.0]], [[r]], [1.0])
    np.testing.assert_allclose(kf.P, Pr, rtol=1e-9)
    np.testing.assert_allclose(kf.x, xr, rtol=1e-9)


@pytest.mark.parametrize("name", BACKENDS)
@pytest.mark.parametrize("m", [2, 3])
@pytest.mark.parametrize("method", ["joint", "sequential"])
def test_joseph_form_with_tiny_R_several_rows(use, name, m, method, exact):
    """The same for 2 and 3 rows (Cholesky path) and for sequential scalar updates: the
    measured variances (R-scale, 1e-9 next to a prior of 1e8) are right to 1e-9 relative
    (the expanded formula gets them 100 % wrong), every entry to 100 eps of the prior's
    scale sqrt(P0_ii P0_jj) (no float64 method does better on the cross terms, whose gain
    entries are not representable), and P stays positive semi-definite: the measured block
    at its own scale (where a variance gone negative would show), the whole to within the
    eigensolver's roundoff, eps ||P0|| (an eigenvalue of a matrix with entries of 1e8 is not
    known to 1e-9: the old bound, -100 eps 1e-9 on the whole, held on one machine's LAPACK
    and failed on another's by -5.6e-9)."""
    use(name)
    n = 4
    P0 = 1e8 * (0.5 * np.eye(n) + 0.5)
    H = np.eye(m, n)
    var = np.full(m, 1e-9)
    z = np.arange(1.0, m + 1.0)
    x, P, _ = linearised_update(np.zeros(n), P0, [Block("z", z, var, H=H)], method=method)
    xr, Pr, _, _ = exact.update(np.zeros(n), P0, H, np.diag(var), z)
    np.testing.assert_allclose(np.diag(P)[:m], np.diag(Pr)[:m], rtol=1e-9)
    scale = np.sqrt(np.outer(np.diag(P0), np.diag(P0)))
    assert (np.abs(P - Pr) / scale).max() <= 100 * EPS
    assert np.linalg.eigvalsh(P[:m, :m]).min() >= -100 * EPS * np.abs(np.diag(Pr)[:m]).max()
    assert np.linalg.eigvalsh(P).min() >= -100 * EPS * np.linalg.norm(P0, 2)
    np.testing.assert_allclose(x, xr, rtol=1e-9)


# --- 5. Covariances are checked where they enter ------------------------------------------


def test_negative_or_zero_variances_refused_by_add():
    for R in ([1.0, -0.5], np.array([0.5, 0.0]), -1.0, 0.0, np.array([[0.0]])):
        with pytest.raises(ValueError, match="block 'b'"):
            Observations().add(
                "b",
                np.ones(np.size(R) if np.ndim(R) == 1 else 1),
                H=np.eye(1, 2) if np.size(R) == 1 else np.eye(2),
                R=R,
            )


def test_indefinite_R_refused_by_add():
    with pytest.raises(CovarianceError, match="R of block 'b' is not positive definite"):
        Observations().add("b", [1.0, 2.0], H=np.eye(2), R=[[0.5, 0.9], [0.9, 0.5]])


@pytest.mark.parametrize("name", BACKENDS)
def test_indefinite_P0_and_negative_Q_refused(use, name):
    use(name)
    bad_P = np.array([[1.0, 2.0], [2.0, 1.0]])
    for make in (
        lambda: KalmanFilter([0, 0], bad_P, F=np.eye(2), Q=0.1),
        lambda: ExtendedKalmanFilter([0, 0], bad_P, f=lambda x, dt, u: x, Q=0.1),
        lambda: UnscentedKalmanFilter([0, 0], bad_P, f=lambda x, dt, u: x, Q=0.1),
    ):
        with pytest.raises(CovarianceError, match="P0 is not positive semi-definite"):
            make()
    with pytest.raises(CovarianceError, match="Q"):
        KalmanFilter([0, 0], np.eye(2), F=np.eye(2), Q=-0.5 * np.eye(2))
    with pytest.raises(CovarianceError, match="Q"):
        ExtendedKalmanFilter([0, 0], np.eye(2), f=lambda x, dt, u: x, Q=[0.1, -0.1])
    kf = KalmanFilter([0, 0], np.eye(2), F=np.eye(2), Q=lambda dt: dt * np.eye(2))
    with pytest.raises(ValueError, match="dt must be"):
        kf.predict(-0.1)  # a negative dt would make Q(dt) negative definite
    with pytest.raises(ValueError, match="dt must be"):
        kf.predict(math.nan)
    neg = KalmanFilter([0, 0], np.eye(2), F=np.eye(2), Q=lambda dt: -np.eye(2))
    with pytest.raises(CovarianceError, match=r"Q\(dt\)"):
        neg.predict(0.1)
    np.testing.assert_array_equal(neg.P, np.eye(2))


# --- 6. Asymmetric input: refused, or symmetrised the same way on both backends ----------


@pytest.mark.parametrize("name", BACKENDS)
def test_asymmetric_covariances(use, name):
    use(name)
    P0 = np.eye(2)
    P0[0, 1] = 0.5
    with pytest.raises(CovarianceError, match=r"P0\[0, 1\] = 0.5 but P0\[1, 0\] = 0"):
        KalmanFilter([0, 0], P0, F=np.eye(2), Q=0.0)
    with pytest.raises(CovarianceError, match="not symmetric"):
        Observations().add("b", [1.0, 1.0], H=np.eye(2), R=[[1.0, 0.9], [-0.9, 1.0]])


def test_roundoff_asymmetry_is_symmetrised_identically(use, exact):
    """Asymmetry within the tolerance (1e-9 relative) is removed where the matrix enters:
    both backends then compute the same numbers."""
    P0 = np.array([[2.0, 0.5], [0.5 * (1 + 1e-12), 1.0]])
    out = []
    for name in BACKENDS:
        use(name)
        kf = KalmanFilter([0.0, 0.0], P0, F=np.eye(2), Q=0.0)
        assert np.array_equal(kf.P, kf.P.T)
        kf.update(Observations().add("z", [1.0], H=[[1.0, 1.0]], R=0.1))
        out.append((kf.x, kf.P))
    np.testing.assert_allclose(out[0][0], out[1][0], rtol=1e-14)
    np.testing.assert_allclose(out[0][1], out[1][1], rtol=1e-14)


# --- 7. The smaller ones ------------------------------------------------------------------


@pytest.mark.parametrize("name", BACKENDS)
def test_scalar_and_vector_Q_on_predict(use, name):
    """predict(dt, Q=0.1) adds 0.1 I (as the constructor reads a scalar), a vector is the
    diagonal; the result is symmetric, on every filter."""
    use(name)
    P0 = np.array([[2.0, 0.3], [0.3, 1.0]])
    for make in (
        lambda: KalmanFilter([0, 0], P0, F=np.eye(2), Q=0.0),
        lambda: ExtendedKalmanFilter(
            [0, 0], P0, f=lambda x, dt, u: x, F=lambda x, dt, u: np.eye(2), Q=0.0
        ),
        lambda: UnscentedKalmanFilter([0, 0], P0, f=lambda x, dt, u: x, Q=0.0),
    ):
        for Q, added in ((0.1, 0.1 * np.eye(2)), ([0.1, 0.2], np.diag([0.1, 0.2]))):
            filt = make()
            filt.predict(0.1, Q=Q)
            np.testing.assert_allclose(filt.P, P0 + added, rtol=1e-12)
            assert np.array_equal(filt.P, filt.P.T)


@pytest.mark.parametrize("name", BACKENDS)
def test_cached_F_and_Q_follow_what_they_depend_on(use, name):
    """F(dt)/Q(dt) are cached per dt (pure functions of dt); cache_dt=False re-evaluates
    them on every predict, and assigning kf.F / kf.Q clears the cache."""
    use(name)
    q = [0.1]
    calls = []

    def Qf(dt):
        calls.append(dt)
        return q[0] * dt * np.eye(1)

    cached = KalmanFilter([0.0], [[1.0]], F=lambda dt: np.eye(1), Q=Qf)
    live = KalmanFilter([0.0], [[1.0]], F=lambda dt: np.eye(1), Q=Qf, cache_dt=False)
    cached.predict(1.0)
    live.predict(1.0)
    q[0] = 0.3
    cached.predict(1.0)
    live.predict(1.0)
    assert cached.P[0, 0] == pytest.approx(1.2) and live.P[0, 0] == pytest.approx(1.4)
    assert calls == [1.0, 1.0, 1.0]
    cached.Q = Qf
    cached.predict(1.0)
    assert cached.P[0, 0] == pytest.approx(1.5)
    ekf = ExtendedKalmanFilter([0.0], [[1.0]], f=lambda x, dt, u: x, Q=Qf, cache_dt=False)
    ekf.predict(1.0)
    q[0] = 0.5
    ekf.predict(1.0)
    assert ekf.P[0, 0] == pytest.approx(1.8)


@pytest.mark.parametrize("name", BACKENDS)
def test_nan_state_is_caught_by_predict(use, name):
    """A NaN put into the state (in place, bypassing the checked setter) is reported by the
    next predict as the state's fault, not blamed on the next observation."""
    use(name)
    for filt in (
        KalmanFilter([0.0, 1.0], np.eye(2), F=np.eye(2), Q=0.1),
        ExtendedKalmanFilter([0.0, 1.0], np.eye(2), f=lambda x, dt, u: x, Q=0.1),
    ):
        filt.x[0] = math.nan
        with pytest.raises(NonFiniteInputError, match="the state x"):
            filt.predict(0.1)
    with pytest.raises(NonFiniteInputError):
        KalmanFilter([0.0, 1.0], np.eye(2), F=np.eye(2), Q=0.1).x = [math.nan, 1.0]


def test_empty_block_refused():
    with pytest.raises(ValueError, match="block 'e': z is empty"):
        Observations().add("e", [], H=np.zeros((0, 2)), R=1.0)
    with pytest.raises(ValueError, match="block 'e': z is empty"):
        Block("e", np.zeros(0), np.zeros(0), H=np.zeros((0, 2)))


@pytest.mark.parametrize("name", BACKENDS)
def test_wrong_shapes_name_the_block(use, name):
    use(name)
    for filt in (
        KalmanFilter([0.0, 1.0], np.eye(2), F=np.eye(2), Q=0.1),
        ExtendedKalmanFilter([0.0, 1.0], np.eye(2), f=lambda x, dt, u: x, Q=0.1),
        UnscentedKalmanFilter([0.0, 1.0], np.eye(2), f=lambda x, dt, u: x, Q=0.1),
    ):
        x0, P0 = filt.x, filt.P
        for obs in (
            Observations().add("wide", [1.0], H=[[1.0, 0.0, 0.0]], R=1.0),
            Observations().add("h2", [1.0], h=lambda x: x, R=1.0),
            Observations()
            .add("ok", [1.0], H=[[1.0, 0.0]], R=1.0)
            .add("wide", [1.0], H=[[1.0, 0.0, 0.0]], R=1.0),
        ):
            label = obs.blocks[-1].label
            with pytest.raises(ValueError, match=f"block '{label}'"):
                filt.update(obs)
            assert filt.x is x0 and filt.P is P0


@pytest.mark.parametrize("name", BACKENDS)
def test_R_zero_is_a_clear_error(use, name):
    use(name)
    for R in (0.0, [0.0], np.zeros((1, 1))):
        with pytest.raises(ValueError, match="block 'z'"):
            Observations().add("z", [1.0], H=[[1.0, 0.0]], R=R)


def test_ukf_recovers_from_a_collapsed_P(use):
    """A P that lost positive definiteness to roundoff (an eigenvalue of -1e-14 next to 1)
    is repaired by the smallest jitter that factorises (recovery policy); far from
    definite, CovarianceError and the state unchanged."""
    v = np.array([1.0, 1.0]) / math.sqrt(2)
    almost = np.eye(2) - (1.0 + 1e-14) * np.outer(v, v) + np.outer([1.0, -1.0], [1.0, -1.0])
    for name in BACKENDS:
        use(name)
        ukf = UnscentedKalmanFilter([0.0, 0.0], np.eye(2), f=lambda x, dt, u: x, Q=0.01)
        ukf._P = almost  # as a long run of updates can leave it (the setter would refuse)
        ukf.predict(0.1)
        assert ukf.repairs == 1 and 0.0 < ukf.last_jitter <= 1e-6 * almost.max()
        np.linalg.cholesky(ukf.P)
        broken = np.array([[1.0, 0.0], [0.0, -0.5]])
        ukf._P = broken
        with pytest.raises(CovarianceError, match="reset the filter"):
            ukf.predict(0.1)
        assert ukf.P is broken


def test_default_alpha_keeps_the_digits():
    """With the default alpha = 1 every sigma-point weight is >= 0 and a linear model's UKF
    equals the KF to ~1e-12 of the state's standard deviation even with a state far from
    0; alpha = 1e-3 (central weight ~ -1e6) loses about six digits of the mean."""
    sp = MerweSigmaPoints(4)
    assert sp.alpha == 1.0 and (sp.Wm >= 0).all() and (sp.Wc >= 0).all()
    rng = np.random.default_rng(3)
    n = 4
    A = rng.normal(size=(n, n))
    P0 = A @ A.T + np.eye(n)
    H = rng.normal(size=(2, n))
    x0 = np.full(n, 1000.0)
    zs = H @ x0 + rng.normal(size=(10, 2))

    def err(alpha):
        kf = KalmanFilter(x0, P0, F=np.eye(n), Q=0.01)
        ukf = UnscentedKalmanFilter(x0, P0, f=lambda x, dt, u: x, Q=0.01, alpha=alpha)
        for z in zs:
            for filt in (kf, ukf):
                filt.predict(0.1)
                filt.update(Observations().add("z", z, H=H, R=0.5))
        return np.abs(ukf.x - kf.x).max() / np.sqrt(np.diag(kf.P)).min()

    assert err(1.0) < 1e-11
    assert err(1e-3) > 1e-8
