"""``train_rough``: the toy train as a real rig shows it, not as the thesis's models assume.

What recordings of a real toy-train rig (low-rate boards, real MaxSonars, a real Pmod NAV)
show and the plain ``train`` world does not, each a world key or a board-model default here
(a measure's ``model`` arg and the world table override them):

- sonars: echoes from the nearest surface within about 30 deg of the beam's axis
  (``half_angle_deg`` 30), missed pings (``miss_prob``), bounces that come back longer
  (``multipath_prob``), echoes of the far side of the track when the train is out of the
  beam (``clutter_prob``);
- low, jittery rates: boards that miss readings (``miss_prob`` of the NAV; the spec's
  periods set the nominal rates: ``deploy/train_rough.toml`` has nav 4-7 Hz, sonars
  1.4-3 Hz as logged by real boards);
- gyroscope scale error +-2 % (``gyro_scale_sigma`` 1 %, drawn per board);
- accelerometer: scale (3 %), a bias the still calibration cannot see (``acc_run_bias``,
  0.002 g: 5-7 % of a_c = r w^2 at 0.6 m and 0.6-0.84 rad/s), a mounting misalignment
  (2 deg roll, 3 deg yaw), a table that is not level (``tilt_deg`` up to 0.15: the still
  calibration, done at one place of the lap, leaves up to 0.026 m/s^2), so a_c / w^2 can
  be off by about 20 %;
- magnetometer: the train placed for calibration up to 30 deg away from where "0 deg" is
  (``rest_phase_deg``: the heading is offset by as much), strong soft iron (up to ~6 deg);
- rails that are not a perfect circle: centre line radius 0.585-0.600 m with a 6 mm
  two-lobe out-of-roundness (``out_of_round``), within the thesis's rails (0.57-0.615 m).

Keys the world table leaves out are drawn from its ``seed`` (so one key gives a new rig; the
boards' own constants are drawn from their seeds, which mix in the world's seed): the
radius, ``round_phase_deg``, ``rest_phase_deg``, ``tilt_deg``, ``tilt_axis_deg`` and the
start ``phase`` (rad). ``omega`` defaults to 0.7 rad/s (the rig of the recordings);
negative runs clockwise.
"""

from __future__ import annotations

import math
import random
from collections.abc import Mapping
from typing import Any

from hera.nodes.world import TRAIN_KEYS, Train, number, register_scenario, train_from

NAV_ROUGH: Mapping[str, Any] = {
    "gyro_scale_sigma": 0.01,
    "acc_scale_sigma": 0.03,
    "acc_run_bias_sigma": 0.002,
    "tilt_roll_deg": 2.0,
    "tilt_yaw_deg": 3.0,
    "soft_iron": ((1.08, 0.04, 0.0), (0.04, 0.93, 0.0), (0.0, 0.0, 1.0)),
    "miss_prob": 0.1,
}
"""NAV error-model defaults of the rough rig (see the module docstring)."""

SONAR_ROUGH: Mapping[str, Any] = {
    "half_angle_deg": 30.0,
    "noise_m": 0.015,
    "miss_prob": 0.15,
    "multipath_prob": 0.03,
    "multipath_max_m": 1.0,
    "clutter_prob": 0.25,
}
"""Sonar error-model defaults of the rough rig (see the module docstring)."""


def rough_train(world: Mapping[str, Any]) -> Train:
    """The ``train_rough`` scenario of a world table (see the module docstring)."""
    seed = int(number(world, "seed", 0.0))
    rng = random.Random(f"train_rough|{seed}")
    drawn = {
        "radius": rng.uniform(0.585, 0.600),
        "round_phase_deg": rng.uniform(0.0, 180.0),
        "rest_phase_deg": rng.uniform(-30.0, 30.0),
        "tilt_deg": rng.uniform(0.0, 0.15),
        "tilt_axis_deg": rng.uniform(0.0, 360.0),
        "phase": rng.uniform(-math.pi, math.pi),
    }
    train = train_from(world, omega=0.7, out_of_round=0.006, **drawn)
    train.nav_model = NAV_ROUGH
    train.sonar_model = SONAR_ROUGH
    return train


register_scenario("train_rough", TRAIN_KEYS, rough_train)
