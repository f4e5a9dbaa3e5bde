"""CompiledExtendedKalmanFilter: the EKF step of numba model functions in one compiled call
gives the numbers and errors of the ordinary EKF's step, and its machine code is cached
across processes (and not reused once the model's source changes)."""

from __future__ import annotations

import importlib
import json
import os
import subprocess
import sys
import uuid
from pathlib import Path

import numba
import numpy as np
import pytest

from hera.estimation import (
    CompiledExtendedKalmanFilter,
    ExtendedKalmanFilter,
    NonFiniteInputError,
    Observations,
    backend,
    compile_model,
    record,
)
from hera.estimation.stacking import EMPTY1

# A pendulum with a sensor bias: x = [angle rad, rate rad/s, bias], u = [torque] or none;
# measured: sin(angle) + bias and the rate. {scale} is g / L (1/s^2).
MODEL = """
import numba
import numpy as np


@numba.njit
def f(x, dt, u):
    a = u[0] if u.shape[0] else 0.0
    return np.array([x[0] + dt * x[1], x[1] + dt * (a - {scale} * np.sin(x[0])), x[2]])


@numba.njit
def F(x, dt, u):
    return np.array(
        [[1.0, dt, 0.0], [-{scale} * dt * np.cos(x[0]), 1.0, 0.0], [0.0, 0.0, 1.0]]
    )


@numba.njit
def h(x):
    return np.array([np.sin(x[0]) + x[2], x[1]])


@numba.njit
def H(x):
    return np.array([[np.cos(x[0]), 0.0, 1.0], [0.0, 1.0, 0.0]])
"""

X0 = np.array([0.3, 0.0, 0.05])
P0 = np.diag([0.1, 0.2, 0.01])


def _write_model(folder: Path, scale: float = 9.81) -> str:
    """A fresh model module in ``folder``; returns its (unique) name."""
    name = f"pendulum_{uuid.uuid4().hex[:12]}"
    (folder / f"{name}.py").write_text(MODEL.format(scale=scale))
    return name


def _forget_step(path: Path) -> None:
    """Delete a generated step module and numba's files for it from the cache."""
    digest = path.stem.removeprefix("ekf_step_")
    for p in list(path.parent.parent.rglob(f"*{digest}*")):
        p.unlink()


def _forget(model) -> None:
    """Delete a model's generated step modules and numba's files for them."""
    for path in model.paths.values():
        if path is not None:
            _forget_step(path)


@pytest.fixture(scope="module")
def pendulum(tmp_path_factory):
    """An importable pendulum model module (so its compiled step is cached), written once
    for this file's tests: its step compiles once, the other tests load it."""
    folder = tmp_path_factory.mktemp("models")
    sys.path.insert(0, str(folder))
    made = []
    try:
        yield importlib.import_module(_write_model(folder)), made
    finally:
        sys.path.remove(str(folder))
        for model in made:
            _forget(model)


def _inputs(steps: int = 240):
    """Measurements with outliers, control inputs on some steps, jittered dt."""
    rng = np.random.default_rng(5)
    out = []
    for k in range(steps):
        z = np.array([np.sin(0.3 * np.cos(0.05 * k)) + 0.05, 0.0]) + rng.normal(0, 0.05, 2)
        if k % 37 == 11:
            z[0] += 3.0  # an outlier the gate rejects
        u = np.array([rng.normal()]) if k % 3 == 0 else None
        out.append((0.02 + 0.005 * rng.random(), z, u))
    return out


@pytest.mark.parametrize("R", [np.array([0.01, 0.02]), np.array([[0.01, 0.004], [0.004, 0.02]])])
def test_fuse_gives_the_ordinary_step_and_the_numpy_backend(pendulum, use, R):
    mod, made = pendulum
    use("numba")
    model = compile_model(mod.f, mod.F, measurements={"imu": (mod.h, mod.H)})
    made.append(model)
    assert model.cached and model.paths["imu"].exists()
    Q = lambda dt: np.diag([1e-6, 1e-3, 1e-7]) * dt  # noqa: E731 - a Q(dt) as users give it
    fast = CompiledExtendedKalmanFilter(X0, P0, model, Q, R, gate=0.999)
    plain = ExtendedKalmanFilter(X0, P0, f=mod.f, F=mod.F, Q=Q, gate=0.999)
    track, rejected = [], 0
    for dt, z, u in _inputs():
        a = fast.fuse(dt, z, u)
        b = plain.step(
            dt,
            Observations().add("imu", z, h=mod.h, jacobian=mod.H, R=R),
            EMPTY1 if u is None else u,
        )
        assert a == b  # the same outcome: label, accepted or not, NIS and gate
        assert a.nis["imu"] == pytest.approx(b.nis["imu"], rel=1e-12)
        np.testing.assert_allclose(fast.x, plain.x, rtol=0, atol=1e-12)
        np.testing.assert_allclose(fast.P, plain.P, rtol=0, atol=1e-12)
        np.testing.assert_allclose(fast.x_prior, plain.x_prior, rtol=0, atol=1e-12)
        np.testing.assert_allclose(fast.P_prior, plain.P_prior, rtol=0, atol=1e-12)
        rejected += not a.updated
        track.append(fast.x.copy())
    assert rejected >= 6  # the outliers were gated out, not fused
    # the numpy backend, running the same (numba) functions from Python
    use("numpy")
    ref = ExtendedKalmanFilter(X0, P0, f=mod.f, F=mod.F, Q=Q, gate=0.999)
    for (dt, z, u), x in zip(_inputs(), track, strict=True):
        ref.step(
            dt,
            Observations().add("imu", z, h=mod.h, jacobian=mod.H, R=R),
            u if u is not None else EMPTY1,
        )
        np.testing.assert_allclose(ref.x, x, rtol=0, atol=1e-9)


def test_the_step_is_cached_pickles_and_a_changed_model_compiles_anew(tmp_path):
    """Three fresh processes. The first compiles the step (a cache miss) and pickles its
    filter half way (a fusion measure's checkpoint); the second unpickles that filter, its
    step loaded from the cache (a hit, nothing compiled), and goes on exactly as the first;
    the third has the model's source changed (g / L 9.81 -> 4.0) and must compile a new
    step and follow the new model, not the cached one."""
    name = _write_model(tmp_path)
    probe = (
        f"import json, pickle, sys, numpy as np; import {name} as m\n"
        "from hera.estimation import CompiledExtendedKalmanFilter, compile_model\n"
        "from hera.estimation import ExtendedKalmanFilter, Observations\n"
        "x0, mode, pkl = np.array([0.3, 0.0, 0.05]), sys.argv[1], sys.argv[2]\n"
        "if mode == 'load':\n"
        "    k = pickle.load(open(pkl, 'rb'))\n"
        "else:\n"
        "    k = CompiledExtendedKalmanFilter(\n"
        "        x0, np.eye(3), compile_model(m.f, m.F, m.h, m.H), 1e-4, [0.01, 0.02])\n"
        "p = ExtendedKalmanFilter(x0, np.eye(3), f=m.f, F=m.F, Q=1e-4)\n"
        "for i in range(10):\n"
        "    z = np.array([0.2 + 0.01 * i, 0.0])\n"
        "    o = Observations().add('z', z, h=m.h, jacobian=m.H, R=[0.01, 0.02])\n"
        "    p.step(0.1, o, np.zeros(0))\n"
        "    if mode != 'load' or i >= 5:\n"
        "        k.fuse(0.1, z)\n"
        "    if mode == 'dump' and i == 4:\n"
        "        pickle.dump(k, open(pkl, 'wb'))\n"
        "s = k.model.steps['z'].stats\n"
        "print(json.dumps({'path': str(k.model.paths['z']), 'hits': len(s.cache_hits), "
        "'misses': len(s.cache_misses), 'x': k.x.tolist(), 'plain': p.x.tolist()}))\n"
    )
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), *sys.path]))
    pkl = str(tmp_path / "filter.pkl")

    def run(mode: str) -> dict:
        got = subprocess.run(
            [sys.executable, "-c", probe, mode, pkl],
            env=env,
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert got.returncode == 0, got.stderr[-3000:]
        out = json.loads(got.stdout.splitlines()[-1])
        # the compiled step follows the functions this process imported, and an unpickled
        # filter goes on as the ordinary EKF that ran all ten steps
        np.testing.assert_allclose(out["x"], out["plain"], rtol=0, atol=1e-12)
        return out

    paths = []
    try:
        first = run("dump")
        paths.append(first["path"])
        assert (first["hits"], first["misses"]) == (0, 1)
        assert Path(pkl).stat().st_size < 4000  # the functions by name, no machine code
        second = run("load")
        assert second["path"] == first["path"]
        assert (second["hits"], second["misses"]) == (1, 0)
        assert second["x"] == first["x"]
        (tmp_path / f"{name}.py").write_text(MODEL.format(scale=4.0))
        third = run("fresh")
        paths.append(third["path"])
        assert third["path"] != first["path"]
        assert (third["hits"], third["misses"]) == (0, 1)
        assert third["x"] != first["x"]
    finally:
        for p in paths:
            _forget_step(Path(p))


def test_several_measurements_each_fused_in_one_call(pendulum, use):
    """A model of two sensors (the tilt sensor, h[0], and the rate sensor, h[1], as two
    measurements): a sample of either is fused by its own step, with the numbers of the
    ordinary step given that sensor's block; naming a sensor is required and checked."""
    mod, made = pendulum
    use("numba")
    tilt = numba.njit(lambda x: mod.h(x)[:1])
    tilt_J = numba.njit(lambda x: mod.H(x)[:1])
    rate = numba.njit(lambda x: mod.h(x)[1:])
    rate_J = numba.njit(lambda x: mod.H(x)[1:])
    model = compile_model(
        mod.f, mod.F, measurements={"tilt": (tilt, tilt_J), "rate": (rate, rate_J)}
    )
    made.append(model)
    R = {"tilt": 0.01, "rate": [0.02]}
    fast = CompiledExtendedKalmanFilter(X0, P0, model, 1e-4, R, gate=0.999)
    plain = ExtendedKalmanFilter(X0, P0, f=mod.f, F=mod.F, Q=1e-4, gate=0.999)
    funcs = {"tilt": (tilt, tilt_J), "rate": (rate, rate_J)}
    for k, (dt, z, u) in enumerate(_inputs(60)):
        name = ("tilt", "rate")[k % 2]
        zk = z[:1] if name == "tilt" else z[1:]
        a = fast.fuse(dt, zk, u, sensor=name)
        h, J = funcs[name]
        obs = Observations().add(name, zk, h=h, jacobian=J, R=R[name])
        assert a == plain.step(dt, obs, EMPTY1 if u is None else u)
        np.testing.assert_allclose(fast.x, plain.x, rtol=0, atol=1e-12)
        np.testing.assert_allclose(fast.P, plain.P, rtol=0, atol=1e-12)
    assert _error(lambda: fast.fuse(0.1, [0.1])) == (
        ValueError,
        "fuse: the model has 2 measurements: name one with sensor= (tilt, rate)",
    )
    assert _error(lambda: fast.fuse(0.1, [0.1], sensor="gyro")) == (
        ValueError,
        "sensor 'gyro' is not a measurement of the model (tilt, rate)",
    )
    assert _error(lambda: CompiledExtendedKalmanFilter(X0, P0, model, 1e-4, 0.01)) == (
        ValueError,
        "R: the model has 2 measurements (tilt, rate): give a dict of their noises",
    )
    assert _error(lambda: CompiledExtendedKalmanFilter(X0, P0, model, 1e-4, {"tilt": 0.01})) == (
        ValueError,
        "R: no noise given for measurement 'rate'",
    )
    assert _error(lambda: setattr(fast, "R", {"tilt": 0.01, "rate": 0.02, "rte": 1.0})) == (
        ValueError,
        "R: 'rte' is not a measurement of the model (tilt, rate)",
    )
    assert _error(lambda: setattr(fast, "R", {"tilt": 0.01, "rate": -1.0}))[0] is ValueError
    assert fast.R["rate"].tolist() == [0.02]  # a refused R changes nothing


def _readme_example() -> str:
    """The README's compiled-model example (estimation library, "A compiled model")."""
    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    start = readme.index("import numba, numpy as np\nfrom hera.estimation import Compiled")
    return readme[start : readme.index("```", start)]


def test_the_readmes_example_runs_uncached_with_the_ordinary_steps_numbers(use):
    """The README's example, run as a script runs it: its functions cannot be imported by
    a fresh process, so the step compiles in this one, uncached, with the same numbers."""
    use("numba")
    ns: dict = {"__name__": "readme_example", "dt": 0.1, "r": 2.05, "a": 0.2}
    exec(compile(_readme_example(), "README.md", "exec"), ns)
    model, ekf = ns["model"], ns["ekf"]
    assert not model.cached and model.paths == {"z": None}
    assert ns["result"].updated and ekf.x[0] > 0.0  # the range says: off the start
    plain = ExtendedKalmanFilter([0.0, 1.0], np.eye(2), f=ns["f"], F=ns["F"], Q=1e-3, gate=0.999)
    fast = CompiledExtendedKalmanFilter([0.0, 1.0], np.eye(2), model, Q=1e-3, R=0.01, gate=0.999)
    for k in range(20):
        z, u = [2.0 + 0.02 * k * k], [0.1 * (k % 3)]
        a = fast.fuse(0.1, z, u=u)
        obs = Observations().add("z", z, h=ns["h"], jacobian=ns["H"], R=0.01)
        assert a == plain.step(0.1, obs, np.asarray(u, float))
        np.testing.assert_allclose(fast.x, plain.x, rtol=0, atol=1e-12)
        np.testing.assert_allclose(fast.P, plain.P, rtol=0, atol=1e-12)


def test_history_and_the_ordinary_calls_still_work(pendulum, use):
    use("numba")
    mod, fast, plain = _pair(pendulum)
    hist_fast, hist_plain = record(fast), record(plain)
    for dt, z, u in _inputs(30):
        fast.fuse(dt, z, u)
        plain.step(
            dt,
            Observations().add("z", z, h=mod.h, jacobian=mod.H, R=[0.01, 0.02]),
            EMPTY1 if u is None else u,
        )
    assert len(hist_fast) == len(hist_plain) == 31  # the start and 30 steps
    np.testing.assert_allclose(hist_fast.x_post, hist_plain.x_post, rtol=0, atol=1e-12)
    np.testing.assert_allclose(hist_fast.t, hist_plain.t, rtol=0, atol=1e-12)
    np.testing.assert_allclose(fast.x, plain.x, rtol=0, atol=1e-12)
    fast.history = None
    fast.predict(0.1)  # u None: an empty input, as fuse
    fast.update(fast.block([0.2, 0.01]))
    plain.predict(0.1, EMPTY1)
    plain.update(Observations().add("z", [0.2, 0.01], h=mod.h, jacobian=mod.H, R=[0.01, 0.02]))
    np.testing.assert_allclose(fast.x, plain.x, rtol=0, atol=1e-12)
    Q = np.diag([1e-5, 2e-3, 1e-8])  # a process noise for one call, as step(..., Q=Q)
    fast.fuse(0.1, [0.25, 0.02], Q=Q)
    plain.step(
        0.1,
        Observations().add("z", [0.25, 0.02], h=mod.h, jacobian=mod.H, R=[0.01, 0.02]),
        EMPTY1,
        Q=Q,
    )
    np.testing.assert_array_equal(fast.P, plain.P)
    fast.joseph = plain.joseph = False  # the short form P - K H P, as the ordinary EKF's
    for dt, z, u in _inputs(10):
        fast.fuse(dt, z, u)
        obs = Observations().add("z", z, h=mod.h, jacobian=mod.H, R=[0.01, 0.02])
        plain.step(dt, obs, EMPTY1 if u is None else u)
        # bit for bit: the same kernel with the same flag (the two forms differ by roundoff)
        np.testing.assert_array_equal(fast.P, plain.P)


def _pair(pendulum):
    """The pendulum module, a compiled EKF of it and the ordinary EKF of its functions."""
    mod, made = pendulum
    model = compile_model(mod.f, mod.F, mod.h, mod.H)
    made.append(model)
    fast = CompiledExtendedKalmanFilter(X0, P0, model, 1e-4, [0.01, 0.02])
    return mod, fast, ExtendedKalmanFilter(X0, P0, f=mod.f, F=mod.F, Q=1e-4)


def _error(call) -> tuple[type, str]:
    with pytest.raises(Exception) as e:
        call()
    return e.type, str(e.value)


def test_bad_inputs_raise_the_ordinary_ekfs_errors_and_leave_its_state(pendulum, use):
    use("numba")
    mod, fast, plain = _pair(pendulum)

    def both(z, u=None, dt=0.1):
        def ordinary():
            obs = Observations().add("z", z, h=mod.h, jacobian=mod.H, R=[0.01, 0.02])
            plain.step(dt, obs, EMPTY1 if u is None else np.asarray(u, float))

        return _error(lambda: fast.fuse(dt, z, u)), _error(ordinary)

    for z, u, dt in (
        ([0.1, 0.2, 0.3], None, 0.1),  # three values for a measurement of two
        ([np.nan, 0.0], None, 0.1),  # a NaN measurement
        ([0.1, 0.0], [np.inf], 0.1),  # an input that makes f(x) infinite
        ([0.1, 0.0], None, -0.1),  # a negative dt
    ):
        a, b = both(z, u, dt)
        assert a == b, (z, u, dt)
        # what stands after the error is the ordinary EKF's too (a NaN z: the predict)
        np.testing.assert_array_equal(fast.x, plain.x)
        np.testing.assert_array_equal(fast.P, plain.P)
    assert both([0.1, 0.0], [np.inf])[0][0] is NonFiniteInputError


def test_what_cannot_be_compiled_is_refused_with_a_sentence(use, pendulum):
    mod, made = pendulum
    use("numba")

    def h(x):
        return np.sin(x[:1])

    kind, text = _error(lambda: compile_model(mod.f, mod.F, h, mod.H))
    assert kind is TypeError
    assert text == "compiled model: h must be a numba.njit function, got function 'h'"

    @numba.njit
    def scalar_h(x):
        return np.sin(x[0])  # a float, not an array: the kernel cannot take it

    model = compile_model(mod.f, mod.F, scalar_h, mod.H)
    kind, text = _error(lambda: CompiledExtendedKalmanFilter(X0, P0, model, 1e-4, 0.01))
    assert (kind, text) == (
        TypeError,
        "compiled model: h returned a value of type float, expected a 1-D float64 array",
    )

    @numba.njit
    def narrow_H(x):
        return np.zeros((1, 2))  # two columns for a state of three

    model = compile_model(mod.f, mod.F, measurements={"a": (mod.h, mod.H), "b": (mod.h, narrow_H)})
    kind, text = _error(lambda: CompiledExtendedKalmanFilter(X0, P0, model, 1e-4, {"a": 1, "b": 1}))
    assert (kind, text) == (
        TypeError,
        "compiled model: H of measurement 'b' returned an array of float64 with shape (1, 2), "
        "expected a float64 array of shape (2, 3)",
    )

    @numba.njit
    def int_z(x):
        return np.array([1, 2])  # integers: numba types the step for them, the kernel not

    model = compile_model(mod.f, mod.F, int_z, mod.H)
    kind, text = _error(lambda: CompiledExtendedKalmanFilter(X0, P0, model, 1e-4, 0.01))
    assert (kind, text) == (
        TypeError,
        "compiled model: h returned an array of int64 with shape (2,), expected a 1-D "
        "float64 array",
    )

    @numba.njit
    def odd_f(x, dt, u):
        return x.reshape((1, 3)) * 1.0  # float64 of the right size, the wrong rank

    model = compile_model(odd_f, mod.F, mod.h, mod.H)
    kind, text = _error(lambda: CompiledExtendedKalmanFilter(X0, P0, model, 1e-4, 0.01))
    assert kind is TypeError and text.startswith(
        "compiled model: f returned an array of float64 with shape (1, 3)"
    )
    kind, text = _error(lambda: CompiledExtendedKalmanFilter(X0, P0, (mod.f, mod.F), 1e-4, 0.01))
    assert (kind, text) == (
        TypeError,
        "model must be a CompiledModel (compile_model(f, F, h, H)), got tuple",
    )
    use("numpy")
    kind, text = _error(lambda: compile_model(mod.f, mod.F, mod.h, mod.H))
    assert kind is RuntimeError and "needs the numba backend" in text
    assert backend.backend() == "numpy"
