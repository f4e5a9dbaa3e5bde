"""How a chip sits on its board: the board's axes as signed chip axes (``axes = "-y,x,z"``).

A real driver turns what its chip reads (in the chip's own axes) into the board frame of
:mod:`hera.nodes.driver` with :func:`from_chip`. The mounting is a turn (a signed permutation
of determinant +1): a mirror image is refused, as no chip can be mounted that way.
"""

from __future__ import annotations

import math

from hera.nodes.geometry import Vec3

Axes = tuple[tuple[int, float], ...]
"""For each board axis x, y, z: (the chip axis 0..2 it is, its sign)."""


def parse_axes(axes: str, arg: str = "axes", mirror_ok: bool = False) -> Axes:
    """For each board axis x, y, z: (the chip axis 0..2, its sign), from ``"-y,x,z"``;
    ValueError naming what is wrong (``arg``: the argument, in the message). A mirror image
    is refused unless ``mirror_ok``: the labels of two dies in one package may differ so."""
    parts = [p.strip() for p in str(axes).split(",")]
    out: list[tuple[int, float]] = []
    for p in parts:
        sign = -1.0 if p.startswith("-") else 1.0
        name = p.lstrip("+-")
        if name not in ("x", "y", "z") or len(p) - len(name) > 1:
            out = []
            break
        out.append(("xyz".index(name), sign))
    if len(parts) != 3 or len(out) != 3 or len({a for a, _ in out}) != 3:
        raise ValueError(
            f"{arg} must name each chip axis once with an optional sign, as '-y,x,z', got {axes!r}"
        )
    # The determinant of a signed permutation: its signs times the permutation's parity.
    perm = [a for a, _ in out]
    inversions = sum(perm[i] > perm[j] for i in range(3) for j in range(i + 1, 3))
    det = math.prod(s for _, s in out) * (-1.0) ** inversions
    if det < 0 and not mirror_ok:
        raise ValueError(
            f"{arg} {axes!r} is a mirror image of the chip's frame (no chip can be mounted so): "
            f"turn the sign of one more axis"
        )
    return tuple(out)


def from_chip(axes: Axes, counts: tuple[int, int, int] | Vec3, scale: float) -> Vec3:
    """A chip reading ``counts`` (in the chip's axes) times ``scale`` (units per count), in
    the board's axes: board j = sign_j * chip[i_j] * scale."""
    return tuple(s * counts[i] * scale for i, s in axes)  # type: ignore[return-value]


def to_chip(axes: Axes, board: Vec3) -> Vec3:
    """The inverse of :func:`from_chip` (scale 1): a board-frame vector in the chip's axes,
    as a chip mounted so reads it (chip[i_j] = sign_j * board j)."""
    out = [0.0, 0.0, 0.0]
    for j, (i, sign) in enumerate(axes):
        out[i] = sign * board[j]
    return (out[0], out[1], out[2])
