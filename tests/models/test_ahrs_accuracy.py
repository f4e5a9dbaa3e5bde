"""Our AHRS against the truth over several seeds of the thesis's benchmark tasks (ch. 7.1.3)
and under a magnetic disturbance, offline (the model objects the live measures run, fed the
simulated Pmod NAV's samples in time order: bias, scale errors, drift, noise, soft iron).

Targets (issue 11) with the worst run measured over 3 seeds x 3 start phases (README
"Attitude and heading"): mean attitude error <= 0.3 deg still (worst 0.13), <= 1 deg on
rotation_slow (0.12), <= 3 deg on rotation_fast (0.15), <= 1 deg while shaking (0.28 with the
accelerometer's block means, 0.99 without them), also at other shake frequencies; a 10 s
magnetic disturbance leaves the tilt as it was and the heading within 5 deg (still,
rotation_slow, shaking: worst 1.7 deg;
rotation_fast, where the heading rides on the gyroscope through 2.5 turns, worst 0.8 deg over
10 seeds with the gyroscope's scale errors estimated, 5.5 deg without: README).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from sim3d import run_ahrs

from hera.models.ahrs.frames import world_reference
from hera.models.ahrs.mekf import Mekf, MekfSettings
from hera.models.ahrs.scoring import heading_error_deg, tilt_error_deg
from hera.nodes.streams import nav3_stream
from hera.nodes.world import make_scenario, state_at

TARGETS = {"still": 0.3, "rotation_slow": 1.0, "rotation_fast": 3.0, "shaking": 1.0}


@pytest.mark.parametrize("scenario", list(TARGETS))
def test_mean_attitude_error_meets_the_target_on_every_seed_and_start(scenario):
    """3 seeds of the board (as node nav_1 of deploy/ahrs.toml) x 3 moments the filter
    starts at (the phase of the motion when it aligns)."""
    means = [
        run_ahrs(scenario, seed, start=start, node="nav_1").att.mean()
        for seed in range(3)
        for start in (3.0, 8.0, 13.0)
    ]
    assert max(means) <= TARGETS[scenario], (scenario, np.round(means, 3))


@pytest.mark.parametrize("frequency", [1.2, 2.0, 5.0, 8.0])
def test_a_1_g_shake_at_other_frequencies_meets_the_shaking_target(frequency):
    """Not only the thesis's 3 Hz: shakes of 1 g peak (the amplitude 10 m/s^2 / (2 pi f)^2,
    17.6 cm at 1.2 Hz down to 4 mm at 8 Hz) meet the shaking target too (measured worst over
    3 seeds x 2 starts: 0.73, 0.31, 0.26, 0.24 deg; the filter fusing every sample alone,
    ``acc_block = 0``: 3.58, 1.21, 1.49, 2.80)."""
    world = {"amplitude": 10.0 / (2.0 * math.pi * frequency) ** 2, "frequency": frequency}
    means = [
        run_ahrs("shaking", seed, 30.0, start=start, node="nav_1", world=world).att.mean()
        for seed in (0, 1)
        for start in (3.0, 8.0)
    ]
    assert max(means) <= 1.0, (frequency, np.round(means, 3))


def _shaken(settings: MekfSettings) -> tuple[np.ndarray, float, float]:
    """The filter over 30 s of the thesis's shake (board seed 2): (its mean standard
    deviations of tilt and heading after 10 s, deg; its mean tilt and |heading| errors)."""
    w = {"scenario": "shaking", "epoch": 0.0}
    sc = make_scenario(w)
    f = Mekf(world_reference(90.0), settings)
    sd, tilt, head = [], [], []
    for s in nav3_stream(w, 30.0, seed=2, start=3.0, node="nav_1").samples:
        v = s.values
        if f.step(s.t, v[0:3], v[3:6], v[6:9]) and s.t > 13.0:
            sd.append(f.std_deg())
            truth = state_at(sc, 0.0, s.t).orientation
            tilt.append(tilt_error_deg(f.q, truth)[0])
            head.append(abs(heading_error_deg(f.q, truth)[0]))
    return np.mean(sd, axis=0), float(np.mean(tilt)), float(np.mean(head))


def test_while_shaking_the_block_means_let_the_filter_know_its_tilt_so_the_compass_holds():
    """Fusing every sample alone (``acc_block = 0``), the filter counts the shake's power and
    believes its tilt to 4.3 deg (1 sigma) where it is within 0.3, so a heading read through
    that tilt (its tan(dip) = 2.1 leak) gets little weight and wanders with the gyroscope;
    with the block means it believes 0.3 deg, still above its errors."""
    (tilt_sd, head_sd), tilt, head = _shaken(MekfSettings())
    (tilt_sd0, head_sd0), tilt0, head0 = _shaken(MekfSettings(acc_block=0.0))
    assert tilt_sd0 > 3.0 and head_sd0 > 6.0, (tilt_sd0, head_sd0)
    assert tilt < tilt_sd < 1.0 and head < head_sd < 2.0, (tilt, tilt_sd, head, head_sd)
    assert tilt < tilt0 and head < head0, (tilt, tilt0, head, head0)


def test_the_thesis_filter_is_run_beside_it_and_fails_while_shaking():
    """Reported, not required: e11 has no gating, so a shake goes straight into its z."""
    ours = run_ahrs("shaking", 0).att.mean()
    thesis = run_ahrs("shaking", 0, thesis=True).att.mean()
    assert thesis > 10.0 > 1.0 > ours, (thesis, ours)


@pytest.mark.parametrize(
    "field",
    [
        [0.1, 0.0, 0.0],  # steel to the east: heading off by 26 deg, norm and dip nearly kept
        [0.0, -0.15, 0.25],  # a magnet: norm and dip far off
    ],
)
@pytest.mark.parametrize("scenario", ["still", "rotation_slow", "rotation_fast", "shaking"])
def test_a_magnetic_disturbance_of_10_s_leaves_tilt_alone_and_heading_within_5_deg(scenario, field):
    on, off = 3.0 + 15.0, 3.0 + 25.0  # epoch times: 15 s into the run, for 10 s
    events = [
        (on, lambda b: b.faults.set("field", sensor="mag", value=field)),
        (off, lambda b: b.faults.clear()),
    ]
    clean = run_ahrs(scenario, 1, 40.0)
    hit = run_ahrs(scenario, 1, 40.0, events=events)
    during = (hit.t >= on) & (hit.t < off)
    assert during.sum() > 900
    # the field never reaches the tilt: the same tilt errors as without the disturbance
    assert np.abs(hit.tilt[during] - clean.tilt[during]).max() < 0.05
    assert np.abs(hit.heading[during]).max() <= 5.0, np.abs(hit.heading[during]).max()
    refused = hit.counters["mag_rejected"] + hit.counters["mag_disturbed"]
    assert refused >= 900, hit.counters
    after = hit.t >= off + 2.0
    assert np.abs(hit.heading[after]).mean() <= np.abs(clean.heading[after]).mean() + 0.3


def test_through_a_disturbance_on_rotation_fast_the_heading_holds_on_every_seed():
    """While the magnetometer is refused for 10 s the board turns 2.5 times (900 deg) on the
    gyroscope alone: its scale error, learnt from the turns before, must not add up. 10 board
    seeds (the simulator draws 0.3 % per axis; the unit tests take 2 %)."""
    on, off = 18.0, 28.0
    events = [
        (on, lambda b: b.faults.set("field", sensor="mag", value=[0.1, 0.0, 0.0])),
        (off, lambda b: b.faults.clear()),
    ]
    worst = []
    for seed in range(10):
        hit = run_ahrs("rotation_fast", seed, 30.0, events=events)
        during = (hit.t >= on) & (hit.t < off)
        worst.append(np.abs(hit.heading[during]).max())
    assert max(worst) <= 2.5, np.round(worst, 2)
