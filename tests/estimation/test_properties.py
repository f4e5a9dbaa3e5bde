"""Property-based tests (hypothesis): the numpy and numba backends give the same result or
the same error on random problems, well- and ill-conditioned, good inputs and bad.

Problems are drawn from a few parameters hypothesis chooses (and shrinks): sizes, the
condition number of P (eigenvalues log-uniform over up to 12 decades, random rotation), the
scale of the variances (1e-10 .. 1e2, as vectors or as full matrices), the kind of block
(linear H, h with Jacobian, h with a numerical Jacobian, a residual function), gating,
Joseph or short form, joint or sequential, and a seed for the numbers.

Stated tolerances. The backends evaluate the same formulas in different orders, so they
differ by roundoff amplified by the conditioning of the innovation covariance S:

* the state: |x_a - x_b| <= tol * (|x_post| + |x_prior| + sqrt(max P_ii)), per entry;
* the covariance: |P_a - P_b| <= tol * max |P_prior|;
* the NIS: relative tol;

with tol = max(1e-9, 100 cond(S) eps): 1e-9 for well-conditioned problems (cond(S) up to
~5e4), else 100 times the error bound of a backward-stable solve. A gate decision is
compared unless the NIS lies within tol of the threshold; likewise success and
CovarianceError may differ only where roundoff decides positive definiteness: S (or a
block's part of it) numerically singular, cond > 1e13, or a posterior variance below 1e-12
of its prior (P's entries then carry roundoff of the variance's size).

Errors must match exactly: the same exception class and the same message.
"""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from hera.estimation import (
    ExtendedKalmanFilter,
    KalmanFilter,
    Observations,
    UnscentedKalmanFilter,
    angle_residual,
    circular_mean,
    gate_threshold,
    linearised_update,
)

EPS = np.finfo(float).eps
SETTINGS = settings(
    max_examples=150,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)


def _rotation(rng, n):
    q, r = np.linalg.qr(rng.normal(size=(n, n)))
    return q * np.sign(np.diag(r))


def _spd(rng, n, decades, scale):
    """A symmetric PD matrix with eigenvalues log-uniform over ``decades`` decades."""
    ev = scale * 10.0 ** rng.uniform(-decades, 0.0, size=n)
    Qr = _rotation(rng, n)
    M = (Qr * ev) @ Qr.T
    return 0.5 * (M + M.T)


def _noise(rng, m, var_exp, full):
    var = 10.0 ** (var_exp + rng.uniform(-1, 1, size=m))
    if not full or m == 1:
        return var
    return _spd(rng, m, 1.0, float(var.max()))


def _blocks(rng, n, sizes, kinds, var_exp, full_R, bad):
    obs = Observations()
    for i, m in enumerate(sizes):
        C = rng.normal(size=(m, n))
        z = rng.normal(size=m)
        R = _noise(rng, m, var_exp, full_R)
        kind = kinds[i % len(kinds)]
        if bad == "z" and i == 0:
            z[0] = math.nan
        if bad == "H" and i == len(sizes) - 1:
            C[0, 0] = math.inf
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
        elif kind == "W":
            obs.add(f"b{i}", z, H=C, R=R, residual=angle_residual)
        else:  # "S": h of the wrong size
            obs.add(f"b{i}", z, h=lambda x, m=m: np.zeros(m + 1), R=R)
    return obs


def _outcome(fn):
    try:
        return ("ok", fn())
    except Exception as e:  # noqa: BLE001 - the point is to compare any error
        return ("error", (type(e), str(e)))


def _both(use, fn):
    use("numpy")
    a = _outcome(fn)
    use("numba")
    b = _outcome(fn)
    return a, b


def _cond_S(x, P, obs, worst=False):
    """cond(S) of the stacked blocks at x (linearised like the filter, for the bound);
    ``worst``: the largest of it and its blocks' diagonal sub-blocks' (which the NIS and
    the sequential updates factorise)."""
    Hs, Rs = [], []
    for b in obs.blocks:
        if b.H is not None:
            Hs.append(b.H)
        else:
            eps = 1e-6
            cols = [(b.h(x + eps * e) - b.h(x - eps * e)) / (2 * eps) for e in np.eye(x.shape[0])]
            Hs.append(np.column_stack(cols).reshape(b.dim, -1))
        Rs.append(b.cov())
    H = np.vstack(Hs)
    R = np.zeros((H.shape[0], H.shape[0]))
    o = 0
    for Rb in Rs:
        d = Rb.shape[0]
        R[o : o + d, o : o + d] = Rb
        o += d
    S = H @ P @ H.T + R
    conds = [float(np.linalg.cond(S))]
    o = 0
    for b in obs.blocks:
        conds.append(float(np.linalg.cond(S[o : o + b.dim, o : o + b.dim])))
        o += b.dim
    return max(conds) if worst else conds[0]


def _tol(cond):
    return max(1e-9, 100.0 * cond * EPS)


def _compare_updates(a, b, x, P, obs, gate):
    if a[0] != b[0]:
        # Only where a positive-definiteness decision is made by roundoff may it go either
        # way, as a gate decision may for a NIS at the threshold: a numerically singular S
        # (cond > 1e13, its smallest Cholesky pivot at roundoff level), or a posterior
        # variance below 1e-12 of its prior (then P's entries, ~1e12 times larger, carry
        # roundoff of its size whatever the form; the short form reaches this sooner).
        # Everywhere else the outcomes must be the same.
        ok = a if a[0] == "ok" else b
        Pp = ok[1][1]
        roundoff_P = (np.diag(Pp) / np.diag(P)).min() < 1e-12
        assert roundoff_P or _cond_S(x, P, obs, worst=True) > 1e13, (a, b)
        return
    if a[0] == "error":
        assert a[1] == b[1]
        return
    (xa, Pa, ra), (xb, Pb, rb) = a[1], b[1]
    tol = _tol(_cond_S(x, P, obs))
    for oa, ob in zip(ra.outcomes, rb.outcomes, strict=True):
        assert (oa.label, oa.dim, oa.threshold) == (ob.label, ob.dim, ob.threshold)
        assert oa.nis == pytest.approx(ob.nis, rel=tol, abs=tol)
        if gate is not None:
            thr = gate_threshold(gate, oa.dim)
            assume(abs(oa.nis - thr) > tol * max(1.0, thr))
            assert oa.accepted == ob.accepted
    scale_x = np.abs(xa) + np.abs(x) + math.sqrt(float(np.diag(P).max()))
    assert (np.abs(xa - xb) <= tol * scale_x).all()
    assert np.abs(Pa - Pb).max() <= tol * np.abs(P).max()
    assert np.array_equal(Pb, Pb.T) and np.array_equal(Pa, Pa.T)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
@SETTINGS
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 6),
    sizes=st.lists(st.integers(1, 4), min_size=1, max_size=3),
    kinds=st.sampled_from(["H", "J", "N", "W", "HJ", "NW", "HN"]),
    decades=st.sampled_from([0.0, 2.0, 6.0, 10.0, 12.0]),
    p_scale=st.sampled_from([1e-6, 1.0, 1e6]),
    var_exp=st.sampled_from([-10.0, -6.0, -2.0, 0.0, 2.0]),
    full_R=st.booleans(),
    joseph=st.booleans(),
    method=st.sampled_from(["auto", "joint", "sequential"]),
    gate=st.sampled_from([None, 0.99]),
)
def test_linearised_update_same_on_both_backends(
    use, seed, n, sizes, kinds, decades, p_scale, var_exp, full_R, joseph, method, gate
):
    rng = np.random.default_rng(seed)
    P = _spd(rng, n, decades, p_scale)
    x = rng.normal(size=n)
    obs = _blocks(rng, n, sizes, kinds, var_exp, full_R, None)
    a, b = _both(use, lambda: linearised_update(x, P, obs.blocks, gate, joseph, method))
    _compare_updates(a, b, x, P, obs, gate)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
@SETTINGS
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 5),
    sizes=st.lists(st.integers(1, 3), min_size=1, max_size=2),
    bad=st.sampled_from(["z", "H", "shape", "P", "none"]),
    method=st.sampled_from(["auto", "joint", "sequential"]),
)
def test_bad_inputs_give_the_same_error_on_both_backends(use, seed, n, sizes, bad, method):
    """Non-finite z or H, h of the wrong size, an indefinite P: the same error class and
    message on both backends (or, for P, both refuse it where it enters)."""
    rng = np.random.default_rng(seed)
    P = _spd(rng, n, 3.0, 1.0)
    if bad == "P":
        P = P - 2.0 * np.eye(n) * float(np.linalg.eigvalsh(P).max())
    x = rng.normal(size=n)
    kinds = "S" if bad == "shape" else "HJ"
    obs = _blocks(rng, n, sizes, kinds, 0.0, False, bad)
    a, b = _both(use, lambda: linearised_update(x, P, obs.blocks, None, True, method))
    if bad != "none":
        assert a[0] == "error", a
    _compare_updates(a, b, x, P, obs, None)


@SETTINGS
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 6),
    kind=st.sampled_from(["KF", "EKF", "UKF"]),
    decades=st.sampled_from([0.0, 4.0, 8.0]),
    q_form=st.sampled_from(["scalar", "vector", "matrix", "override"]),
    steps=st.integers(1, 5),
)
def test_trajectories_same_on_both_backends(use, seed, n, kind, decades, q_form, steps):
    """Several predict/update steps of each filter: the same trajectory on both backends
    (tolerance of the well-conditioned case, these problems are moderate)."""
    rng = np.random.default_rng(seed)
    P0 = _spd(rng, n, decades, 1.0)
    A = np.eye(n) + 0.1 * rng.normal(size=(n, n))
    Qm = _spd(rng, n, 2.0, 0.01)
    Q = {"scalar": 0.01, "vector": np.diag(Qm), "matrix": Qm, "override": 0.0}[q_form]
    C = rng.normal(size=(1, n))
    zs = rng.normal(size=steps)

    def run():
        x0 = rng_x = np.random.default_rng(seed + 1).normal(size=n)
        del rng_x
        if kind == "KF":
            filt = KalmanFilter(x0, P0, F=A, Q=Q)
        elif kind == "EKF":
            filt = ExtendedKalmanFilter(x0, P0, f=lambda x, dt, u: A @ x + 0.01 * np.sin(x), Q=Q)
        else:
            filt = UnscentedKalmanFilter(x0, P0, f=lambda x, dt, u: A @ x + 0.01 * np.sin(x), Q=Q)
        out = []
        for z in zs:
            if q_form == "override":
                filt.predict(0.1, Q=Qm)
            else:
                filt.predict(0.1)
            obs = Observations().add("a", [z], h=lambda x: np.tanh(C @ x), R=0.3)
            if kind == "UKF":
                obs.add(
                    "b",
                    [math.pi - 0.01],
                    h=lambda x: np.array([math.atan2(x[0], -1.0)]),
                    R=0.5,
                    mean=circular_mean,
                    residual=angle_residual,
                )
            filt.update(obs)
            out.append((filt.x, filt.P))
        return out

    a, b = _both(use, run)
    assert a[0] == b[0], (a, b)
    if a[0] == "error":
        assert a[1] == b[1]
        return
    for (xa, Pa), (xb, Pb) in zip(a[1], b[1], strict=True):
        np.testing.assert_allclose(xb, xa, rtol=1e-8, atol=1e-8 * math.sqrt(np.abs(P0).max()))
        np.testing.assert_allclose(Pb, Pa, rtol=1e-8, atol=1e-8 * np.abs(P0).max())
