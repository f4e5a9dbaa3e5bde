"""Small 3-D vector and quaternion helpers in plain Python (cheap for one sample at a time).

Conventions used throughout :mod:`hera.nodes`:

- vectors are 3-tuples of floats;
- a quaternion is ``(w, x, y, z)``, unit norm, and rotates **body to world**:
  ``v_world = rotate(q, v_body)``; ``rotate(conj(q), v_world)`` goes back to the body frame;
- the world frame is right-handed with z up (x east, y north by default); a body frame is
  right-handed with x forward, y left, z up.
"""

from __future__ import annotations

import math

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]

IDENTITY: Quat = (1.0, 0.0, 0.0, 0.0)
ZERO: Vec3 = (0.0, 0.0, 0.0)


def add(a: Vec3, b: Vec3) -> Vec3:
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def sub(a: Vec3, b: Vec3) -> Vec3:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def scale(a: Vec3, k: float) -> Vec3:
    return (a[0] * k, a[1] * k, a[2] * k)


def dot(a: Vec3, b: Vec3) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def cross(a: Vec3, b: Vec3) -> Vec3:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def norm(a: Vec3) -> float:
    return math.sqrt(dot(a, a))


def unit(a: Vec3) -> Vec3:
    """``a / |a|``; raises ValueError for the zero vector."""
    n = norm(a)
    if n == 0.0:
        raise ValueError("cannot normalise the zero vector")
    return scale(a, 1.0 / n)


def vec3(value: object, what: str) -> Vec3:
    """Coerce a 3-sequence of numbers to a Vec3, or raise ValueError naming ``what``."""
    try:
        x, y, z = (float(v) for v in value)  # type: ignore[union-attr]
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a list of 3 numbers, got {value!r}") from None
    if not all(math.isfinite(v) for v in (x, y, z)):
        raise ValueError(f"{what} must be finite, got {value!r}")
    return (x, y, z)


def quat_mul(a: Quat, b: Quat) -> Quat:
    """Hamilton product ``a * b`` (apply ``b`` first, then ``a``)."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def conj(q: Quat) -> Quat:
    return (q[0], -q[1], -q[2], -q[3])


def axis_angle(axis: Vec3, angle: float) -> Quat:
    """The rotation of ``angle`` rad about ``axis`` (right-hand rule)."""
    ux, uy, uz = unit(axis)
    s = math.sin(angle / 2.0)
    return (math.cos(angle / 2.0), ux * s, uy * s, uz * s)


def yaw(angle: float) -> Quat:
    """Rotation of ``angle`` rad about the world z axis (counter-clockwise seen from above)."""
    return (math.cos(angle / 2.0), 0.0, 0.0, math.sin(angle / 2.0))


def from_euler(roll: float, pitch: float, yaw_: float) -> Quat:
    """Body-to-world rotation ``Rz(yaw) Ry(pitch) Rx(roll)`` (angles in rad)."""
    qx = axis_angle((1.0, 0.0, 0.0), roll)
    qy = axis_angle((0.0, 1.0, 0.0), pitch)
    qz = axis_angle((0.0, 0.0, 1.0), yaw_)
    return quat_mul(qz, quat_mul(qy, qx))


def matrix(q: Quat) -> tuple[Vec3, Vec3, Vec3]:
    """The 3x3 rotation matrix (rows) of a unit quaternion."""
    w, x, y, z = q
    return (
        (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
    )


def mat_vec(m: tuple[Vec3, Vec3, Vec3], v: Vec3) -> Vec3:
    return (dot(m[0], v), dot(m[1], v), dot(m[2], v))


def mat_t_vec(m: tuple[Vec3, Vec3, Vec3], v: Vec3) -> Vec3:
    """``m^T v``."""
    return (
        m[0][0] * v[0] + m[1][0] * v[1] + m[2][0] * v[2],
        m[0][1] * v[0] + m[1][1] * v[1] + m[2][1] * v[2],
        m[0][2] * v[0] + m[1][2] * v[1] + m[2][2] * v[2],
    )


def rotate(q: Quat, v: Vec3) -> Vec3:
    """``R(q) v``: a body vector expressed in the world frame."""
    return mat_vec(matrix(q), v)


def unrotate(q: Quat, v: Vec3) -> Vec3:
    """``R(q)^T v``: a world vector expressed in the body frame."""
    return mat_t_vec(matrix(q), v)


def wrap_angle(a: float) -> float:
    """``a`` wrapped to ``[-pi, pi)`` rad."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi
