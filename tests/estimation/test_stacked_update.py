"""Several blocks fused in one step on the numpy backend: the stacked fast path
(``correction._fast_stacked``) equals the general path.

A model that fuses two or three sensors in one update (an accelerometer and a gyroscope
row, say) hands the filter several blocks of 2-3 rows in all. The numpy backend runs them
as one stacked block on Python floats: unrolled at n <= ``unrolled.MAX_N``, through the
small Cholesky helpers above, each block's NIS from its own diagonal sub-block of S. Each
test runs the same filter twice, once with the fast path switched off (the reference: the
general path's stacking, per-block Cholesky and joint factor), and compares every state,
covariance, NIS and gate decision to 1e-10 over 40 steps; the fast path must have been
taken.
"""

import math

import numpy as np
import pytest
from filter_runs import error_of, record, same_runs

from hera.estimation import (
    ExtendedKalmanFilter,
    KalmanFilter,
    Observations,
)
from hera.estimation import correction as C
from hera.estimation import unrolled as U
from hera.estimation.small import block_nis

TOL = {"rtol": 1e-10, "atol": 1e-10}
"""40 steps of roundoff summed in another order (a wrong term would differ by O(1))."""
DIMS = [(1, 1), (1, 2), (2, 1), (1, 1, 1)]
SIZES = [1, 2, 3, 5, U.MAX_N, U.MAX_N + 1, 8]  # unrolled up to MAX_N, small helpers above


@pytest.fixture(autouse=True)
def numpy_backend(use):
    use("numpy")


@pytest.fixture
def path(monkeypatch):
    """path.general() switches the stacked fast path off; path.fast() back on, counting
    how many updates it finished (``path.taken``)."""

    class Switch:
        taken = 0

        def general(self):
            monkeypatch.setattr(C, "_fast_stacked", lambda *a: None)

        def fast(self):
            def counted(*a):
                out = real(*a)
                self.taken += out is not None
                return out

            monkeypatch.setattr(C, "_fast_stacked", counted)

    real = C._fast_stacked
    return Switch()


def _problem(n, dims, seed):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n))
    P0 = A @ A.T + np.eye(n)
    F = np.eye(n) + np.diag(np.full(n - 1, 0.1), 1)
    Q = np.diag(rng.uniform(0.01, 0.1, n))
    Hs = [rng.normal(size=(d, n)) for d in dims]
    return rng.normal(size=n), P0, F, Q, Hs, rng


def _blocks(dims, Hs, zs, kind, rng_seed):
    """Observations of the stacked blocks; ``kind``: "linear" (diagonal R), "full" (the
    last block's R a full matrix), "mixed" (the first block h(x) = sin(H x) with its
    Jacobian, the second with a residual function, the rest linear)."""
    obs = Observations()
    rng = np.random.default_rng(rng_seed)
    for i, (d, H, z) in enumerate(zip(dims, Hs, zs, strict=True)):
        R = np.linspace(0.2, 0.6, d)
        if kind == "full" and i == len(dims) - 1 and d > 1:
            B = rng.normal(size=(d, d))
            R = 0.5 * (B @ B.T) + 0.2 * np.eye(d)
        if kind == "mixed" and i == 0:
            obs.add(
                f"b{i}",
                np.sin(z),
                h=lambda x, H=H: np.sin(H @ x),
                jacobian=lambda x, H=H: np.cos(H @ x)[:, None] * H,
                R=R,
            )
        elif kind == "mixed" and i == 1:
            obs.add(f"b{i}", z, H=H, R=R, residual=lambda z, hx: 0.9 * (z - hx))
        else:
            obs.add(f"b{i}", z, H=H, R=R)
    return obs


def _run(n, dims, seed, kind, joseph=True, gate=None, consider=None):
    x0, P0, F, Q, Hs, rng = _problem(n, dims, seed)
    kf = KalmanFilter(x0, P0, F=F, Q=Q, joseph=joseph, gate=gate)
    out = []
    for step in range(40):
        kf.predict(0.1)
        zs = [3.0 * rng.normal(size=d) for d in dims]
        out.append(record(kf, kf.update(_blocks(dims, Hs, zs, kind, step), consider=consider)))
    return out


def _same(got, want):
    return same_runs(got, want, TOL)


@pytest.mark.parametrize("n", SIZES)
@pytest.mark.parametrize("dims", DIMS, ids=str)
def test_stacked_blocks_equal_the_general_path(n, dims, path):
    cases = [
        ("linear", True, None),
        ("full", True, None),
        ("mixed", True, None),
        ("linear", False, None),  # the short form
        ("mixed", True, 0.9),  # gated: some blocks rejected, the others fused
    ]
    for seed, (kind, joseph, gate) in enumerate(cases):
        path.fast()
        taken = path.taken
        got = _run(n, dims, seed, kind, joseph, gate)
        path.general()
        want = _run(n, dims, seed, kind, joseph, gate)
        accepted = _same(got, want)
        assert path.taken > taken, "the fast path was not taken"
        if gate is None:
            assert accepted == 40 * len(dims)
            assert path.taken - taken == 40
        else:
            assert 0 < accepted < 40 * len(dims), "the gate case must reject some blocks"


@pytest.mark.parametrize("n", [4, U.MAX_N + 2])
def test_a_consider_update_of_stacked_blocks_equals_the_general_path(n, path):
    path.fast()
    got = _run(n, (1, 1, 1), 7, "mixed", consider=[n - 1])
    path.general()
    want = _run(n, (1, 1, 1), 7, "mixed", consider=[n - 1])
    _same(got, want)
    assert path.taken == 40
    assert got[-1][0][n - 1] == pytest.approx(got[0][0][n - 1])  # a considered state stays


def test_an_ekf_fusing_two_sensors_per_step_equals_the_general_path(path):
    def run():
        f = lambda x, dt, u: x + dt * np.sin(x)  # noqa: E731
        fj = lambda x, dt, u: np.eye(4) + dt * np.diag(np.cos(x))  # noqa: E731
        ekf = ExtendedKalmanFilter([0.1, 0.2, 0.3, 0.4], np.eye(4), f=f, F=fj, Q=0.01)
        rng = np.random.default_rng(4)
        out = []
        for _ in range(40):
            ekf.predict(0.05)
            obs = Observations()
            obs.add("acc", [rng.normal()], h=lambda x: [x[0] * x[1]], R=0.2)  # numerical J
            obs.add("gyro", [rng.normal()], H=[[0.0, 1.0, 0.0, 0.0]], R=0.1)
            out.append(record(ekf, ekf.update(obs)))
        return out

    path.fast()
    got = run()
    path.general()
    _same(got, run())
    assert path.taken == 40


def test_more_than_three_rows_or_one_block_or_details_take_other_paths(path):
    path.fast()
    kf = KalmanFilter(np.zeros(4), np.eye(4), F=np.eye(4), Q=0.01)
    H = np.eye(4)
    kf.update(
        Observations().add("a", [1.0, 2.0], H=H[:2], R=0.5).add("b", [1.0, 2.0], H=H[2:], R=0.5)
    )
    kf.update(Observations().add("a", [1.0], H=H[:1], R=0.5))
    kf.update(
        Observations().add("a", [1.0], H=H[:1], R=0.5).add("b", [2.0], H=H[1:2], R=0.5),
        method="sequential",
    )
    kf.update(
        Observations().add("a", [1.0], H=H[:1], R=0.5).add("b", [2.0], H=H[1:2], R=0.5),
        details=True,
    )
    assert path.taken == 0


def test_block_nis_is_each_blocks_own():
    """Against y_b^T S_bb^-1 y_b written with numpy's solve, ragged and square S alike."""
    rng = np.random.default_rng(2)
    for dims in DIMS:
        m = sum(dims)
        B = rng.normal(size=(m, m))
        S = B @ B.T + 0.5 * np.eye(m)
        y = rng.normal(size=m)
        want, o = [], 0
        for d in dims:
            Sb = S[o : o + d, o : o + d]
            want.append(float(y[o : o + d] @ np.linalg.solve(Sb, y[o : o + d])))
            o += d
        ragged = [S[i, : i + 1].tolist() for i in range(m)]
        np.testing.assert_allclose(block_nis(ragged, y.tolist(), dims), want, rtol=1e-12)
        np.testing.assert_allclose(block_nis(S.tolist(), y.tolist(), dims), want, rtol=1e-12)
    assert block_nis([[1.0], [0.0, -1.0]], [1.0, 1.0], (1, 1)) is None  # not PD


def test_the_unrolled_update_returns_the_lower_triangle_of_s():
    rng = np.random.default_rng(6)
    n, m = 5, 3
    A = rng.normal(size=(n, n))
    P = A @ A.T + np.eye(n)
    H = rng.normal(size=(m, n))
    v = [0.2, 0.3, 0.4]
    out = U.linear_update(n, m, False, True, None, False, True)(
        [0.0] * n, P.ravel().tolist(), H.ravel().tolist(), [0.1, 0.2, 0.3], v, math.inf
    )
    S = H @ P @ H.T + np.diag(v)
    assert [len(r) for r in out[3]] == [1, 2, 3]
    for i in range(m):
        np.testing.assert_allclose(out[3][i], S[i, : i + 1], **TOL)


# numpy warns as the reference path computes with the inf before it names it
@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
@pytest.mark.parametrize("n", [3, U.MAX_N + 1])
@pytest.mark.parametrize(
    "case", ["nan z", "inf H", "nan h(x)", "negative R", "S not PD", "P goes bad", "bad shape"]
)
def test_what_the_fast_path_cannot_decide_raises_the_general_paths_error(n, case, path):
    def run():
        kf = KalmanFilter(np.ones(n), np.eye(n), F=np.eye(n), Q=0.01)
        row = np.eye(n)[:1]
        z2, H2, R2 = [2.0], row, 0.5
        if case == "nan z":
            z2 = [math.nan]
        if case == "inf H":
            H2 = np.where(row > 0, math.inf, 0.0)
        if case == "S not PD":
            kf.P = np.zeros((n, n))
        if case == "P goes bad":  # the short form rounds P_11 to exactly 0
            kf.joseph, H2, R2 = False, np.eye(n)[1:2], 1e-300
        if case == "bad shape":
            H2 = np.ones((1, n + 1))
        obs = Observations().add("a", [1.0], H=row, R=0.5)
        if case == "nan h(x)":
            obs.add("b", z2, h=lambda x: [math.nan], R=R2)
        else:
            obs.add("b", z2, H=H2, R=R2)
        if case == "negative R":  # a variance that went bad after the block was built
            obs.blocks[-1].var = np.array([-0.5])
        x, P = kf.x.copy(), kf.P.copy()
        try:
            kf.update(obs)
        finally:
            np.testing.assert_array_equal(kf.x, x)
            np.testing.assert_array_equal(kf.P, P)

    path.fast()
    got = error_of(run)
    path.general()
    assert got == error_of(run)
