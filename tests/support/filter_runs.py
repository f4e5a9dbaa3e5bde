"""Two runs of a filter compared step by step: what the estimation tests use to hold a fast
path (unrolled, stacked) to the path it stands in for."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import pytest

from hera.estimation import CovarianceError, NonFiniteInputError


def record(filt: Any, result: Any = None) -> tuple[np.ndarray, np.ndarray, list | None]:
    """A step of a run: the filter's x and P (copies) and, after an update, each block's
    (label, accepted, NIS)."""
    blocks = None
    if result is not None:
        blocks = [(o.label, o.accepted, o.nis) for o in result.outcomes]
    return filt.x.copy(), filt.P.copy(), blocks


def same_runs(
    got: Sequence[tuple],
    want: Sequence[tuple],
    tol: Mapping[str, float],
    nis_tol: Mapping[str, float] | None = None,
) -> int:
    """Assert two runs of :func:`record` steps equal: x and P within ``tol``
    (``assert_allclose`` keywords), P exactly symmetric, the same blocks accepted, the NIS
    within ``nis_tol`` (default ``tol``). Returns how many blocks were accepted."""
    accepted = 0
    for (xa, Pa, ra), (xb, Pb, rb) in zip(got, want, strict=True):
        np.testing.assert_allclose(xa, xb, **tol)
        np.testing.assert_allclose(Pa, Pb, **tol)
        assert np.array_equal(Pa, Pa.T)
        if ra is not None:
            assert [r[:2] for r in ra] == [r[:2] for r in rb]
            nis_a, nis_b = [r[2] for r in ra], [r[2] for r in rb]
            np.testing.assert_allclose(nis_a, nis_b, **(tol if nis_tol is None else nis_tol))
            accepted += sum(r[1] for r in ra)
    return accepted


def error_of(run: Callable[[], Any]) -> tuple[type, str]:
    """The (type, message) of the error ``run()`` raises, to compare two paths' errors;
    fails the test when it raises none."""
    try:
        run()
    except (NonFiniteInputError, CovarianceError, ValueError) as e:
        return type(e), str(e)
    pytest.fail("no error")
