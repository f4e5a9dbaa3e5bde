"""Calibrations of the Pmod NAV (thesis ch. 3.2.1, 6.6, 7.1.1) and where they are kept.

Pure computations (no I/O) and routines that drive a board through a calibration. A routine
takes a ``turn(axis, degrees)`` callable for the steps where a person turns the board: the
simulator does it itself (:meth:`SimNavBoard.turn`); for a real board pass a function that
asks the operator and waits. Results are plain dicts (msgpack-able) stored in the replicated
args store under ``calib/<node>/<measure>`` and read back first, so a restarted measure
never recalibrates (REFERENCE "Core framework"; thesis ch. 4 "Workers restarting").
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager, nullcontext
from typing import Any

from hera.measure import MeasureContext
from hera.nodes.driver import NavDriver, NoReading
from hera.nodes.geometry import Vec3, wrap_angle

Turn = Callable[[str, float], None]


def mean3(samples: Sequence[Vec3]) -> Vec3:
    """Component-wise mean of 3-vectors (ValueError if empty)."""
    if not samples:
        raise ValueError("no samples to average")
    n = float(len(samples))
    return (
        sum(s[0] for s in samples) / n,
        sum(s[1] for s in samples) / n,
        sum(s[2] for s in samples) / n,
    )


def hard_iron_2d(m1: Vec3, m2: Vec3) -> tuple[float, float]:
    """Hard-iron bias (b_x, b_y) from readings before and after a 180 deg turn about z:
    b = (m1 + m2) / 2 (thesis ch. 6.6, steps 1-4)."""
    return ((m1[0] + m2[0]) / 2.0, (m1[1] + m2[1]) / 2.0)


def hard_iron_3d(m1: Vec3, m2: Vec3, m3: Vec3) -> Vec3:
    """Hard-iron bias from readings flat (m1), after 180 deg about z (m2) and then 180 deg
    about x (m3): b_x, b_y from m1, m2; b_z from m1, m3 (thesis ch. 7.1.1, steps 1-6)."""
    return ((m1[0] + m2[0]) / 2.0, (m1[1] + m2[1]) / 2.0, (m1[2] + m3[2]) / 2.0)


def tilt_sin(acc_mean: Vec3) -> float:
    """sin(theta) of the board's tilt about y, from the still mean (g): the x axis reads
    g sin(theta) of gravity (thesis eq. 3.7), with |g| taken as 1 g as in the original."""
    return max(-1.0, min(1.0, -acc_mean[0]))


def rotate_y(v: Vec3, sin_t: float) -> Vec3:
    """Rotate ``v`` about y by the tilt angle theta (thesis eq. 3.11, a_theta = R_y a)."""
    cos_t = math.sqrt(1.0 - sin_t * sin_t)
    return (cos_t * v[0] + sin_t * v[2], v[1], -sin_t * v[0] + cos_t * v[2])


def heading(mx: float, my: float, bias: Sequence[float], offset: float) -> float:
    """atan2(m_y - b_y, m_x - b_x) - offset, wrapped to [-pi, pi) (thesis eq. 6.6)."""
    return wrap_angle(math.atan2(my - bias[1], mx - bias[0]) - offset)


def _read_mag(nav: NavDriver, n: int) -> Vec3:
    return mean3([_retry(nav.read_mag) for _ in range(n)])


def _retry(read: Callable[[], Any], tries: int = 20) -> Any:
    for _ in range(tries - 1):
        try:
            return read()
        except NoReading:
            continue
    return read()


def _held(nav: NavDriver) -> AbstractContextManager[Any]:
    hold = getattr(nav, "hold_still", None)
    return hold() if hold is not None else nullcontext()


def default_turn(nav: NavDriver) -> Turn:
    """The simulator's own ``turn``; a real driver has none (pass one that asks a person)."""
    turn = getattr(nav, "turn", None)
    if turn is None:
        raise ValueError("this board cannot turn itself: pass turn=<function asking a person>")
    return turn


def calibrate_nav(nav: NavDriver, n: int = 500) -> dict[str, Any]:
    """Means of ``n`` still samples of the accelerometer (g) and gyroscope (deg/s), and the
    tilt sin(theta) (REFERENCE "nav": mean of 500 still samples; thesis ch. 3.2.1)."""
    with _held(nav):
        acc = mean3([_retry(nav.read_acc) for _ in range(n)])
        gyro = mean3([_retry(nav.read_gyro) for _ in range(n)])
    return {"acc": list(acc), "gyro": list(gyro), "sin_tilt": tilt_sin(acc), "n": n}


def calibrate_mag(nav: NavDriver, turn: Turn | None = None, n: int = 10) -> dict[str, Any]:
    """Hard-iron bias from two means of ``n`` readings 180 deg apart about z (thesis ch. 6.6),
    then the heading ``offset`` of the board in its "0 deg" pose (turned back)."""
    with _held(nav):
        turn = turn or default_turn(nav)
        m1 = _read_mag(nav, n)
        turn("z", 180.0)
        m2 = _read_mag(nav, n)
        turn("z", -180.0)
        bias = hard_iron_2d(m1, m2)
        m0 = _read_mag(nav, n)
    offset = math.atan2(m0[1] - bias[1], m0[0] - bias[0])
    return {"bias": list(bias), "offset": offset, "n": n}


def calibrate_nav3(
    nav: NavDriver, turn: Turn | None = None, n_gyro: int = 300, n_mag: int = 10
) -> dict[str, Any]:
    """Gyroscope bias (mean of ``n_gyro`` still samples, deg/s) and the 3-D hard-iron bias
    (gauss) by the turns of thesis ch. 7.1.1 (z 180 deg, then x 180 deg)."""
    with _held(nav):
        turn = turn or default_turn(nav)
        gyro = mean3([_retry(nav.read_gyro) for _ in range(n_gyro)])
        m1 = _read_mag(nav, n_mag)
        turn("z", 180.0)
        m2 = _read_mag(nav, n_mag)
        turn("x", 180.0)
        m3 = _read_mag(nav, n_mag)
        turn("x", -180.0)
        turn("z", -180.0)
    return {"gyro": list(gyro), "mag": list(hard_iron_3d(m1, m2, m3)), "n": n_gyro}


def calib_key(ctx: MeasureContext) -> str:
    """``calib/<node>/<measure name>``: where a measure's calibration lives in ``ctx.args``."""
    return f"calib/{ctx.node}/{ctx.spec.name}"


def stored_or_run(
    ctx: MeasureContext, run: Callable[[], dict[str, Any]], check: Callable[[Any], bool]
) -> dict[str, Any]:
    """The calibration stored for this measure if ``check`` accepts it, else ``run()`` it
    and store the result (so a restarted measure does not recalibrate)."""
    key = calib_key(ctx)
    held = ctx.args.get(key)
    if held is not None and check(held):
        return dict(held)
    if held is not None:
        ctx.log.warning("ignoring malformed calibration %s = %r; recalibrating", key, held)
    result = run()
    ctx.args.put(key, result)
    return result


def is_vec(value: Any, n: int = 3) -> bool:
    """True if ``value`` is a list of ``n`` finite numbers."""
    return (
        isinstance(value, (list, tuple))
        and len(value) == n
        and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
            for v in value
        )
    )
