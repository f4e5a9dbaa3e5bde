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

import numpy as np

from hera.measure import MeasureContext, NotReady
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


class CannotTurn(ValueError):
    """A calibration needs the board turned and the board cannot turn itself (a real one)."""


def default_turn(nav: NavDriver) -> Turn:
    """The simulator's own ``turn``; a real driver has none (pass one that asks a person):
    :class:`CannotTurn`."""
    turn = getattr(nav, "turn", None)
    if turn is None:
        raise CannotTurn(
            "this board cannot turn itself: calibrate it by hand, a person turning it "
            "(turn=<a function asking them>)"
        )
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


def ellipsoid_fit(
    samples: Sequence[Vec3], radius: float | None = None
) -> tuple[Vec3, list[list[float]]]:
    """Offset and scale correction of a 3-axis sensor that reads a vector of fixed length in
    any orientation (Earth's field, gravity), from readings taken in many orientations:
    ``v = W (m - c)`` lies on a sphere (AN4246 for a magnetometer: hard and soft iron, the
    soft-iron calibration thesis ch. 7.1.1 left out; the "six faces" calibration of an
    accelerometer: bias and scale).

    Fits the quadric ``x^T A x + 2 b^T x = 1`` by least squares, then ``c = -A^-1 b`` and
    ``W`` the symmetric square root of ``A / (1 + c^T A c)`` (a sphere of radius 1), times
    ``radius``, or when ``radius`` is None scaled to keep the mean radius (W of determinant
    1: the corrected readings stay in the sensor's units). Returns (c, W rows). ValueError if
    the readings do not determine an ellipsoid (too few or too flat poses).
    """
    m = np.asarray(samples, dtype=np.float64).reshape(-1, 3)
    if len(m) < 9:
        raise ValueError(f"an ellipsoid fit needs at least 9 readings, got {len(m)}")
    x, y, z = m[:, 0], m[:, 1], m[:, 2]
    D = np.column_stack((x * x, y * y, z * z, 2 * x * y, 2 * x * z, 2 * y * z, 2 * x, 2 * y, 2 * z))
    sv = np.linalg.svd(D, compute_uv=False)
    if not sv[-1] > 1e-9 * sv[0]:
        raise ValueError(
            "the readings do not determine an ellipsoid: the poses do not spread the vector "
            "over enough directions"
        )
    v, *_ = np.linalg.lstsq(D, np.ones(len(m)), rcond=None)
    A = np.array(((v[0], v[3], v[4]), (v[3], v[1], v[5]), (v[4], v[5], v[2])))
    try:
        c = -np.linalg.solve(A, v[6:9])
    except np.linalg.LinAlgError:
        raise ValueError("the readings do not determine an ellipsoid") from None
    M = A / (1.0 + float(c @ A @ c))
    lam, V = np.linalg.eigh(M)
    if not (np.all(lam > 0) and np.all(np.isfinite(lam))):
        raise ValueError("the readings do not lie on an ellipsoid (too few poses?)")
    k = float(np.prod(lam)) ** (-1.0 / 6.0) if radius is None else float(radius)
    W = (V * np.sqrt(lam)) @ V.T * k
    return (float(c[0]), float(c[1]), float(c[2])), W.tolist()


def level_rotation(acc_mean: Vec3) -> list[list[float]]:
    """The rotation (rows of a 3x3 matrix) taking a board's axes to its body's when the body
    is level at rest: the shortest turn carrying the still mean of the accelerometer (bias
    removed) onto +z (the tilt correction of thesis eqs. 3.7-3.11, in 3-D). The yaw of the
    board on its body cannot be seen by gravity and is taken as zero."""
    a = np.asarray(acc_mean, dtype=np.float64)
    n = float(np.linalg.norm(a))
    if not n > 0:
        raise ValueError("the accelerometer read zero at rest: cannot level the board")
    u = a / n
    axis = np.cross(u, (0.0, 0.0, 1.0))
    s, c = float(np.linalg.norm(axis)), float(u[2])
    if s < 1e-12:
        return np.eye(3).tolist() if c > 0 else np.diag((1.0, -1.0, -1.0)).tolist()
    k = axis / s
    K = np.array(((0.0, -k[2], k[1]), (k[2], 0.0, -k[0]), (-k[1], k[0], 0.0)))
    return (np.eye(3) + s * K + (1.0 - c) * (K @ K)).tolist()


def _mean_acc(nav: NavDriver, n: int) -> Vec3:
    return mean3([_retry(nav.read_acc) for _ in range(n)])


def _poses(nav: NavDriver, turn: Turn, n: int) -> tuple[list[Vec3], list[Vec3]]:
    """Mean accelerometer and magnetometer readings (``n`` each) in 48 orientations: the
    board rolled about its x axis in steps of 45 deg, and at each roll turned about its z
    axis in steps of 60 deg, so that gravity and Earth's field sweep the sphere of
    directions in the board's frame (steps of 90 deg would not do: their symmetry leaves
    the fit undetermined). The board ends where it started."""
    acc, mag = [], []
    for _ in range(8):
        for _ in range(6):
            acc.append(_mean_acc(nav, n))
            mag.append(_read_mag(nav, n))
            turn("z", 60.0)
        turn("x", 45.0)
    return acc, mag


def _apply(W: Sequence[Sequence[float]], c: Sequence[float], v: Vec3) -> Vec3:
    d = (v[0] - c[0], v[1] - c[1], v[2] - c[2])
    return (
        W[0][0] * d[0] + W[0][1] * d[1] + W[0][2] * d[2],
        W[1][0] * d[0] + W[1][1] * d[1] + W[1][2] * d[2],
        W[2][0] * d[0] + W[2][1] * d[1] + W[2][2] * d[2],
    )


def calibrate_nav3(
    nav: NavDriver,
    turn: Turn | None = None,
    n_gyro: int = 300,
    n_mag: int = 10,
    *,
    full: bool = False,
    n_pose: int = 50,
) -> dict[str, Any]:
    """Gyroscope bias (mean of ``n_gyro`` still samples, deg/s) and the 3-D hard-iron bias
    (gauss) by the turns of thesis ch. 7.1.1 (z 180 deg, then x 180 deg).

    ``full``: beyond the thesis, the gyroscope bias as before, then readings in 48 poses
    (``n_pose`` each, :func:`_poses`) for two :func:`ellipsoid_fit`: the accelerometer's
    bias ``acc_bias`` (g) and scale ``acc_scale`` (3x3 rows, to a 1 g sphere) and the
    magnetometer's hard iron
    ``mag`` and soft iron ``soft_iron`` (3x3 rows); and the board's :func:`level_rotation`
    on its body, ``mount`` (3x3 rows), from the corrected accelerometer at rest (the body is
    taken to be level in the pose the board is calibrated in)."""
    with _held(nav):
        turn = turn or default_turn(nav)
        gyro = mean3([_retry(nav.read_gyro) for _ in range(n_gyro)])
        if full:
            rest = _mean_acc(nav, n_gyro)
            accs, mags = _poses(nav, turn, n_pose)
            acc_bias, acc_scale = ellipsoid_fit(accs, radius=1.0)
            hard, soft = ellipsoid_fit(mags)
            return {
                "gyro": list(gyro),
                "n": n_gyro,
                "acc_bias": list(acc_bias),
                "acc_scale": acc_scale,
                "mag": list(hard),
                "soft_iron": soft,
                "mount": level_rotation(_apply(acc_scale, acc_bias, rest)),
            }
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
    and store the result (so a restarted measure does not recalibrate). A calibration that
    needs a person (:class:`CannotTurn`) is NotReady: the measure waits until one is stored
    (``hera args set NODE calib/NODE/MEASURE JSON``) and then starts with it."""
    key = calib_key(ctx)
    held = ctx.args.get(key)
    if held is not None and check(held):
        return dict(held)
    if held is not None:
        ctx.log.warning("ignoring malformed calibration %s = %r; recalibrating", key, held)
    try:
        result = run()
    except CannotTurn as e:
        raise NotReady(
            f"no calibration stored at {key}, and {e}; store its result with "
            f"'hera args set {ctx.node} {key} JSON' (README: a real Pmod NAV)"
        ) from None
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
