"""The first compile shared between processes (``hera.estimation.backend``): how the kernels
are split, how many processes, and what happens when a helper fails. The real parallel
compile runs in tests/estimation/test_backend_loading.py and tests/packaging/test_install.py
(a fresh cache each), which check its lines on stderr."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from hera.estimation import backend

NAMES = tuple(backend.COMPILE_SECONDS)


def _load(share: list[str]) -> float:
    return sum(backend.COMPILE_SECONDS[n] for n in share)


@pytest.mark.parametrize("jobs", [1, 2, 3, 4])
def test_every_kernel_in_exactly_one_share_and_the_shares_balanced(jobs):
    parts = backend.shares(NAMES, jobs)
    assert sorted(n for p in parts for n in p) == sorted(NAMES)
    assert len(parts) == jobs
    loads = [_load(p) for p in parts]
    assert loads == sorted(loads, reverse=True)  # this process keeps the largest share
    # longest-first greedy is within 4/3 of the best split (Graham 1969), and the best is
    # at least the even share and at least the longest unit (a kernel or a TOGETHER group)
    longest = max(
        max(backend.COMPILE_SECONDS.values()),
        *(backend.unit_seconds(g) for g in backend.TOGETHER),
    )
    best = max(sum(loads) / jobs, longest)
    assert max(loads) <= 4 / 3 * best
    if jobs == 2:  # 60 s of compile in two processes: about 30 s each
        assert max(loads) <= 0.55 * sum(loads)


@pytest.mark.parametrize("jobs", [1, 2, 3, 4])
def test_kernels_that_share_a_compiled_helper_are_compiled_by_one_process(jobs):
    for group in backend.TOGETHER:
        assert len(group) > 1 and set(group) <= set(NAMES)
        holders = [p for p in backend.shares(NAMES, jobs) if set(group) & set(p)]
        assert len(holders) == 1 and set(group) <= set(holders[0]), holders
    # a group of which only some kernels are asked for keeps what is asked, once
    part = backend.shares(["lin_update1", "ekf_step"], 2)
    assert sorted(n for p in part for n in p) == ["ekf_step", "lin_update1"]


def test_more_processes_than_kernels_gives_no_empty_share():
    assert backend.shares(["kf_step", "ekf_step"], 4) == [["ekf_step"], ["kf_step"]]
    assert backend.shares(["a_new_kernel"], 2) == [["a_new_kernel"]]


@pytest.mark.parametrize(
    "raw,count,expected", [("1", 12, 1), ("3", 12, 3), ("8", 2, 2), (" 2 ", 12, 2)]
)
def test_the_variable_sets_the_process_count(monkeypatch, raw, count, expected):
    monkeypatch.setenv(backend.JOBS_ENV, raw)
    assert backend.compile_jobs(count) == expected


def test_the_default_is_the_cpu_count_at_most_four(monkeypatch):
    monkeypatch.delenv(backend.JOBS_ENV, raising=False)
    for cpus, expected in ((1, 1), (2, 2), (16, 4), (None, 1)):
        monkeypatch.setattr(backend.os, "cpu_count", lambda c=cpus: c)
        assert backend.compile_jobs(12) == expected


@pytest.mark.parametrize("raw", ["0", "-1", "two", "1.5"])
def test_a_bad_process_count_is_one_sentence_naming_the_variable(monkeypatch, raw):
    monkeypatch.setenv(backend.JOBS_ENV, raw)
    with pytest.raises(ValueError) as e:
        backend.compile_jobs(12)
    assert str(e.value) == (f"HERA_COMPILE_JOBS={raw!r}: expected a whole number of processes >= 1")


def _exits(code: int):
    def spawn(share: list[str]) -> subprocess.Popen:
        return subprocess.Popen([sys.executable, "-c", f"raise SystemExit({code})"])

    return spawn


def test_helpers_take_the_other_shares_and_their_failures_are_returned():
    here: list[str] = []
    spawned: list[list[str]] = []

    def spawn(share):
        spawned.append(share)
        return _exits(0 if len(spawned) == 1 else 3)(share)

    failed = backend.compile_shared(NAMES, 3, here.append, spawn)
    parts = backend.shares(NAMES, 3)
    assert here == parts[0] and spawned == parts[1:]
    assert failed == [(parts[2], 3)]  # the caller compiles that share itself


def test_a_helper_that_cannot_start_is_a_failure_and_the_rest_goes_on():
    here: list[str] = []

    def spawn(share):
        raise OSError("no more processes")

    failed = backend.compile_shared(NAMES, 2, here.append, spawn)
    parts = backend.shares(NAMES, 2)
    assert here == parts[0] and failed == [(parts[1], -1)]


def test_one_process_spawns_nothing():
    here: list[str] = []
    assert backend.compile_shared(NAMES, 1, here.append, _exits(9)) == []
    assert sorted(here) == sorted(NAMES)


def test_a_helper_that_hangs_is_killed_after_the_timeout(monkeypatch):
    monkeypatch.setattr(backend, "HELPER_TIMEOUT_S", 0.5)

    def spawn(share):
        return subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])

    failed = backend.compile_shared(NAMES, 2, lambda name: None, spawn)
    assert len(failed) == 1 and failed[0][1] != 0


def _decoy(where) -> None:
    """A folder like a source checkout seen from a non-editable install: its ``hera``
    refuses to be imported (hera/__init__.py's checkout check does so)."""
    (where / "hera").mkdir()
    (where / "hera" / "__init__.py").write_text("raise ImportError('the decoy hera')\n")


def test_a_compile_helper_imports_this_hera_not_the_working_folders(tmp_path, monkeypatch):
    """``python -c`` puts the working folder first on the path: run from a source checkout
    (the README's install and run, in the clone), the helpers imported the checkout's hera,
    which refused, and the first compile fell back to one process (60 s instead of 25 s,
    with "a compile helper ended with code 1")."""
    import numba  # noqa: F401  (a test requirement: the helper imports it)

    _decoy(tmp_path)
    monkeypatch.chdir(tmp_path)
    # this hera's folder on the path already, as an install's site-packages is: the helper
    # then adds nothing in front of the working folder
    root = str(Path(backend.__file__).resolve().parents[2])
    monkeypatch.setenv("PYTHONPATH", root)
    helper = backend._spawn_helper([], tmp_path / "cache")  # loads the kernels' module only
    assert helper.wait(timeout=120) == 0


def test_the_memory_probe_of_the_kalman_bench_imports_this_hera(tmp_path, monkeypatch):
    from hera.bench import kalman

    _decoy(tmp_path)
    monkeypatch.chdir(tmp_path)
    assert kalman.loaded_rss_mb(backend="numpy") is not None
