"""The seed-000 rig's simulated boards: the Sharp IR response and noise against the seed's
lab-1 figures, the plate's heat against an independent finite-difference solution and the
seed's 25-160 s delays, the scenarios, and the two measures (faults, drivers, bad args)."""

from __future__ import annotations

import math
import random
import statistics

import numpy as np
import pytest
from nodes_helpers import FakeClock, boards_of, make_ctx

from hera.nodes.faults import clear_fault, set_fault
from hera.nodes.ir.driver import IrDriver, IrDriverBase, ThermocoupleDriver
from hera.nodes.ir.measures import SharpIr, Thermocouple
from hera.nodes.ir.plate import Block, Plate, PlateHeat, ThermocoupleModel
from hera.nodes.ir.scenarios import PlateScene
from hera.nodes.ir.sharp import ADC_CODES, V_REF, SharpModel, curve, reading, variant
from hera.nodes.ir.sim import SimSharpIr
from hera.nodes.world import make_scenario
from hera.schema import SchemaError

QUANTUM = V_REF / ADC_CODES
SEED_ENDPOINTS = {
    "GP2Y0A41SK0F": ((4.0, 2.34), (30.0, 0.34)),
    "GP2Y0A21YK0F": ((10.0, 1.99), (80.0, 0.14)),
    "GP2Y0A02YK0F": ((20.0, 2.50), (150.0, 0.40)),
}
SEED_STD = {"GP2Y0A41SK0F": 0.026, "GP2Y0A21YK0F": 0.015, "GP2Y0A02YK0F": 0.089}


def _readings(part: str, d: float, n: int = 4000, **model) -> np.ndarray:
    v, m, rng = variant(part), SharpModel.from_args(model), random.Random(5)
    return np.array([reading(v, m, d, rng) for _ in range(n)])


@pytest.mark.parametrize("part", sorted(SEED_ENDPOINTS))
def test_each_fit_passes_through_the_seed_endpoints(part):
    v = variant(part)
    for d, volts in SEED_ENDPOINTS[part]:
        assert curve(v, d) == pytest.approx(volts, abs=1e-9)
    # monotonic falling over the whole range, as the lab-1 curves
    ds = np.linspace(v.d_min, v.d_max, 200)
    assert np.all(np.diff([curve(v, d) for d in ds]) < 0)


def test_the_exponents_are_the_seeds_jacobians():
    """Seed: H_long = -29.088 d^-1.873, H_medium = -8.594 d^-1.7114 (so b - 1)."""
    assert variant("long").b - 1 == pytest.approx(-1.873)
    assert variant("medium").b - 1 == pytest.approx(-1.7114)
    # the scale we fit to the endpoints is within 5 % of the seed's Jacobian factor
    assert variant("long").a * variant("long").b == pytest.approx(-29.088, rel=0.05)
    assert variant("medium").a * variant("medium").b == pytest.approx(-8.594, rel=0.05)


@pytest.mark.parametrize("part", sorted(SEED_STD))
def test_noise_has_the_seeds_residual_std_and_no_bias(part):
    v = variant(part)
    d = (v.d_min + v.d_max) / 2
    r = _readings(part, d, tail_prob=0.0, toggle_prob=0.0)
    assert statistics.stdev(r) == pytest.approx(SEED_STD[part], rel=0.08)
    assert abs(statistics.fmean(r) - curve(v, d)) < 3 * SEED_STD[part] / math.sqrt(len(r)) + QUANTUM


def test_readings_are_12_bit_codes_clamped_to_the_adc_range():
    r = np.concatenate([_readings("long", 15.0, 500, offset_v=1.5), _readings("short", 60.0, 500)])
    codes = r / QUANTUM
    assert np.allclose(codes, np.round(codes), atol=1e-6)
    assert r.min() >= 0.0 and r.max() <= V_REF
    assert (r == V_REF).sum() > 100  # the offset pushes the long sensor into the clamp


def test_the_short_sensor_toggles_between_two_spikes():
    """Seed lab 1: a bimodal "two-spike" histogram at 24 cm."""
    v = variant("short")
    r = _readings("short", 24.0, tail_prob=0.0)
    base = curve(v, 24.0)
    high = np.abs(r - (base + 0.25)) < 4 * 0.026
    low = np.abs(r - base) < 4 * 0.026
    assert high.mean() == pytest.approx(0.2, abs=0.03) and low.mean() > 0.75
    middle = np.abs(r - (base + 0.125)) < 0.03  # almost nothing between the spikes
    assert middle.mean() < 0.01
    assert (
        np.abs(_readings("medium", 24.0, tail_prob=0.0) - curve(variant("medium"), 24.0)).max()
        < 0.1
    )


def test_tails_are_heavier_than_gaussian():
    v = variant("medium")
    for tails, more in ((0.0, False), (0.01, True)):
        e = _readings("medium", 40.0, 20000, tail_prob=tails) - curve(v, 40.0)
        kurt = float(np.mean(e**4) / np.mean(e**2) ** 2)
        assert (kurt > 4.0) is more, kurt


def test_below_the_minimum_range_the_curve_folds_back():
    """Two distances give one voltage: a reading there cannot be inverted."""
    v = variant("medium")
    peak = 0.7 * v.d_min
    assert curve(v, peak) > curve(v, v.d_min) > curve(v, 30.0)
    near = [curve(v, d) for d in np.linspace(0.0, peak, 50)]
    assert np.all(np.diff(near) > 0)  # rising towards the peak from 0 cm
    target = curve(v, v.d_min)
    below = [d for d in np.linspace(0.0, peak, 2000) if abs(curve(v, d) - target) < 0.01]
    assert below  # a second distance, under the peak, reads like d_min


def test_readings_are_reproducible_from_the_seed():
    world = {"scenario": "ir_stationary", "distance_cm": 30.0}
    boards = [
        SimSharpIr(
            "n/ir",
            variant("medium"),
            SharpModel(),
            make_scenario(world),
            0.0,
            seed,
            clock=FakeClock(),
        )
        for seed in (1, 1, 2)
    ]
    a, b, c = ([x.read_sample().volts for _ in range(50)] for x in boards)
    assert a == b and a != c


# -- the plate --------------------------------------------------------------------------


def _finite_difference(plate: Plate, tau: float, h: float = 0.25) -> np.ndarray:
    """An independent solution of theta_t = alpha lap(theta) - theta / loss + source on the
    plate (explicit Euler, insulated edges by mirrored ghost cells)."""
    n = round(plate.width / h)
    xs = (np.arange(n) + 0.5) * h
    hot = plate.hot
    mask = (xs[None, :] >= hot.x) & (xs[None, :] < hot.x + hot.w)
    mask = mask & ((xs[:, None] >= hot.y) & (xs[:, None] < hot.y + hot.h))
    q = plate.rise_c / plate.loss_time_s * plate.width * plate.height / (mask.sum() * h * h)
    dt = 0.2 * h * h / plate.alpha
    theta = np.zeros((n, n))
    for _ in range(round(tau / dt)):
        p = np.pad(theta, 1, mode="edge")
        lap = (p[2:, 1:-1] + p[:-2, 1:-1] + p[1:-1, 2:] + p[1:-1, :-2] - 4 * theta) / (h * h)
        theta = theta + dt * (plate.alpha * lap - theta / plate.loss_time_s + q * mask)
    return theta


def test_the_modal_heat_solution_matches_finite_differences():
    plate = Plate(blocks=(Block(6.0, 6.0, 2.0, 2.0, hot=True),), modes=60)
    heat = PlateHeat(plate)
    fd = _finite_difference(plate, 60.0)
    for px, py in ((0.625, 0.625), (5.125, 5.125), (6.875, 6.875), (9.375, 0.625)):
        i, j = int(py / 0.25), int(px / 0.25)
        assert heat.rise(px, py, 60.0) == pytest.approx(fd[i, j], rel=0.03, abs=0.02)


def test_the_steady_mean_rise_is_rise_c_and_the_lag_is_first_order():
    plate = Plate(blocks=(Block(2.0, 2.0, 2.0, 2.0, hot=True),), rise_c=8.0)
    heat = PlateHeat(plate)
    pts = (np.arange(40) + 0.5) * 0.25
    mean = np.mean([[heat.rise(x, y, 5000.0) for x in pts] for y in pts])
    assert mean == pytest.approx(8.0, rel=0.01)
    # the lagged rise solves y' = (x - y) / lag: compare with a fine Euler integration
    lag, dt, y = 2.0, 0.01, 0.0
    for k in range(int(30 / dt)):
        y += dt * (heat.rise(5.0, 5.0, k * dt) - y) / lag
    assert heat.lagged_rise(5.0, 5.0, 30.0, lag) == pytest.approx(y, rel=0.01)


@pytest.mark.parametrize("hot_xy", [(6.0, 6.0), (1.0, 1.0), (4.0, 7.0)])
def test_thermocouple_delays_span_the_seeds_25_to_160_s(hot_xy):
    """Seed lab 3: the thermal responses arrive 25-160 s after the block is put down. Every
    thermocouple's time to half its final rise lies in that span (within 15 s), the farthest
    takes over two minutes, and the farthest is the last to show 10 % of its rise."""
    blocks = [{"x": hot_xy[0], "y": hot_xy[1], "w": 2, "h": 2, "hot": True}]
    scene = make_scenario({"scenario": "ir_plate", "blocks": blocks})
    hot = scene.plate.hot
    ts = np.arange(0.0, 400.0, 1.0)
    times = []
    for x, y in scene.thermocouples:
        final = scene.heat.lagged_rise(x, y, 3000.0, 2.0)
        rises = np.array([scene.heat.lagged_rise(x, y, t, 2.0) for t in ts])
        tenth, half = ts[np.argmax(rises >= final / 10)], ts[np.argmax(rises >= final / 2)]
        times.append((math.dist((x, y), hot.center), tenth, half))
    times.sort()
    halves = [t[2] for t in times]
    assert min(halves) >= 25 and max(halves) <= 175, times
    assert times[-1][2] >= 120 and times[-1][1] == max(t[1] for t in times), times


def test_a_thermocouple_reads_through_its_offset_noise_and_resolution():
    model = ThermocoupleModel.from_args({"offset_c": 0.8})
    rng = random.Random(3)
    r = [model.read(30.0, model.offset(rng), rng) for _ in range(3000)]
    assert all(abs(x / 0.25 - round(x / 0.25)) < 1e-9 for x in r)
    assert statistics.fmean(r) == pytest.approx(30.8, abs=0.02)
    assert statistics.stdev(r) == pytest.approx(0.21, abs=0.03)  # 0.2 noise + quantisation


# -- scenarios ---------------------------------------------------------------------------


def test_constant_velocity_is_constant_but_for_smooth_turns():
    sc = make_scenario({"scenario": "ir_constant_velocity", "speed_cm_s": 2.0, "turn_s": 2.0})
    ts = np.arange(0.0, 120.0, 0.01)
    d = np.array([sc.distance(t)[0] for t in ts])
    v = np.array([sc.distance(t)[1] for t in ts])
    assert np.allclose(np.gradient(d, ts)[1:-1], v[1:-1], atol=0.01)
    assert d.min() >= 20.0 and d.max() <= 60.0
    assert np.mean(np.abs(np.abs(v) - 2.0) < 1e-9) > 0.9  # constant speed 90 % of the time
    assert np.max(np.abs(np.diff(v) / 0.01)) <= 2.0 + 1e-6  # turns: |a| <= 2 v / turn


def test_back_and_forth_depends_on_the_world_seed_and_stays_on_the_track():
    a = make_scenario({"scenario": "ir_back_and_forth", "seed": 1})
    b = make_scenario({"scenario": "ir_back_and_forth", "seed": 1})
    c = make_scenario({"scenario": "ir_back_and_forth", "seed": 2})
    ts = np.arange(0, 60, 0.1)
    da, db, dc = ([s.distance(t)[0] for t in ts] for s in (a, b, c))
    assert da == db and da != dc
    assert min(da) >= 30.0 and max(da) <= 60.0


def test_ir_beams_see_the_first_visible_block_or_the_frame():
    world = {
        "scenario": "ir_plate",
        "blocks": [
            {"x": 2, "y": 3, "w": 2, "h": 2},
            {"x": 6, "y": 3, "w": 2, "h": 2},
            {"x": 5, "y": 7, "w": 1, "h": 1, "visible": False},
        ],
    }
    sc = make_scenario(world)
    assert isinstance(sc, PlateScene)
    assert sc.beam_distance(-5.0, 4.0, 0.0) == pytest.approx(7.0)  # the first block
    assert sc.beam_distance(15.0, 4.0, 180.0) == pytest.approx(7.0)  # from the right
    assert sc.beam_distance(-5.0, 7.5, 0.0) == pytest.approx(17.0)  # invisible: the frame
    assert sc.beam_distance(7.0, -5.0, 90.0) == pytest.approx(8.0)
    assert sc.beam_distance(-5.0, 5.1, 0.0) == pytest.approx(7.0)  # the beam's edge (0.2)
    assert sc.beam_distance(-5.0, 5.3, 0.0) == pytest.approx(17.0)
    x, y, h = sc.scanner("left").pose(sc.plate, 1.5)  # a quarter of the 6 s sweep
    assert (x, h) == (-5.0, 0.0) and y == pytest.approx(5.0)


@pytest.mark.parametrize(
    ("world", "words"),
    [
        (
            {"scenario": "ir_plate", "blocks": [{"x": 1, "y": 1, "w": 0, "h": 1}]},
            ["blocks", "w and h"],
        ),
        ({"scenario": "ir_plate", "blocks": [{"x": 1, "y": 1, "w": 1}]}, ["'h'"]),
        ({"scenario": "ir_plate", "blocks": [{"x": 1, "y": 1, "w": 1, "h": 1, "hot": 1}]}, ["hot"]),
        ({"scenario": "ir_plate", "scanners": ["diagonal"]}, ["scanners", "left"]),
        ({"scenario": "ir_plate", "speed_cm_s": 2}, ["unknown world keys", "speed_cm_s"]),
        ({"scenario": "ir_constant_velocity", "near_cm": 80}, ["near_cm < far_cm"]),
    ],
)
def test_bad_worlds_are_refused_naming_the_key(world, words):
    with pytest.raises(ValueError) as e:
        make_scenario(world)
    for w in words:
        assert w in str(e.value)


# -- measures ----------------------------------------------------------------------------


def test_sharp_ir_publishes_volts_and_the_scanner_pose():
    ctx = make_ctx("ir_left", {"scenario": "ir_plate", "epoch": 1000.0}, period=0.02)
    m = SharpIr()
    m.init({"variant": "short", "scanner": "left"}, ctx)
    board = boards_of(ctx).get("ir")
    board.clock = FakeClock(1000.0, 0.02)
    rows = [m.measure() for _ in range(150)]
    assert all(r is not None and len(r.values) == 4 for r in rows)
    ys = [r.values[2] for r in rows]
    assert min(ys) < 1.0 and max(ys) > 5.0  # the carriage sweeps along the left edge
    assert {r.values[1] for r in rows} == {-5.0} and {r.values[3] for r in rows} == {0.0}


def test_a_disconnected_channel_is_skipped_and_counted_then_back():
    ctx = make_ctx("ir_long", {"scenario": "ir_stationary", "epoch": 1000.0}, period=0.02)
    m = SharpIr()
    m.init({"variant": "long"}, ctx)
    boards_of(ctx).get("ir").clock = FakeClock(1000.0, 0.02)
    assert m.measure() is not None
    set_fault(boards_of(ctx), "ir", "disconnect")
    assert [m.measure() for _ in range(5)] == [None] * 5
    assert ctx.counters["disconnected"] == 5
    clear_fault(boards_of(ctx), "ir")
    r = m.measure()
    expected = curve(variant("long"), 70.0)  # the long sensor at 70 cm
    assert r is not None and abs(r.values[0] - expected) < 5 * 0.089


def test_thermocouples_take_their_place_from_the_plate_world():
    ctx = make_ctx("tc5", {"scenario": "ir_plate", "epoch": 1000.0, "hot_since_s": 600.0})
    m = Thermocouple()
    m.init({"index": 4}, ctx)
    boards_of(ctx).get("tc").clock = FakeClock(1000.0, 0.2)
    r = m.measure()
    assert tuple(r.values[1:]) == (5.0, 5.0)
    assert r.values[0] > 24.0  # the plate under it is warm after 10 minutes
    with pytest.raises(ValueError, match="index"):
        Thermocouple().init({"index": 9}, make_ctx("tc9", {"scenario": "ir_plate"}))


class FakeAdc(IrDriverBase):
    """A real-driver stand-in: a constant voltage."""

    def __init__(self, volts: float = 1.0) -> None:
        self.volts = volts

    def read_volts(self) -> float:
        return self.volts


def test_a_real_driver_takes_the_simulators_place():
    ctx = make_ctx("ir", {"scenario": "ir_stationary"})
    m = SharpIr()
    m.init(
        {
            "driver": f"{__name__}:FakeAdc",
            "driver_args": {"volts": 1.25},
            "position_cm": [3.0, 4.0],
            "heading_deg": 90.0,
        },
        ctx,
    )
    assert isinstance(boards_of(ctx).get("ir"), IrDriver)
    assert not isinstance(boards_of(ctx).get("ir"), ThermocoupleDriver)
    assert list(m.measure().values) == [1.25, 3.0, 4.0, 90.0]


@pytest.mark.parametrize(
    ("measure", "args", "words"),
    [
        (SharpIr, {"variant": "GP2Y0A99"}, ["variant", "GP2Y0A99"]),
        (SharpIr, {"variant": "short", "scanner": "left"}, ["ir_plate"]),
        (SharpIr, {"variant": "short", "model": {"toggle_v": "big"}}, ["toggle_v"]),
        (SharpIr, {"variant": "short", "model": {"gian": 1.0}}, ["gian", "gain"]),
        (Thermocouple, {"model": {"lag_s": -1}}, ["lag_s", ">= 0"]),
    ],
)
def test_bad_board_args_are_refused_with_a_clear_sentence(measure, args, words):
    with pytest.raises((ValueError, SchemaError)) as e:
        measure().init(args, make_ctx("x", {"scenario": "ir_stationary"}))
    for w in words:
        assert w in str(e.value)
