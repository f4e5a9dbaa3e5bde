"""Error model of the simulated Pmod NAV (LSM9DS1 accelerometer/gyroscope/magnetometer and
LPS25HB barometer), in the driver's units.
Sources of every default: the README, "Simulated boards and their error models".

Reading models (board frame, see :mod:`hera.nodes.driver`):

- accelerometer (g): ``a = (1 + s_a) * (R_m^T R^T (acc + g_up)) / G + b_a + n_a + v_a``
  (+ ``acc_run_bias`` while the board is not held still for a calibration);
- gyroscope (deg/s): ``w = (1 + s_g) * deg(R_m^T omega) + b_g + walk(t) + n_g + v_g``;
- magnetometer (gauss): ``m = S R_m^T R^T B_earth + h + n_m`` (soft iron S, hard iron h);
- barometer (hPa): ``p = p_ISA(altitude + z) + b_p + n_p``;

with R the body orientation, R_m the mounting rotation of the board on the body (tilt,
thesis app. B fig. B.1), s scale errors, b constant biases, walk a random walk, n white noise,
v the vehicle's vibration (scenario). A read fails (no reading) with ``miss_prob``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from typing import Any

from hera.nodes import geometry as gm
from hera.nodes.geometry import Quat, Vec3
from hera.nodes.world import Environment, G, Motion


@dataclass(frozen=True)
class NavModel:
    """Parameters of the NAV error model. ``None`` biases/scales are drawn once per board
    from the board seed with the matching ``*_sigma``."""

    # Accelerometer (g).
    acc_noise: float = 0.005  # white noise std per axis
    acc_bias: Vec3 | None = None
    acc_bias_sigma: float = 0.02  # LSM9DS1 data sheet: zero-g level offset +/-90 mg (typ.)
    acc_scale: Vec3 | None = None
    acc_scale_sigma: float = 0.01
    # Gyroscope (deg/s).
    gyro_noise: float = 0.1
    gyro_bias: Vec3 | None = None
    gyro_bias_sigma: float = 1.0  # LSM9DS1 data sheet: zero-rate level +/-30 dps (typ.)
    gyro_drift: float = 0.01  # random walk of the bias, deg/s per sqrt(s)
    gyro_scale: Vec3 | None = None
    gyro_scale_sigma: float = 0.003  # thesis ch. 6.4: the gyro alone converged to the true omega
    # Bias that differs between the still calibration and the run (g): warm-up, a
    # calibration spot not level with the track; the calibration cannot see it.
    acc_run_bias: Vec3 | None = None
    acc_run_bias_sigma: float = 0.0
    # Magnetometer (gauss).
    mag_noise: float = 0.003
    hard_iron: Vec3 = (0.12, -0.2, 0.08)
    soft_iron: tuple[Vec3, Vec3, Vec3] = ((1.02, 0.01, 0.0), (0.01, 0.97, 0.0), (0.0, 0.0, 1.0))
    # Barometer (hPa).
    baro_noise: float = 0.01  # LPS25HB data sheet: RMS noise 0.01 hPa (with averaging)
    baro_bias: float = 0.0
    # Mounting of the board on the body (deg): thesis app. B fig. B.1, tilt about 5 deg.
    tilt_roll_deg: float = 0.0
    tilt_pitch_deg: float = 5.0
    tilt_yaw_deg: float = 0.0
    # Readings the board fails to deliver (a busy bus, a slow board): probability per read.
    miss_prob: float = 0.0

    @classmethod
    def from_args(cls, table: Mapping[str, Any] | None) -> NavModel:
        """Build from a spec table (e.g. the measure arg ``model = {acc_noise = 0.01}``);
        ValueError names an unknown key or a bad value."""
        table = dict(table or {})
        known = {f.name: f for f in fields(cls)}
        unknown = set(table) - set(known)
        if unknown:
            raise ValueError(f"unknown NAV model keys {sorted(unknown)}; known: {sorted(known)}")
        out: dict[str, Any] = {}
        for key, value in table.items():
            if key == "soft_iron":
                rows = tuple(gm.vec3(r, "soft_iron row") for r in value)
                if len(rows) != 3:
                    raise ValueError("soft_iron must be a 3x3 matrix (list of 3 rows)")
                out[key] = rows
            elif key in (
                "acc_bias",
                "acc_scale",
                "acc_run_bias",
                "gyro_bias",
                "gyro_scale",
                "hard_iron",
            ):
                out[key] = None if value is None else gm.vec3(value, key)
            else:
                try:
                    out[key] = float(value)
                except (TypeError, ValueError):
                    raise ValueError(f"NAV model {key!r} must be a number, got {value!r}") from None
                if not math.isfinite(out[key]) or (
                    (key.endswith("_noise") or key.endswith("_sigma") or key == "gyro_drift")
                    and out[key] < 0
                ):
                    raise ValueError(f"NAV model {key!r} must be finite and >= 0, got {value!r}")
        if not 0.0 <= out.get("miss_prob", 0.0) < 1.0:
            raise ValueError(f"NAV model 'miss_prob' must be in [0, 1), got {out['miss_prob']!r}")
        return replace(cls(), **out)

    @property
    def mount(self) -> Quat:
        """Board-to-body rotation of the mounting tilt."""
        return gm.from_euler(
            math.radians(self.tilt_roll_deg),
            math.radians(self.tilt_pitch_deg),
            math.radians(self.tilt_yaw_deg),
        )


def ideal_acc(m: Motion, mount: Quat) -> Vec3:
    """Specific force (g) an ideal accelerometer on the board reads: R_m^T R^T (a + g_up) / G."""
    body = gm.unrotate(m.orientation, (m.acceleration[0], m.acceleration[1], m.acceleration[2] + G))
    return gm.scale(gm.unrotate(mount, body), 1.0 / G)


def ideal_gyro(m: Motion, mount: Quat) -> Vec3:
    """Angular rate (deg/s) an ideal gyroscope on the board reads: deg(R_m^T omega_body)."""
    return gm.scale(gm.unrotate(mount, m.angular_rate), 180.0 / math.pi)


def ideal_mag(m: Motion, mount: Quat, env: Environment, extra: Vec3 | None = None) -> Vec3:
    """Earth's field (gauss) in the board frame: R_m^T R^T B_earth; ``extra`` (gauss, world
    frame) is a disturbance added to Earth's field (the ``field`` board fault)."""
    field = env.field if extra is None else gm.add(env.field, extra)
    return gm.unrotate(mount, gm.unrotate(m.orientation, field))


def ideal_baro(m: Motion, env: Environment) -> float:
    """Pressure (hPa) at the body's height."""
    return env.pressure(m.position[2])
