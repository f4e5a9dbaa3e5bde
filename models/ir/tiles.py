"""The occupancy map on the bus: rows of at most 256 values (a "tile"), the most one sample
carries (:data:`hera.wire.MAX_VALUES`).

A map of R x C cells (log-odds, row-major: row = y index, column = x index) is published as
ceil(R C / 248) rows, all stamped with the map's time. Each row is

    [tile, tiles, rows, cols, cell [cm], hot x [cm], hot y [cm], hot p, c_0 .. c_247]

``tile`` counts from 0; a map's last tile is padded with zeros (log-odds 0: unknown), so
every row has the same 256 values whatever the map's size (the CSV logs and ``hera eval``
read them as one table). ``hot x/y`` is the estimated centre of the hot block and ``hot p``
the posterior mass within a cell of it (-1, -1, 0 when unknown); every tile repeats them,
so any one tile says where the hot block is. :func:`assemble` puts complete maps back
together.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import numpy as np

from hera.wire import MAX_VALUES

HEADER = ("tile", "tiles", "rows", "cols", "cell [cm]", "hot x [cm]", "hot y [cm]", "hot p")
TILE = MAX_VALUES - len(HEADER)
"""Cells per tile: 248."""
COLUMNS = (*HEADER, *(f"c{i} [log-odds]" for i in range(TILE)))
"""The columns of every tile row."""


def split(logodds: np.ndarray, cell: float, hot: tuple[float, float, float]) -> list[list[float]]:
    """The tile rows of one map (``logodds`` of shape (rows, cols))."""
    rows, cols = logodds.shape
    flat = np.round(logodds.reshape(-1), 3)
    tiles = math.ceil(flat.size / TILE)
    out = []
    for k in range(tiles):
        part = flat[k * TILE : (k + 1) * TILE].tolist()
        out.append([k, tiles, rows, cols, cell, *hot, *part, *([0.0] * (TILE - len(part)))])
    return out


def assemble(
    times: Sequence[float], rows: Iterable[Sequence[float]]
) -> list[tuple[float, np.ndarray, tuple[float, float, float], float]]:
    """Complete maps from tile rows (in publication order): (time, log-odds (rows, cols),
    (hot x, hot y, hot p), cell cm) for every time whose tiles all arrived."""
    pending: dict[float, dict[int, Sequence[float]]] = {}
    out = []
    for t, row in zip(times, rows, strict=True):
        k, n = int(row[0]), int(row[1])
        got = pending.setdefault(float(t), {})
        got[k] = row
        if len(got) == n:
            del pending[float(t)]
            r, c = int(row[2]), int(row[3])
            cells = np.concatenate([np.asarray(got[i][len(HEADER) :]) for i in range(n)])
            grid = cells[: r * c].reshape(r, c)
            out.append(
                (float(t), grid, (float(row[5]), float(row[6]), float(row[7])), float(row[4]))
            )
    return out
