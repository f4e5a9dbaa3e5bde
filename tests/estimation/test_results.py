"""UpdateResult: the one-block result the hot path builds lazily equals the eager one."""

from __future__ import annotations

import numpy as np
import pytest

from hera.estimation import ExtendedKalmanFilter, Observations, backend
from hera.estimation.results import BlockOutcome, DetailedResult, UpdateResult, single_result


@pytest.mark.parametrize("accepted", [True, False])
def test_single_result_equals_eager(accepted: bool) -> None:
    thr = 3.0 if not accepted else None
    lazy = single_result("z", 2, 4.5, accepted, thr)
    eager = UpdateResult([BlockOutcome("z", 2, 4.5, accepted, thr)])
    # the helpers answer from the stored fields before the list exists ...
    assert lazy.accepted == eager.accepted == (["z"] if accepted else [])
    assert lazy.rejected == eager.rejected == ([] if accepted else ["z"])
    assert lazy.nis == eager.nis == {"z": 4.5}
    assert lazy.updated is eager.updated is accepted
    assert bool(lazy) is bool(eager)
    # ... and the list, built on first read, is the same and stays the same object
    assert lazy == eager
    assert lazy.outcomes == eager.outcomes
    assert lazy.outcomes is lazy.outcomes
    assert type(lazy.outcomes[0]) is BlockOutcome
    assert repr(lazy) == repr(eager)


def test_assigned_outcomes_replace_the_single_block() -> None:
    r = single_result("z", 1, 0.5, True, None)
    r.outcomes = [BlockOutcome("a", 1, 9.0, False, 3.8), BlockOutcome("b", 2, 1.0, True, 6.0)]
    assert r.accepted == ["b"]
    assert r.rejected == ["a"]
    assert r.nis == {"a": 9.0, "b": 1.0}
    assert UpdateResult().outcomes == [] and not UpdateResult()
    d = DetailedResult([BlockOutcome("z", 1, 0.5, True, None)], None)
    assert d.accepted == ["z"] and d != UpdateResult(d.outcomes)


@pytest.mark.parametrize("name", ["numpy", "numba"])
@pytest.mark.parametrize("gate", [None, 0.5])
def test_filter_results_same_on_both_backends(name: str, gate: float | None) -> None:
    """The EKF's one-block result (lazy on the compiled hot path, eager on numpy) gives
    the same outcomes, helpers and comparisons; gate 0.5 rejects some of the steps."""
    old = backend.backend()
    try:
        got = []
        for b in ("numpy", name):
            backend.set_backend(b)
            f = ExtendedKalmanFilter(
                [0.1, 0.2],
                np.eye(2),
                f=lambda x, dt, u=None: x,
                Q=0.01,
                F=lambda x, dt, u: np.eye(2),
            )
            rng = np.random.default_rng(3)
            out = []
            for z in rng.normal(scale=2.0, size=20):
                f.predict(0.1)
                r = f.update(
                    Observations().add(
                        "s",
                        [z],
                        R=0.5,
                        h=lambda x: np.sin(x[:1]),
                        jacobian=lambda x: [[np.cos(x[0]), 0.0]],
                    ),
                    gate=gate,
                )
                out.append((r.accepted, r.rejected, r.updated, r.outcomes))
            got.append(out)
        (ref, new) = got
        assert [o[:3] for o in new] == [o[:3] for o in ref]
        for (*_, a), (*_, b) in zip(new, ref, strict=True):
            assert [(o.label, o.dim, o.accepted, o.threshold) for o in a] == [
                (o.label, o.dim, o.accepted, o.threshold) for o in b
            ]
            np.testing.assert_allclose([o.nis for o in a], [o.nis for o in b], rtol=1e-10)
        if gate is not None:
            assert any(o[1] for o in ref) and any(o[0] for o in ref)  # both kinds occur
    finally:
        backend.set_backend(old)
