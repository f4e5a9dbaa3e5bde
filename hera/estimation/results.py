"""The result of an update step: which blocks were fused, which were gated out, their NIS."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

__all__ = ["BlockOutcome", "UpdateResult", "make_outcome", "make_result", "make_result1"]


class BlockOutcome(NamedTuple):
    """One block's verdict (an immutable record). ``nis`` = y^T S^-1 y against the predicted
    state (dimensionless, chi-square with ``dim`` degrees of freedom when the model is
    right); ``threshold`` is the gate used (None when gating was off)."""

    label: str
    dim: int
    nis: float
    accepted: bool
    threshold: float | None = None


@dataclass(slots=True)
class UpdateResult:
    """Outcome of ``update``: ``outcomes`` in block order; helpers by label."""

    outcomes: list[BlockOutcome] = field(default_factory=list)

    @property
    def accepted(self) -> list[str]:
        """Labels of the blocks fused into the state."""
        return [o.label for o in self.outcomes if o.accepted]

    @property
    def rejected(self) -> list[str]:
        """Labels of the blocks gated out (state not affected by them)."""
        return [o.label for o in self.outcomes if not o.accepted]

    @property
    def nis(self) -> dict[str, float]:
        """NIS by label."""
        return {o.label: o.nis for o in self.outcomes}

    @property
    def updated(self) -> bool:
        """True when at least one block was fused."""
        return any(o.accepted for o in self.outcomes)

    def __bool__(self) -> bool:
        return self.updated


_new = object.__new__
_tuple_new = tuple.__new__
_set_outcomes = UpdateResult.outcomes.__set__  # type: ignore[attr-defined]


def make_outcome(
    label: str, dim: int, nis: float, accepted: bool, threshold: float | None
) -> BlockOutcome:
    """``BlockOutcome(label, dim, nis, accepted, threshold)`` for the hot path: the same
    record, built by ``tuple.__new__`` (no keyword handling of the generated ``__new__``)."""
    return _tuple_new(BlockOutcome, (label, dim, nis, accepted, threshold))


def make_result(outcomes: list[BlockOutcome]) -> UpdateResult:
    """``UpdateResult(outcomes)`` for the hot path (same object, no dataclass ``__init__``)."""
    r = _new(UpdateResult)
    _set_outcomes(r, outcomes)
    return r


def make_result1(
    label: str, dim: int, nis: float, accepted: bool, threshold: float | None
) -> UpdateResult:
    """``UpdateResult([BlockOutcome(label, dim, nis, accepted, threshold)])`` for the
    one-block hot path: ``make_result([make_outcome(...)])`` with two calls less."""
    r = _new(UpdateResult)
    _set_outcomes(r, [_tuple_new(BlockOutcome, (label, dim, nis, accepted, threshold))])
    return r
