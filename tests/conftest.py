"""Shared fixtures: real clusters started with ``hera up`` on loopback, always cleaned up."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from harness import Cluster, cluster_env

SLOW_TIMEOUT_S = 1800


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """A ``slow`` test is a long campaign (the full nemesis runs 11 minutes): it gets
    ``SLOW_TIMEOUT_S``, not the 300 s of the configuration, unless it names its own."""
    for item in items:
        if item.get_closest_marker("slow") and not item.get_closest_marker("timeout"):
            item.add_marker(pytest.mark.timeout(SLOW_TIMEOUT_S))


@pytest.fixture
def cluster(tmp_path: Path) -> Iterator[Callable[..., Cluster]]:
    """Start clusters from spec text; stops them all at the end and fails on leftovers."""
    started: list[Cluster] = []

    def start(
        spec_text: str,
        name: str = "run",
        duration: float | None = None,
        connect: bool = True,
        overwrite: bool = False,
    ) -> Cluster:
        spec = tmp_path / f"{name}.toml"
        spec.write_text(spec_text)
        c = Cluster(spec, tmp_path / name, cluster_env(tmp_path), duration, overwrite)
        started.append(c)
        if connect:
            c.connect()
        return c

    yield start
    errors = []
    for c in started:
        try:
            c.stop()
        except AssertionError as e:
            errors.append(str(e))
    assert not errors, errors
