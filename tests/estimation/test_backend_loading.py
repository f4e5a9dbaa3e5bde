"""Where the compiled kernels are cached, and that nothing loads numba before a filter is
made (a node that runs no filter stays small). The compile-once behaviour on a fresh,
read-only install is tested in tests/packaging/test_install.py."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from hera.estimation import backend


@pytest.mark.parametrize(
    "env,expected",
    [
        ({"NUMBA_CACHE_DIR": "/n", "HERA_CACHE_DIR": "/h", "XDG_CACHE_HOME": "/x"}, "/n"),
        ({"HERA_CACHE_DIR": "/h", "XDG_CACHE_HOME": "/x"}, "/h/numba"),
        ({"XDG_CACHE_HOME": "/x"}, "/x/hera/numba"),
        ({"HOME": "/home/u"}, "/home/u/.cache/hera/numba"),
    ],
)
def test_cache_dir_is_per_user_and_numba_setting_wins(monkeypatch, env, expected):
    for var in ("NUMBA_CACHE_DIR", "HERA_CACHE_DIR", "XDG_CACHE_HOME"):
        monkeypatch.delenv(var, raising=False)
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    assert backend.cache_dir() == Path(expected)


def test_the_compile_marker_is_per_source_path_as_numbas_cache_is(tmp_path):
    """numba caches a kernel under its source file's absolute path: a second install or
    checkout of the same code compiles again, so it must not find the first one's marker
    (it would then compile one kernel after the other, silently, instead of in parallel
    with a line saying so)."""
    import types

    import numba  # noqa: F401  (a test requirement: the marker names numba's version)

    source = Path(backend.__file__).with_name("kernels_numba.py").read_bytes()
    markers = []
    for place in ("one", "two", "one"):
        (tmp_path / place).mkdir(exist_ok=True)
        copy = tmp_path / place / "kernels_numba.py"
        copy.write_bytes(source)
        k = object.__new__(backend._Kernels)
        k.cache, k._mod = tmp_path / "cache", types.SimpleNamespace(__file__=str(copy))
        markers.append(k.marker())
    assert markers[0] != markers[1] and markers[0] == markers[2]
    assert all(m.parent == tmp_path / "cache" for m in markers)


def test_prefer_refuses_an_unknown_name_and_changes_nothing_now():
    with pytest.raises(ValueError, match="unknown estimation backend 'cuda'"):
        backend.prefer("cuda")


def test_the_backend_choices_the_readme_names_are_public():
    import hera.estimation as est

    for name in ("set_backend", "prefer", "warmup", "active_backend"):
        assert getattr(est, name) is getattr(backend, name) and name in est.__all__


PROBE = """
import sys, types
from hera.node import Node
import hera.measures.counter, hera.measures.beacon  # what an observer node runs
Node._select_estimation_backend(types.SimpleNamespace(spec=types.SimpleNamespace(
    estimation_backend={choice!r})))
print("after start:", "numba" in sys.modules, "numpy" in sys.modules)
from hera.estimation import KalmanFilter, backend
print("after import:", "numba" in sys.modules)
KalmanFilter([0.0], [[1.0]], F=[[1.0]], Q=0.1)
print("after filter:", "numba" in sys.modules, backend.backend())
"""


@pytest.mark.parametrize("choice", ["auto", "numba", "numpy"])
def test_a_node_loads_numba_only_when_a_measure_makes_a_filter(choice):
    """The node's start records the spec's backend (importing neither the estimation
    package nor numpy); numba is imported (and its kernels loaded) by the first filter, on
    the numba and auto backends only."""
    import numba  # noqa: F401  (a test requirement: missing, the test fails, never skips)

    out = subprocess.run(
        [sys.executable, "-c", PROBE.format(choice=choice)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    compiled = choice != "numpy"
    assert out.stdout.splitlines() == [
        "after start: False False",  # nor numpy: an observer node never loads it
        "after import: False",
        f"after filter: {compiled} {'numba' if compiled else 'numpy'}",
    ]


def test_prefer_once_a_filter_exists_applies_at_once_and_filters_keep_working(use):
    import numba  # noqa: F401  (a test requirement: "auto" is numba here)

    from hera.estimation import KalmanFilter, Observations

    use("numpy")
    kf = KalmanFilter([0.0], [[1.0]], F=[[1.0]], Q=0.1)
    for name in ("auto", "numpy"):
        backend.prefer(name)
        assert backend._active is not backend._UNRESOLVED
        assert backend.backend() == ("numpy" if name == "numpy" else "numba")
        kf.predict(0.1)
        assert kf.update(Observations().add("z", [1.0], H=[[1.0]], R=0.5)).accepted == ["z"]
