"""The compiled (numba) backend equals the numpy path to 1e-12 and fails the same way.

Every test runs the same problem twice, once per backend, and compares. The numpy path is
always tested (the rest of this folder runs on whichever backend ``HERA_ESTIMATION_BACKEND``
selects: numba when installed, as in CI); numba is a test requirement, so these tests fail,
never skip, without it.
"""

import math

import numpy as np
import pytest

from hera.estimation import (
    CovarianceError,
    ExtendedKalmanFilter,
    KalmanFilter,
    NonFiniteInputError,
    Observations,
    UnscentedKalmanFilter,
    backend,
    linearised_update,
)
from hera.estimation import correction as corr

TOL = {"rtol": 1e-12, "atol": 1e-12}


@pytest.fixture
def use():
    """use(name) switches the backend for the rest of the test; restored afterwards."""
    before = backend.backend()
    yield backend.set_backend
    backend.set_backend(before)


@pytest.fixture
def numba_kernels():
    import numba  # noqa: F401  (a test requirement: missing, the tests fail, never skip)

    return True


def _spd(rng, n, scale=1.0):
    A = rng.normal(size=(n, n))
    return scale * (A @ A.T / n + np.eye(n))


def _obs(rng, n, sizes, kinds, full_R=False):
    """Blocks of the given sizes; kinds cycles over 'H' (linear), 'J' (h with Jacobian),
    'N' (h, numerical Jacobian), 'W' (linear with a residual function)."""
    obs = Observations()
    for i, m in enumerate(sizes):
        C = rng.normal(size=(m, n))
        var = rng.uniform(0.2, 1.0, size=m)
        R = np.diag(var) if full_R else var
        z = rng.normal(size=m)
        kind = kinds[i % len(kinds)]
        if kind == "H":
            obs.add(f"b{i}", z, H=C, R=R)
        elif kind == "J":
            obs.add(
                f"b{i}",
                z,
                h=lambda x, C=C: np.tanh(C @ x),
                jacobian=lambda x, C=C: (1.0 - np.tanh(C @ x) ** 2)[:, None] * C,
                R=R,
            )
        elif kind == "N":
            obs.add(f"b{i}", z, h=lambda x, C=C: np.sin(C @ x), R=R)
        else:
            obs.add(f"b{i}", z, H=C, R=R, residual=lambda a, b: a - b)
    return obs


def _both(use, fn):
    use("numpy")
    ref = fn()
    use("numba")
    got = fn()
    return ref, got


def _same_result(ra, rb, rtol=1e-10):
    assert [(o.label, o.dim, o.accepted, o.threshold) for o in ra.outcomes] == [
        (o.label, o.dim, o.accepted, o.threshold) for o in rb.outcomes
    ]
    np.testing.assert_allclose(
        [o.nis for o in ra.outcomes], [o.nis for o in rb.outcomes], rtol=rtol, atol=1e-12
    )


def test_backend_switch(use):
    assert use("numpy") == "numpy" and backend.backend() == "numpy"
    assert backend.warmup() == 0.0
    with pytest.raises(ValueError, match="unknown estimation backend"):
        use("cuda")
    name = use("auto")
    assert name in ("numba", "numpy")


def test_kernel_protocol_matches(numba_kernels):
    from hera.estimation import kernels_numba as kn

    assert (kn.ALL_REJECTED, kn.MODE_HX, kn.MODE_GIVEN) == (corr.ALL_REJECTED, 1, 2)
    assert kn.WS_SMALL == corr._WS_SMALL
    assert (corr._MODE_HX, corr._MODE_GIVEN, corr._DIAG, corr._JOSEPH, corr._SEQUENTIAL) == (
        kn.MODE_HX,
        kn.MODE_GIVEN,
        kn.DIAG,
        kn.JOSEPH,
        kn.SEQUENTIAL,
    )


@pytest.mark.parametrize("n", [1, 2, 4, 9])
@pytest.mark.parametrize(
    "sizes,kinds",
    [
        ((1,), "H"),
        ((2,), "J"),
        ((3,), "N"),
        ((3,), "W"),
        ((4,), "H"),
        ((1, 2), "HJ"),
        ((3, 1, 2), "HNJ"),
        ((2, 2, 3), "WHJ"),
    ],
)
@pytest.mark.parametrize("joseph", [True, False])
@pytest.mark.parametrize("method", ["auto", "joint", "sequential"])
def test_linearised_update_matches_numpy(use, numba_kernels, n, sizes, kinds, joseph, method):
    rng = np.random.default_rng(n * 1000 + sum(sizes) * 10 + len(kinds))
    x, P = rng.normal(size=n), _spd(rng, n)
    obs = _obs(rng, n, sizes, kinds)
    (xa, Pa, ra), (xb, Pb, rb) = _both(
        use, lambda: linearised_update(x, P, obs.blocks, None, joseph, method)
    )
    np.testing.assert_allclose(xb, xa, **TOL)
    np.testing.assert_allclose(Pb, Pa, **TOL)
    assert np.array_equal(Pb, Pb.T)
    _same_result(ra, rb)


@pytest.mark.parametrize("full_R", [False, True])
@pytest.mark.parametrize("sizes", [(1,), (3,), (1, 2, 2), (2, 3)])
@pytest.mark.parametrize("offset", [0.0, 3.0, 50.0])
def test_gated_update_matches_numpy(use, numba_kernels, full_R, sizes, offset):
    """Some, all or none of the blocks gated out (outliers added to every second block)."""
    n = 4
    rng = np.random.default_rng(len(sizes) * 7 + int(offset))
    x, P = rng.normal(size=n), _spd(rng, n, 0.1)
    obs = _obs(rng, n, sizes, "HJ", full_R=full_R)
    for i, b in enumerate(obs.blocks):
        if i % 2 == 0:
            b.z = b.z + offset
    method = "joint" if full_R else "auto"
    (xa, Pa, ra), (xb, Pb, rb) = _both(
        use, lambda: linearised_update(x, P, obs.blocks, 0.99, True, method)
    )
    _same_result(ra, rb)
    np.testing.assert_allclose(xb, xa, **TOL)
    np.testing.assert_allclose(Pb, Pa, **TOL)
    if not ra.updated:
        assert xb is x and Pb is P


def _run_kf(use, n, with_u, joseph, steps=25):
    rng = np.random.default_rng(n)
    F = np.eye(n) + 0.1 * rng.normal(size=(n, n))
    Q = _spd(rng, n, 0.01)
    B = rng.normal(size=(n, 2))
    H = rng.normal(size=(2, n))
    zs = rng.normal(size=(steps, 2))
    us = rng.normal(size=(steps, 2))

    def run():
        kf = KalmanFilter(np.zeros(n), np.eye(n), F=F, Q=Q, B=B if with_u else None)
        kf.joseph = joseph
        out = []
        for z, u in zip(zs, us, strict=True):
            kf.predict(0.1, u if with_u else None)
            r = kf.update(Observations().add("z", z, H=H, R=[0.3, 0.5]), gate=0.999)
            out.append((kf.x.copy(), kf.P.copy(), r))
        kf.predict(0.1, F=F.T.copy(), Q=2 * Q)
        out.append((kf.x.copy(), kf.P.copy(), None))
        return out

    return _both(use, run)


@pytest.mark.parametrize("n", [1, 2, 4, 9])
@pytest.mark.parametrize("with_u", [False, True])
@pytest.mark.parametrize("joseph", [True, False])
def test_kf_trajectory_matches_numpy(use, numba_kernels, n, with_u, joseph):
    ref, got = _run_kf(use, n, with_u, joseph)
    for (xa, Pa, ra), (xb, Pb, rb) in zip(ref, got, strict=True):
        np.testing.assert_allclose(xb, xa, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(Pb, Pa, rtol=1e-10, atol=1e-12)
        if ra is not None:
            _same_result(ra, rb)


@pytest.mark.parametrize("n", [2, 4, 9])
def test_ekf_trajectory_matches_numpy(use, numba_kernels, n):
    rng = np.random.default_rng(10 + n)
    A = np.eye(n) + 0.05 * rng.normal(size=(n, n))
    Q = _spd(rng, n, 0.01)
    zs = rng.normal(size=(20, 2))

    def f(x, dt, u):
        return A @ x + 0.01 * np.sin(x)

    def fj(x, dt, u):
        return A + np.diag(0.01 * np.cos(x))

    def h(x):
        return np.array([math.hypot(x[0], 1.0), x[-1] ** 2])

    def hj(x):
        J = np.zeros((2, n))
        J[0, 0] = x[0] / math.hypot(x[0], 1.0)
        J[1, -1] += 2 * x[-1]
        return J

    def run():
        out = []
        for F in (fj, None):  # analytic and numerical process Jacobians
            ekf = ExtendedKalmanFilter(0.1 * np.ones(n), np.eye(n), f=f, F=F, Q=Q)
            for z in zs if F is not None else zs[:4]:  # see the tolerance note below
                ekf.predict(0.1)
                r = ekf.update(Observations().add("r", z, h=h, jacobian=hj, R=0.2))
                out.append((ekf.x.copy(), ekf.P.copy(), r, F is None))
        return out

    ref, got = _both(use, run)
    for (xa, Pa, ra, fd), (xb, Pb, rb, _) in zip(ref, got, strict=True):
        # A central-difference Jacobian (step ~6e-6) amplifies roundoff-level differences
        # of x by ~1e5 on the next step; the kernels themselves agree to 1e-12.
        tol = {"rtol": 1e-8, "atol": 1e-10} if fd else {"rtol": 1e-10, "atol": 1e-12}
        np.testing.assert_allclose(xb, xa, **tol)
        np.testing.assert_allclose(Pb, Pa, **tol)
        _same_result(ra, rb, tol["rtol"])


@pytest.mark.parametrize("n", [2, 4, 9])
@pytest.mark.parametrize("sizes", [(1,), (3,), (2, 1)])
@pytest.mark.parametrize("gate", [None, 0.99])
@pytest.mark.parametrize("full_R", [False, True])
def test_ukf_trajectory_matches_numpy(use, numba_kernels, n, sizes, gate, full_R):
    rng = np.random.default_rng(100 + n + len(sizes))
    A = np.eye(n) + 0.05 * rng.normal(size=(n, n))
    Q = _spd(rng, n, 0.01)
    Cs = [rng.normal(size=(m, n)) for m in sizes]
    zs = [rng.normal(size=sum(sizes)) for _ in range(15)]
    zs[5] = zs[5] + 40.0  # an outlier step (gated out when gating is on)

    def run():
        ukf = UnscentedKalmanFilter(
            np.zeros(n),
            np.eye(n),
            f=lambda x, dt, u: A @ x + 0.01 * np.sin(x),
            Q=Q,
            alpha=0.5,
            gate=gate,
        )
        out = []
        for z in zs:
            ukf.predict(0.1)
            obs = Observations()
            o = 0
            for i, C in enumerate(Cs):
                m = C.shape[0]
                R = np.diag(np.full(m, 0.4)) if full_R else 0.4
                obs.add(f"s{i}", z[o : o + m], h=lambda x, C=C: np.tanh(C @ x), R=R)
                o += m
            r = ukf.update(obs)
            out.append((ukf.x.copy(), ukf.P.copy(), r))
        return out

    ref, got = _both(use, run)
    for (xa, Pa, ra), (xb, Pb, rb) in zip(ref, got, strict=True):
        np.testing.assert_allclose(xb, xa, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(Pb, Pa, rtol=1e-10, atol=1e-12)
        _same_result(ra, rb)


@pytest.mark.parametrize("name", ["numpy", "numba"])
@pytest.mark.parametrize("bad", ["z", "H", "h"])
def test_nonfinite_rejected_state_unchanged(use, name, bad):
    use(name)
    n = 3
    kf = KalmanFilter(np.ones(n), np.eye(n), F=np.eye(n), Q=0.1 * np.eye(n))
    x0, P0 = kf.x.copy(), kf.P.copy()
    z, R, H = np.ones(2), np.ones(2), np.ones((2, n))
    if bad == "z":
        z = np.array([1.0, np.nan])
    elif bad == "H":
        H = H.copy()
        H[1, 2] = np.nan
    obs = Observations()
    if bad == "h":
        obs.add("s", z, h=lambda x: np.array([x[0], np.nan]), R=R)
    else:
        obs.add("s", z, H=H, R=R)
    with pytest.raises(NonFiniteInputError) as ei:
        kf.update(obs)
    assert ei.value.label == "s"
    np.testing.assert_array_equal(kf.x, x0)
    np.testing.assert_array_equal(kf.P, P0)


@pytest.mark.parametrize(
    "R", [np.array([1.0, np.inf]), [1.0, np.nan], np.array([[1, 0], [0, np.nan]])]
)
def test_nonfinite_R_refused_by_add(R):
    with pytest.raises(NonFiniteInputError) as ei:
        Observations().add("s", np.ones(2), H=np.ones((2, 3)), R=R)
    assert ei.value.label == "s" and ei.value.what == "R"


@pytest.mark.parametrize("name", ["numpy", "numba"])
def test_bad_covariance_and_foreign_arrays(use, name):
    use(name)
    ukf = UnscentedKalmanFilter(np.zeros(2), np.eye(2), f=lambda x, dt, u: x, Q=np.eye(2))
    with pytest.raises(CovarianceError, match="not positive semi-definite"):
        ukf.P = np.array([[1.0, 2.0], [2.0, 1.0]])  # indefinite: refused where it enters
    np.testing.assert_array_equal(ukf.P, np.eye(2))
    # Arrays of another layout or dtype are converted on assignment, the same on both
    # backends: the state is always a C-contiguous float64 array.
    kf = KalmanFilter(np.zeros(3), np.eye(3), F=np.eye(3), Q=np.eye(3))
    kf.P = np.asfortranarray(2.0 * np.eye(3))[:, :]
    kf.x = np.arange(3)  # integers
    assert kf.x.dtype == np.float64 and kf.P.flags.c_contiguous
    kf.x = [1.0, 2.0, 3.0]  # a list
    np.testing.assert_array_equal(kf.x, [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="x has 2 values, the state has 3"):
        kf.x = [1.0, 2.0]
    kf.predict(0.1)
    kf.update(Observations().add("z", [1.0], H=np.array([[1, 0, 0]]), R=1.0))
    assert kf.P[0, 0] == pytest.approx(3.0 - 9.0 / 4.0)


# --- Allocation-free single-block kernel (lin_update1) and the predict kernels ---------


@pytest.mark.parametrize("n", [1, 2, 9])
@pytest.mark.parametrize("m", [1, 2, 3, 4])
@pytest.mark.parametrize("kind", ["H", "J", "N", "W"])
@pytest.mark.parametrize("full_R", [False, True])
@pytest.mark.parametrize("joseph", [True, False])
@pytest.mark.parametrize("symmetric", [True, False])
def test_single_block_kernel_matches_numpy(
    use, numba_kernels, n, m, kind, full_R, joseph, symmetric
):
    """Every branch of lin_update1: innovation mode, diagonal/full R, one row (scalar S) or
    several (Cholesky), Joseph or short form, P given exactly symmetric or asymmetric by an
    ulp (symmetrised where it enters, the same on both backends)."""
    rng = np.random.default_rng(n * 97 + m * 13 + len(kind))
    x, P = rng.normal(size=n), _spd(rng, n)
    if not symmetric and n > 1:  # asymmetric by one ulp, as roundoff leaves a user's P
        P[0, -1] = np.nextafter(P[0, -1], np.inf)
    obs = _obs(rng, n, (m,), kind, full_R=full_R)
    for gate in (None, 0.999):
        (xa, Pa, ra), (xb, Pb, rb) = _both(
            use, lambda g=gate: linearised_update(x, P, obs.blocks, g, joseph, "joint")
        )
        np.testing.assert_allclose(xb, xa, **TOL)
        np.testing.assert_allclose(Pb, Pa, **TOL)
        assert np.array_equal(Pb, Pb.T)
        _same_result(ra, rb)


def test_non_contiguous_and_readonly_inputs(use, numba_kernels):
    """Strided / read-only user arrays take the general kernel signature: same results."""
    n, m = 4, 2
    rng = np.random.default_rng(5)
    x, P = rng.normal(size=n), _spd(rng, n)
    H = np.asfortranarray(rng.normal(size=(m, n)))
    z = rng.normal(size=2 * m)[::2]
    var = np.array([0.3, 0.5])
    var.flags.writeable = False
    obs = Observations().add("s", z, H=H, R=var)
    (xa, Pa, ra), (xb, Pb, rb) = _both(use, lambda: linearised_update(x, P, obs.blocks))
    np.testing.assert_allclose(xb, xa, **TOL)
    np.testing.assert_allclose(Pb, Pa, **TOL)
    _same_result(ra, rb)
    F = np.asfortranarray(np.eye(n) + 0.1 * rng.normal(size=(n, n)))

    def run():
        ekf = ExtendedKalmanFilter(
            x, P, f=lambda s, dt, u: F @ s, F=lambda s, dt, u: F, Q=np.eye(n)
        )
        ekf.predict(0.1)
        kf = KalmanFilter(x, P, F=F, Q=np.eye(n))
        kf.predict(0.1)
        return ekf.x, ekf.P, kf.x, kf.P

    for a, b in zip(*_both(use, run), strict=True):
        np.testing.assert_allclose(b, a, **TOL)


def test_scratch_grows_for_large_states(use, numba_kernels):
    """n = 70: n^2 exceeds the initial scratch array; the kernels ask for more and retry."""
    from hera.estimation import stacking

    n = 70
    rng = np.random.default_rng(70)
    A = np.eye(n) + 0.01 * rng.normal(size=(n, n))
    H = rng.normal(size=(2, n))
    stacking.SCRATCH[0] = np.empty(16)  # as if freshly started with a tiny scratch array

    def run():
        out = []
        kf = KalmanFilter(np.zeros(n), np.eye(n), F=A, Q=0.01 * np.eye(n))
        ekf = ExtendedKalmanFilter(
            np.zeros(n), np.eye(n), f=lambda s, dt, u: A @ s, F=lambda s, dt, u: A, Q=np.eye(n)
        )
        for filt in (kf, ekf):
            filt.predict(0.1)
            filt.update(Observations().add("z", [0.5, -0.2], H=H, R=0.3))
            out += [filt.x, filt.P]
        return out

    for a, b in zip(*_both(use, run), strict=True):
        np.testing.assert_allclose(b, a, rtol=1e-10, atol=1e-12)
    assert stacking.SCRATCH[0].shape[0] >= n * n


def test_kernels_reject_inconsistent_shapes(numba_kernels):
    """Called directly with arrays that do not fit together, the kernels return BAD_SHAPE
    (never read or write out of bounds); wrong ranks or dtypes are refused by dispatch."""
    from hera.estimation import kernels_numba as kn
    from hera.estimation.stacking import SCRATCH

    k = backend._numba_kernels()
    n = 3
    for m in (1, 2):
        x, P, H = np.zeros(n), np.eye(n), np.ones((m, n))
        z, hx, var = np.ones(m), np.zeros(m), np.ones(m)
        ws = SCRATCH[0]
        ok = (x, P, H, z, hx, var, math.inf, kn.DIAG | kn.JOSEPH | kn.MODE_HX)
        assert k.lin_update1(*ok, ws, np.empty(n), np.empty((n, n))) >= 0.0
        bad = [
            (0, np.zeros(n + 1)),
            (1, np.eye(n + 1)),
            (2, np.ones((m, n + 1))),
            (3, np.ones(m + 1)),
            (4, np.zeros(m + 1)),
            (5, np.ones(m + 2)),
        ]
        for i, arr in bad:
            args = list(ok)
            args[i] = arr
            got = k.lin_update1(*args, ws, np.empty(n), np.empty((n, n)))
            assert got == kn.BAD_SHAPE, (m, i)
        assert k.lin_update1(*ok, ws, np.empty(n + 1), np.empty((n, n))) == kn.BAD_SHAPE
        assert k.lin_update1(*ok, ws, np.empty(n), np.empty((n, n + 1))) == kn.BAD_SHAPE
        if m > 1:
            full = list(ok)
            full[-1] = kn.JOSEPH | kn.MODE_HX  # a full R expected: m * m values, not m
            assert k.lin_update1(*full, ws, np.empty(n), np.empty((n, n))) == kn.BAD_SHAPE
        assert k.lin_update1(*ok, np.empty(3), np.empty(n), np.empty((n, n))) == kn.WS_SMALL
        neg = list(ok)
        neg[5] = -var
        assert k.lin_update1(*neg, ws, np.empty(n), np.empty((n, n))) == kn.BAD_R
        with pytest.raises(TypeError):
            k.lin_update1(x, P, H.ravel(), *ok[3:], ws, np.empty(n), np.empty((n, n)))
        with pytest.raises(TypeError):
            k.lin_update1(x, P, H.astype(np.float32), *ok[3:], ws, np.empty(n), np.empty((n, n)))
    Po = np.empty((n, n))
    assert k.ekf_predict(x, P, np.eye(n + 1), P, ws, Po) == kn.BAD_SHAPE
    assert k.ekf_predict(np.zeros(n + 1), P, P, P, ws, Po) == kn.BAD_SHAPE
    assert k.kf_predict(x, P, P, np.eye(n - 1), ws, np.empty(n), Po) == kn.BAD_SHAPE
    assert k.kf_predict(x, P, P, P, np.empty(2), np.empty(n), Po) == kn.WS_SMALL
    # the UKF kernels on deviations: OK for consistent shapes, BAD_SHAPE otherwise
    N = 2 * n + 1
    Wc = np.full(N, 1.0 / N)
    D = np.random.default_rng(1).normal(size=(N, n))
    assert k.ukf_predict_dev(D, Wc, P, Po) == kn.OK
    assert k.ukf_predict_dev(D[:, :2], Wc, P, Po) == kn.BAD_SHAPE
    Dy = D[:, :2]
    ends, thr = np.array([2]), np.array([math.inf])
    args = (x, P, D, Dy, np.ones(2), np.ones(2), True, ends, thr, Wc)
    assert k.ukf_update_dev(*args, np.empty(n), np.empty((n, n)), np.empty(1)) == kn.OK
    assert (
        k.ukf_update_dev(*args[:4], np.ones(3), *args[5:], np.empty(n), Po, np.empty(1))
        == kn.BAD_SHAPE
    )


@pytest.mark.parametrize("name", ["numpy", "numba"])
def test_wrong_jacobian_shapes_raise_clearly(use, name):
    use(name)
    n = 3
    ekf = ExtendedKalmanFilter(
        np.zeros(n), np.eye(n), f=lambda s, dt, u: s, F=lambda s, dt, u: np.eye(2), Q=np.eye(n)
    )
    x0, P0 = ekf.x, ekf.P
    with pytest.raises(ValueError, match="Jacobian F has shape"):
        ekf.predict(0.1)
    obs = Observations().add(
        "r", [1.0], h=lambda s: np.array([s[0]]), jacobian=lambda s: np.ones((1, n + 1)), R=1.0
    )
    with pytest.raises(ValueError, match="block 'r'"):
        ekf.update(obs)
    assert ekf.x is x0 and ekf.P is P0


def test_compiled_paths_do_not_fall_back(use, numba_kernels, monkeypatch):
    """On the numba backend every ordinary step runs compiled: with the numpy fallbacks
    made to fail, each kind of block (linear, Jacobian, numerical Jacobian, residual, full
    R, several blocks, sequential rows) and the UKF with mean/residual functions still
    update and predict (so the agreement tests above compare two implementations)."""
    from hera.estimation import angle_residual, circular_mean, make_mean, make_residual
    from hera.estimation import ukf as ukf_mod

    use("numba")

    def boom(*a, **k):
        raise AssertionError("numpy fallback used")

    monkeypatch.setattr(corr, "linearised_update_numpy", boom)
    monkeypatch.setattr(ukf_mod.UnscentedKalmanFilter, "_correct_numpy", boom)
    rng = np.random.default_rng(9)
    n = 4
    for sizes, kinds, full in (
        ((1,), "H", False),
        ((2,), "J", True),
        ((3,), "N", False),
        ((1,), "W", False),
        ((2, 1), "HJ", False),
        ((5,), "H", False),
    ):
        kf = KalmanFilter(np.zeros(n), np.eye(n), F=np.eye(n), Q=0.1)
        kf.predict(0.1)
        res = kf.update(_obs(rng, n, sizes, kinds, full_R=full))
        assert res.updated
    ukf = UnscentedKalmanFilter(
        np.zeros(n),
        np.eye(n),
        f=lambda x, dt, u: x,
        Q=0.1,
        x_mean=make_mean(angles=[0]),
        residual_x=make_residual(angles=[0]),
    )
    ukf.predict(0.1)
    obs = Observations().add(
        "b", [3.1], h=lambda x: x[:1], R=0.1, mean=circular_mean, residual=angle_residual
    )
    assert ukf.update(obs).updated
    plain = UnscentedKalmanFilter(np.zeros(n), np.eye(n), f=lambda x, dt, u: x, Q=0.1)
    plain.predict(0.1)
    assert plain.update(_obs(rng, n, (2, 1), "HJ")).updated
