"""Unit tests of the AHRS: its arithmetic against numerical derivatives, the numba and numpy
paths against each other, the reference frames, the errors it is scored by, the thesis's
filter and the fusion models' bookkeeping."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hera.estimation import active_backend, set_backend
from hera.models.ahrs import kernels as npk
from hera.models.ahrs.frames import Reference, triad, triad_quat, world_reference
from hera.models.ahrs.mekf import Mekf, MekfSettings
from hera.models.ahrs.model import AhrsModel, ThesisAhrsModel
from hera.models.ahrs.scoring import (
    attitude_error_deg,
    heading_error_deg,
    tilt_error_deg,
    yaw_pitch_roll_deg,
)
from hera.models.ahrs.thesis import ThesisAhrs
from hera.nodes.streams import nav3_stream
from hera.store import Sample

UP = np.array((0.0, 0.0, 1.0))
FIELD = np.array((0.0, 0.205, -0.44))  # gauss: north along +y, 65 deg below


def _rand_quat(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


def _perturb(q: np.ndarray, d: np.ndarray) -> np.ndarray:
    """q * Exp(d): the error-state convention (a small rotation in the body frame)."""
    return npk.quat_mul(q, npk.rotvec_quat(d))


@pytest.fixture(autouse=True)
def _restore_backend():
    was = active_backend()
    yield
    set_backend(was)


def test_vector_jacobian_matches_numerical_derivative():
    """H = s [v x] of the vector observation is the derivative of s R(q Exp(d))^T r."""
    rng = np.random.default_rng(1)
    for _ in range(5):
        q = _rand_quat(rng)
        h = lambda d, q=q: 9.81 * npk.quat_matrix(_perturb(q, d)).T @ UP  # noqa: E731
        v = npk.quat_matrix(q).T @ UP
        H = 9.81 * npk.skew(v)
        eps = 1e-6
        num = np.column_stack([(h(eps * e) - h(-eps * e)) / (2 * eps) for e in np.eye(3)])
        assert np.allclose(H, num, atol=1e-6)


def test_heading_jacobian_matches_numerical_derivative():
    """alpha's derivative is -(up + tan(dip) north)^T R(q): a tilt about north leaks into
    the measured heading through the dip angle."""
    rng = np.random.default_rng(2)
    north = np.array((0.0, 1.0, 0.0))
    for _ in range(5):
        q_true = _rand_quat(rng)
        m = npk.quat_matrix(q_true).T @ FIELD  # what the magnetometer reads

        def alpha(d, q_true=q_true, m=m):
            R = npk.quat_matrix(_perturb(q_true, d))
            mn = R @ m
            mh = mn - (mn @ UP) * UP
            return math.atan2(UP @ np.cross(north, mh), north @ mh)

        R = npk.quat_matrix(q_true)
        mn = R @ m
        tan_dip = -(mn @ UP) / np.linalg.norm(mn - (mn @ UP) * UP)
        H = -(R.T @ UP + tan_dip * (R.T @ north))
        eps = 1e-6
        num = np.array([(alpha(eps * e) - alpha(-eps * e)) / (2 * eps) for e in np.eye(3)])
        # the filter's estimate is q, the truth q Exp(d): alpha(estimate) = -H d
        assert np.allclose(-num, H, atol=1e-6)


def test_predict_integrates_a_constant_rate_exactly():
    q, g, P = np.array((1.0, 0.0, 0.0, 0.0)), np.zeros(6), np.eye(6) * 1e-6
    w = np.array((0.3, -1.2, 2.0))
    for _ in range(100):
        npk.predict(q, g, P, *w, 0.01, np.zeros(3), 0.0, 0.0)
    want = npk.rotvec_quat(w * 1.0)
    assert attitude_error_deg(q, want)[0] < 1e-9


def test_predict_divides_the_rate_by_the_scale_and_its_jacobian_matches():
    """With scale errors k the body turns at (w_m - b) / (1 + k); Phi's blocks for b and k
    are the derivatives of the turned angle (body frame) over one step, numerically (to
    first order in the step's angle, as Sola 2017 eq. 269 takes them: a short step)."""
    g = np.array((0.01, -0.02, 0.03, 0.2, -0.1, 0.3))  # large scale errors: 1/(1+k) shows
    wm = np.array((0.3, -1.2, 2.0))
    dt = 0.001
    q0 = np.array((1.0, 0.0, 0.0, 0.0))

    def step(g):
        q, P = q0.copy(), np.zeros((9, 9))
        npk.predict(q, g, P, *wm, dt, np.zeros(3), 0.0, 0.0)
        return q

    q = step(g)
    want = npk.rotvec_quat((wm - g[:3]) / (1 + g[3:]) * dt)
    assert attitude_error_deg(q, want)[0] < 1e-9
    P = np.eye(9)
    npk.predict(q0.copy(), g, P, *wm, dt, np.zeros(3), 0.0, 0.0)
    # P = Phi Phi^T; Phi's attitude row block against b and k, from the turned angle
    eps = 1e-7
    num = np.zeros((3, 6))
    for j in range(6):
        d = np.zeros(6)
        d[j] = eps
        # truth g + d: the estimate's error is the rotation from it to the truth's
        dq = npk.quat_mul(np.array((q[0], -q[1], -q[2], -q[3])), step(g + d))
        num[:, j] = 2.0 * dq[1:] / eps
    Rd = npk.quat_matrix(npk.rotvec_quat((wm - g[:3]) / (1 + g[3:]) * dt))
    tol = np.linalg.norm(wm) * dt * dt  # the step's angle, relative, times dt
    assert np.abs(P[:3, 3:] - num).max() < tol, (P[:3, 3:], num)
    assert np.abs(P[:3, :3] - (Rd.T @ Rd + num @ num.T)).max() < tol * dt


def test_triad_recovers_an_attitude_from_two_vectors():
    rng = np.random.default_rng(3)
    ref = world_reference(90.0)
    for _ in range(10):
        q = _rand_quat(rng)
        R = npk.quat_matrix(q)
        acc, mag = R.T @ UP * 9.81, R.T @ FIELD
        assert np.allclose(triad(acc, mag, ref), R, atol=1e-12)
        assert attitude_error_deg(triad_quat(acc, mag, ref), q)[0] < 1e-6
    assert triad((0, 0, 1), (0, 0, 2), ref) is None  # parallel: no attitude


def test_reference_of_keeps_only_the_horizontal_part_of_north():
    ref = Reference.of((0, 0, 2), FIELD)
    assert np.allclose(ref.up, UP) and np.allclose(ref.north, (0, 1, 0))
    with pytest.raises(ValueError, match="north"):
        Reference.of((0, 0, 1), (0, 0, -1))


def test_errors_split_into_heading_and_tilt():
    yaw = npk.rotvec_quat(np.radians((0.0, 0.0, 5.0)))
    pitch = npk.rotvec_quat(np.radians((0.0, 3.0, 0.0)))
    ident = np.array((1.0, 0.0, 0.0, 0.0))
    assert attitude_error_deg(yaw, ident)[0] == pytest.approx(5.0)
    assert tilt_error_deg(yaw, ident)[0] == pytest.approx(0.0, abs=1e-6)
    assert heading_error_deg(ident, yaw)[0] == pytest.approx(5.0)  # truth 5 deg ccw
    assert heading_error_deg(yaw, ident)[0] == pytest.approx(-5.0)
    assert tilt_error_deg(pitch, ident)[0] == pytest.approx(3.0)
    assert heading_error_deg(pitch, ident)[0] == pytest.approx(0.0, abs=1e-6)
    assert attitude_error_deg(-yaw, ident)[0] == pytest.approx(5.0)  # q and -q agree
    ypr = yaw_pitch_roll_deg(npk.quat_mul(yaw, pitch))[0]
    assert np.allclose(ypr, (5.0, 3.0, 0.0), atol=1e-9)


def _run(stream, settings=None, backend="numpy"):
    set_backend(backend)
    f = Mekf(world_reference(90.0), settings)
    out = []
    for s in stream.samples:
        v = s.values
        f.step(s.t, v[0:3], v[3:6], v[6:9])
        out.append(np.concatenate((f.q, f.g, f.P.ravel())))
    return np.array(out), f


@pytest.mark.parametrize("mode", ["heading", "vector"])
@pytest.mark.parametrize(
    ("scenario", "scale_std0"),
    [("shaking", 0.03), ("rotation_fast", 0.03), ("rotation_fast", 0.0)],
)
def test_numba_and_numpy_paths_agree(mode, scenario, scale_std0):
    """The compiled kernels and the numpy ones give the same filter, step after step, on a
    run with rejected samples in it (a shake or turns, and a magnetic disturbance), with the
    gyroscope's scale errors estimated (9 error states) or not (6)."""
    events = [
        (3.0, lambda b: b.faults.set("field", sensor="mag", value=[0.2, 0.0, 0.0])),
        (4.0, lambda b: b.faults.clear()),
    ]
    model = {"gyro_scale": [0.01, -0.01, 0.02]}
    stream = nav3_stream(
        {"scenario": scenario, "epoch": 0.0}, 6.0, seed=5, events=events, model=model
    )
    settings = MekfSettings(mag_mode=mode, reacquire_s=0.5, scale_std0=scale_std0)
    a, fa = _run(stream, settings, "numpy")
    b, fb = _run(stream, settings, "numba")
    assert fa.P.shape == fb.P.shape == ((9, 9) if scale_std0 else (6, 6))
    assert fa.counters == fb.counters
    assert fa.counters["mag_disturbed"] + fa.counters["mag_rejected"] > 20
    if scale_std0 and scenario == "rotation_fast":  # the scale states moved: a real check
        assert abs(fa.scale[2]) > 0.005, fa.scale
    assert np.abs(a - b).max() < 1e-12, np.abs(a - b).max()


def _heading_during(stream, settings, on, off):
    """Run the filter; (its largest |heading error| (deg) over [on, off), the filter as it
    was at ``on``)."""
    from hera.nodes.world import make_scenario, state_at

    sc = make_scenario({"scenario": "rotation_fast", "epoch": 0.0})
    f = Mekf(world_reference(90.0), settings)
    worst, at_on = 0.0, None
    for s in stream.samples:
        v = s.values
        if f.step(s.t, v[0:3], v[3:6], v[6:9]) and on <= s.t < off:
            if at_on is None:
                at_on = (f.scale.copy(), math.sqrt(f.P[8, 8]) if f.P.shape[0] > 6 else 0.0)
            err = heading_error_deg(f.q, state_at(sc, 0.0, s.t).orientation)[0]
            worst = max(worst, abs(err))
    return worst, at_on


@pytest.mark.parametrize("seed", [0, 1])
def test_the_gyroscope_scale_error_is_learnt_and_carries_the_heading_through_a_disturbance(
    seed,
):
    """A z gyroscope reading 2 % high (a MEMS gyroscope's usual 1-3 %), turned 360 deg every
    4 s: in the 15 s before a 10 s magnetic disturbance the filter learns the scale error from
    the turns, and while the magnetometer is refused it keeps the heading; without the scale
    states each turn adds 7 deg of heading error."""
    on, off = 18.0, 28.0
    events = [
        (on, lambda b: b.faults.set("field", sensor="mag", value=[0.1, 0.0, 0.0])),
        (off, lambda b: b.faults.clear()),
    ]
    stream = nav3_stream(
        {"scenario": "rotation_fast", "epoch": 0.0}, 30.0, seed=seed, start=3.0,
        model={"gyro_scale": [0.0, 0.0, 0.02]}, events=events,
    )  # fmt: skip
    worst, (k, k_sd) = _heading_during(stream, MekfSettings(), on, off)
    # the board's 5 deg mounting tilt leaves 0.02 cos^2(5 deg) = 1.985 % on the body's z
    assert abs(k[2] - 0.02) < 0.002, k
    assert np.all(np.abs(k[:2]) < 0.003), k  # never turned about x or y: left near 0
    assert k_sd < 0.01  # its standard deviation, 0.03 at the start, has shrunk
    assert worst < 2.0, worst
    without, _ = _heading_during(stream, MekfSettings(scale_std0=0.0), on, off)
    assert without > 10.0, without


def test_the_filter_refuses_bad_settings():
    with pytest.raises(ValueError, match="gyro_noise"):
        MekfSettings(gyro_noise=-1.0)
    with pytest.raises(ValueError, match="gyro_noise"):
        MekfSettings(gyro_noise=(1e-3, 1e-3))
    with pytest.raises(ValueError, match="acc_gate"):
        MekfSettings(acc_gate=1.5)
    with pytest.raises(ValueError, match="mag_mode"):
        MekfSettings(mag_mode="compass")
    with pytest.raises(ValueError, match="scale_std0"):
        MekfSettings(scale_std0=-0.01)
    with pytest.raises(ValueError, match="scale_walk"):
        MekfSettings(scale_walk=math.nan)
    with pytest.raises(ValueError, match="acc_block"):
        MekfSettings(acc_block=-1.0)
    with pytest.raises(ValueError, match="block_tau"):
        MekfSettings(block_tau=0.0)
    assert MekfSettings(gyro_noise=[1e-3, 2e-3, 3e-3]).gyro_noise == (1e-3, 2e-3, 3e-3)


def _feed_still_frame(acc_world, rate=100.0):
    """Both accelerometer paths fed ``acc_world`` (N, 3), m/s^2, at the identity attitude
    with P = 0 (so nothing moves the estimate): (the per-sample path's added covariance's
    trace, the block means' covariance ``D``, how many block means were compared, the mean
    share of the information given to the block means)."""
    q, g, P, out = np.array((1.0, 0.0, 0.0, 0.0)), np.zeros(6), np.zeros((6, 6)), np.zeros(5)
    par = np.zeros(npk.ACC_PARAMS)
    par[0:3], par[3], par[4], par[5] = UP, 9.81, 0.3**2, 100.0
    par[6], par[7], par[8] = 1.0, 2.0, 1.0
    stats, blk = np.zeros(npk.STATS), np.zeros(npk.BLOCK)
    dt, added, shares = 1.0 / rate, 0.0, []
    for z in acc_world:
        npk.vector_update(q, g, P, *z, par, stats, min(1.0, dt / 0.5), 1e9, out)
        added = out[3]
        shares.append(out[4])
        npk.block_update(q, g, P, *z, dt, par, blk, out[4], 1e9, out)
    return added, blk[17:26].reshape(3, 3), blk[26], float(np.mean(shares[500:]))


def test_block_means_see_through_a_shake_that_the_per_sample_path_counts_in_full():
    """A 1 g shake at 3 Hz (thesis ch. 7.1.3): the per-sample path, which counts the
    acceleration's power for its correlation time, adds hundreds of (m/s^2)^2; the block
    means' covariance, what is left of it at the filter's low frequencies, is 1000 times
    smaller, and the block means get nearly all the information. On white noise alone
    ``D`` is the noise of a Bartlett mean, 3 sigma^2 / n, and the per-sample path keeps
    nearly all of it (the filter as it was without block means)."""
    rng = np.random.default_rng(1)
    t = np.arange(6000) / 100.0
    noise = rng.normal(0.0, 0.3, (t.size, 3))
    still = noise + 9.81 * UP
    added, D, compared, share = _feed_still_frame(still)
    assert compared == 58  # one a second from the third block's end
    assert np.trace(D) == pytest.approx(3 * 0.3**2 / 100, rel=0.35)
    assert share < 0.1, share
    shake = still.copy()
    shake[:, 0] += 10.0 * np.sin(2 * np.pi * 3.0 * t)
    shake[:, 1] += 3.2 * np.sin(2 * np.pi * 2.31 * t)
    added, D, _, share = _feed_still_frame(shake)
    assert added > 300.0, added
    assert np.trace(D) < added / 1000.0, (np.trace(D), added)
    assert share > 0.95, share
    slow = still.copy()  # 0.27 m/s^2 at 1/6 Hz (target3d): the blocks see it as motion
    slow[:, 0] += 0.27 * np.cos(2 * np.pi * t / 6.0)
    _, D, _, _ = _feed_still_frame(slow)
    assert D[0, 0] > 5 * 0.3**2 / 100, D[0, 0]


def test_alignment_holds_the_estimate_back_then_starts_near_the_truth():
    stream = nav3_stream({"scenario": "still", "epoch": 0.0, "yaw": 0.5}, 3.0, seed=1)
    f = Mekf(world_reference(90.0))
    started_at = None
    for s in stream.samples:
        v = s.values
        used = f.step(s.t, v[0:3], v[3:6], v[6:9])
        if used and started_at is None:
            started_at = s.t - stream.samples[0].t
    assert 0.99 <= started_at <= 1.05
    truth = npk.rotvec_quat(np.array((0.0, 0.0, 0.5)))
    assert attitude_error_deg(f.q, truth)[0] < 0.5
    tilt_sd, head_sd = f.std_deg()
    assert 0 < tilt_sd < 0.5 and 0 < head_sd < 1.0


def test_a_sample_older_than_the_filter_is_skipped():
    stream = nav3_stream({"scenario": "still", "epoch": 0.0}, 1.5, seed=1)
    f = Mekf(world_reference(90.0))
    for s in stream.samples:
        f.step(s.t, s.values[0:3], s.values[3:6], s.values[6:9])
    q = f.q.copy()
    old = stream.samples[-5]
    assert not f.step(old.t, old.values[0:3], old.values[3:6], old.values[6:9])
    assert f.counters["skipped"] == 1 and np.array_equal(q, f.q)


def test_thesis_filter_aligns_the_sign_and_normalises():
    ref = world_reference(90.0)
    f = ThesisAhrs(ref)
    R = np.eye(3)
    acc, mag = R.T @ UP * 9.81, R.T @ FIELD
    assert f.step(0.0, acc, (0, 0, 0), mag)
    f.ekf.reset(-f.ekf.x, f.ekf.P)  # the other hemisphere: eq. 7.5 must flip it back
    assert f.step(0.01, acc, (0, 0, 0), mag)
    assert f.q[0] > 0.99 and np.linalg.norm(f.q) == pytest.approx(1.0)
    assert not f.step(0.005, acc, (0, 0, 0), mag)  # older than the filter
    assert not f.step(0.02, acc, (0, 0, 0), None)  # no magnetometer: no q_am
    assert f.skipped == 2


def _nav3(node, t, values):
    return Sample("nav3", node, 1, t, 0.0, 0.0, tuple(values))


def test_models_follow_one_board_and_count_the_others():
    stream = nav3_stream({"scenario": "still", "epoch": 0.0}, 1.5, seed=2)
    for model in (AhrsModel(), ThesisAhrsModel()):
        for s in stream.samples:
            model.process(s)
        assert model.board == "nav"
        est = model.estimate()
        assert est is not None and len(est[1]) == len(model.columns)
        assert not model.process(_nav3("other", est[0] + 1, stream.samples[-1].values))
        assert model.counters()["other"] == 1
        assert not model.process(Sample("nav3", "nav", 9, est[0] + 2, 0, 0, (1.0, 2.0)))
    pinned = AhrsModel(board="nav_2")
    assert not pinned.process(stream.samples[0]) and pinned.estimate() is None


def test_model_settings_are_checked_by_the_measure():
    from hera.models.ahrs.measures import Ahrs

    with pytest.raises(ValueError, match="gyro_noise"):
        Ahrs.make_model({"gyro_noise": 0})
    with pytest.raises(ValueError, match="unknown setting 'north'"):
        Ahrs.make_model({"north": 90})
    assert Ahrs.make_model({"north_deg": 0.0, "mag_mode": "vector"}).filter.s.mag_mode == "vector"
