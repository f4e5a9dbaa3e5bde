"""The simulated Pmod NAV reads what its configured error model says (mean and spread)."""

from __future__ import annotations

import math
import statistics

import pytest
from nodes_helpers import (
    FakeClock,
)

from hera.nodes import geometry as gm
from hera.nodes.imu_model import NavModel
from hera.nodes.noise import RandomWalk
from hera.nodes.sim_nav import SimNavBoard
from hera.nodes.world import G, environment, make_scenario

N = 3000


def _board(world: dict, clock=None, seed: int = 7, **model) -> SimNavBoard:
    return SimNavBoard(
        "n1/nav",
        make_scenario(world),
        environment(world),
        float(world.get("epoch", 0.0)),
        NavModel.from_args(model),
        seed,
        clock or FakeClock(),
    )


def _stats(samples, axis):
    xs = [s[axis] for s in samples]
    return statistics.fmean(xs), statistics.stdev(xs)


def _check(samples, expected_mean, sigma):
    """Mean within 5 standard errors, spread within 10 % of the configured sigma."""
    for i in range(len(expected_mean)):
        mean, sd = _stats(samples, i)
        assert mean == pytest.approx(expected_mean[i], abs=5 * sigma / math.sqrt(len(samples)))
        assert sd == pytest.approx(sigma, rel=0.1)


EXACT = {
    "acc_scale": [0, 0, 0],
    "gyro_scale": [0, 0, 0],
    "gyro_drift": 0.0,
    "tilt_pitch_deg": 0.0,
}


def test_accelerometer_reads_gravity_bias_and_noise() -> None:
    b = _board({"scenario": "still"}, acc_bias=[0.01, -0.02, 0.03], acc_noise=0.004, **EXACT)
    samples = [b.read_acc() for _ in range(N)]
    _check(samples, (0.01, -0.02, 1.03), 0.004)


def test_mounting_tilt_shows_gravity_on_x() -> None:
    b = _board({"scenario": "still"}, acc_bias=[0, 0, 0], acc_scale=[0, 0, 0])
    mean_x, _ = _stats([b.read_acc() for _ in range(N)], 0)
    # default tilt 5 deg (thesis app. B): a_x = -sin(5 deg) g
    assert mean_x == pytest.approx(-math.sin(math.radians(5.0)), abs=5 * 0.005 / math.sqrt(N))


def test_gyroscope_reads_rate_bias_and_noise() -> None:
    b = _board(
        {"scenario": "train", "vibration_gyro": 0.0},
        gyro_bias=[0.5, -0.3, 0.2],
        gyro_noise=0.08,
        **EXACT,
    )
    samples = [b.read_gyro() for _ in range(N)]
    _check(samples, (0.5, -0.3, 0.2 + math.degrees(0.84)), 0.08)


def test_train_vibration_adds_the_thesis_variances() -> None:
    b = _board({"scenario": "train"}, acc_noise=0.0, gyro_noise=0.0, **EXACT)
    acc = [b.read_acc() for _ in range(N)]
    gyro = [b.read_gyro() for _ in range(N)]
    # thesis eq. 6.1 / 6.4: sigma_ac^2 = 0.8 (m/s^2)^2, sigma_g^2 = 0.005 (rad/s)^2
    assert _stats(acc, 1)[1] * G == pytest.approx(math.sqrt(0.8), rel=0.1)
    assert math.radians(_stats(gyro, 2)[1]) == pytest.approx(math.sqrt(0.005), rel=0.1)


def test_magnetometer_reads_earth_field_through_hard_and_soft_iron() -> None:
    world = {"scenario": "still", "yaw": 0.7}
    soft = [[1.05, 0.02, 0.0], [0.02, 0.95, 0.0], [0.0, 0.0, 1.0]]
    b = _board(world, hard_iron=[0.3, -0.1, 0.05], soft_iron=soft, mag_noise=0.002, **EXACT)
    field = gm.unrotate(gm.yaw(0.7), environment(world).field)
    expected = gm.add(gm.mat_vec(tuple(map(tuple, soft)), field), (0.3, -0.1, 0.05))
    _check([b.read_mag() for _ in range(N)], expected, 0.002)


def test_barometer_reads_the_standard_atmosphere() -> None:
    b = _board({"scenario": "still", "altitude": 0.0}, baro_noise=0.02)
    samples = [(b.read_baro(),) for _ in range(N)]
    _check(samples, (1013.25,), 0.02)
    high = _board({"scenario": "still", "altitude": 1000.0}, baro_noise=0.0)
    assert high.read_baro() == pytest.approx(898.7, abs=0.5)  # ISA table value at 1 km


def test_gyro_bias_random_walk_has_the_configured_diffusion() -> None:
    walk = RandomWalk(seed=3, stream="g", sigma=0.02, step=1.0)
    knots = [walk(float(k)) for k in range(0, 4001)]
    steps = [b - a for a, b in zip(knots, knots[1:], strict=False)]
    assert statistics.stdev(steps) == pytest.approx(0.02, rel=0.1)
    assert walk(10.5) == pytest.approx((walk(10.0) + walk(11.0)) / 2)


def test_unseeded_biases_are_drawn_once_per_board() -> None:
    a = _board({"scenario": "still"}, seed=1)
    b = _board({"scenario": "still"}, seed=2)
    assert a.acc_bias != b.acc_bias
    assert a.acc_bias == _board({"scenario": "still"}, seed=1).acc_bias
    assert all(abs(x) < 5 * 0.02 for x in a.acc_bias)


def test_model_tables_are_checked() -> None:
    with pytest.raises(ValueError, match="unknown NAV model keys"):
        NavModel.from_args({"acc_nosie": 1})
    with pytest.raises(ValueError, match=">= 0"):
        NavModel.from_args({"acc_noise": -1})
    with pytest.raises(ValueError, match="3 numbers"):
        NavModel.from_args({"hard_iron": [1, 2]})
