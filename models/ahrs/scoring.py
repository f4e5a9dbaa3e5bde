"""Attitude errors: how far an estimated orientation is from the truth, split into heading
and tilt.

Quaternions are scalar first and rotate body -> world (z up). For an estimate ``q_est`` and
the truth ``q_true``:

- the attitude error is the angle of ``q_est^-1 q_true`` (deg): the smallest rotation that
  takes the estimate onto the truth;
- the tilt error is the angle between the world's up seen in the body by the estimate and
  by the truth, ``R_est^T z`` and ``R_true^T z`` (deg): roll and pitch together, blind to
  heading;
- the heading error is the twist about the world's up of ``q_true q_est^-1`` (the error in
  the world frame), signed, in (-180, 180] deg: the part of the error a compass would see.
"""

from __future__ import annotations

import numpy as np


def _arr(q: object) -> np.ndarray:
    a = np.asarray(q, dtype=np.float64)
    return a.reshape(-1, 4)


def conj(q: np.ndarray) -> np.ndarray:
    """Conjugates of an (N, 4) array of quaternions."""
    return q * np.array((1.0, -1.0, -1.0, -1.0))


def mul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Row-wise Hamilton products ``p * q`` of (N, 4) arrays."""
    w1, x1, y1, z1 = p.T
    w2, x2, y2, z2 = q.T
    return np.column_stack(
        (
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        )
    )


def normalised(q: object) -> np.ndarray:
    """Unit quaternions (rows)."""
    a = _arr(q)
    return a / np.linalg.norm(a, axis=1, keepdims=True)


def attitude_error_deg(q_est: object, q_true: object) -> np.ndarray:
    """Angle of ``q_est^-1 q_true`` (deg), per row; in [0, 180]."""
    e = mul(conj(normalised(q_est)), normalised(q_true))
    return np.degrees(2.0 * np.arccos(np.clip(np.abs(e[:, 0]), 0.0, 1.0)))


def up_in_body(q: object) -> np.ndarray:
    """The world's up, ``R(q)^T z``, in the body frame (rows)."""
    w, x, y, z = normalised(q).T
    return np.column_stack((2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)))


def tilt_error_deg(q_est: object, q_true: object) -> np.ndarray:
    """Angle (deg) between the world's up in the body by the estimate and by the truth."""
    d = np.sum(up_in_body(q_est) * up_in_body(q_true), axis=1)
    return np.degrees(np.arccos(np.clip(d, -1.0, 1.0)))


def heading_error_deg(q_est: object, q_true: object) -> np.ndarray:
    """Signed twist (deg) about the world's up of the world-frame error ``q_true q_est^-1``
    (swing-twist decomposition: the twist's quaternion is ``(w, 0, 0, z)`` normalised)."""
    e = mul(normalised(q_true), conj(normalised(q_est)))
    ang = 2.0 * np.arctan2(e[:, 3], e[:, 0])
    return np.degrees((ang + np.pi) % (2.0 * np.pi) - np.pi)


def yaw_pitch_roll_deg(q: object) -> np.ndarray:
    """Rows of (yaw, pitch, roll) in deg, ``R = Rz(yaw) Ry(pitch) Rx(roll)``."""
    w, x, y, z = normalised(q).T
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    return np.degrees(np.column_stack((yaw, pitch, roll)))
