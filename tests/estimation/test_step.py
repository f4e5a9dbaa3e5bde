"""Filter.step(dt, obs) is predict then update, fused into one compiled call where it can
be: the same state, prior, result, history and errors as the two calls."""

import math

import numpy as np
import pytest

from hera.estimation import (
    ExtendedKalmanFilter,
    KalmanFilter,
    NonFiniteInputError,
    Observations,
    UnscentedKalmanFilter,
    angle_residual,
    record,
)

BACKENDS = ["numpy", "numba"]


def _blocks(kind, z, n):
    C = np.linspace(0.5, 1.5, n).reshape(1, -1)
    if kind == "H":
        return Observations().add("s", [z], H=C, R=0.2)
    if kind == "H2":
        return Observations().add("s", [z, -z], H=np.vstack([C, C[:, ::-1]]), R=[0.2, 0.3])
    if kind == "J":
        return Observations().add(
            "s",
            [z],
            h=lambda x: np.tanh(C @ x),
            jacobian=lambda x: (1 - np.tanh(C @ x) ** 2)[:, None] * C,
            R=0.2,
        )
    if kind == "N":
        return Observations().add("s", [z], h=lambda x: np.sin(C @ x), R=0.2)
    if kind == "W":
        return Observations().add("s", [z], H=C, R=0.2, residual=angle_residual)
    if kind == "R":
        return Observations().add("s", [z, z], H=np.vstack([C, 2 * C]), R=[[0.3, 0.1], [0.1, 0.4]])
    return Observations().add("a", [z], H=C, R=0.2).add("b", [z], h=lambda x: np.sin(C @ x), R=0.3)


def _filters(n):
    A = np.eye(n) + 0.05 * np.triu(np.ones((n, n)), 1)
    P0 = np.eye(n) + 0.1
    yield lambda: KalmanFilter(np.ones(n), P0, F=A, Q=0.01)
    yield lambda: ExtendedKalmanFilter(
        np.ones(n),
        P0,
        f=lambda x, dt, u: A @ x + 0.01 * np.sin(x),
        F=lambda x, dt, u: A + np.diag(0.01 * np.cos(x)),
        Q=0.01,
    )
    yield lambda: ExtendedKalmanFilter(np.ones(n), P0, f=lambda x, dt, u: A @ x, Q=[0.01] * n)
    yield lambda: UnscentedKalmanFilter(np.ones(n), P0, f=lambda x, dt, u: A @ x, Q=0.01)


@pytest.mark.parametrize("name", BACKENDS)
@pytest.mark.parametrize("n", [1, 3, 9])
@pytest.mark.parametrize("kind", ["H", "H2", "J", "N", "W", "R", "two"])
@pytest.mark.parametrize("gate", [None, 0.99])
def test_step_equals_predict_then_update(use, name, n, kind, gate):
    use(name)
    zs = [0.3, -0.2, 25.0, 0.1]  # the third is gated out when gating is on
    for make in _filters(n):
        a, b = make(), make()
        ha, hb = record(a), record(b)
        for z in zs:
            ra = a.step(0.1, _blocks(kind, z, n), gate=gate)
            b.predict(0.1)
            rb = b.update(_blocks(kind, z, n), gate=gate)
            assert [(o.label, o.accepted, o.threshold) for o in ra.outcomes] == [
                (o.label, o.accepted, o.threshold) for o in rb.outcomes
            ]
            assert [o.nis for o in ra.outcomes] == pytest.approx(
                [o.nis for o in rb.outcomes], rel=1e-12
            )
            for attr in ("x", "P", "x_prior", "P_prior", "x_post", "P_post"):
                np.testing.assert_allclose(
                    getattr(a, attr), getattr(b, attr), rtol=1e-12, atol=1e-14
                )
        assert len(ha) == len(hb) == len(zs) + 1
        np.testing.assert_allclose(ha.P_prior, hb.P_prior, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(ha.x_post, hb.x_post, rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("name", BACKENDS)
def test_step_errors_are_those_of_the_two_calls(use, name):
    """A bad predict leaves the state as it was; a bad block raises after the predict
    stood, as predict() then update() would."""
    use(name)
    for make in _filters(2):
        filt = make()
        x0 = filt.x
        with pytest.raises(ValueError, match="dt must be"):
            filt.step(-1.0, _blocks("H", 0.1, 2))
        assert filt.x is x0
        bad = Observations().add("nan", [math.nan], H=[[1.0, 0.0]], R=0.1)
        with pytest.raises(NonFiniteInputError, match="'nan'"):
            filt.step(0.1, bad)
        assert filt.x is filt.x_prior and filt.x is not x0
        wide = Observations().add("wide", [1.0], H=[[1.0, 0.0, 0.0]], R=0.1)
        with pytest.raises(ValueError, match="block 'wide'"):
            filt.step(0.1, wide)
        assert filt.x is filt.x_prior
        r = filt.step(0.1, None)  # no block: predict only
        assert not r.outcomes and filt.x is filt.x_prior


def test_step_runs_fused_on_numba(use, monkeypatch):
    """On the numba backend step() does not fall back to the two calls for the usual
    blocks (so the equality above compares the fused kernels with predict + update)."""
    use("numba")

    def boom(*a, **k):
        raise AssertionError("fell back to predict + update")

    monkeypatch.setattr(KalmanFilter, "predict", boom)
    monkeypatch.setattr(ExtendedKalmanFilter, "_predict_given", boom)
    for make in list(_filters(3))[:3]:
        filt = make()
        for kind in (
            ("H", "H2", "R")
            if isinstance(filt, KalmanFilter) and not isinstance(filt, ExtendedKalmanFilter)
            else ("H", "J", "N", "W", "R")
        ):
            assert filt.step(0.1, _blocks(kind, 0.2, 3)).updated
