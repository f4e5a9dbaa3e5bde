"""Agreement with FilterPy (an independent implementation) on random problems, to 1e-9."""

import numpy as np
import pytest
from filterpy import kalman as filterpy

from hera.estimation import (
    ExtendedKalmanFilter,
    KalmanFilter,
    Observations,
    UnscentedKalmanFilter,
)


def _spd(rng, n, scale=1.0):
    A = rng.normal(size=(n, n))
    return scale * (A @ A.T + n * np.eye(n))


@pytest.mark.parametrize("n,m", [(2, 1), (3, 2), (4, 3), (6, 5), (9, 2)])
@pytest.mark.parametrize("joseph", [True, False])
def test_kf_matches_filterpy(n, m, joseph):
    rng = np.random.default_rng(10 * n + m)
    F = np.eye(n) + 0.1 * rng.normal(size=(n, n))
    Q, P0 = _spd(rng, n, 0.01), _spd(rng, n)
    B = rng.normal(size=(n, 2))
    H = rng.normal(size=(m, n))
    R = _spd(rng, m, 0.1)
    x0 = rng.normal(size=n)
    ref = filterpy.KalmanFilter(dim_x=n, dim_z=m, dim_u=2)
    ref.x, ref.P, ref.F, ref.Q, ref.H, ref.R, ref.B = x0.copy(), P0.copy(), F, Q, H, R, B
    kf = KalmanFilter(x0, P0, F=F, Q=Q, B=B, joseph=joseph)
    for _ in range(30):
        u = rng.normal(size=2)
        z = rng.normal(size=m)
        ref.predict(u=u)
        ref.update(z)
        kf.predict(0.1, u)
        kf.update(Observations().add("z", z, H=H, R=R))
        np.testing.assert_allclose(kf.x, ref.x, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(kf.P, ref.P, rtol=1e-9, atol=1e-9)


def _nonlinear(n, m, rng):
    A = np.eye(n) + 0.05 * rng.normal(size=(n, n))
    C = rng.normal(size=(m, n))

    def f(x, dt, u=None):
        return A @ x + dt * np.sin(x)

    def fj(x, dt, u=None):
        return A + np.diag(dt * np.cos(x))

    def h(x):
        return np.sqrt(1.0 + (C @ x) ** 2)

    def hj(x):
        cx = C @ x
        return (cx / np.sqrt(1.0 + cx**2))[:, None] * C

    return f, fj, h, hj


@pytest.mark.parametrize("n,m", [(2, 1), (4, 2), (5, 3), (9, 3), (4, 5)])
@pytest.mark.parametrize("analytic", [True, False])
def test_ekf_matches_filterpy(n, m, analytic):
    rng = np.random.default_rng(100 + 10 * n + m)
    f, fj, h, hj = _nonlinear(n, m, rng)
    Q, P0, R = _spd(rng, n, 0.01), _spd(rng, n), _spd(rng, m, 0.2)
    x0 = rng.normal(size=n)
    dt = 0.05

    class Ref(filterpy.ExtendedKalmanFilter):
        def predict_x(self, u=0):
            self.x = f(self.x, dt)

    ref = Ref(dim_x=n, dim_z=m)
    ref.x, ref.P, ref.Q, ref.R = x0.copy(), P0.copy(), Q, R
    ekf = ExtendedKalmanFilter(x0, P0, f=f, F=fj if analytic else None, Q=Q)
    tol = 1e-9 if analytic else 1e-6  # central differences are accurate to ~1e-10 here
    for _ in range(25):
        z = rng.normal(size=m) + 1.5
        ref.F = fj(ref.x, dt)
        ref.predict()
        ref.update(z, hj, h)
        ekf.predict(dt)
        ekf.update(Observations().add("z", z, h=h, jacobian=hj if analytic else None, R=R))
        np.testing.assert_allclose(ekf.x, ref.x, rtol=tol, atol=tol)
        np.testing.assert_allclose(ekf.P, ref.P, rtol=tol, atol=tol)


@pytest.mark.parametrize("n,m", [(2, 1), (3, 2), (4, 3), (9, 2), (5, 6)])
@pytest.mark.parametrize("alpha,beta,kappa", [(0.5, 2.0, 0.0), (1.0, 2.0, 1.0), (0.3, 1.0, 3.0)])
def test_ukf_matches_filterpy(n, m, alpha, beta, kappa):
    rng = np.random.default_rng(1000 + 10 * n + m)
    f, _, h, _ = _nonlinear(n, m, rng)
    Q, P0, R = _spd(rng, n, 0.01), _spd(rng, n), _spd(rng, m, 0.2)
    x0 = rng.normal(size=n)
    dt = 0.05
    pts = filterpy.MerweScaledSigmaPoints(n, alpha=alpha, beta=beta, kappa=kappa)
    ref = filterpy.UnscentedKalmanFilter(dim_x=n, dim_z=m, dt=dt, hx=h, fx=f, points=pts)
    ref.x, ref.P, ref.Q, ref.R = x0.copy(), P0.copy(), Q, R
    ukf = UnscentedKalmanFilter(x0, P0, f=f, Q=Q, alpha=alpha, beta=beta, kappa=kappa)
    for _ in range(20):
        z = rng.normal(size=m) + 1.5
        ref.predict()
        ref.update(z)
        ukf.predict(dt)
        ukf.update(Observations().add("z", z, h=h, R=R))
        np.testing.assert_allclose(ukf.x, ref.x, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(ukf.P, ref.P, rtol=1e-9, atol=1e-9)
