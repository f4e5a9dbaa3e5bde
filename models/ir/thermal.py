"""Where is the hot block? The thermal inverse model of the plate map (seed 000, lab 3).

Model: the steady temperature rise at a thermocouple at s from a small hot block at c is
A G(s, c) + B, with G the steady-state Green's function of an insulated rectangular plate
losing heat to the air (cosine modes, eigenvalues k^2 + 1 / ell^2, ell the plate's fin
length ``kernel_cm``), A >= 0 the unknown power and B an unknown common offset (the
ambient, whatever it is). For each cell c, (A, B) are fitted to the rises by least squares;
the residual gives the likelihood

    L(c) = exp(-RSS(c) / (2 sigma^2)),  sigma^2 = noise^2 + (model_error * spread)^2,

with ``spread`` the range of the rises: the model error term stands for what the steady
model leaves out (the plate is still warming, the block is not a point). Candidates c lie
on a half-cell lattice (cell centres, corners and edge middles: a block of even size is
centred on a corner); the posterior of "the hot block is centred at c" is L normalised
over them (uniform prior).

Thermal evidence is "there is a hot block here", never "this cell is free": a cold block
gives no heat. So the occupancy log-odds it adds to a cell is
logit(1/2 + P_cover(c) / 2) >= 0, P_cover the chance the hot block covers c (the
posterior of its centre spread over its expected footprint, a square of ``block_cells``
cells; at most 0.99) - Bayes with a 1/2 prior for everything that is not hot.

The ell default, 6 cm, is the fin length sqrt(k t / (2 h)) of a 1 mm aluminium plate
(k = 200 W/m/K) in still air (h = 25 W/m^2/K), not a figure of the simulator.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

MODES = 40


def green(
    points: np.ndarray, sources: np.ndarray, width: float, height: float, ell: float
) -> np.ndarray:
    """G[i, j]: steady rise at ``points[i]`` from a unit source at ``sources[j]`` (cm)
    on an insulated ``width`` x ``height`` plate with fin length ``ell`` (module docstring).
    Normalised so that the largest value is 1."""
    m = np.arange(MODES)
    kx, ky = m * math.pi / width, m * math.pi / height
    nx = np.where(m == 0, 1.0, 2.0) / width
    ny = np.where(m == 0, 1.0, 2.0) / height
    lam = kx[:, None] ** 2 + ky[None, :] ** 2 + 1.0 / ell**2
    weight = (nx[:, None] * ny[None, :]) / lam
    px, py = np.cos(np.outer(points[:, 0], kx)), np.cos(np.outer(points[:, 1], ky))
    sx, sy = np.cos(np.outer(sources[:, 0], kx)), np.cos(np.outer(sources[:, 1], ky))
    g = np.einsum("im,jm,mn,in,jn->ij", px, sx, weight, py, sy, optimize=True)
    return g / np.max(np.abs(g))


def lattice(cols: int, rows: int, cell: float) -> np.ndarray:
    """Candidate centres of the hot block: every cell centre, cell corner and edge middle
    inside the grid (a half-cell lattice: a 2 x 2 block is centred on a corner), (N, 2) cm."""
    ys, xs = np.mgrid[1 : 2 * rows, 1 : 2 * cols]
    return np.column_stack((xs.ravel() * cell / 2.0, ys.ravel() * cell / 2.0))


def coverage(points: np.ndarray, cols: int, rows: int, cell: float, side: float) -> np.ndarray:
    """C[k, i]: the fraction of cell k (row-major) a square block of ``side`` cm centred at
    ``points[i]`` covers."""
    lo = np.arange(cols) * cell
    ov_x = np.clip(
        np.minimum(lo[:, None] + cell, points[None, :, 0] + side / 2)
        - np.maximum(lo[:, None], points[None, :, 0] - side / 2),
        0.0,
        cell,
    )
    lo = np.arange(rows) * cell
    ov_y = np.clip(
        np.minimum(lo[:, None] + cell, points[None, :, 1] + side / 2)
        - np.maximum(lo[:, None], points[None, :, 1] - side / 2),
        0.0,
        cell,
    )
    return (ov_y[:, None, :] * ov_x[None, :, :]).reshape(rows * cols, -1) / (cell * cell)


class ThermalModel:
    """Posterior over candidate centres of where the hot block is, from thermocouple rises
    (module docstring). ``candidates``: (N, 2) cm; ``sensors``: (S, 2) positions."""

    def __init__(
        self,
        candidates: np.ndarray,
        sensors: Sequence[tuple[float, float]],
        width: float,
        height: float,
        ell: float = 6.0,
        noise: float = 0.5,
        model_error: float = 0.15,
        min_spread: float = 1.5,
    ) -> None:
        self.sensors = np.asarray(sensors, dtype=float).reshape(-1, 2)
        self.g = green(self.sensors, np.asarray(candidates, dtype=float), width, height, ell)
        self.noise, self.model_error, self.min_spread = noise, model_error, min_spread

    def posterior(self, rises: Sequence[float]) -> np.ndarray | None:
        """P(the hot block is centred at each candidate | rises), or None when the rises do
        not yet show a hot block (their spread is under ``min_spread`` degC) or are too few."""
        y = np.asarray(rises, dtype=float)
        if len(y) < 3 or len(y) != self.g.shape[0] or not np.all(np.isfinite(y)):
            return None
        spread = float(np.max(y) - np.min(y))
        if spread < self.min_spread:
            return None
        g = self.g  # (S, N)
        gm, ym = g.mean(axis=0), y.mean()
        gc = g - gm
        var_g = np.sum(gc * gc, axis=0)
        a = np.where(var_g > 0, (gc.T @ (y - ym)) / np.where(var_g > 0, var_g, 1.0), 0.0)
        a = np.maximum(a, 0.0)  # a hot block heats, it does not cool
        b = ym - a * gm
        rss = np.sum((y[:, None] - (a * g + b)) ** 2, axis=0)
        sigma2 = self.noise**2 + (self.model_error * spread) ** 2
        ll = -rss / (2.0 * sigma2)
        p = np.exp(ll - ll.max())
        return p / p.sum()


def cover_log_odds(cover: np.ndarray) -> np.ndarray:
    """Occupancy log-odds thermal evidence adds to a cell the hot block covers with
    probability ``cover``: logit(1/2 + min(cover, 0.99) / 2) (module docstring)."""
    p = 0.5 + 0.5 * np.minimum(0.99, cover)
    return np.log(p / (1.0 - p))
