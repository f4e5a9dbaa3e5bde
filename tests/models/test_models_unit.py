"""Unit tests of the train models, bilateration, recordings and the fusion measure."""

from __future__ import annotations

import math
import subprocess
import sys
import time

import numpy as np
import pytest

from hera.args import ArgsStore
from hera.estimation import numerical_jacobian
from hera.fusion import time_order
from hera.keys import Keys
from hera.measure import MeasureContext, MeasureSpec
from hera.models.train.bilateration import Bilateration, intersect
from hera.models.train.measures import TrackGyro
from hera.models.train.tracker import LADDER, TrainTracker
from hera.recordings import RecordingError, read_recordings, recorded_time, split_stem
from hera.store import Sample, Store
from hera.wire import Message


def sample(name, node, seq, t, *values):
    return Sample(name, node, seq, t, 0.0, 0.0, tuple(float(v) for v in values))


def test_intersect_finds_both_points_and_refuses_disjoint_circles():
    a, b = intersect((0.0, 0.0), 5.0, (8.0, 0.0), 5.0)
    assert sorted([a, b]) == sorted([(4.0, 3.0), (4.0, -3.0)])
    assert intersect((0.0, 0.0), 1.0, (5.0, 0.0), 1.0) is None
    assert intersect((0.0, 0.0), 1.0, (0.1, 0.0), 5.0) is None  # one inside the other


def test_bilateration_keeps_the_upper_solution_of_fresh_readings():
    m = Bilateration(max_age=1.0)
    p = (0.2, 0.9)  # a target above two sonars on y = -1
    r1, r2 = math.dist(p, (-0.5, -1.0)), math.dist(p, (0.5, -1.0))
    assert not m.process(sample("sonar", "s1", 1, 10.0, r1, -0.5, -1.0))
    assert m.process(sample("sonar", "s2", 1, 10.05, r2, 0.5, -1.0))
    t, (x, y, span) = m.estimate()
    assert t == 10.05 and x == pytest.approx(p[0]) and y == pytest.approx(p[1])
    assert span == pytest.approx(0.05)  # the older reading's age: the fix is of ~25 ms earlier
    # a reading older than max_age is not paired
    assert not Bilateration(max_age=0.01).process(sample("sonar", "s2", 1, 10.05, r2, 0.5, -1.0))
    with pytest.raises(ValueError, match="max_age"):
        Bilateration(max_age=0)


def test_bilateration_rejects_a_solution_outside_either_beam():
    beams = {"s1": [0.0, 1.0], "s2": [0.0, 1.0]}  # both pointing up, 20 degree half-angle
    inside, outside = (0.1, 0.2), (1.2, 0.3)  # 7 and 27 degrees off the axis of s2
    for p, kept in ((inside, True), (outside, False)):
        m = Bilateration(beams=beams)
        r1, r2 = math.dist(p, (-0.3, -1.5)), math.dist(p, (0.3, -1.5))
        m.process(sample("sonar", "s1", 1, 10.0, r1, -0.3, -1.5))
        assert m.process(sample("sonar", "s2", 1, 10.1, r2, 0.3, -1.5)) is kept
        assert m.outside == (0 if kept else 1)
        assert (m.estimate() is not None) is kept
    with pytest.raises(ValueError, match="s1"):
        Bilateration(beams={"s1": [0.0, 0.0]})


@pytest.mark.parametrize("rung", ["e6", "e8"])
def test_process_jacobian_matches_a_numerical_one(rung):
    m = TrainTracker(rung=rung)
    x = np.array([0.3, -0.4, 0.7, 0.84, 0.61, 0.01][: m.n])  # e8: + the gyro scale state
    num = numerical_jacobian(lambda s: m._f(s, 0.05), x)
    assert np.allclose(m._F(x, 0.05), num, atol=1e-6)


def test_e4_keeps_the_sign_of_omega0_since_r_w2_cannot_tell():
    m = TrainTracker(rung="e4", radius=0.6, omega0=0.5)
    m.ekf.reset(np.array([-0.8]), np.array([[0.5]]))  # as if noise had pushed it through 0
    m.process(sample("nav", "n", 1, 1.0, 0.6 * 0.84**2, 0.84))
    assert m.estimate()[1][0] > 0 and m.direction_fixes == 1


def test_a_wrong_way_omega_is_mirrored_not_stuck_at_zero():
    m = TrainTracker(rung="e5")
    P = np.diag([1.0, 1.0, 1.0, 0.25]) + 0.1
    m.ekf.reset(np.array([0.0, 0.6, 1.5, -0.3]), P)
    m._keep_direction()
    assert list(m.ekf.x) == [0.0, 0.6, 1.5, 0.3] and m.direction_fixes == 1
    m._keep_direction()  # a right-way state is left alone
    assert m.ekf.x[3] == 0.3 and m.direction_fixes == 1
    # with only the accelerometer, w keeps converging: at w = 0, d(r w^2)/dw = 0 would not
    for k in range(200):
        m.process(sample("nav", "n", k, 1.0 + 0.01 * k, 0.6 * 0.84**2, 0.84))
    assert m.estimate()[1][3] == pytest.approx(0.84, rel=0.02)


def test_sonar_readings_near_the_beam_edge_are_skipped():
    m = TrainTracker(
        rung="e7",
        target_length=0.5,
        target_radius=0.05,
        beams={"s1": [0.0, 1.0]},
        half_angle_deg=20,
        beam_margin_deg=4,
    )
    ahead = np.array([0.0, 0.0, 0.0, 0.84])
    aside = np.array([1.0, -1.0, 0.0, 0.84])  # 45 deg off the beam axis of a sonar at (0,-1.5)
    assert m._in_beam("s1", ahead, 0.0, -1.5)
    assert not m._in_beam("s1", aside, 0.0, -1.5)
    assert m._in_beam("unknown-sonar", aside, 0.0, -1.5)  # no direction known: kept


def test_capsule_range_is_shorter_than_the_point_model_seen_end_on():
    point = TrainTracker(rung="e6")
    capsule = TrainTracker(rung="e6", target_length=0.5, target_radius=0.05)
    x = np.array([0.6, 0.0, 0.0, 0.84])  # at theta 0 the train runs along +y
    # a sonar straight ahead on the track's tangent sees the train's nose
    assert point._range(x, 0.6, 1.0) == pytest.approx(1.0)
    assert capsule._range(x, 0.6, 1.0) == pytest.approx(1.0 - 0.25 - 0.05)


def test_samples_older_than_the_filter_by_max_lag_are_dropped_and_counted():
    m = TrainTracker(rung="e7", max_lag=0.2)
    assert m.process(sample("nav", "n", 1, 10.0, 0.42, 0.84))
    assert m.process(sample("nav", "n", 2, 9.9, 0.42, 0.84))  # late, within max_lag
    assert not m.process(sample("nav", "n", 3, 9.5, 0.42, 0.84))
    assert (m.out_of_order, m.late) == (1, 1)


def test_a_late_bilateration_fix_is_taken_as_of_its_own_time():
    """A fix fused after the filter has moved on (it came late: the second reading's ping,
    then bilateration's own reordering) still describes the train at span / 2 before its
    own time, not before the filter's: theta is not pulled back by the lateness."""
    m = TrainTracker(rung="e5", branches=0, var_bilat=1e-3, radius=0.6)
    assert m.process(sample("nav", "n", 1, 10.0, 0.42, 0.84))
    th0, w = 1.0, 0.84
    m.ekf.x = np.array([0.6 * math.cos(th0), 0.6 * math.sin(th0), th0, w])
    m.ekf.P = np.diag([1e-2, 1e-2, 0.05, 1e-6])
    t_fix, span = 9.85, 0.1  # 0.15 s late; the train was there at 9.8 s
    th = th0 - w * (10.0 - (t_fix - span / 2))
    assert m.process(
        sample("bilateration", "n", 1, t_fix, 0.6 * math.cos(th), 0.6 * math.sin(th), span)
    )
    assert m.out_of_order == 1 and m.t == 10.0
    assert abs(m.ekf.x[2] - th0) < 0.005, m.ekf.x[2]  # as of 10 - span / 2: 0.12 rad back


def test_unknown_rung_and_bad_variances_are_refused():
    with pytest.raises(ValueError, match="unknown rung 'e42'"):
        TrainTracker(rung="e42")
    with pytest.raises(ValueError, match="var_sonar must be > 0"):
        TrainTracker(var_sonar=0)
    assert set(LADDER) == {"e4", "e5", "e6", "e7", "e8", "e9"}


def test_recordings_parse_names_with_underscores_and_report_bad_rows(tmp_path):
    (tmp_path / "track_gyro_nav_1.csv").write_text("1,1000.0,0.1,0.2,0.3,0.84\n")
    assert split_stem("track_gyro_nav_1", ["track_gyro"]) == ("track_gyro", "nav_1")
    got = read_recordings(tmp_path, ["track_gyro"], known=["track_gyro"])
    assert [(s.name, s.node, s.seq, s.t) for s in got] == [("track_gyro", "nav_1", 1, 1.0)]
    (tmp_path / "sonar_s1.csv").write_text("1,1000.0,1.2,0,0\n2,abc,1,2,3\n")
    with pytest.raises(RecordingError, match=r"sonar_s1.csv:2: expected seq,timestamp_ms"):
        read_recordings(tmp_path, ["sonar"])
    with pytest.raises(RecordingError, match="no <name>_<node>.csv"):
        read_recordings(tmp_path / "missing")


def test_time_order_is_total_and_deterministic():
    a = [sample("b", "n2", 1, 1.0), sample("a", "n1", 2, 1.0), sample("a", "n1", 1, 0.5)]
    assert [(s.name, s.seq) for s in time_order(a)] == [("a", 1), ("a", 2), ("b", 1)]


def test_fusion_measure_in_arrival_mode_fuses_a_late_sample_in_time_order():
    store = Store()
    ctx = MeasureContext(
        node="c",
        cluster="t",
        spec=MeasureSpec(name="track_gyro", period=0.01),
        store=store,
        args=ArgsStore("c"),
        session=None,
        keys=Keys("t"),
    )
    m = TrackGyro()
    m.init({"mode": "arrival", "reorder_s": 0.05}, ctx)
    seen = []
    real = m.model.process
    m.model.process = lambda s: seen.append(s.t) or real(s)
    t0 = int(time.time()) + 0.1234567  # a time a recording rounds (to the microsecond)
    assert recorded_time(t0) != t0
    store.offer("nav", "n", Message(1, t0 + 0.02, (0.42, 0.84)))
    store.offer("sonar", "s", Message(1, t0, (1.2, 0.3, -1.5)))  # stamped earlier, late
    deadline = time.monotonic() + 5
    while len(seen) < 2 and time.monotonic() < deadline:
        m.measure()
    # in time order, at the times a recording keeps (to the microsecond), as a replay gives
    assert seen == [recorded_time(t0), recorded_time(t0 + 0.02)]
    assert m.ctx.counters["fused"] == 2
    m.close()


SONARS = ((-0.3, -1.5), (0.3, -1.5))


def circle_samples(seconds, theta0=-1.0, omega=0.84, radius=0.6, gyro_scale=1.0, t0=100.0):
    """Noise-free samples of a point target on a circle about (0, 0): nav at 100 Hz (the gyro
    scaled by ``gyro_scale``), each sonar at 5 Hz (point ranges)."""
    out = []
    for k in range(int(seconds * 100)):
        t = t0 + k * 0.01
        out.append(sample("nav", "n", k, t, radius * omega**2, gyro_scale * omega))
        if k % 10 == 0:
            th = theta0 + omega * (t - t0)
            px, py = SONARS[(k // 10) % 2]
            rng = math.hypot(radius * math.cos(th) - px, radius * math.sin(th) - py)
            out.append(sample("sonar", f"s{(k // 10) % 2}", k, t, rng, px, py))
    return out


def test_estimate_keeps_the_rung_columns_with_the_hidden_gyro_scale_state():
    for rung in ("e7", "e8", "e9"):
        m = TrainTracker(rung=rung)
        hidden = 2 if rung == "e9" else 1  # e9: + the magnetometer's heading offset
        assert m.k_i is not None and m.n == len(m.columns) + hidden
        m.process(sample("nav", "n", 1, 1.0, 0.42, 0.84))
        assert len(m.estimate()[1]) == len(m.columns)
        off = TrainTracker(rung=rung, gyro_scale_var0=None, mag_offset_var0=None)
        assert off.k_i is None and off.b_i is None and off.n == len(off.columns)
    assert TrainTracker(rung="e6").k_i is None  # no gyro, no scale to learn
    with pytest.raises(ValueError):
        TrainTracker(rung="e7", gyro_scale_var0=0.0)


def test_gyro_scale_state_removes_the_gyros_scale_error_from_omega():
    samples = circle_samples(30.0, gyro_scale=1.02)  # a gyro reading 2 % high
    with_k, without = TrainTracker(rung="e7"), TrainTracker(rung="e7", gyro_scale_var0=None)
    for s in samples:
        with_k.process(s)
        without.process(s)
    assert with_k.locked and with_k.unlocks == 0
    w = with_k.estimate()[1][3]
    assert abs(w / 0.84 - 1) < 0.003  # the sonars' theta progression tells w from the scale
    assert with_k.ekf.x[with_k.k_i] == pytest.approx(0.02, abs=0.003)
    assert without.estimate()[1][3] / 0.84 - 1 > 0.005  # without it, most of the bias stays


def test_sonar_variance_switches_to_tracking_only_on_consistent_innovations():
    # the lock test alone (branches=0: no branch grid seeds or checks the EKF)
    m = TrainTracker(rung="e7", var_sonar=0.02, var_sonar_track=1e-3, lock_count=5, branches=0)
    assert not m.locked and m.sonar_var() == 0.02
    for s in circle_samples(1.0):
        m.process(s)
    assert m.locked and m.sonar_var() == 1e-3
    # a filter confidently on a wrong branch: small P, innovations of tens of cm: no lock
    wrong = TrainTracker(rung="e7", var_sonar=0.02, var_sonar_track=1e-3, lock_count=5, branches=0)
    x = np.array([0.6 * math.cos(0.2), 0.6 * math.sin(0.2), 0.2, 0.84, 0.0])
    wrong.ekf.reset(x, np.diag([1e-4, 1e-4, 1e-3, 1e-4, 1e-4]))
    wrong.t = 100.0
    for s in circle_samples(1.0):
        wrong.process(s)
    assert not wrong.locked and wrong.sonar_var() == 0.02
    # var_sonar_track=None: the original single variance, never locked
    same = TrainTracker(rung="e7", var_sonar_track=None, branches=0)
    for s in circle_samples(1.0):
        same.process(s)
    assert not same.locked and same.sonar_var() == same.var["sonar"]


def test_a_locked_filter_unlocks_after_successive_gated_out_sonar_readings():
    m = TrainTracker(rung="e7", unlock_count=3)
    samples = circle_samples(2.0)
    for s in samples:
        m.process(s)
    assert m.locked
    p_theta, t = m.ekf.P[2, 2], samples[-1].t
    for i in range(3):  # 1 m too far: gated out every time
        px, py = SONARS[i % 2]
        m.process(sample("sonar", "s0", 900 + i, t + 0.01 * (i + 1), 3.0, px, py))
    assert not m.locked and m.unlocks == 1 and m.rejected >= 3
    assert m.ekf.P[2, 2] > p_theta + 0.1  # theta may be pulled back by the sonars


def test_replay_cli_runs_a_model_over_original_hera_csvs(tmp_path):
    """Recordings in the original layout (no header, milliseconds from an arbitrary origin,
    here 100 s after boot): ``hera replay --models`` runs the model and writes its output in
    the same layout."""
    rec = tmp_path / "rec"
    (rec / "measures").mkdir(parents=True)
    files: dict[str, list[str]] = {}
    for s in circle_samples(20.0):
        cells = [str(s.seq), f"{s.t * 1000:.3f}", *(repr(v) for v in s.values)]
        files.setdefault(f"{s.name}_{s.node}", []).append(",".join(cells))
    for stem, rows in files.items():
        (rec / "measures" / f"{stem}.csv").write_text("\n".join(rows) + "\n")
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "hera", "replay", str(rec), "--out", str(out)]
    proc = subprocess.run([*cmd, "--models", "track_gyro"], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    rows = (out / "measures" / "track_gyro_replay.csv").read_text().splitlines()
    assert len(rows) > 2000  # one estimate per fused sample (nav at 100 Hz, sonars at 5 Hz)
    seq, t_ms, x, y, theta, omega = (float(c) for c in rows[-1].split(","))
    assert seq == len(rows) and 100_000 <= t_ms <= 120_000  # the recordings' own origin
    assert omega == pytest.approx(0.84, rel=0.01)
    assert math.hypot(x, y) == pytest.approx(0.6, abs=0.02)
    bad = subprocess.run([*cmd, "--models", "no_such_model"], capture_output=True, text=True)
    assert bad.returncode != 0 and "no_such_model" in bad.stderr
