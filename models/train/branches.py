"""Which branch is the train on? Hypotheses on its angle, weighed by every reading.

A sonar range is ambiguous in theta (the same range at several places of the lap), so an
EKF started or pushed onto a wrong branch can stay there: the readings that would correct
it are skipped (predicted outside the beam) or gated out. :class:`BranchGrid` keeps
hypotheses on the train's angle instead of one: cells of a grid over (phase, speed ratio),
cell (i, j) saying theta(t) = phi_j + s_i Omega(t), where Omega(t) is the tracker's own
integrated angular speed (int w dt) and s_i how far off that speed is (its sign: the
direction, when the rung cannot tell it otherwise). Each reading adds to every cell its
log-likelihood under a robust model (thesis ch. 3.5.1 "data association", with outliers):

- a sonar range the cell predicts in the beam: (1 - eps) N(range; h(theta), var) + eps d;
  one it predicts outside: d_out (an echo of something else: the far side of the track, a
  wall); near the beam's edge the better of the two;
- a position (bilateration): N(|p - p(theta)|; var) in the plane, with outliers.

Old evidence fades with time constant ``memory_s`` (a drifting speed ratio, a changed
speed), so the grid always says which branch the recent readings favour; the tracker seeds
its EKF from it and checks its locked EKF against it (:meth:`BranchGrid.best`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

TWO_PI = 2.0 * math.pi


@dataclass(frozen=True)
class Branch:
    """The grid's favoured branch: ``theta`` (rad, in (-pi, pi]) and its spread ``var``
    (rad^2), the speed ratio ``ratio`` (and its ``ratio_var``), and ``mass``: the posterior
    probability that the train is within ``cluster_deg`` of ``theta`` (with that sign of
    the ratio)."""

    theta: float
    var: float
    ratio: float
    ratio_var: float
    mass: float


def wrap(a: np.ndarray | float) -> np.ndarray | float:
    """Angle(s) wrapped to [-pi, pi)."""
    return (np.asarray(a) + math.pi) % TWO_PI - math.pi


@dataclass(frozen=True)
class Track:
    """What the grid needs to know of the track: its centre (m), the target's half length
    and radius (m, the capsule of the range model), the sonars' unit beam directions and
    the cosines of the beam's half-angle less and plus the edge margin."""

    center: tuple[float, float]
    half_length: float
    target_radius: float
    beams: Mapping[str, tuple[float, float]]
    cos_inner: float
    cos_outer: float


def capsule_ranges(
    theta: np.ndarray, radius: float, track: Track, px: float, py: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For trains at angles ``theta`` on a circle of ``radius``: the range from the sonar at
    (px, py) to the nearest surface of the capsule (thesis eq. 6.2 with the train's shape,
    as :meth:`TrainTracker._range`), and the vector (dx, dy) from the sonar to the nearest
    point of the capsule's axis (to test it against the beam)."""
    c, s = np.cos(theta), np.sin(theta)
    dx = track.center[0] + radius * c - px
    dy = track.center[1] + radius * s - py
    if track.half_length > 0.0:
        along = np.clip(-(dx * -s + dy * c), -track.half_length, track.half_length)
        dx, dy = dx - along * s, dy + along * c
    return np.hypot(dx, dy) - track.target_radius, dx, dy


class BranchGrid:
    """Hypotheses on the train's angle (see the module docstring).

    ``ratios``: the speed ratios s_i; ``bins``: phases per ratio (72: 5 deg); ``memory_s``:
    time constant of forgetting (s); ``eps``, ``d_in`` (1/m), ``d_out`` (1/m): the robust
    range model; ``cluster_deg``: the half-width of the favoured branch in :meth:`best`.
    """

    def __init__(
        self,
        track: Track,
        ratios: Sequence[float],
        bins: int = 72,
        memory_s: float = 30.0,
        eps: float = 0.1,
        d_in: float = 1.0 / 3.0,
        d_out: float = 0.1,
        cluster_deg: float = 30.0,
    ) -> None:
        if bins < 8 or not ratios:
            raise ValueError(f"a branch grid needs >= 8 bins and a ratio, got {bins}, {ratios}")
        self.track = track
        self.s = np.asarray(ratios, dtype=float)[:, None]
        self.phi = (np.arange(bins) * (TWO_PI / bins))[None, :]
        self.L = np.zeros((len(ratios), bins))
        self.memory = float(memory_s)
        self.log_in = (math.log1p(-eps), math.log(eps * d_in))
        self.log_eps = math.log(eps)
        self.log_out = math.log(d_out)
        self.cluster = math.radians(cluster_deg)
        self.bin_var = (TWO_PI / bins) ** 2 / 12.0
        self.omega_int = 0.0
        self.t: float | None = None
        self.readings = 0

    def advance(self, t: float, w: float) -> None:
        """Move every cell to time ``t``: Omega += w dt (``w``: the tracker's angular speed
        over the step), and let old evidence fade."""
        if self.t is not None and t > self.t:
            dt = t - self.t
            self.omega_int += w * dt
            self.L *= math.exp(-dt / self.memory)
        if self.t is None or t > self.t:
            self.t = t

    def thetas(self, ago: float = 0.0, speed: float = 0.0) -> np.ndarray:
        """The angle of every cell now (rad, not wrapped), or ``ago`` s earlier when the
        grid's reference speed was ``speed``."""
        return self.phi + self.s * (self.omega_int - speed * ago)

    def add_range(self, node: str, rng: float, px: float, py: float, radius: float, var: float):
        """Weigh the cells by one sonar range (m) from the sonar ``node`` at (px, py)."""
        tr = self.track
        pred, dx, dy = capsule_ranges(self.thetas(), radius, tr, px, py)
        nu = rng - pred
        log_n = -0.5 * (nu * nu / var + math.log(TWO_PI * var))
        a, b = self.log_in[0] + log_n, self.log_in[1]
        inside = np.logaddexp(a, b)
        d = tr.beams.get(node)
        if d is None:
            ll = inside
        else:
            cos = (dx * d[0] + dy * d[1]) / np.maximum(np.hypot(dx, dy), 1e-9)
            ll = np.where(
                cos >= tr.cos_inner,
                inside,
                np.where(cos >= tr.cos_outer, np.maximum(inside, self.log_out), self.log_out),
            )
        self._add(ll)

    def add_position(
        self, x: float, y: float, radius: float, var: float, ago: float = 0.0, speed: float = 0.0
    ) -> None:
        """Weigh the cells by a position fix (m) with variance ``var`` per axis (an outlier
        with probability eps, spread over about 4 m^2) of where the train was ``ago`` s
        earlier (the reference speed was then ``speed``)."""
        th = self.thetas(ago, speed)
        cx, cy = self.track.center
        d2 = (x - cx - radius * np.cos(th)) ** 2 + (y - cy - radius * np.sin(th)) ** 2
        a = self.log_in[0] - 0.5 * d2 / var - math.log(TWO_PI * var)
        self._add(np.logaddexp(a, self.log_eps - math.log(4.0)))

    def _add(self, ll: np.ndarray) -> None:
        self.L += ll
        self.L -= self.L.max()  # only differences matter; keep the numbers small
        self.readings += 1

    def best(self) -> Branch:
        """The favoured branch now (see :class:`Branch`)."""
        p = np.exp(self.L - self.L.max())
        p /= p.sum()
        th = self.thetas()
        i, j = np.unravel_index(int(np.argmax(p)), p.shape)
        t0 = float(th[i, j])
        dev = wrap(th - t0)
        near = (np.abs(dev) < self.cluster) & (np.sign(self.s) == np.sign(self.s[i, 0]))
        pc = np.where(near, p, 0.0)
        mass = float(pc.sum())
        mean_dev = float((pc * dev).sum() / mass)
        var = float((pc * (dev - mean_dev) ** 2).sum() / mass) + self.bin_var
        s = np.broadcast_to(self.s, p.shape)
        ratio = float((pc * s).sum() / mass)
        ratio_var = float((pc * (s - ratio) ** 2).sum() / mass)
        return Branch(float(wrap(t0 + mean_dev)), var, ratio, ratio_var, mass)
