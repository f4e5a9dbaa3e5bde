"""The balancing robot's axle travel (``Balancing.axle``), the simulated wheel encoders and
the ``wheel_encoder`` measure."""

from __future__ import annotations

import math
import pickle
import random

import numpy as np
import pytest
from nodes_helpers import FakeClock, boards_of, make_ctx
from scipy.integrate import solve_ivp

from hera.nodes import boards
from hera.nodes.lsm6dsl.scenario import AXLE_STEP_S, Balancing
from hera.nodes.wheels.app import WheelBoards
from hera.nodes.wheels.driver import COUNTS_PER_M, WheelEncoderDriver, WheelReading
from hera.nodes.wheels.measures import WheelEncoder
from hera.nodes.wheels.sim import SimWheels
from hera.nodes.world import make_scenario

BALANCING = {"scenario": "balancing", "epoch": 0.0}


def motion_a_w(sc: Balancing, tau: float) -> float:
    """The axle's acceleration as ``motion()`` has it: the board's x acceleration less its
    own, relative to the axle."""
    th, dth, ddth = sc.theta(tau)
    h = sc.sensor
    return sc.motion(tau).acceleration[0] - h * (ddth * math.cos(th) - dth * dth * math.sin(th))


def reference(sc: Balancing, end: float):
    """x, v by an adaptive 8th-order Runge-Kutta on motion()'s a_w, tight tolerances and
    steps of at most 20 ms (it shrinks them around the jumps of a_w by itself)."""
    return solve_ivp(
        lambda t, y: (y[1], motion_a_w(sc, t)),
        (0.0, end),
        (0.0, 0.0),
        method="DOP853",
        rtol=1e-11,
        atol=1e-11,
        max_step=0.02,
        dense_output=True,
    ).sol


def wheels(sc=None, seed=1, start=0.0, step=1 / 26, **kw) -> SimWheels:
    sc = Balancing() if sc is None else sc
    return SimWheels("robot/wheels", sc, 0.0, seed, clock=FakeClock(start, step), **kw)


# -- the axle -----------------------------------------------------------------------------------


def test_the_axle_acceleration_is_the_one_motion_uses():
    for sc in (Balancing(), Balancing(reaction_k=0.5, wheel_radius_m=0.04, parked=[[30, 40]])):
        for tau in [k * 0.37 for k in range(150)] + [13.0, 23.0]:
            assert sc.axle_acc(tau) == pytest.approx(motion_a_w(sc, tau), abs=1e-12)


@pytest.mark.parametrize(
    ("world", "end"),
    [
        ({}, 100.0),
        ({"reaction_k": 0.5, "wheel_radius_m": 0.04, "parked": [[30, 40]], "seed": 3}, 60.0),
    ],
)
def test_the_axle_travel_matches_a_fine_reference(world, end):
    sc = make_scenario({**BALANCING, **world})
    sol = reference(sc, end)
    kicks = [sc.first_push + k * sc.push_every for k in range(10) if sc.first_push + k * 10 < end]
    taus = sorted(
        [0.3 + k * (end - 0.3) / 499 for k in range(500)]
        + [t + d for t in kicks for d in (-1e-3, 0.0, 1e-3)]
        + [sc.still_s + k * 0.05 for k in range(21)]  # the rise
    )
    got = np.array([sc.axle(t) for t in taus])
    want = sol(taus).T
    err = np.abs(got - want).max(axis=0)
    assert err[0] < 1e-6 and err[1] < 1e-7, err  # m, m/s (measured: 2e-8 m, 1e-9 m/s)
    assert np.abs(got[:, 0]).max() > 0.5  # it did drive (not a trivial agreement)
    # across a kick theta' steps but the axle's velocity does not
    for t in (t for t in kicks if sc.segment(t) == "push"):  # not those on the stand
        before, after = sc.axle(t - 1e-6)[1], sc.axle(t + 1e-6)[1]
        assert abs(after - before) < 1e-5
        assert abs(sc.theta(t + 1e-6)[1] - sc.theta(t - 1e-6)[1]) > 0.1


def test_on_its_stand_before_it_rises_the_axle_stays_at_zero():
    sc = Balancing(still_s=8.0)
    for tau in (-5.0, 0.0, 0.5, 3.0, 7.999, 8.0):
        assert sc.axle(tau) == (0.0, 0.0)
    assert sc.axle(8.5)[1] != 0.0
    # parked, it coasts: a_w is 0 on the stand
    sc = Balancing(parked=[[30.0, 40.0]])
    (x1, v1), (x2, v2) = sc.axle(32.0), sc.axle(37.0)
    assert v2 == pytest.approx(v1, abs=1e-12) and x2 - x1 == pytest.approx(5.0 * v1, abs=1e-9)


def test_the_axle_is_a_pure_function_of_tau_whatever_the_reading_order():
    taus = [8.0 + k / 26.0 for k in range(26 * 30)]
    sc = Balancing(seed=2)
    forward = [sc.axle(t) for t in taus]
    for i in range(0, len(taus), 97):  # a new robot read once
        assert Balancing(seed=2).axle(taus[i]) == forward[i]
    back = [sc.axle(t) for t in reversed(taus)][::-1]
    assert back == forward
    order = random.Random(4).sample(range(len(taus)), 60)
    other = Balancing(seed=2)
    assert [other.axle(taus[i]) for i in order] == [forward[i] for i in order]
    copy = pickle.loads(pickle.dumps(sc))  # the cache does not travel; the values do
    assert copy.axle(taus[-1]) == forward[-1]


def test_the_axle_keeps_one_checkpoint_a_second():
    sc = Balancing()
    sc.axle(300.5)
    track = sc._axle_track()
    assert len(track.xs) == 302  # 0 .. 301 s (the second read ends at the next one)
    sc.axle(12.25)  # back: from the checkpoint at 12 s, none made
    assert len(track.xs) == 302
    window = track._window
    assert window[0] == 12 and len(window[1]) <= round(1 / AXLE_STEP_S) + 5
    sc.axle(600.0)
    assert len(track.xs) == 602


def test_an_axle_read_far_beyond_the_epoch_is_refused():
    with pytest.raises(ValueError, match="is the world's epoch right"):
        Balancing().axle(1.7e9)  # epoch 0 and a wall-clock time


def test_a_robot_leaning_forward_drives_forward():
    # a slow wander only: theta = 5 deg sin(2 pi 0.02 t + ph)
    sc = Balancing(sway_deg=0.0, wander_deg=5.0, wander_hz=0.02, first_push_s=1e9, lean_deg=0)
    checked = 0
    for a in range(10, 110, 5):
        b = a + 5.0
        mean_theta = sum(sc.theta(a + k * 0.05)[0] for k in range(101)) / 101
        if abs(mean_theta) < math.radians(0.5):
            continue
        (xa, va), (xb, vb) = sc.axle(a), sc.axle(b)
        assert (vb - va) * mean_theta > 0 and (xb - xa - va * 5.0) * mean_theta > 0, a
        checked += 1
    assert checked >= 15
    # leaning forward as it rises, it drives off forward (and back when leaning back)
    for lean in (3.0, -3.0):
        sc = Balancing(lean_deg=lean, sway_deg=0.0, wander_deg=0.0, first_push_s=1e9)
        x, v = sc.axle(20.0)
        assert x * lean > 0 and v * lean > 0


# -- the simulated board ------------------------------------------------------------------------


def test_counts_are_the_floored_travel_with_the_boards_wheel_scale_error():
    sc = Balancing()
    b = wheels(sc, start=9.0)
    assert isinstance(b, WheelEncoderDriver) and b.counts_per_m == COUNTS_PER_M
    assert pytest.approx(7051.8, abs=0.1) == COUNTS_PER_M
    s = b.scale_error
    assert s != 0.0 and abs(s) < 0.05
    assert s == wheels(seed=1).scale_error and s != wheels(seed=2).scale_error
    assert wheels(seed=1, scale_error_sigma=0.0).scale_error == 0.0
    for _ in range(26 * 30):
        r = b.read_wheels()
        x = sc.axle(r.t)[0]
        assert isinstance(r.counts, int)
        assert r.counts == math.floor(x * (1 + s) * COUNTS_PER_M)
        assert 0 <= x * (1 + s) - r.counts / COUNTS_PER_M < 1 / COUNTS_PER_M
    assert abs(r.counts) > 1000  # it drove
    # a robot driving 10 m reads the scale error
    far = wheels(sc, start=99.0, step=1.0, scale_error_sigma=0.05)
    r = far.read_wheels()
    x = sc.axle(r.t)[0]
    assert abs(x) > 3.0
    assert r.counts / COUNTS_PER_M / x - 1 == pytest.approx(far.scale_error, abs=1e-3)


def test_it_balances_when_the_robot_is_up_on_its_wheels():
    b = wheels(start=0.0, step=0.25)
    on = [b.read_wheels().balancing for _ in range(80)]  # t = 0.25 .. 20 s
    assert on == [False] * 35 + [True] * 45  # on its stand to 8 s, getting up to 9 s


def test_a_world_without_wheels_is_refused_naming_its_scenario():
    with pytest.raises(ValueError, match="scenario 'still' does not track any wheel's travel"):
        SimWheels("r/wheels", make_scenario({"scenario": "still"}), 0.0, 1)
    with pytest.raises(ValueError, match="counts_per_m must be a number > 0"):
        wheels(counts_per_m=0.0)


def test_a_stuck_counter_freezes_and_other_faults_apply():
    b = wheels(start=10.0, step=0.1)
    b.faults.set("stuck")
    stuck = [b.read_wheels() for _ in range(50)]
    assert len({r.counts for r in stuck}) == 1 and stuck[0].counts != 0
    assert abs(b.travel(stuck[-1].t) - b.travel(stuck[0].t)) > 0.01  # while the robot moved
    b.faults.clear()
    assert b.read_wheels().counts != stuck[0].counts
    b.faults.set("bias", value=500)
    r = b.read_wheels()
    want = math.floor(b.travel(r.t) * (1 + b.scale_error) * COUNTS_PER_M) + 500
    assert r.counts == want
    with pytest.raises(ValueError, match="fault 'field' needs 'sensor'"):
        b.faults.set("field", value=[1.0])
    assert b.describe()["sensors"] == ["wheels"] and b.describe()["fault"]["fault"] == "bias"


# -- the measure and its application ------------------------------------------------------------


def _measure(args=None, world=None, start=0.0, step=1 / 26):
    ctx = make_ctx("wheels", world or BALANCING, node="robot", period=1 / 26)
    ctx.resources.put(boards.CLOCK, FakeClock(start, step))
    m = WheelEncoder()
    m.init(args or {}, ctx)
    return m, ctx


def test_the_measure_publishes_the_travel_in_metres_and_the_balancing():
    assert WheelEncoder.columns == ("x_wheel [m]", "balancing")
    assert WheelEncoder.period == pytest.approx(1 / 26)
    m, ctx = _measure(start=7.0)
    board = boards_of(ctx).get("robot/wheels")
    assert isinstance(board, SimWheels) and board.clock is ctx.resources.get(boards.CLOCK)
    rows = [m.measure() for _ in range(26 * 20)]
    for r in rows:
        x = board.travel(r.t)
        counts = math.floor(x * (1 + board.scale_error) * COUNTS_PER_M)
        assert r.values[0] == counts / COUNTS_PER_M
        if abs(r.t - 9.0) > 1e-6:  # up on its wheels from 9 s (8 s on its stand, 1 s rising)
            assert r.values[1] == (1.0 if r.t > 9.0 else 0.0)
    assert rows[0].values == (0.0, 0.0) and abs(rows[-1].values[0]) > 0.05
    # the board's seed is the node's, as the IMU's: another node, another scale error
    other, ctx2 = _measure()
    _ = other
    assert boards_of(ctx2).get("robot/wheels").scale_error == board.scale_error
    ctx3 = make_ctx("wheels", BALANCING, node="robot2", period=1 / 26)
    WheelEncoder().init({}, ctx3)
    assert boards_of(ctx3).get("robot2/wheels").scale_error != board.scale_error


def test_the_measure_takes_counts_per_m_and_a_model():
    m, ctx = _measure({"counts_per_m": 10000.0, "model": {"scale_error_sigma": 0.0}}, start=20)
    board = boards_of(ctx).get("robot/wheels")
    assert board.counts_per_m == 10000.0 and board.scale_error == 0.0
    r = m.measure()
    assert r.values[0] == pytest.approx(board.travel(r.t), abs=1e-4)
    problems = WheelEncoder.check_args(
        {"counts_per_m": -1, "model": {"sigma": 1}}, "spec: measure 'wheels'"
    )
    assert any("counts_per_m" in p for p in problems), problems
    assert any("model: unknown key 'sigma'" in p for p in problems), problems


def test_the_measure_counts_dropouts_and_disconnections():
    m, ctx = _measure(start=10.0)
    board = boards_of(ctx).get("robot/wheels")
    board.faults.set("dropout")
    assert m.measure() is None and ctx.counters["dropouts"] == 1
    board.faults.set("disconnect")
    assert m.measure() is None and ctx.counters["disconnected"] == 1
    board.faults.clear()
    assert m.measure() is not None


def test_the_measure_refuses_a_world_without_wheels():
    with pytest.raises(ValueError, match="scenario 'still' does not track"):
        _measure(world={"scenario": "still", "epoch": 0.0})


def test_a_real_driver_is_used_with_its_counts_per_m():
    class Counter:
        counts_per_m = 2000.0

        def read_wheels(self) -> WheelReading:
            return WheelReading(5.0, 1000, True)

    ctx = make_ctx("wheels", BALANCING, node="robot", period=1 / 26)
    boards_of(ctx).register(Counter(), "robot/wheels")
    m = WheelEncoder()
    m.init({}, ctx)
    r = m.measure()
    assert r.values == (0.5, 1.0) and r.t == 5.0


def test_the_app_checks_its_world():
    app = WheelBoards()
    assert app.name == "wheels" and app.measures == ("wheel_encoder",)
    assert app.check_world(BALANCING) == []
    assert app.check_world({"scenario": "balancing", "push_deg": 80})
