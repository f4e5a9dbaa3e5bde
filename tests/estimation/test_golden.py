"""Golden vectors of the original unit tests (docs REFERENCE.md)."""

import numpy as np

from hera.estimation import ExtendedKalmanFilter, KalmanFilter, Observations

SONAR = [-0.0139570, 0.0177654, -0.0043154, -0.0032242, -0.0011087, 0.0068842, 0.0127815]
SONAR += [-0.0054593, 0.0172686]
ACC = [-0.067219, -0.187752, 0.039476, -0.629077, 0.294998, -0.018021, -0.089338, 0.316988]
ACC += [-0.110355]

X_EXPECTED = [-0.003818873411179362, -0.0030451417563099863, 0.010728608371567826]
P_EXPECTED = [
    [0.0011803595978981166, 0.002838977349786346, 0.003240423305540969],
    [0.0028389773497863456, 0.008065893282913787, 0.012971945407050236],
    [0.0032404233055409693, 0.012971945407050232, 0.036352205605987994],
]


def _linear_kf(method: str):
    dt = 0.1
    F = np.array([[1, dt, dt**2 / 2], [0, 1, dt], [0, 0, 1]])
    G = F[:, 2:3]
    kf = KalmanFilter(np.zeros(3), np.zeros((3, 3)), F=F, Q=0.01 * G @ G.T, joseph=False)
    H = np.array([[1.0, 0, 0], [0, 0, 1]])
    for s, a in zip(SONAR, ACC, strict=True):
        kf.predict(dt)
        kf.update(Observations().add("sonar+acc", [s, a], H=H, R=[0.01, 0.2]), method=method)
    return kf


def test_linear_kf_golden_joint():
    kf = _linear_kf("joint")
    np.testing.assert_allclose(kf.x, X_EXPECTED, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(kf.P, P_EXPECTED, rtol=1e-12, atol=1e-15)


def test_linear_kf_golden_sequential():
    kf = _linear_kf("sequential")
    np.testing.assert_allclose(kf.x, X_EXPECTED, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(kf.P, P_EXPECTED, rtol=1e-10, atol=1e-14)


def test_linear_kf_golden_separate_blocks():
    """Sonar and accelerometer as two blocks of one step give the same numbers."""
    dt = 0.1
    F = np.array([[1, dt, dt**2 / 2], [0, 1, dt], [0, 0, 1]])
    G = F[:, 2:3]
    kf = KalmanFilter(np.zeros(3), np.zeros((3, 3)), F=lambda _dt: F, Q=0.01 * G @ G.T)
    kf.joseph = False
    for s, a in zip(SONAR, ACC, strict=True):
        kf.predict(dt)
        obs = Observations().add("sonar", s, H=[1.0, 0, 0], R=0.01)
        obs.add("acc", a, H=[0, 0, 1.0], R=0.2)
        kf.update(obs)
    np.testing.assert_allclose(kf.x, X_EXPECTED, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(kf.P, P_EXPECTED, rtol=1e-12, atol=1e-15)


def _ekf(joseph: bool, jac: bool):
    zs = [1.3076, 1.8246, 1.7409, 1.5532, 1.7215, 1.6290, 1.2415, 2.0059, 1.7394]
    ekf = ExtendedKalmanFilter(
        [1.0],
        [[1.0]],
        f=lambda x, dt, u: x,
        F=(lambda x, dt, u: np.eye(1)) if jac else None,
        Q=np.zeros((1, 1)),
        joseph=joseph,
    )
    for z in zs:
        ekf.predict(0.1)
        h = lambda x: x**2  # noqa: E731
        ekf.update(
            Observations().add("z", z, h=h, jacobian=(lambda x: 2 * x) if jac else None, R=0.2)
        )
    return ekf


def test_ekf_golden():
    for joseph in (True, False):
        for jac in (True, False):
            ekf = _ekf(joseph, jac)
            assert round(float(ekf.x[0]), 4) == 1.2855
            assert round(float(ekf.P[0, 0]), 4) == 0.0036
