"""The simulated LSM6DSL, its ``balancing`` scenario, the gyro calibration with motion
detection, the ``lsm6dsl`` measure and its ``gyro_calibration`` verb (seed 003)."""

from __future__ import annotations

import math
import random
import statistics

import numpy as np
import pytest
from nodes_helpers import FakeClock, boards_of, make_ctx

from hera.application import VerbContext
from hera.args import ArgsStore
from hera.nodes import geometry as gm
from hera.nodes.driver import NoReading
from hera.nodes.lsm6dsl.app import gyro_calibration
from hera.nodes.lsm6dsl.calibration import DONE, MOVING, GyroCalibration
from hera.nodes.lsm6dsl.measures import CALIBRATED, CALIBRATING, Lsm6dsl
from hera.nodes.lsm6dsl.model import ImuModel
from hera.nodes.lsm6dsl.scenario import Balancing
from hera.nodes.lsm6dsl.sim import FIFO_SAMPLES, SimLsm6dsl, mean_rate
from hera.nodes.world import G, Motion, Scenario, make_scenario

ODR = 26.0


class Leaning(Scenario):
    """A body still, turned by ``theta`` rad about y."""

    def __init__(self, theta: float) -> None:
        self.m = Motion(position=(0.0, 0.0, 0.2), orientation=gm.axis_angle((0, 1, 0), theta))

    def motion(self, tau: float) -> Motion:
        return self.m


def imu(scenario, seed=1, start=100.0, **model):
    clock = FakeClock(start, 1.0 / ODR)
    return SimLsm6dsl("robot/imu", scenario, 0.0, ImuModel.from_args(model), seed, ODR, clock)


def test_still_it_reads_gravity_and_the_gyro_bias_with_the_data_sheets_noise():
    b = imu(Leaning(math.radians(10.0)), gyro_drift=0.0)
    rs = [b.read_imu() for _ in range(3000)]
    ax = [r.acc[0] for r in rs]
    # a right-handed chip leaning forward by theta reads x = -sin(theta) g
    assert statistics.mean(ax) == pytest.approx(
        -(1 + b.acc_scale[0]) * math.sin(math.radians(10)) + b.acc_bias[0], abs=2e-4
    )
    noise = 80e-6 * math.sqrt(ODR / 2)  # density x sqrt(bandwidth)
    assert statistics.stdev(r.acc[2] for r in rs) == pytest.approx(noise, rel=0.3)
    gy = [r.gyro[1] for r in rs]
    assert statistics.mean(gy) == pytest.approx(b.gyro_bias[1], abs=0.002)
    assert statistics.stdev(gy) == pytest.approx(0.004 * math.sqrt(ODR / 2), rel=0.3)


def test_the_gyro_sample_is_the_mean_rate_over_its_interval():
    sc = make_scenario({"scenario": "balancing", "first_push_s": 12.0})
    b = imu(sc, start=10.0, gyro_bias=[0, 0, 0], gyro_density=0.0, gyro_drift=0.0)
    b.gyro_scale = (0.0, 0.0, 0.0)
    sc.vibration_gyro = 0.0
    # integrate through a push (a kick at 12 s): the angle comes out right
    angle, t = sc.theta(10.0)[0], 10.0
    for _ in range(130):
        r = b.read_imu()
        angle += math.radians(r.gyro[1]) / ODR
        t = r.t
    assert angle == pytest.approx(sc.theta(t)[0], abs=math.radians(0.02))
    w = mean_rate(gm.axis_angle((0, 1, 0), 0.1), gm.axis_angle((0, 1, 0), 0.3), 10.0)
    assert w == pytest.approx((0.0, math.degrees(2.0), 0.0))


def test_a_ramp_drifts_the_gyro_bias_as_asked():
    model = ImuModel(gyro_ramp_dps_s=0.5 / 60, ramp_start_s=10.0, ramp_s=60.0)
    assert model.ramp(5.0) == 0.0
    assert model.ramp(40.0) == pytest.approx(0.25)
    assert model.ramp(100.0) == pytest.approx(0.5)
    b = imu(Leaning(0.0), gyro_ramp_dps_s=0.5 / 60, ramp_start_s=10.0, gyro_drift=0.0)
    assert b.bias(80.0)[1] - b.bias(5.0)[1] == pytest.approx(0.5)


def _chip(reads, seed=3, sleep=None):
    """A chip-clocked board read at ``reads`` (epoch s): every sample read, in order."""
    now = [0.0]
    b = SimLsm6dsl(
        "robot/imu",
        make_scenario({"scenario": "balancing"}),
        0.0,
        ImuModel(),
        seed,
        ODR,
        clock=lambda: now[0],
        stamps="chip",
        sleep=sleep,
    )
    got = []
    for t in reads:
        now[0] = t
        try:
            got.append(b.read_imu())
        except NoReading:
            continue
        while b.pending:
            got.append(b.read_imu())
    return b, got


def test_on_its_own_clock_the_chip_gives_every_sample_once_whatever_the_read_times():
    rnd = random.Random(5)
    steady = [20.0 + k / ODR for k in range(300)]
    jittery = [t + rnd.gauss(0.0, 0.004) for t in steady]
    late = [20.0 + k * 3 / ODR for k in range(100)]  # a node that reads every third period
    b, a = _chip(steady)
    _, j = _chip(jittery, sleep=lambda s: None)
    _, s3 = _chip(late)
    period = 1.0 / ODR
    assert np.allclose(np.diff([r.t for r in a]), period, atol=1e-9)
    assert (a[0].t - b.phase) * ODR == pytest.approx(round((a[0].t - b.phase) * ODR), abs=1e-6)
    n = min(len(a), len(j), len(s3)) - 3
    assert n > 250
    for x, y, z in zip(a[1:n], j[1:n], s3[1:n], strict=True):  # the same samples, read alike
        assert x == y == z
    assert _chip(steady, seed=4)[0].phase != b.phase  # the phase is the chip's (its seed)


def test_a_read_before_the_next_sample_waits_for_it_or_is_a_dropout():
    slept = []
    b, got = _chip([30.0], sleep=slept.append)
    nxt = got[-1].t + 1.0 / ODR
    b.clock = lambda: nxt - 0.01  # 10 ms early: within half a period, it waits
    assert b.read_imu().t == pytest.approx(nxt) and slept == [pytest.approx(0.01)]
    b.clock = lambda: nxt + 1.0 / ODR - 0.03  # 30 ms early: more than half a period
    with pytest.raises(NoReading, match="no new sample: the next is due in 30.0 ms"):
        b.read_imu()
    b.sleep = None  # without a way to wait, even a little early is a dropout
    b.clock = lambda: nxt + 1.0 / ODR - 0.001
    with pytest.raises(NoReading):
        b.read_imu()


def test_a_reader_too_late_for_the_fifo_loses_the_oldest_samples():
    b, got = _chip([10.0, 10.0 + 100 / ODR])
    assert len(got) == 1 + FIFO_SAMPLES and b.lost == 100 - FIFO_SAMPLES
    assert got[1].t == pytest.approx(got[0].t + (100 - FIFO_SAMPLES + 1) / ODR)
    assert b.describe()["fifo_lost"] == b.lost and b.describe()["stamps"] == "chip"
    with pytest.raises(ValueError, match="stamps must be one of"):
        SimLsm6dsl("x", Leaning(0.0), 0.0, ImuModel(), 1, stamps="late")


def test_bad_output_data_rates_and_models_are_refused():
    with pytest.raises(ValueError, match="output data rate must be one of"):
        SimLsm6dsl("x", Leaning(0.0), 0.0, ImuModel(), 1, odr_hz=25.0)
    with pytest.raises(ValueError, match="acc_bias must be \\[x, y, z\\]"):
        ImuModel.from_args({"acc_bias": [0.1]})
    problems = Lsm6dsl.check_args({"odr_hz": 25, "model": {"noise": 1}}, "spec: measure 'imu'")
    assert any("odr_hz must be one of" in p for p in problems), problems
    assert any("model: unknown key 'noise'" in p for p in problems), problems


def test_the_balancing_robots_accelerometer_feels_its_wheels():
    sc = Balancing()
    for tau in (2.0, 9.5, 14.0, 25.0):
        th, dth, ddth = sc.theta(tau)
        m = sc.motion(tau)
        f = gm.unrotate(m.orientation, (m.acceleration[0], 0.0, m.acceleration[2] + G))
        if sc.segment(tau) == "still":
            assert f[0] == pytest.approx(-G * math.sin(th), abs=1e-9)  # gravity only
        else:  # inverted pendulum on a cart: (sensor - L) theta'' along x
            assert f[0] == pytest.approx((sc.sensor - sc.pendulum) * ddth, abs=1e-9)
    assert {sc.segment(t * 0.1) for t in range(400)} == {"still", "rise", "sway", "push"}
    assert not sc.motors_on(1.0) and sc.motors_on(12.0)
    assert Balancing(parked=[[30, 40]]).segment(35.0) == "still"


def test_wheels_that_need_torque_show_a_share_of_the_tilt():
    k, r = 0.5, 0.04
    sc = make_scenario({"scenario": "balancing", "reaction_k": k, "wheel_radius_m": r})
    assert sc.theta(20.0) == Balancing().theta(20.0)  # the same robot, other wheels
    for tau in (25.0, 31.0, 47.5):
        th, _, ddth = sc.theta(tau)
        m = sc.motion(tau)
        f = gm.unrotate(m.orientation, (m.acceleration[0], 0.0, m.acceleration[2] + G))
        # a_w = (g sin th - (L + r) th'') / ((1 + k) cos th), so along the board's x:
        # -k / (1 + k) g sin th + (s - (L + r) / (1 + k)) th''
        want = -k / (1 + k) * G * math.sin(th) + (sc.sensor - (sc.pendulum + r) / (1 + k)) * ddth
        assert f[0] == pytest.approx(want, abs=1e-9)
        assert abs(f[0] - (sc.sensor - sc.pendulum) * ddth) > 1e-3  # not the default's
    with pytest.raises(ValueError, match="balancing reaction_k must be a number >= 0, got -0.1"):
        make_scenario({"scenario": "balancing", "reaction_k": -0.1})
    with pytest.raises(ValueError, match="world 'wheel_radius_m' must be a number"):
        make_scenario({"scenario": "balancing", "wheel_radius_m": "big"})


def test_pushes_vary_with_the_seed_and_bad_worlds_are_refused():
    a, b = (
        make_scenario({"scenario": "balancing"}),
        make_scenario({"scenario": "balancing", "seed": 3}),
    )
    assert a.theta(14.0)[0] != b.theta(14.0)[0]
    with pytest.raises(ValueError, match="parked"):
        make_scenario({"scenario": "balancing", "parked": [[5]]})
    with pytest.raises(ValueError, match="push_deg must be below 60"):
        make_scenario({"scenario": "balancing", "push_deg": 80})


# -- calibration (pure) -------------------------------------------------------------------


def test_calibration_is_the_mean_of_n_still_samples():
    cal = GyroCalibration(n=100)
    for k in range(99):
        assert not cal.feed((0.0, 0.0, 1.0), (0.5 + 0.01 * (k % 3 - 1), -0.2, 0.1))
    assert cal.feed((0.0, 0.0, 1.0), (0.5, -0.2, 0.1))
    assert cal.status().state == DONE and cal.status().restarts == 0
    assert cal.result == pytest.approx((0.5, -0.2, 0.1), abs=1e-3)


def test_calibration_refuses_to_finish_while_the_body_moves():
    cal = GyroCalibration(n=20, gyro_tol_dps=1.5, acc_tol_g=0.02)
    for k in range(400):  # a sway: 10 deg/s peaks
        rate = 10.0 * math.sin(2 * math.pi * k / 24)
        assert not cal.feed((0.02 * math.sin(2 * math.pi * k / 24), 0.0, 1.0), (rate, 0.0, 0.0))
    st = cal.status()
    assert st.state == MOVING and st.restarts > 20 and st.collected < 20
    for _ in range(20):
        cal.feed((0.0, 0.0, 1.0), (0.3, 0.0, 0.0))
    assert cal.status().state == DONE and cal.result[0] == pytest.approx(0.3)


# -- the measure and its verb -----------------------------------------------------------------


def _measure(scenario, args=None, store=None, start=100.0):
    ctx = make_ctx(
        "imu", {"scenario": "still"}, node="robot", period=1 / ODR, args=store or ArgsStore("robot")
    )
    boards_of(ctx).register(imu(scenario, start=start), "robot/imu")
    m = Lsm6dsl()
    m.init(args or {}, ctx)
    return m, ctx


def test_the_measure_calibrates_at_start_and_keeps_the_bias_in_the_args_store():
    store = ArgsStore("robot")
    m, ctx = _measure(Leaning(math.radians(5.0)), store=store)
    first = [m.measure() for _ in range(100)]
    assert [r.values[4] for r in first[:99]] == [CALIBRATING] * 99
    assert first[99].values[4] == CALIBRATED and ctx.counters["calibrations"] == 1
    b = m.board.gyro_bias[1] + m.board.walks[1](100.0)
    assert first[99].values[3] == pytest.approx(math.radians(b), abs=math.radians(0.01))
    a_x, a_z = first[-1].values[:2]  # the seed's convention: a_X = |g| sin(theta)
    assert math.degrees(math.atan2(a_x, a_z)) == pytest.approx(5.0, abs=0.3)
    stored = store.get("calib/robot/imu")
    # a restarted measure (same args store) publishes the stored bias at once
    again, ctx2 = _measure(Leaning(math.radians(5.0)), store=store)
    r = again.measure()
    assert r.values[4] == CALIBRATED and r.values[3] == first[99].values[3]
    assert "calibrations" not in ctx2.counters and store.get("calib/robot/imu") == stored


def test_on_request_calibration_waits_for_the_operator_and_refuses_motion():
    sc = make_scenario({"scenario": "balancing"})
    m, ctx = _measure(sc, {"calibration": "on_request"}, start=20.0)  # balancing by then
    assert m.measure().values[3:] == (0.0, 0.0)  # no bias yet, none asked
    verb_ctx = VerbContext("robot", "t", {}, ctx.resources)
    reply = gyro_calibration({"measure": "imu"}, verb_ctx)
    assert reply["requested"] is True and reply["state"] == "none"
    for _ in range(300):  # 11 s of balancing: never still
        assert m.measure().values[4] == CALIBRATING
    st = gyro_calibration({}, verb_ctx)["calibrations"]["imu"]
    assert st["state"] == "calibrating" and st["restarts"] > 10 and st["collected"] < 100
    assert ctx.counters["calib_restarts"] == st["restarts"]
    assert "calib/robot/imu" not in ctx.args


@pytest.mark.parametrize(
    ("request_", "message"),
    [
        ({"measure": ""}, "needs 'measure'"),
        ({"measure": "gyro"}, "no lsm6dsl measure 'gyro' on this node; lsm6dsl measures: imu"),
        ({"measure": "imu", "now": True}, "takes only 'measure'"),
    ],
)
def test_bad_calibration_requests_are_refused_with_one_sentence(request_, message):
    _, ctx = _measure(Leaning(0.0))
    with pytest.raises(ValueError, match=message):
        gyro_calibration(request_, VerbContext("robot", "t", {}, ctx.resources))


def test_a_period_that_does_not_match_the_data_rate_is_refused():
    ctx = make_ctx("imu", {"scenario": "still"}, node="robot", period=0.01)
    with pytest.raises(ValueError, match=r"period 0.01 s does not match odr_hz 26; give period"):
        Lsm6dsl().init({}, ctx)
