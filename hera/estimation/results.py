"""The result of an update step: which blocks were fused, which were gated out, their NIS."""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["BlockOutcome", "UpdateResult", "make_outcome", "make_result", "make_result1"]


@dataclass(slots=True, frozen=True)
class BlockOutcome:
    """One block's verdict. ``nis`` = y^T S^-1 y against the predicted state (dimensionless,
    chi-square with ``dim`` degrees of freedom when the model is right); ``threshold`` is the
    gate used (None when gating was off)."""

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
_set_label = BlockOutcome.label.__set__  # type: ignore[attr-defined]
_set_dim = BlockOutcome.dim.__set__  # type: ignore[attr-defined]
_set_nis = BlockOutcome.nis.__set__  # type: ignore[attr-defined]
_set_accepted = BlockOutcome.accepted.__set__  # type: ignore[attr-defined]
_set_threshold = BlockOutcome.threshold.__set__  # type: ignore[attr-defined]


def make_outcome(
    label: str, dim: int, nis: float, accepted: bool, threshold: float | None
) -> BlockOutcome:
    """``BlockOutcome(label, dim, nis, accepted, threshold)`` for the hot path: the same
    frozen object, built through its slot descriptors (half the cost of the frozen
    dataclass ``__init__``, which goes through ``object.__setattr__`` per field)."""
    o = _new(BlockOutcome)
    _set_label(o, label)
    _set_dim(o, dim)
    _set_nis(o, nis)
    _set_accepted(o, accepted)
    _set_threshold(o, threshold)
    return o


_set_outcomes = UpdateResult.outcomes.__set__  # type: ignore[attr-defined]


def make_result(outcomes: list[BlockOutcome]) -> UpdateResult:
    """``UpdateResult(outcomes)`` for the hot path (same object, no dataclass ``__init__``)."""
    r = _new(UpdateResult)
    _set_outcomes(r, outcomes)
    return r


def make_result1(
    label: str, dim: int, nis: float, accepted: bool, threshold: float | None
) -> UpdateResult:
    """``UpdateResult([BlockOutcome(label, dim, nis, accepted, threshold)])`` for the
    one-block hot path: ``make_result(make_outcome(...))`` with one call less."""
    o = _new(BlockOutcome)
    _set_label(o, label)
    _set_dim(o, dim)
    _set_nis(o, nis)
    _set_accepted(o, accepted)
    _set_threshold(o, threshold)
    r = _new(UpdateResult)
    _set_outcomes(r, [o])
    return r
