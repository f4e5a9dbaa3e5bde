"""Heat in the seed's plate, and what a type-K thermocouple under it reads (seed 000, lab 3).

The plate (``width`` x ``height`` cm, aluminium in the seed) has insulated edges and loses
heat to the air at the rate ``1 / loss_time_s``. A hot block put on it at time ``t_on``
heats its footprint uniformly from then on. The temperature rise is the exact solution of
the heat equation with loss, in the plate's cosine eigenmodes (Neumann edges):

    theta(p, tau) = sum_mn phi_mn(p) q_mn (1 - exp(-k_mn tau)) / k_mn,
    k_mn = alpha pi^2 (m^2 / W^2 + n^2 / H^2) + 1 / loss_time_s,

with q_mn the projection of the source on phi_mn and tau = t - t_on. The source power is
given as ``rise_c``: the steady rise of the plate's mean temperature. A pure function of
time, so every process agrees on the truth without talking.

Defaults (alpha = 0.3 cm^2/s, loss time 150 s) put the thermocouples' responses where the
seed measured them: 10 % of the final rise after 10 - 70 s and half of it after 45 -
170 s, depending on where the block is (the seed: "25-160 second delays").

A thermocouple reads the rise at its spot through a first-order lag (``lag_s``: bead and
contact), plus the ambient temperature, plus its amplifier's cold-junction offset (drawn
per board), plus white noise, quantised to 0.25 degC (a MAX31855-class amplifier).
"""

from __future__ import annotations

import math
import random
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hera.nodes.ir.tables import numbers_into


@dataclass(frozen=True)
class Block:
    """A block on the plate: top-left corner (``x``, ``y``) and size (``w``, ``h``), cm;
    ``hot`` if it heats the plate; ``visible`` false if an IR beam passes through it
    unseen (a block too low for the beams, say)."""

    x: float
    y: float
    w: float
    h: float
    hot: bool = False
    visible: bool = True

    def contains(self, px: float, py: float) -> bool:
        return self.x <= px < self.x + self.w and self.y <= py < self.y + self.h

    @property
    def center(self) -> tuple[float, float]:
        return (self.x + self.w / 2.0, self.y + self.h / 2.0)


@dataclass(frozen=True)
class Plate:
    """The plate, its blocks and its thermal constants (see the module docstring)."""

    width: float = 10.0
    height: float = 10.0
    blocks: tuple[Block, ...] = ()
    alpha: float = 0.3
    loss_time_s: float = 150.0
    rise_c: float = 8.0
    ambient_c: float = 22.0
    t_on: float = 0.0
    modes: int = 40

    @property
    def hot(self) -> Block | None:
        """The hot block (the first one marked hot), or None."""
        return next((b for b in self.blocks if b.hot), None)

    def occupied(self, px: float, py: float) -> bool:
        """Whether point (px, py) cm lies in a block."""
        return any(b.contains(px, py) for b in self.blocks)


class PlateHeat:
    """The temperature field of a :class:`Plate` (modal solution, see module docstring)."""

    def __init__(self, plate: Plate) -> None:
        self.plate = plate
        hot = plate.hot
        m = np.arange(plate.modes)
        self._kx = m * math.pi / plate.width
        self._ky = m * math.pi / plate.height
        self._coef = None
        if hot is None or plate.rise_c == 0.0:
            return
        mu = 1.0 / plate.loss_time_s
        nx = np.where(m == 0, 1.0 / plate.width, 2.0 / plate.width)
        ny = np.where(m == 0, 1.0 / plate.height, 2.0 / plate.height)
        ix = _cos_integral(self._kx, hot.x, hot.x + hot.w)
        iy = _cos_integral(self._ky, hot.y, hot.y + hot.h)
        # Source density so that the steady mean rise is rise_c: q * area / (W H mu) = rise_c.
        q = plate.rise_c * mu * plate.width * plate.height / (hot.w * hot.h)
        self._k = plate.alpha * (self._kx[:, None] ** 2 + self._ky[None, :] ** 2) + mu
        self._coef = q * (nx * ix)[:, None] * (ny * iy)[None, :]

    def rise(self, px: float, py: float, tau: float) -> float:
        """Temperature rise (degC) at (px, py) cm, ``tau`` s after the block was put down."""
        if self._coef is None or tau <= 0.0:
            return 0.0
        cx = np.cos(self._kx * px)
        cy = np.cos(self._ky * py)
        growth = -np.expm1(-self._k * tau) / self._k
        return float(cx @ (self._coef * growth) @ cy)

    def temperature(self, px: float, py: float, t: float) -> float:
        """Temperature (degC) at (px, py) cm at scenario time ``t`` s."""
        return self.plate.ambient_c + self.rise(px, py, t - self.plate.t_on)

    def lagged_rise(self, px: float, py: float, tau: float, lag_s: float) -> float:
        """The rise seen through a first-order lag of time constant ``lag_s`` (the lag
        solved in closed form, mode by mode)."""
        if self._coef is None or tau <= 0.0:
            return 0.0
        if lag_s <= 0.0:
            return self.rise(px, py, tau)
        cx = np.cos(self._kx * px)
        cy = np.cos(self._ky * py)
        k = self._k
        a = 1.0 / lag_s
        # y' = a (x - y), x = (1 - e^{-k t}) / k, y(0) = 0:
        # y = (1 - e^{-a t}) / k - (e^{-k t} - e^{-a t}) a / (k (a - k)).
        ea = math.exp(-a * tau)
        ek = np.exp(-k * tau)
        near = np.abs(a - k) < 1e-9
        diff = np.where(near, 1.0, a - k)
        second = np.where(near, a * tau * ek, (ek - ea) * a / diff)
        growth = ((1.0 - ea) - second) / k
        return float(cx @ (self._coef * growth) @ cy)


def _cos_integral(k: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Integral of cos(k x) over [lo, hi] for each k (k = 0 gives the length)."""
    out = np.empty_like(k)
    zero = k == 0
    out[zero] = hi - lo
    kk = k[~zero]
    out[~zero] = (np.sin(kk * hi) - np.sin(kk * lo)) / kk
    return out


@dataclass(frozen=True)
class ThermocoupleModel:
    """Error model of one simulated thermocouple board (measure arg ``model``)."""

    noise_c: float = 0.2
    """White noise std (degC) (A: a MAX31855-class amplifier, a few LSB)."""
    resolution_c: float = 0.25
    """Quantisation step (degC) (data sheet of the MAX31855: 14 bits, 0.25 degC)."""
    cold_junction_sigma_c: float = 0.5
    """Std of the per-board cold-junction offset (degC) (A, well inside the data
    sheet's +/-2 degC)."""
    offset_c: float | None = None
    """A fixed cold-junction offset (degC) instead of a drawn one."""
    lag_s: float = 2.0
    """Time constant of the bead and its contact with the plate (s) (A)."""

    @classmethod
    def from_args(cls, table: Any) -> ThermocoupleModel:
        """A model from the measure arg ``model``; ValueError naming a bad field."""
        positive = ("noise_c", "resolution_c", "cold_junction_sigma_c", "lag_s")
        return numbers_into(cls, table, "thermocouple model", positive)

    def offset(self, rng: random.Random) -> float:
        """This board's cold-junction offset (degC)."""
        return (
            self.offset_c
            if self.offset_c is not None
            else rng.gauss(0.0, self.cold_junction_sigma_c)
        )

    def read(self, true_c: float, offset: float, rng: random.Random) -> float:
        """One reading (degC) of a true temperature, with the board's offset."""
        value = true_c + offset + rng.gauss(0.0, self.noise_c)
        if self.resolution_c > 0:
            value = round(value / self.resolution_c) * self.resolution_c
        return value


def blocks_from(table: Sequence[Any]) -> tuple[Block, ...]:
    """Blocks from the world's ``blocks`` list of tables; ValueError naming a bad one."""
    out = []
    if not isinstance(table, (list, tuple)):
        raise ValueError(f"world 'blocks' must be a list of tables, got {table!r}")
    for i, entry in enumerate(table):
        if not isinstance(entry, dict):
            raise ValueError(f"world 'blocks'[{i}] must be a table {{x, y, w, h, hot}}")
        unknown = set(entry) - {"x", "y", "w", "h", "hot", "visible"}
        if unknown:
            raise ValueError(
                f"world 'blocks'[{i}]: unknown keys {sorted(unknown)}; allowed: x, y, w, h, "
                "hot, visible"
            )
        try:
            x, y, w, h = (float(entry[k]) for k in ("x", "y", "w", "h"))
        except KeyError as e:
            raise ValueError(f"world 'blocks'[{i}] needs {e.args[0]!r} (cm)") from None
        except (TypeError, ValueError):
            raise ValueError(f"world 'blocks'[{i}]: x, y, w, h must be numbers (cm)") from None
        if not all(math.isfinite(v) for v in (x, y, w, h)) or w <= 0 or h <= 0:
            raise ValueError(f"world 'blocks'[{i}]: w and h must be > 0 cm, all finite")
        hot, visible = entry.get("hot", False), entry.get("visible", True)
        if not isinstance(hot, bool) or not isinstance(visible, bool):
            raise ValueError(f"world 'blocks'[{i}]: hot and visible must be true or false")
        out.append(Block(x, y, w, h, hot, visible))
    return tuple(out)
