"""Variadic observations (thesis listing 4.1).

A fusion model builds one :class:`Block` per sample that is present in this step and hands
the :class:`Observations` to ``update``; the filter stacks whatever blocks exist. Blocks of
different sizes mix freely, and no block at all means "predict only" (``update`` is a no-op).

Each block carries: ``z`` (vector), either a linear ``H`` or a function ``h(x)`` (with an
optional Jacobian ``jacobian(x)``; a central-difference Jacobian is used otherwise), ``R``
(a scalar variance, a vector of variances, or a full covariance matrix), an optional
``residual(z, hx)`` (e.g. angle wrapping, thesis eq. 6.7), and a ``label`` used in results,
errors and health statistics. Labels should be unique within one step.

Building is cheap: inputs are converted to float64 arrays once, shapes are checked with
integer comparisons, R is checked here (variances in (0, inf); a matrix symmetric and
positive definite), and the rest (finite z, H or h(x) of the state's size) is checked by the
filter before anything touches its state; every error names the block.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import numpy as np

from .numerics import NonFiniteInputError, as_covariance

__all__ = ["Block", "Observations"]

_F64 = np.float64
_F64T = np.dtype(np.float64)  # dtypes are singletons: ``a.dtype is _F64T`` is a fast test
_ND = np.ndarray
_INF = math.inf


def _vec(z: Any) -> np.ndarray:
    if type(z) is np.ndarray and z.dtype == _F64 and z.ndim == 1:
        return z
    if isinstance(z, float | int):
        return np.array((z,), dtype=_F64)
    return np.asarray(z, dtype=_F64).reshape(-1)


def _matrix(label: str, H: Any, m: int) -> np.ndarray:
    """A block's linear measurement matrix as float64 (m, n); a vector is one row."""
    Hm = H if type(H) is _ND and H.dtype is _F64T else np.asarray(H, dtype=_F64)
    if Hm.ndim == 1:
        Hm = Hm.reshape(1, -1)
    if Hm.ndim != 2 or Hm.shape[0] != m:
        raise ValueError(f"block {label!r}: H has shape {Hm.shape}, z has {m} rows")
    return Hm


def _bad_variance(label: str, v: float, what: str = "R") -> ValueError:
    if v != v or v in (math.inf, -math.inf):
        return NonFiniteInputError(label, "R")
    return ValueError(f"block {label!r}: variance {what} must be > 0, got {v!r}")


def _noise(label: str, R: Any, m: int) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(variances, None) when R is a scalar or a vector, (None, covariance) for a matrix;
    checked: variances in (0, inf), a matrix symmetric and positive definite."""
    if isinstance(R, float | int):
        if not 0.0 < R < _INF:
            raise _bad_variance(label, float(R))
        return np.array((float(R),) * m), None  # float64; cheaper than np.full
    try:
        Rm = R if type(R) is _ND and R.dtype is _F64T else np.asarray(R, dtype=_F64)
    except (TypeError, ValueError):
        raise ValueError(f"block {label!r}: R must be a number, a vector or a matrix") from None
    if Rm.ndim <= 1:
        var = Rm.reshape(-1)
        if var.shape[0] != m:
            raise ValueError(f"block {label!r}: {var.shape[0]} variances for {m} rows")
        for i, v in enumerate(var.tolist()):
            if not 0.0 < v < _INF:
                raise _bad_variance(label, v, f"R[{i}]")
        return var, None
    if Rm.shape != (m, m):
        raise ValueError(f"block {label!r}: R has shape {Rm.shape}, expected ({m}, {m})")
    if not np.isfinite(Rm).all():
        raise NonFiniteInputError(label, "R")
    return None, as_covariance(Rm, m, f"R of block {label!r}")


class Block:
    """One observation block (one sensor sample). See the module docstring.

    Attributes: ``label``, ``z`` (m,), ``H`` (m, n) or None, ``h``, ``jacobian``,
    ``var`` (m,) variances when R is diagonal else None, ``R`` (m, m) full covariance or None
    (``cov()`` always gives the matrix), ``noise`` (the variances, or R row by row, as one
    vector for the compiled kernels, with ``kflags`` saying which), ``residual``, ``mean``,
    ``dim`` (= m).

    Refused here, with a ValueError naming the block: no rows, H and h both or neither,
    H rows that do not match z, a variance that is not > 0 (NonFiniteInputError for NaN or
    inf), a matrix R that is not symmetric or not positive definite (CovarianceError).
    """

    __slots__ = (
        "H",
        "R",
        "dim",
        "h",
        "jacobian",
        "kflags",
        "label",
        "mean",
        "noise",
        "residual",
        "var",
        "vectorized",
        "z",
    )

    def __init__(
        self,
        label: str,
        z: Any,
        R: Any,
        H: Any = None,
        h: Callable[[np.ndarray], Any] | None = None,
        jacobian: Callable[[np.ndarray], Any] | None = None,
        residual: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
        vectorized: bool = False,
        mean: Callable[[np.ndarray, np.ndarray], Any] | None = None,
    ) -> None:
        # Fast paths first (float64 ndarrays of the right rank): this runs once per sensor
        # sample, so every operation here counts.
        zv = z if type(z) is _ND and z.dtype is _F64T and z.ndim == 1 else _vec(z)
        m = zv.shape[0]
        if not m:
            raise ValueError(f"block {label!r}: z is empty (leave the block out instead)")
        if h is None:
            if H is None:
                raise ValueError(f"block {label!r}: give H (linear) or h (function), got neither")
            H = _matrix(label, H, m)
        elif H is not None:
            raise ValueError(f"block {label!r}: give H (linear) or h (function), not both")
        if type(R) is _ND and R.dtype is _F64T and R.ndim == 1 and R.shape[0] == m:
            for v in R.tolist():
                if not 0.0 < v < _INF:
                    _noise(label, R, m)  # raises the precise error
            var = noise = R
            cov = None
            self.kflags = 4  # the compiled kernels' DIAG flag: noise holds variances
        else:
            var, cov = _noise(label, R, m)
            if cov is None:
                noise = var
                self.kflags = 4
            else:
                noise = cov.reshape(-1)
                self.kflags = 0
        self.label = label
        self.z = zv
        self.H = H
        self.h = h
        self.jacobian = jacobian
        self.var = var
        self.R = cov
        self.noise = noise
        self.residual = residual
        self.mean = mean
        self.dim = m
        self.vectorized = vectorized

    def cov(self) -> np.ndarray:
        """The block's measurement covariance as an (m, m) matrix."""
        return self.R if self.R is not None else np.diag(self.var)

    def __repr__(self) -> str:
        kind = "H" if self.H is not None else "h"
        return f"Block({self.label!r}, dim={self.dim}, {kind})"


_new = object.__new__
_block_init = Block.__init__


class Observations:
    """An ordered, variadic set of observation blocks for one filter step (thesis listing
    4.1). ``add`` returns self so calls chain; an empty set means predict only."""

    __slots__ = ("blocks",)

    def __init__(self, blocks: Sequence[Block] | None = None) -> None:
        self.blocks: list[Block] = list(blocks) if blocks else []

    def add(
        self,
        label: str,
        z: Any,
        *,
        R: Any,
        H: Any = None,
        h: Callable[[np.ndarray], Any] | None = None,
        jacobian: Callable[[np.ndarray], Any] | None = None,
        residual: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
        vectorized: bool = False,
        mean: Callable[[np.ndarray, np.ndarray], Any] | None = None,
    ) -> Observations:
        """Append one block. ``R``: variance (scalar), variances (vector) or covariance
        (matrix), in the squared units of ``z``. ``residual(a, b)``: the difference a - b of
        two measurements (e.g. ``angle_residual``); also used by numerical Jacobians.
        ``mean(Y, Wm)``: the weighted mean of the UKF's (N, m) predicted measurements
        (e.g. ``circular_mean`` for angles; default ``Wm @ Y``). ``vectorized=True``
        promises that ``h`` (and ``residual``) also accept a batch of N rows: h maps
        (N, n) states to (N, m), residual (N, m) and (m,) to (N, m) (used by the UKF)."""
        b = _new(Block)  # Block(...) without type.__call__'s layer: this runs every step
        _block_init(b, label, z, R, H, h, jacobian, residual, vectorized, mean)
        self.blocks.append(b)
        return self

    def append(self, block: Block) -> Observations:
        """Append a prebuilt :class:`Block`."""
        self.blocks.append(block)
        return self

    @property
    def dim(self) -> int:
        """Total number of stacked rows."""
        return sum(b.dim for b in self.blocks)

    @property
    def labels(self) -> list[str]:
        return [b.label for b in self.blocks]

    def __len__(self) -> int:
        return len(self.blocks)

    def __bool__(self) -> bool:
        return bool(self.blocks)

    def __iter__(self) -> Iterator[Block]:
        return iter(self.blocks)

    def __repr__(self) -> str:
        return f"Observations({self.blocks!r})"
