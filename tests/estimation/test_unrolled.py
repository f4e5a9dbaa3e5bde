"""The unrolled Python-float steps (``hera.estimation.unrolled``) equal the numpy path.

The numpy backend runs every KF/EKF predict and one-block update at n <= MAX_N through
generated straight-line code. Each test compares it with the same filter on the general
numpy path (``MAX_N`` set to 0 for the reference), to 1e-12, at every size, zero pattern
and option, and checks that what the unrolled code cannot decide (non-finite input, an S
that is not positive definite, a covariance that goes bad) raises exactly the numpy
path's error.
"""

import copy
import math
import pickle

import numpy as np
import pytest
from filter_runs import error_of, record, same_runs

from hera.estimation import (
    ExtendedKalmanFilter,
    KalmanFilter,
    Observations,
    backend,
)
from hera.estimation import unrolled as U

TOL = {"rtol": 1e-12, "atol": 1e-12}


@pytest.fixture(autouse=True)
def numpy_backend():
    before = backend.backend()
    backend.set_backend("numpy")
    yield
    backend.set_backend(before)


@pytest.fixture
def general(monkeypatch):
    """general() runs the rest of a block on the general numpy path; unrolled() back."""

    class Switch:
        def __call__(self):
            monkeypatch.setattr(U, "MAX_N", 0)

        def unrolled(self):
            monkeypatch.setattr(U, "MAX_N", 6)

    return Switch()


def _problem(n, m, seed, sparse):
    rng = np.random.default_rng(seed)
    F = np.eye(n) + 0.1 * rng.normal(size=(n, n))
    H = rng.normal(size=(m, n))
    if sparse:  # a chain F and rows that see one or two states, as the models have
        F = np.eye(n) + np.diag(np.full(n - 1, 0.1), 1)
        H = np.zeros((m, n))
        for i in range(m):
            H[i, i % n] = 1.0
            H[i, (i + 2) % n] += 0.5
    A = rng.normal(size=(n, n))
    P0 = A @ A.T + np.eye(n)
    Q = np.diag(rng.uniform(0.01, 0.1, n))
    zs = rng.normal(size=(40, m))
    return rng.normal(size=n), P0, F, Q, H, zs


def _kf_run(n, m, seed, sparse, full_R, joseph, gate):
    x0, P0, F, Q, H, zs = _problem(n, m, seed, sparse)
    if full_R:
        B = np.random.default_rng(seed + 1).normal(size=(m, m))
        R = 0.5 * (B @ B.T) + 0.2 * np.eye(m)
    else:
        R = np.linspace(0.2, 0.6, m)
    kf = KalmanFilter(x0, P0, F=F, Q=Q, joseph=joseph, gate=gate)
    out = []
    for z in zs:
        kf.predict(0.1)
        out.append(record(kf))
        out.append(record(kf, kf.update(Observations().add("z", 3.0 * z, H=H, R=R))))
    return out


def _same(a, b):
    # The NIS within 1e-12 too, not relative only: a NIS near 0 is a difference of near
    # equal numbers, 1.3e-12 apart relatively on one machine's compiled kernels (0.0076).
    return same_runs(a, b, TOL, TOL)


@pytest.mark.parametrize("n", range(1, U.MAX_N + 1))
@pytest.mark.parametrize("m", range(1, U.MAX_M + 1))
def test_kf_trajectory_equals_the_numpy_path(n, m, general):
    cases = [
        (False, False, True, None),
        (True, False, True, None),
        (True, True, True, None),
        (False, True, False, None),
        (True, False, True, 0.9),  # gated: some blocks are rejected
    ]
    for seed, (sparse, full_R, joseph, gate) in enumerate(cases):
        general.unrolled()
        got = _kf_run(n, m, seed, sparse, full_R, joseph, gate)
        general()
        want = _kf_run(n, m, seed, sparse, full_R, joseph, gate)
        accepted = _same(got, want)
        if gate is None:
            assert accepted == len(want) // 2
        elif n > 1:
            assert 0 < accepted < len(want) // 2, "the gate case must reject some blocks"


def _ekf_run(n, m, seed):
    x0, P0, F, Q, H, zs = _problem(n, m, seed, sparse=True)

    def f(x, dt, u):
        return x + dt * np.sin(x)

    def fj(x, dt, u):
        return np.eye(n) + dt * np.diag(np.cos(x))

    idx = np.arange(m) % n
    ekf = ExtendedKalmanFilter(x0, P0, f=f, F=fj, Q=Q)
    out = []
    for z in zs:
        ekf.predict(0.1)
        out.append(record(ekf))
        res = ekf.update(
            Observations().add(
                "s",
                np.sin(z),
                h=lambda x: np.sin(x[idx]),
                jacobian=lambda x: np.eye(n)[idx] * np.cos(x),
                R=np.full(m, 0.3),
            )
        )
        out.append(record(ekf, res))
    return out


@pytest.mark.parametrize("n", [1, 3, 6])
@pytest.mark.parametrize("m", [1, 3])
def test_ekf_trajectory_equals_the_numpy_path(n, m, general):
    general.unrolled()
    got = _ekf_run(n, m, 5)
    general()
    assert _same(got, _ekf_run(n, m, 5)) == len(got) // 2


def test_the_generated_code_computes_the_textbook_equations():
    """Against the equations written with numpy's solve (not the library's code)."""
    rng = np.random.default_rng(3)
    for n in range(1, U.MAX_N + 1):
        for m in range(1, U.MAX_M + 1):
            x, P, F, Q, H, zs = _problem(n, m, n * 10 + m, sparse=False)
            Pp = F @ P @ F.T + Q
            xl, Pl = U.predict_step(n)(
                x.tolist(), P.ravel().tolist(), F.ravel().tolist(), Q.ravel().tolist()
            )
            np.testing.assert_allclose(xl, F @ x, **TOL)
            np.testing.assert_allclose(np.reshape(Pl, (n, n)), Pp, **TOL)
            R = np.diag(rng.uniform(0.1, 1.0, m))
            y = zs[0]
            S = H @ P @ H.T + R
            K = P @ H.T @ np.linalg.inv(S)
            IKH = np.eye(n) - K @ H
            joseph = IKH @ P @ IKH.T + K @ R @ K.T
            for full, noise in ((False, np.diag(R).tolist()), (True, R.ravel().tolist())):
                nis, xn, Pn = U.linear_update(n, m, full, True)(
                    x.tolist(), P.ravel().tolist(), H.ravel().tolist(), y.tolist(), noise, math.inf
                )
                assert nis == pytest.approx(float(y @ np.linalg.solve(S, y)), rel=1e-10)
                np.testing.assert_allclose(xn, x + K @ y, rtol=1e-10, atol=1e-10)
                np.testing.assert_allclose(np.reshape(Pn, (n, n)), joseph, rtol=1e-10, atol=1e-10)
            short = U.linear_update(n, m, False, False)(
                x.tolist(),
                P.ravel().tolist(),
                H.ravel().tolist(),
                y.tolist(),
                np.diag(R).tolist(),
                math.inf,
            )[2]
            np.testing.assert_allclose(
                np.reshape(short, (n, n)), P - K @ H @ P, rtol=1e-10, atol=1e-10
            )


def test_a_gated_out_block_leaves_the_state():
    kf = KalmanFilter([0.0, 0.0], np.eye(2), F=np.eye(2), Q=0.01)
    x, P = kf.x, kf.P
    res = kf.update(Observations().add("far", [50.0], H=[[1.0, 0.0]], R=0.1), gate=0.99)
    assert res.rejected == ["far"] and res.nis["far"] == pytest.approx(50.0**2 / 1.1)
    assert kf.x is x and kf.P is P


# numpy warns as the reference path computes with the inf before it names it
@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
@pytest.mark.parametrize(
    "case",
    [
        "nan z",
        "inf H",
        "negative R",
        "S not PD",
        "nan F",
        "inf Q",
        "nan f(x)",
        "P overflows",
        "P goes bad",
    ],
)
def test_what_it_cannot_decide_raises_the_numpy_paths_error(case, general):
    def run():
        kf = KalmanFilter([1.0, 2.0], np.eye(2), F=np.eye(2), Q=0.01)
        R, H, z = 0.5, [[1.0, 0.0]], [1.0]
        if case == "nan z":
            z = [math.nan]
        if case == "inf H":
            H = [[math.inf, 0.0]]
        if case == "negative R":
            R = [-0.5]
        if case == "S not PD":
            R = np.array([[0.5]])
            kf.P = np.zeros((2, 2))
        if case == "nan F":
            kf.predict(0.1, F=[[math.nan, 0.0], [0.0, 1.0]])
        if case == "inf Q":
            kf.Q = lambda dt: np.diag([math.inf, 1.0])
            kf.predict(0.1)
        if case == "P overflows":  # finite F and P whose product is not
            kf.predict(0.1, F=[[1e200, 0.0], [0.0, 1.0]])
        if case == "nan f(x)":
            ekf = ExtendedKalmanFilter([1.0], [[1.0]], f=lambda x, dt, u: x * math.nan, Q=0.1)
            ekf.predict(0.1)
        if case == "P goes bad":  # the short form's P - K H P rounds P_00 to exactly 0
            kf.joseph = False
            R = 1e-300
        x, P = kf.x.copy(), kf.P.copy()
        try:
            kf.update(Observations().add("b", z, H=H, R=R))
        finally:
            np.testing.assert_array_equal(kf.x, x)
            np.testing.assert_array_equal(kf.P, P)

    general.unrolled()
    got = error_of(run)
    general()
    assert got == error_of(run)


def test_a_pattern_per_zero_structure_and_a_bound_on_them(monkeypatch):
    """An F whose zeros move gets the right answer each time, and past PATTERNS_PER_SIZE
    patterns of one size the dense step is used instead of compiling more."""
    monkeypatch.setattr(U, "_seen", {})
    n = 4
    rng = np.random.default_rng(9)
    A = rng.normal(size=(n, n))
    P = A @ A.T + np.eye(n)
    Q = 0.1 * np.eye(n)
    before = U.predict_step.cache_info().currsize
    assert U._pattern(("F", n), [1.0, 0.0, -0.0, math.nan]) == (True, False, False, True)
    for k in range(U.PATTERNS_PER_SIZE + 4):
        F = rng.normal(size=(n, n))
        F.ravel()[k % (n * n)] = 0.0
        F.ravel()[(3 * k + 1) % (n * n)] = 0.0
        x, Pn = U.predict(np.ones(n), P, F, Q)
        np.testing.assert_allclose(Pn, F @ P @ F.T + Q, **TOL)
        np.testing.assert_allclose(x, F @ np.ones(n), **TOL)
    assert len(U._seen[("F", n)]) == U.PATTERNS_PER_SIZE
    assert U._pattern(("F", n), [0.0] * (n * n)) is None  # one more: dense
    seen = sorted(U._seen[("F", n)])[0]
    assert U._pattern(("F", n), [float(v) for v in seen]) == seen  # those seen stay sparse
    added = U.predict_step.cache_info().currsize - before
    assert added <= U.PATTERNS_PER_SIZE + 1  # the patterns seen and the dense step


def test_an_f_changed_in_place_is_seen_and_filters_still_pickle(general):
    """The filter's memo reuses its F's step while F holds the same values: a zero of F
    made non-zero in place must not be left out; and the memo pickles as empty."""

    def run():
        kf = KalmanFilter([1.0, 2.0], np.eye(2), F=np.eye(2), Q=0.01)
        kf.predict(0.1)
        kf.F[0, 1] = 0.5  # in place: the cache of F(dt) holds this very array
        kf.predict(0.1)
        kf.update(Observations().add("z", [1.5], H=[[1.0, 0.0]], R=0.2))
        return kf

    general.unrolled()
    kf = run()
    assert len(kf._unrolled) == 2
    general()
    want = run()
    np.testing.assert_allclose(kf.x, want.x, **TOL)
    np.testing.assert_allclose(kf.P, want.P, **TOL)
    general.unrolled()
    for f in (kf, copy.deepcopy(kf)):
        back = pickle.loads(pickle.dumps(f))
        assert len(back._unrolled) == 0
        back.predict(0.1)
        f.predict(0.1)
        np.testing.assert_allclose(back.P, f.P, **TOL)
    del kf._unrolled  # a filter pickled before the memo existed: predicts without one
    kf.predict(0.1)
    assert kf._unrolled is None


def test_sizes_outside_the_range_are_refused():
    with pytest.raises(ValueError, match="1 to 6 states, got 7"):
        U.predict_step(7)
    with pytest.raises(ValueError, match="1 to 3 rows, got 4"):
        U.linear_update(2, 4, False, True)
    with pytest.raises(ValueError, match="a pattern of 3 entries for a 2 x 2 matrix"):
        U.predict_step(2, (True, False, True))
