"""Unit tests of the train models on real-rig troubles (issue 20): the branch grid,
re-acquisition from a wrong branch, consider states while acquiring, both directions, the
magnetometer's heading offset, the signed a_c's slope at w = 0, and the eval metrics of
lock and wrong branches. Synthetic samples of a point target on a circle, no simulator."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hera.models.train.app import branch_scores, lock_time, longest_span
from hera.models.train.branches import BranchGrid, Track, wrap
from hera.models.train.tracker import ACC_RATIOS, GYRO_RATIOS, TrainTracker, folded_mean
from hera.store import Sample

SONARS = {"s0": (-0.3, -1.5), "s1": (0.3, -1.5)}
BEAMS = {"s0": [0.0, 1.0], "s1": [0.0, 1.0]}
R = 0.6


def sample(name, node, seq, t, *values):
    return Sample(name, node, seq, t, 0.0, 0.0, tuple(float(v) for v in values))


def in_beam(node: str, x: float, y: float, half_deg: float = 20.0) -> bool:
    px, py = SONARS[node]
    return (y - py) / math.hypot(x - px, y - py) >= math.cos(math.radians(half_deg))


def run_samples(seconds, omega=0.84, theta0=-1.0, t0=100.0, nav_hz=50, sonar_hz=5, mag=None):
    """Noise-free samples: nav [r w |w|, w] at nav_hz, each sonar at sonar_hz when the
    target is in its 20 deg beam (the far side of the track too), and a heading
    ``theta + mag`` at 10 Hz when ``mag`` is given."""
    out, k = [], 0
    n_nav = int(seconds * nav_hz)
    for i in range(n_nav):
        t = t0 + i / nav_hz
        th = theta0 + omega * (t - t0)
        out.append(sample("nav", "n", i, t, R * omega * abs(omega), omega))
        if i % (nav_hz // sonar_hz) == 0:
            node = "s0" if (i // (nav_hz // sonar_hz)) % 2 == 0 else "s1"
            x, y = R * math.cos(th), R * math.sin(th)
            if in_beam(node, x, y):
                px, py = SONARS[node]
                k += 1
                out.append(sample("sonar", node, k, t + 1e-4, math.hypot(x - px, y - py), px, py))
        if mag is not None and i % (nav_hz // 10) == 0:
            out.append(sample("mag", "n", i, t + 2e-4, float(wrap(th + mag))))
    return out


def theta_err(m: TrainTracker, t: float, omega=0.84, theta0=-1.0, t0=100.0) -> float:
    th = m.estimate()[1][2]
    return math.degrees(abs(float(wrap(th - (theta0 + omega * (t - t0))))))


def grid(ratios) -> BranchGrid:
    cos20, cos24 = math.cos(math.radians(20)), math.cos(math.radians(24))
    beams = {n: (0.0, 1.0) for n in SONARS}
    return BranchGrid(Track((0.0, 0.0), 0.0, 0.0, beams, cos20, cos24), ratios)


@pytest.mark.parametrize("omega", [0.84, -0.84])
def test_the_grid_finds_the_branch_and_the_direction_from_ranges_alone(omega):
    g = grid(ACC_RATIOS)  # speed relative to 0.5 rad/s, either sign
    theta0, t0 = 2.5, 100.0
    for s in run_samples(20.0, omega=omega, theta0=theta0):
        if s.name == "sonar":
            g.advance(s.t, 0.5)
            g.add_range(s.node, s.values[0], s.values[1], s.values[2], R, 0.02)
    b = g.best()
    truth = theta0 + omega * (g.t - t0)
    assert b.mass > 0.99
    assert math.degrees(abs(float(wrap(b.theta - truth)))) < 10
    assert b.ratio * 0.5 == pytest.approx(omega, rel=0.05)  # speed and sign from the ranges


def test_a_far_side_echo_alone_does_not_make_the_grid_confident():
    g = grid(GYRO_RATIOS)
    g.advance(100.0, 0.84)
    g.add_range("s0", 2.1, *SONARS["s0"], R, 0.02)  # what the far side of the track gives
    assert g.best().mass < 0.9


def test_a_filter_on_a_wrong_branch_unlocks_and_is_reseeded_within_a_lap():
    m = TrainTracker(rung="e7", beams=BEAMS)
    samples = run_samples(40.0)
    first = [s for s in samples if s.t < 115.0]
    for s in first:
        m.process(s)
    assert m.locked and theta_err(m, m.t) < 5
    x = m.ekf.x.copy()  # a confident filter pushed 120 deg onto a wrong branch
    x[2] += math.radians(120)
    x[0], x[1] = R * math.cos(x[2]), R * math.sin(x[2])
    P = np.diag([1e-6, 1e-6, 1e-5, 1e-6, 1e-6])
    m.ekf.reset(x, P)
    seeds, unlocks = m.seeds, m.unlocks
    lap = 2 * math.pi / 0.84
    for s in (s for s in samples if 115.0 <= s.t < 115.0 + lap):
        m.process(s)
    assert m.unlocks > unlocks and m.seeds > seeds
    assert theta_err(m, m.t) < 10
    for s in (s for s in samples if s.t >= 115.0 + lap):
        m.process(s)
    assert m.locked and theta_err(m, m.t) < 5


def test_while_acquiring_a_range_moves_theta_but_never_w_r_or_the_scale():
    """Schmidt consider states: a wrong echo accepted while theta is acquired cannot drag
    w, the radius or the gyro's scale (the far-side reading of issue 20)."""
    m = TrainTracker(rung="e8", beams=BEAMS, radius=0.57, radius_var0=0.0025)
    for s in run_samples(40.0):
        m.process(s)
        if m.seeded and not m.locked:
            break
    assert m.seeded and not m.locked
    x0, P0 = m.ekf.x.copy(), m.ekf.P.copy()
    node = next(n for n, (px, py) in SONARS.items() if m._in_beam(n, x0, px, py))
    px, py = SONARS[node]
    echo = math.hypot(x0[0] - px, x0[1] - py) + 0.25  # a bounce: 25 cm long, within the gate
    m.process(sample("sonar", node, 999, m.t, echo, px, py))
    assert not m.rejected and not m.locked
    moved = m.ekf.x - x0
    assert moved[2] != 0.0  # theta took it
    for i in (3, 4, m.k_i):  # w, r, k did not, nor their covariance
        assert moved[i] == 0.0 and m.ekf.P[i, i] == P0[i, i]


@pytest.mark.parametrize("rung", ["e4", "e6", "e7", "e9"])
@pytest.mark.parametrize("omega", [0.84, -0.84])
def test_both_directions_of_travel(rung, omega):
    m = TrainTracker(rung=rung, beams=BEAMS)
    for s in run_samples(30.0, omega=omega, mag=0.0):
        m.process(s)
    w = m.estimate()[1][m.w_i]
    assert w == pytest.approx(omega, rel=0.02)
    if rung != "e4":
        assert theta_err(m, m.t, omega=omega) < 5


def test_e9_learns_the_magnetometers_heading_offset():
    offset = math.radians(25)  # the train was not placed exactly "at 0 deg"
    m = TrainTracker(rung="e9", beams=BEAMS)
    for s in run_samples(40.0, mag=offset):
        m.process(s)
    assert m.ekf.x[m.b_i] == pytest.approx(offset, abs=math.radians(3))
    assert theta_err(m, m.t) < 3
    assert m.estimate()[1][4] == pytest.approx(R, abs=0.01)  # the radius is not pulled


def test_a_w_at_zero_is_not_stuck_the_acc_slope_is_taken_statistically():
    """At w = 0 the point slope of a_c = r w |w| is 0: a plain EKF would never move."""
    m = TrainTracker(rung="e4", radius=R, omega0=0.5)
    m.ekf.reset(np.array([0.0]), np.array([[0.3]]))
    for i in range(400):
        m.process(sample("nav", "n", i, 1.0 + 0.01 * i, -R * 0.84**2, 0.0))
    assert m.estimate()[1][0] == pytest.approx(-0.84, rel=0.02)
    assert folded_mean(0.0, 1.0) == pytest.approx(math.sqrt(2 / math.pi))
    assert folded_mean(3.0, 0.01) == pytest.approx(3.0)
    assert folded_mean(-3.0, 0.0) == 3.0


def test_lock_and_wrong_branch_metrics():
    t = np.arange(0.0, 40.0, 0.1)
    omega = 2 * math.pi / 8.0  # 8 s laps
    truth = omega * t
    good = truth + np.radians(np.where(t < 6.0, 90.0, 5.0))  # on the branch from 6 s
    s = branch_scores(t, good, truth, omega)
    assert s["lock_laps"] == pytest.approx(6.0 / 8.0, abs=0.02) and s["wrong_laps"] == 0.0
    # 10 s (1.25 laps) on a wrong branch after the lock: the metric must see it
    bad = good + np.radians(np.where((t > 20) & (t < 30), 120.0, 0.0))
    s = branch_scores(t, bad, truth, omega)
    assert s["wrong_laps"] == pytest.approx(10.0 / 8.0, abs=0.03)
    never = branch_scores(t, truth + math.pi, truth, omega)
    assert never["lock_laps"] is None
    assert lock_time(t, t > 35, 8.0) == pytest.approx(35.1)  # less than a lap left: to the end
    assert longest_span(t, (t > 1) & (t < 2)) == pytest.approx(0.9)
