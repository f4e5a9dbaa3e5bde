"""A ToF sensor's range to the desk from the board's height and tilt (what the seed lacks).

Board frame: x right, y forward, z up, origin at the centre sensor; the board's orientation
is R = Ry(pitch) Rx(roll) (yaw does not change a range to a level desk). A sensor at (x, y)
on the board sits at height z = h - x sin(pitch) + y sin(roll) cos(pitch) and looks along the
board's -z axis, whose vertical component is -cos(roll) cos(pitch), so its range is

    d = h / (cos r cos p) - x tan p / cos r + y tan r                       (m, rad)

with the partial derivatives of :func:`range_jacobian` (h is the height of the board's
origin: the centre sensor's point).
"""

from __future__ import annotations

import math


def range_of(h: float, pitch: float, roll: float, x: float, y: float) -> float:
    """The range (m) a sensor at (x, y) on the board reads (module docstring)."""
    cp, cr = math.cos(pitch), math.cos(roll)
    return h / (cr * cp) - x * math.tan(pitch) / cr + y * math.tan(roll)


def range_jacobian(h: float, pitch: float, roll: float, x: float, y: float) -> tuple[float, ...]:
    """(dd/dh, dd/dpitch, dd/droll) of :func:`range_of`."""
    cp, cr = math.cos(pitch), math.cos(roll)
    sp, sr = math.sin(pitch), math.sin(roll)
    tp = sp / cp
    return (
        1.0 / (cr * cp),
        (h * sp - x) / (cr * cp * cp),
        (h * sr / cp - x * tp * sr) / (cr * cr) + y / (cr * cr),
    )
