"""Schmidt "consider" states (``update(..., consider=...)``): the update equals the textbook
Schmidt-Kalman update (gain rows of the considered states zero, Joseph form) on both
backends, leaves the considered states alone, and keeps P consistent with the actual
errors where ignoring the parameter's uncertainty does not."""

import numpy as np
import pytest

from hera.estimation import ExtendedKalmanFilter, KalmanFilter, Observations, backend, record
from hera.estimation.consider import consider_indices

TOL = {"rtol": 1e-10, "atol": 1e-12}


@pytest.fixture(params=["numpy", "numba"])
def use_backend(request):
    before = backend.backend()
    if request.param == "numba":
        import numba  # noqa: F401  (a test requirement: missing, the test fails, never skips)
    backend.set_backend(request.param)
    yield request.param
    backend.set_backend(before)


def _spd(rng, n):
    A = rng.normal(size=(n, n))
    return A @ A.T / n + np.eye(n)


def schmidt(x, P, H, R, z, idx):
    """The textbook Schmidt-Kalman update, written out: K = P H^T S^-1, rows idx zeroed,
    Joseph form."""
    S = H @ P @ H.T + R
    K = P @ H.T @ np.linalg.inv(S)
    K[idx, :] = 0.0
    A = np.eye(len(x)) - K @ H
    return x + K @ (z - H @ x), A @ P @ A.T + K @ R @ K.T


@pytest.mark.parametrize("sizes", [(1,), (2,), (3,), (2, 3), (1, 1, 1, 1)])
def test_consider_update_equals_the_schmidt_kalman_update(use_backend, sizes):
    rng = np.random.default_rng(sum(sizes) * 7 + len(sizes))
    n = 6
    idx = [1, 4]
    x0, P0 = rng.normal(size=n), _spd(rng, n)
    obs = Observations()
    Hs, vs, zs = [], [], []
    for i, m in enumerate(sizes):
        H, var, z = rng.normal(size=(m, n)), rng.uniform(0.2, 1.0, m), rng.normal(size=m)
        obs.add(f"b{i}", z, H=H, R=var)
        Hs.append(H)
        vs.append(var)
        zs.append(z)
    H, R, z = np.vstack(Hs), np.diag(np.concatenate(vs)), np.concatenate(zs)
    kf = KalmanFilter(x0, P0, F=np.eye(n), Q=np.zeros((n, n)))
    kf.update(obs, consider=idx)
    x_ref, P_ref = schmidt(x0, P0, H, R, z, idx)
    assert np.allclose(kf.x, x_ref, **TOL)
    assert np.allclose(kf.P, P_ref, **TOL)
    assert np.array_equal(kf.x[idx], x0[idx])  # considered: untouched, exactly
    assert np.array_equal(kf.P[np.ix_(idx, idx)], P0[np.ix_(idx, idx)])
    assert np.allclose(kf.P, kf.P.T, **TOL) and np.linalg.eigvalsh(kf.P).min() > 0
    # the estimated states get the optimal update's values (their rows of K are optimal)
    full = KalmanFilter(x0, P0, F=np.eye(n), Q=np.zeros((n, n)))
    full.update(obs, method="joint")
    est = [i for i in range(n) if i not in idx]
    assert np.allclose(kf.x[est], full.x[est], **TOL)
    assert not np.allclose(kf.x[idx], full.x[idx])  # the optimal update would move them


def test_nonlinear_blocks_and_a_boolean_mask(use_backend):
    rng = np.random.default_rng(3)
    n = 5
    x0, P0 = rng.normal(size=n) + 2.0, _spd(rng, n)
    ekf = ExtendedKalmanFilter(x0, P0, lambda x, dt, u: x, np.zeros((n, n)))

    def h(s):
        return np.array([s[0] * s[3] + s[2] ** 2])

    def jac(s):
        return np.array([[s[3], 0.0, 2 * s[2], s[0], 0.0]])

    obs = Observations()
    obs.add("nl", [1.5], h=h, jacobian=jac, R=0.3)
    mask = np.array([False, False, False, True, True])
    ekf.update(obs, consider=mask)
    H = jac(x0)
    S = H @ P0 @ H.T + 0.3
    K = P0 @ H.T / S
    K[3:] = 0.0
    A = np.eye(n) - K @ H
    assert np.allclose(ekf.x, x0 + (K * (1.5 - h(x0)[0])).ravel(), **TOL)
    assert np.allclose(ekf.P, A @ P0 @ A.T + 0.3 * K @ K.T, **TOL)


def test_a_gated_out_block_leaves_the_state_alone(use_backend):
    x0, P0 = np.zeros(3), np.eye(3) * 0.01
    kf = KalmanFilter(x0, P0, F=np.eye(3), Q=np.zeros((3, 3)))
    obs = Observations()
    obs.add("far", [10.0], H=np.array([[1.0, 1.0, 0.0]]), R=0.01)
    res = kf.update(obs, gate=0.999, consider=[2])
    assert res.rejected and np.array_equal(kf.x, x0) and np.array_equal(kf.P, P0)


def test_the_considered_state_is_the_steps_posterior_in_the_history(use_backend):
    """What a recorded filter (``hera replay --smooth``) keeps of a consider update is the
    state the filter holds after it: x_post, P_post and the history's step agree, the
    considered state unchanged (a smoother must not see the unrestored joint update)."""
    kf = KalmanFilter(np.zeros(2), np.eye(2), F=np.eye(2), Q=0.01 * np.eye(2))
    hist = record(kf)
    for z in (1.0, 1.2, 0.9):
        kf.predict(1.0)
        obs = Observations()
        obs.add("z", [z], H=np.array([[1.0, 1.0]]), R=0.1)
        res = kf.update(obs, consider=[1], details=True)
        assert hist.log_likelihood[-1] == res.log_likelihood  # counted once
        assert np.array_equal(kf.x_post, kf.x) and np.array_equal(kf.P_post, kf.P)
        assert np.array_equal(hist.x_post[-1], kf.x)
        assert np.array_equal(hist.P_post[-1], kf.P)
        assert kf.x[1] == 0.0  # considered: never moved
    assert len(hist) == 4 and np.count_nonzero(hist.log_likelihood) == 3


def test_bad_consider_arguments_are_refused_with_what_is_wrong():
    kf = KalmanFilter(np.zeros(3), np.eye(3), F=np.eye(3), Q=np.zeros((3, 3)))
    obs = Observations()
    obs.add("b", [1.0], H=np.array([[1.0, 0.0, 0.0]]), R=1.0)
    with pytest.raises(ValueError, match="out of range for 3 states"):
        kf.update(obs, consider=[3])
    with pytest.raises(ValueError, match=r"shape \(2,\), expected \(3,\)"):
        kf.update(obs, consider=np.array([True, False]))
    with pytest.raises(ValueError, match="joint update"):
        kf.update(obs, consider=[1], method="sequential")
    assert np.array_equal(kf.x, np.zeros(3))  # nothing was applied
    assert consider_indices([2, 0, 2], 3).tolist() == [0, 2]


def test_schmidt_covariance_is_consistent_where_ignoring_the_parameter_is_not():
    """A position p observed through z = p + b + noise with an uncertain constant bias b
    (sigma 0.5) that the filter may not estimate. Over 4000 runs of 5 updates, the Schmidt
    filter's P_pp matches the actual variance of its p error (NEES about 1); a filter that
    simply leaves b out (P_bb = 0) claims far less than its actual error (NEES >> 1)."""
    rng = np.random.default_rng(11)
    runs, steps, sb, sr, sp = 4000, 5, 0.5, 0.2, 1.0
    H = np.array([[1.0, 1.0]])
    nees = {"schmidt": [], "ignored": []}
    for _ in range(runs):
        p, b = rng.normal(0, sp), rng.normal(0, sb)
        zs = p + b + rng.normal(0, sr, steps)
        for kind, Pbb in (("schmidt", sb**2), ("ignored", 0.0)):
            kf = KalmanFilter(np.zeros(2), np.diag([sp**2, Pbb + 1e-300]), F=np.eye(2), Q=0.0)
            for z in zs:
                obs = Observations()
                obs.add("z", [z], H=H, R=sr**2)
                kf.update(obs, consider=[1])
            nees[kind].append((kf.x[0] - p) ** 2 / kf.P[0, 0])
    schmidt_nees, ignored_nees = np.mean(nees["schmidt"]), np.mean(nees["ignored"])
    assert 0.9 < schmidt_nees < 1.1, schmidt_nees
    assert ignored_nees > 3.0, ignored_nees
