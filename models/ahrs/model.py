"""The AHRS fusion models: our error-state filter (:mod:`.mekf`) and the thesis's (e11,
:mod:`.thesis`), each fed the ``nav3`` samples of one board in time order.

Input ``nav3``: ``[acc (m/s^2), gyro (rad/s), mag (gauss)]`` in the body frame of a board
calibrated with ``calibration = "full"`` (see ``hera measures nav3``). The reference frame is
the world's: z up, magnetic north at ``north_deg`` from x (the world's ``mag_north_deg``).
Both models predict at every sample (the gyroscope's rate) and take dt from the samples'
measurement times; a model follows one board: ``board`` (a node name), or the first node
whose ``nav3`` it sees.

Published columns: the quaternion (body -> world, scalar first), yaw, pitch and roll (deg,
``R = Rz(yaw) Ry(pitch) Rx(roll)``); ours adds the standard deviations of its tilt and
heading (deg) and its estimates of the gyroscope's bias (deg/s) and scale errors (%, 0 when
they are not estimated: ``scale_std0 = 0``).
"""

from __future__ import annotations

import math
from typing import Any

from hera.models.ahrs.frames import world_reference
from hera.models.ahrs.mekf import Mekf, MekfSettings
from hera.models.ahrs.scoring import yaw_pitch_roll_deg
from hera.models.ahrs.thesis import ThesisAhrs
from hera.store import Sample

QUAT = ("qw", "qx", "qy", "qz")
ANGLES = ("yaw [deg]", "pitch [deg]", "roll [deg]")
STD = ("tilt std [deg]", "heading std [deg]")
BIAS = ("gyro bias x [deg/s]", "gyro bias y [deg/s]", "gyro bias z [deg/s]")
SCALE = ("gyro scale x [%]", "gyro scale y [%]", "gyro scale z [%]")


def check_common(settings: dict[str, Any]) -> None:
    """Check and take out the settings every AHRS model has: ``board`` and ``north_deg``."""
    board = settings.pop("board", None)
    if board is not None and not isinstance(board, str):
        raise ValueError(f"board must be a node name, got {board!r}")
    north = settings.pop("north_deg", 90.0)
    if isinstance(north, bool) or not isinstance(north, (int, float)) or not math.isfinite(north):
        raise ValueError(f"north_deg must be a number of degrees, got {north!r}")


class _Follow:
    """The board a model follows and its samples' checks."""

    inputs = ("nav3",)

    def __init__(self, board: str | None) -> None:
        self.board = board
        self.t: float | None = None
        self.late = 0
        self.other = 0

    def accept(self, sample: Sample) -> bool:
        if sample.name != "nav3" or len(sample.values) < 9:
            return False
        if self.board is None:
            self.board = sample.node
        if sample.node != self.board:
            self.other += 1
            return False
        return True


class AhrsModel(_Follow):
    """Our AHRS (:class:`.mekf.Mekf`). Settings: ``board``, ``north_deg`` (90) and the noise
    model and gates of :class:`.mekf.MekfSettings` (same names and units)."""

    columns = (*QUAT, *ANGLES, *STD, *BIAS, *SCALE)

    def __init__(
        self,
        board: str | None = None,
        north_deg: float = 90.0,
        gyro_noise: float | list[float] = MekfSettings.gyro_noise,
        gyro_scale: float = MekfSettings.gyro_scale,
        scale_std0: float = MekfSettings.scale_std0,
        scale_walk: float = MekfSettings.scale_walk,
        bias_walk: float = MekfSettings.bias_walk,
        acc_noise: float = MekfSettings.acc_noise,
        gravity: float = MekfSettings.gravity,
        mag_noise: float = MekfSettings.mag_noise,
        acc_gate: float = MekfSettings.acc_gate,
        mag_gate: float = MekfSettings.mag_gate,
        ext_tau: float = MekfSettings.ext_tau,
        acc_block: float = MekfSettings.acc_block,
        block_tau: float = MekfSettings.block_tau,
        ext_kappa_max: float = MekfSettings.ext_kappa_max,
        mag_norm_tol: float = MekfSettings.mag_norm_tol,
        mag_dip_tol_deg: float = MekfSettings.mag_dip_tol_deg,
        ref_tau: float = MekfSettings.ref_tau,
        reacquire_s: float = MekfSettings.reacquire_s,
        align_s: float = MekfSettings.align_s,
        bias_std0: float = MekfSettings.bias_std0,
        gyro_trapezoid: bool = MekfSettings.gyro_trapezoid,
        mag_mode: str = MekfSettings.mag_mode,
        dip_deg: float | None = MekfSettings.dip_deg,
        mag_step_sigma: float = MekfSettings.mag_step_sigma,
        step_tau: float = MekfSettings.step_tau,
    ) -> None:
        super().__init__(board)
        settings = MekfSettings(
            gyro_noise=gyro_noise,
            gyro_scale=gyro_scale,
            scale_std0=scale_std0,
            scale_walk=scale_walk,
            bias_walk=bias_walk,
            acc_noise=acc_noise,
            gravity=gravity,
            mag_noise=mag_noise,
            acc_gate=acc_gate,
            mag_gate=mag_gate,
            ext_tau=ext_tau,
            acc_block=acc_block,
            block_tau=block_tau,
            ext_kappa_max=ext_kappa_max,
            mag_norm_tol=mag_norm_tol,
            mag_dip_tol_deg=mag_dip_tol_deg,
            ref_tau=ref_tau,
            reacquire_s=reacquire_s,
            align_s=align_s,
            bias_std0=bias_std0,
            gyro_trapezoid=gyro_trapezoid,
            mag_mode=mag_mode,
            dip_deg=dip_deg,
            mag_step_sigma=mag_step_sigma,
            step_tau=step_tau,
        )
        self.filter = Mekf(world_reference(north_deg), settings)

    @classmethod
    def check(cls, settings: dict[str, Any]) -> None:
        """Raise ValueError naming a bad setting, without building the filter (whose
        kernels may be compiled)."""
        s = dict(settings)
        check_common(s)
        MekfSettings(**s)

    def process(self, sample: Sample) -> bool:
        """Predict to the sample's time and fuse it; True once the estimate moved."""
        if not self.accept(sample):
            return False
        v = sample.values
        f = self.filter
        if not f.step(sample.t, v[0:3], v[3:6], v[6:9]):
            if f.started:
                self.late += 1
            return False
        return True

    def estimate(self) -> tuple[float, list[float]] | None:
        f = self.filter
        if f.t is None:
            return None
        q = [float(x) for x in f.q]
        ypr = yaw_pitch_roll_deg(q)[0]
        tilt, heading = f.std_deg()
        bias = [math.degrees(float(b)) for b in f.b]
        scale = [100.0 * float(k) for k in f.scale]
        return f.t, [*q, *(float(a) for a in ypr), tilt, heading, *bias, *scale]

    def counters(self) -> dict[str, int]:
        """Accelerometer and magnetometer samples fused or refused (``mag_disturbed``: the
        field's norm or dip out of its window), headings re-acquired, samples of another
        board (``other``) or older than the filter (``late``)."""
        return {**self.filter.counters, "other": self.other, "late": self.late}


class ThesisAhrsModel(_Follow):
    """The thesis's AHRS, e11 (:class:`.thesis.ThesisAhrs`). Settings: ``board``,
    ``north_deg`` (90), ``q_var`` (1e-3 per step) and ``r_var`` (1e-2), thesis eq. 7.4."""

    columns = (*QUAT, *ANGLES)

    def __init__(
        self,
        board: str | None = None,
        north_deg: float = 90.0,
        q_var: float = 1e-3,
        r_var: float = 1e-2,
    ) -> None:
        super().__init__(board)
        self.filter = ThesisAhrs(world_reference(north_deg), q_var, r_var)

    @classmethod
    def check(cls, settings: dict[str, Any]) -> None:
        """Raise ValueError naming a bad setting."""
        s = dict(settings)
        check_common(s)
        ThesisAhrs(world_reference(), **s)

    def process(self, sample: Sample) -> bool:
        if not self.accept(sample):
            return False
        v = sample.values
        return self.filter.step(sample.t, v[0:3], v[3:6], v[6:9])

    def estimate(self) -> tuple[float, list[float]] | None:
        f = self.filter
        if f.t is None:
            return None
        q = [float(x) for x in f.q]
        return f.t, [*q, *(float(a) for a in yaw_pitch_roll_deg(q)[0])]

    def counters(self) -> dict[str, int]:
        """Samples of another board (``other``), unusable or older than the filter
        (``skipped``)."""
        return {"other": self.other, "skipped": self.filter.skipped}
