"""The simulated VL53L1 board, its ``desk`` scenario and the ``vl53l1`` measure (seed 001)."""

from __future__ import annotations

import math
import statistics

import pytest
from nodes_helpers import FakeClock, boards_of, make_ctx

from hera.nodes import geometry as gm
from hera.nodes.driver import NoReading
from hera.nodes.tof import driver as d
from hera.nodes.tof.measures import MOUNTS, Vl53l1
from hera.nodes.tof.model import TofModel
from hera.nodes.tof.scenario import Desk, min_jerk
from hera.nodes.tof.sim import SimVl53l1, true_range
from hera.nodes.world import Motion, Scenario, make_scenario

QUIET = {"invalid_prob": 0.0, "outlier_prob": 0.0}


class Posed(Scenario):
    """A board held still at a height with a pitch and roll (rad)."""

    def __init__(self, h: float, pitch: float = 0.0, roll: float = 0.0) -> None:
        self.m = Motion(position=(0.0, 0.0, h), orientation=gm.from_euler(roll, pitch, 0.0))

    def motion(self, tau: float) -> Motion:
        return self.m


def board(scenario, mount=(0.0, 0.0), seed=1, clock=None, **model):
    return SimVl53l1(
        "n/tof", scenario, 0.0, TofModel.from_args(model), mount, seed, clock or FakeClock(10.0)
    )


def readings(b, n):
    return [b.read_ranging() for _ in range(n)]


def test_a_reading_is_the_seeds_four_values_with_3_mm_noise():
    b = board(Posed(0.2), **QUIET)
    rs = readings(b, 3000)
    assert all(len(r.values()) == 4 and r.status == d.RANGE_VALID for r in rs)
    errs = [r.distance - 0.2 for r in rs]
    assert abs(statistics.mean(errs)) < 0.0003
    assert 0.0027 < statistics.stdev(errs) < 0.0033  # sigma 3 mm, rounded to 1 mm
    assert all(round(r.distance * 1000) == r.distance * 1000 for r in rs[:50])  # whole mm
    assert all(r.signal > r.ambient > 0 for r in rs)


def test_a_tilted_board_gives_three_different_ranges_from_its_geometry():
    pitch, roll, h = math.radians(8), math.radians(-6), 0.18
    for name, mount in MOUNTS.items():
        got = true_range((0.0, 0.0, h), gm.from_euler(roll, pitch, 0.0), mount)
        # independent: the sensor's height over the desk along the board's -z axis
        x, y = mount
        z = h - x * math.sin(pitch) + y * math.sin(roll) * math.cos(pitch)
        assert got == pytest.approx(z / (math.cos(pitch) * math.cos(roll)), rel=1e-12), name
    ranges = {n: true_range((0, 0, h), gm.from_euler(roll, pitch, 0), m) for n, m in MOUNTS.items()}
    assert len({round(v, 4) for v in ranges.values()}) == 3


def test_statuses_for_out_of_range_too_close_and_weak_signal():
    assert {r.status for r in readings(board(Posed(5.0), **QUIET), 20)} == {d.OUT_OF_BOUNDS}
    near = readings(board(Posed(0.02), **QUIET), 20)
    assert {r.status for r in near} == {d.MIN_RANGE_CLIPPED}
    assert {r.distance for r in near} == {0.04}
    dark = readings(board(Posed(1.5), min_signal_mcps=0.5, **QUIET), 20)  # signal ~0.09 Mcps
    assert {r.status for r in dark} == {d.SIGNAL_FAIL}
    noisy = readings(board(Posed(1.0), sigma_limit_m=0.004, **QUIET), 20)  # sigma 6 mm at 1 m
    assert {r.status for r in noisy} == {d.SIGMA_FAIL}
    looking_up = readings(board(Posed(0.2, pitch=math.pi), **QUIET), 5)
    assert {r.status for r in looking_up} == {d.OUT_OF_BOUNDS}


def test_invalid_rangings_and_outliers_come_at_their_rates():
    rs = readings(board(Posed(0.2), invalid_prob=0.05, outlier_prob=0.05), 4000)
    invalid = [r for r in rs if r.status != d.RANGE_VALID]
    assert 0.035 < len(invalid) / len(rs) < 0.065
    assert {r.status for r in invalid} == {d.SIGMA_FAIL, d.SIGNAL_FAIL, d.WRAP_TARGET_FAIL}
    outliers = [r for r in rs if r.status == d.RANGE_VALID and abs(r.distance - 0.2) >= 0.019]
    assert 0.035 < len(outliers) / len(rs) < 0.065
    assert max(abs(r.distance - 0.2) for r in outliers) <= 0.3 + 0.011


def test_offsets_and_scales_are_drawn_per_sensor_when_asked():
    b = board(Posed(0.2), offset_sigma_m=0.002, scale_sigma=0.01, **QUIET)
    c = board(Posed(0.2), seed=2, offset_sigma_m=0.002, scale_sigma=0.01, **QUIET)
    assert (b.offset, b.scale) != (c.offset, c.scale)
    mean = statistics.mean(r.distance for r in readings(b, 2000))
    assert mean == pytest.approx((1 + b.scale) * 0.2 + b.offset, abs=0.0003)
    assert board(Posed(0.2)).offset == 0.0 and board(Posed(0.2)).scale == 0.0  # calibrated


def test_readings_are_deterministic_in_the_seed_and_times():
    sc = make_scenario({"scenario": "desk"})
    a, b = (readings(board(sc, clock=FakeClock(3.0, 0.1)), 200) for _ in range(2))
    assert a == b
    c = readings(board(sc, seed=2, clock=FakeClock(3.0, 0.1)), 200)
    assert a != c


def test_faults_freeze_drop_or_bias_the_readings():
    b = board(Posed(0.2), **QUIET)
    b.faults.set("stuck")
    first, *rest = readings(b, 5)
    assert all(r.values() == first.values() for r in rest)
    b.faults.set("dropout")
    with pytest.raises(NoReading):
        b.read_ranging()
    b.faults.set("bias", sensor="distance", value=0.05)
    assert statistics.mean(r.distance for r in readings(b, 200)) == pytest.approx(0.25, abs=0.001)
    assert {r.status for r in readings(b, 20)} == {d.RANGE_VALID}
    b.faults.clear()
    assert statistics.mean(r.distance for r in readings(b, 200)) == pytest.approx(0.2, abs=0.001)


def test_the_desk_scenario_is_smooth_and_has_every_segment():
    sc = make_scenario({"scenario": "desk", "seed": 4})
    assert isinstance(sc, Desk)
    kinds = {sc.segment(t * 0.05) for t in range(2000)}
    assert kinds == {"still", "slow", "fast", "tilt"}
    dt = 1e-4
    for k in range(1, 2400):
        t = k * 0.05
        (p0, r0, _), (p1, r1, _) = sc.pose(t), sc.pose(t + dt)
        for i in range(3):
            assert abs(p1[i] - p0[i]) <= dt * 2.0  # no jump: |rate| < 2 units/s
            assert abs(r1[i] - r0[i]) <= dt * 20.0  # rates continuous too
    fast = [max(abs(sc.pose(t * 0.01)[1][0]) for t in range(1200, 1400))]
    assert fast[0] > 0.3  # a fast segment moves at tens of cm/s
    assert sc.rest_motion().position == (0.0, 0.0, 0.12)


def test_the_desk_cycles_vary_with_the_seed_but_the_first_does_not():
    a = make_scenario({"scenario": "desk", "seed": 1})
    b = make_scenario({"scenario": "desk", "seed": 2})
    assert [a.pose(t)[0] for t in range(0, 35)] == [b.pose(t)[0] for t in range(0, 35)]
    assert [a.pose(t)[0] for t in range(40, 75)] != [b.pose(t)[0] for t in range(40, 75)]


def test_min_jerk_ends_at_rest():
    assert min_jerk(0.0) == (0.0, 0.0, 0.0) and min_jerk(1.0) == (1.0, 0.0, 0.0)
    s, ds, dds = min_jerk(0.5)
    assert s == pytest.approx(0.5) and ds == pytest.approx(1.875) and dds == pytest.approx(0.0)


def test_bad_desk_worlds_are_refused_naming_the_key():
    with pytest.raises(ValueError, match="unknown world keys.*'heigth'"):
        make_scenario({"scenario": "desk", "heigth": 0.1})
    with pytest.raises(ValueError, match="low < height < high"):
        make_scenario({"scenario": "desk", "low": 0.3})
    with pytest.raises(ValueError, match="world 'seed' must be an integer"):
        make_scenario({"scenario": "desk", "seed": 1.5})


def _ctx(sensor="centre", **world):
    return make_ctx("tof", {"scenario": "desk", "epoch": 0.0, **world}, node=f"tof_{sensor}")


def test_the_measure_publishes_every_ranging_with_where_its_sensor_sits():
    ctx = _ctx("left")
    sim = SimVl53l1("tof_left/tof", Posed(0.15), 0.0, TofModel(), MOUNTS["left"], 3, FakeClock())
    boards_of(ctx).register(sim)
    m = Vl53l1()
    m.init({"sensor": "left"}, ctx)
    out = [m.measure() for _ in range(300)]
    assert all(len(r.values) == 6 and tuple(r.values[4:]) == MOUNTS["left"] for r in out)
    assert ctx.counters["rangings"] == 300
    assert ctx.counters["invalid"] == sum(r.values[3] != 0 for r in out) > 0  # 1 %
    sim.faults.set("dropout")
    assert m.measure() is None and ctx.counters["dropouts"] == 1


def test_the_measure_builds_its_simulator_at_the_given_position():
    ctx = _ctx()
    m = Vl53l1()
    m.init({"position": [0.01, 0.02], "model": {"sigma_m": 0.001}}, ctx)
    assert m.mount == (0.01, 0.02) and m.board.mount == (0.01, 0.02)
    assert m.board.model.sigma_m == 0.001
    assert boards_of(ctx).find("tof_centre/tof") is m.board


class FixedTof:
    """A VL53L1 driver written from the protocol alone."""

    def read_ranging(self):
        return d.TofReading(1.0, 0.123, 0.5, 8.0, 0)


def test_the_measure_runs_on_a_real_driver_named_in_its_args():
    m = Vl53l1()
    m.init({"driver": f"{__name__}:FixedTof"}, _ctx())
    r = m.measure()
    assert tuple(r.values) == (0.123, 0.5, 8.0, 0.0, 0.0, 0.0) and r.t == 1.0


@pytest.mark.parametrize(
    ("args", "problem"),
    [
        ({"model": {"sigma": 0.003}}, "model: unknown key 'sigma'"),
        ({"model": {"sigma_m": -1}}, "model: sigma_m must be a number > 0"),
        ({"position": [0.1]}, "position must be [x, y]"),
        ({"sensor": "middle"}, "sensor must be one of left, centre, right"),
    ],
)
def test_bad_measure_args_are_refused_naming_them(args, problem):
    problems = Vl53l1.check_args(args, "spec: measure 'tof'")
    assert problems and all(p.startswith("spec: measure 'tof'") for p in problems)
    assert any(problem in p for p in problems), problems
