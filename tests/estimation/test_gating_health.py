"""Chi-square quantiles, innovation gating, health monitoring."""

import numpy as np
import pytest
from scipy import stats as scipy_stats

from hera.estimation import (
    HealthMonitor,
    KalmanFilter,
    Observations,
    UnscentedKalmanFilter,
    chi2_cdf,
    chi2_ppf,
    gate_threshold,
)


@pytest.mark.parametrize("dof", list(range(1, 13)) + [20, 50, 100])
def test_chi2_ppf_matches_scipy(dof):
    for p in [1e-8, 1e-3, 0.05, 0.3, 0.5, 0.9, 0.95, 0.99, 0.999, 0.9999, 1 - 1e-9]:
        assert chi2_ppf(p, dof) == pytest.approx(scipy_stats.chi2.ppf(p, dof), rel=1e-6)
        x = scipy_stats.chi2.ppf(p, dof)
        assert chi2_cdf(x, dof) == pytest.approx(p, rel=1e-6)


def test_chi2_ppf_rejects_bad_arguments():
    for p in (0.0, 1.0, -0.1, 1.5):
        with pytest.raises(ValueError):
            chi2_ppf(p, 2)
    with pytest.raises(ValueError):
        chi2_ppf(0.5, 0)


def _tracker():
    F = np.array([[1.0, 0.1], [0.0, 1.0]])
    return KalmanFilter([0.0, 1.0], np.eye(2) * 0.01, F=F, Q=1e-4 * np.eye(2))


@pytest.mark.parametrize("kind", ["kf", "ukf"])
def test_outlier_gated_normal_data_passes(kind):
    rng = np.random.default_rng(42)
    if kind == "kf":
        filt = _tracker()
    else:
        F = np.array([[1.0, 0.1], [0.0, 1.0]])
        filt = UnscentedKalmanFilter(
            [0.0, 1.0], np.eye(2) * 0.01, f=lambda x, dt, u: F @ x, Q=1e-4 * np.eye(2)
        )
    truth = np.array([0.0, 1.0])
    rejected_normal = 0
    for k in range(200):
        truth = np.array([truth[0] + 0.1 * truth[1], truth[1]])
        filt.predict(0.1)
        z = truth[0] + rng.normal(scale=0.1)
        if k == 150:
            x_before = filt.x.copy()
            obs = Observations().add("pos", z + 5.0, H=[[1.0, 0.0]], R=0.01)
            obs.add("vel", truth[1] + rng.normal(scale=0.1), H=[[0.0, 1.0]], R=0.01)
            res = filt.update(obs, gate=0.999)
            assert res.rejected == ["pos"] and res.accepted == ["vel"]
            assert res.nis["pos"] > gate_threshold(0.999, 1)
            assert abs(filt.x[0] - x_before[0]) < 0.05  # the outlier did not pull x
            continue
        res = filt.update(Observations().add("pos", z, H=[[1.0, 0.0]], R=0.01), gate=0.999999)
        rejected_normal += len(res.rejected)
    assert rejected_normal == 0


def test_gate_uses_block_dimension():
    """A NIS of 10 passes a 3-row block (chi2_3 at 0.99 = 11.34) but fails a 1-row block
    (chi2_1 at 0.99 = 6.63)."""
    kf = KalmanFilter(np.zeros(3), np.eye(3), F=np.eye(3), Q=np.zeros((3, 3)))
    # S = P + R = 2 I, so NIS = |y|^2 / 2.
    y3 = np.full(3, np.sqrt(20.0 / 3.0))
    res3 = kf.update(Observations().add("three", y3, H=np.eye(3), R=1.0), gate=0.99)
    assert res3.accepted == ["three"]
    assert res3.nis["three"] == pytest.approx(10.0)
    assert res3.outcomes[0].threshold == pytest.approx(scipy_stats.chi2.ppf(0.99, 3))
    kf.reset(np.zeros(3), np.eye(3))
    res1 = kf.update(Observations().add("one", [np.sqrt(20.0)], H=[[1, 0, 0]], R=1.0), gate=0.99)
    assert res1.rejected == ["one"]
    assert res1.nis["one"] == pytest.approx(10.0)
    np.testing.assert_array_equal(kf.x, np.zeros(3))


def test_health_monitor_nis_trace_and_reset():
    kf = KalmanFilter([0.0], [[1.0]], F=[[1.0]], Q=[[1.0]])
    resets = []
    mon = HealthMonitor(window=3, trace_limit=50.0, on_reset=lambda f: resets.append(f))
    for z in [0.0, 1.0, -1.0, 2.0, 0.5]:
        kf.predict(1.0)
        mon.record(kf.update(Observations().add("z", z, H=[[1.0]], R=1.0)))
        assert not mon.check(kf)
    st = mon.stats["z"]
    assert st.count == 5 and len(st.recent) == 3 and st.dim == 1
    assert st.mean == pytest.approx(sum(mon.stats["z"].recent) / 3, rel=10) and st.mean > 0
    for _ in range(60):  # open loop: trace(P) grows by 1 per step
        kf.predict(1.0)
        if mon.check(kf):
            break
    assert resets == [kf] and mon.resets == 1
    mon2 = HealthMonitor(trace_limit=10.0, reset_state=([3.0], [[2.0]]))
    assert mon2.check(kf)
    np.testing.assert_array_equal(kf.x, [3.0])
    np.testing.assert_array_equal(kf.P, [[2.0]])
    assert mon.summary()["z"]["count"] == 5
