"""The result of an update step: which blocks were fused, which were gated out, their NIS."""

from __future__ import annotations

import math
from typing import ClassVar, NamedTuple

import numpy as np

__all__ = [
    "BlockOutcome",
    "UpdateDetails",
    "UpdateResult",
    "gaussian_log_likelihood",
    "make_outcome",
    "make_result",
    "single_result",
]


class BlockOutcome(NamedTuple):
    """One block's verdict (an immutable record). ``nis`` = y^T S^-1 y against the predicted
    state (dimensionless, chi-square with ``dim`` degrees of freedom when the model is
    right); ``threshold`` is the gate used (None when gating was off)."""

    label: str
    dim: int
    nis: float
    accepted: bool
    threshold: float | None = None


class UpdateDetails(NamedTuple):
    """What an update computed, for the rows it fused (``update(..., details=True)``), in
    block order: ``labels`` of the fused blocks, innovation ``y`` (m,), its covariance
    ``S`` (m, m) = H P H^T + R (KF/EKF) or the unscented one (UKF), gain ``K`` (n, m), the
    linearised ``H`` (m, n; None for the UKF), and ``log_likelihood`` = log N(y; 0, S) =
    -(y^T S^-1 y + log det S + m log 2 pi) / 2 (natural log, of the fused rows jointly)."""

    labels: tuple[str, ...]
    y: np.ndarray
    S: np.ndarray
    K: np.ndarray
    H: np.ndarray | None
    log_likelihood: float


_LOG_2PI = math.log(2.0 * math.pi)
_new = object.__new__
_tuple_new = tuple.__new__


def gaussian_log_likelihood(nis: float, log_det: float, m: int) -> float:
    """log N(y; 0, S) from y^T S^-1 y, log det S and the dimension m."""
    return -0.5 * (nis + log_det + m * _LOG_2PI)


class UpdateResult:
    """Outcome of ``update``: ``outcomes`` in block order; helpers by label. ``details``
    (an :class:`UpdateDetails`) is None unless the update was asked for it and fused a
    block.

    ``UpdateResult(outcomes)``; compares equal to a result of the same class with equal
    outcomes. The one-block hot path of the filters stores that block's fields only
    (``single_result``); the BlockOutcome list is built when ``outcomes`` is first read,
    and ``accepted``, ``rejected``, ``nis`` and ``updated`` answer without building it.
    """

    __slots__ = ("_one", "_outcomes")
    __match_args__ = ("outcomes",)
    __hash__ = None  # type: ignore[assignment] - mutable, compared by value
    details: ClassVar[UpdateDetails | None] = None  # an instance attribute of DetailedResult

    def __init__(self, outcomes: list[BlockOutcome] | None = None) -> None:
        self._outcomes = [] if outcomes is None else outcomes
        self._one = None

    @property
    def outcomes(self) -> list[BlockOutcome]:
        """The BlockOutcome of every block, in block order."""
        o = self._outcomes
        if o is None:  # a single_result: built on first use
            o = self._outcomes = [_tuple_new(BlockOutcome, self._one)]
        return o

    @outcomes.setter
    def outcomes(self, value: list[BlockOutcome]) -> None:
        self._outcomes = value
        self._one = None

    @property
    def log_likelihood(self) -> float | None:
        """Log-likelihood of the fused rows (see UpdateDetails), or None without details."""
        d = self.details
        return None if d is None else d.log_likelihood

    @property
    def accepted(self) -> list[str]:
        """Labels of the blocks fused into the state."""
        one = self._one
        if one is not None:
            return [one[0]] if one[3] else []
        return [o.label for o in self.outcomes if o.accepted]

    @property
    def rejected(self) -> list[str]:
        """Labels of the blocks gated out (state not affected by them)."""
        one = self._one
        if one is not None:
            return [] if one[3] else [one[0]]
        return [o.label for o in self.outcomes if not o.accepted]

    @property
    def nis(self) -> dict[str, float]:
        """NIS by label."""
        one = self._one
        if one is not None:
            return {one[0]: one[2]}
        return {o.label: o.nis for o in self.outcomes}

    @property
    def updated(self) -> bool:
        """True when at least one block was fused."""
        one = self._one
        if one is not None:
            return one[3]
        return any(o.accepted for o in self.outcomes)

    def __bool__(self) -> bool:
        return self.updated

    def __eq__(self, other: object) -> bool:
        if other.__class__ is self.__class__:
            return self.outcomes == other.outcomes  # type: ignore[attr-defined]
        return NotImplemented

    def __repr__(self) -> str:
        return f"{type(self).__qualname__}(outcomes={self.outcomes!r})"


class DetailedResult(UpdateResult):
    """An UpdateResult that carries its :class:`UpdateDetails`."""

    __slots__ = ("details",)

    def __init__(self, outcomes: list[BlockOutcome], details: UpdateDetails | None) -> None:
        self.outcomes = outcomes
        self.details = details  # type: ignore[misc]


def make_outcome(
    label: str, dim: int, nis: float, accepted: bool, threshold: float | None
) -> BlockOutcome:
    """``BlockOutcome(label, dim, nis, accepted, threshold)`` for the hot path: the same
    record, built by ``tuple.__new__`` (no keyword handling of the generated ``__new__``)."""
    return _tuple_new(BlockOutcome, (label, dim, nis, accepted, threshold))


def make_result(outcomes: list[BlockOutcome]) -> UpdateResult:
    """``UpdateResult(outcomes)`` for the hot path (the same object, no ``__init__`` call)."""
    r = _new(UpdateResult)
    r._outcomes = outcomes
    r._one = None
    return r


def single_result(
    label: str, dim: int, nis: float, accepted: bool, threshold: float | None
) -> UpdateResult:
    """``UpdateResult([BlockOutcome(label, dim, nis, accepted, threshold)])`` for the hot
    path, the outcome built when first read (the filters write this out inline)."""
    r = _new(UpdateResult)
    r._one = (label, dim, nis, accepted, threshold)
    r._outcomes = None
    return r
