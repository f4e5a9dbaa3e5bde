"""Every problem of a spec at once (a problem in one table hides none of another's), and
sync slots no longer than the sync lease grants, refused before anything starts."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from harness import cluster_env

from hera.preflight import check_spec
from hera.spec import SpecError, parse_spec

BASE = {"cluster": {"name": "c"}, "nodes": [{"name": "a"}]}
CLUSTER_TYPO = (
    "s.toml: [cluster]: unknown key 'base_prot' (did you mean 'base_port'?); known keys: name, "
    "host, base_port, lease_ms, sync_lease_ms, multicast_scouting, estimation_backend"
)
RADIUS_TYPO = (
    "s.toml: measure 'track_radius' of node 'a': args: model: unknown setting 'radius_m' (did "
    "you mean 'radius'?); known settings: radius, center, "
)


def problems_of(data: dict) -> list[str]:
    with pytest.raises(SpecError) as e:
        check_spec(parse_spec(data, "s.toml"))
    return e.value.problems


def runs(data: dict) -> None:
    check_spec(parse_spec(data, "s.toml"))


def test_the_readmes_two_problem_example_reports_both():
    """README "Spec format": a typo in [cluster] and one in a model's settings, both."""
    got = problems_of(
        {
            "cluster": {"name": "c", "base_prot": 7000},
            "nodes": [
                {
                    "name": "a",
                    "measures": [{"use": "track_radius", "args": {"model": {"radius_m": 0.6}}}],
                }
            ],
        }
    )
    assert len(got) == 2, got
    assert got[0] == CLUSTER_TYPO
    assert got[1].startswith(RADIUS_TYPO), got[1]


def test_a_thread_and_sync_conflict_hides_no_argument_problem():
    got = problems_of(
        {
            **BASE,
            "measures": [
                {
                    "use": "track_gyro",
                    "thread": "shared",
                    "sync": True,
                    "args": {"mode": "arrival", "max_age": 1, "reorder_s": 9},
                }
            ],
        }
    )
    assert got == [
        "s.toml: [[measures]] #1: measure 'track_gyro': thread = \"shared\" is for "
        "unsynchronised measures (sync = true)",
        "s.toml: measure 'track_gyro' of node 'a': args: reorder_s must be a number >= 0 and "
        "<= 5, got 9",
        "s.toml: measure 'track_gyro' of node 'a': args: max_age is for period mode and does "
        'nothing in arrival mode (set mode = "period" or leave max_age out)',
    ]  # and not "no node hosts group 'track_gyro'": that depends on the conflicting sync


def test_checks_that_depend_on_a_broken_value_are_skipped():
    """A broken period hides the offset check (against which period?); broken args hide
    the argument check; a broken [world] hides the world check; the rest is reported."""
    got = problems_of(
        {
            **BASE,
            "world": 5,
            "measures": [
                {"use": "counter", "name": "p", "period": -1, "offset": 0.5},
                {"use": "counter", "name": "q", "args": 3},
                {"use": "counter", "name": "r", "args": {"prefxi": "x"}},
                {"use": "no_such_measure"},
            ],
        }
    )
    assert got[:3] == [
        "s.toml: [world] must be a table",
        "s.toml: [[measures]] #1: period must be a number > 0, got -1",
        "s.toml: [[measures]] #2: args must be a table, got 3",
    ]
    assert got[3].startswith(
        "s.toml: measure 'r' of node 'a': args: unknown key 'prefxi' (did you mean 'prefix'?)"
    )
    assert got[4].startswith("s.toml: measure 'no_such_measure' of node 'a': unknown measure")
    assert len(got) == 5, got


def test_the_command_line_reports_the_problems_of_three_tables_exit_2(tmp_path):
    """``hera up`` (the venv's console script) on a spec with a problem in [cluster], in
    [supervisor] and in a measure's arguments: all three, one line each, exit code 2."""
    spec = tmp_path / "bad.toml"
    spec.write_text(
        '[cluster]\nname = "e"\nbase_prot = 7000\n'
        '[supervisor]\nstrategy = "all_for_none"\n'
        '[[nodes]]\nname = "a"\n'
        '[[nodes.measures]]\nuse = "track_radius"\nargs = { model = { radius_m = 0.6 } }\n'
    )
    out = subprocess.run(
        [str(Path(sys.executable).with_name("hera")), "up", str(spec), "--run-dir", "run"],
        env=cluster_env(tmp_path),
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    head = f"hera up: {spec}: "
    assert lines[:2] == [
        head + CLUSTER_TYPO.removeprefix("s.toml: "),
        head + "[supervisor]: strategy must be one of one_for_one, one_for_all, rest_for_one, "
        "got 'all_for_none'",
    ], out.stderr
    assert lines[2].startswith(head + RADIUS_TYPO.removeprefix("s.toml: ")), out.stderr
    assert len(lines) == 3, out.stderr
    assert not (tmp_path / "run").exists()


def synced(slot: float, lease_ms: int | None = None, **measure) -> dict:
    cluster = {"name": "c"} if lease_ms is None else {"name": "c", "sync_lease_ms": lease_ms}
    return {
        "cluster": cluster,
        "nodes": [
            {
                "name": "a",
                "sync_hosts": ["g"],
                "measures": [{"use": "counter", "sync_group": "g", "slot": slot, **measure}],
            }
        ],
    }


def test_a_slot_longer_than_the_sync_lease_grants_is_refused_before_start():
    """The client asks for slot + max(5 ms, 25 %) and a leader grants at most half of
    sync_lease_ms: with the default 300 ms, 0.12 s is the longest slot, not 0.15 s."""
    assert problems_of(synced(0.5, sync=True)) == [
        "s.toml: measure 'counter' of node 'a': slot 0.5 s is too long for "
        "[cluster] sync_lease_ms = 300: its lease (0.625 s: the slot plus 25%, at least 5 ms) "
        "must fit in half the sync lease, so the longest slot is 0.12 s; shorten the slot or "
        "raise [cluster] sync_lease_ms to 1250 or more"
    ]
    for slot in (0.15, 0.1201):  # half the lease, and just above the longest
        (line,) = problems_of(synced(slot, sync=True))
        assert "the longest slot is 0.12 s" in line and "sync_lease_ms to " in line
    runs(synced(0.12, sync=True))  # the longest is taken
    (line,) = problems_of(synced(0.5, 1000, sync=True))
    assert "sync_lease_ms = 1000" in line and "the longest slot is 0.4 s" in line
    runs(synced(0.4, 1000, sync=True))
    runs(synced(0.5, 1250, sync=True))


def test_the_slot_check_follows_the_class_when_the_spec_leaves_sync_out():
    """sonar is synchronised by its class; counter is not (its slot is unused)."""
    runs(synced(0.5))  # counter, unsynchronised: the slot does nothing
    runs(synced(0.5, sync=False))
    data = synced(0.5, use="sonar")
    (line,) = problems_of(data)
    assert line.startswith("s.toml: measure 'sonar' of node 'a': slot 0.5 s")


def test_the_spec_check_and_the_sync_service_share_one_limit():
    """The largest slot the spec takes is the largest the running service grants, for any
    lease; one more 0.1 ms is refused by both."""
    from hera.spec import longest_slot, max_slot_lease, slot_problem
    from hera.sync.client import slot_duration
    from hera.sync.service import SyncService

    for ms in (20, 49, 60, 150, 300, 301, 1000, 1600):
        service = SyncService(None, None, "a", (), lease_ms=ms)  # hosts nothing: no session
        longest = longest_slot(max_slot_lease(ms))
        assert longest > 0
        assert slot_duration(longest) <= service.timing.max_slot
        assert slot_problem(longest, ms) is None
        assert slot_duration(longest + 1e-4) > service.timing.max_slot
        assert slot_problem(longest + 1e-4, ms) is not None


def test_the_run_time_refusal_names_the_spec_key():
    """A slot too long at run time (a spec not checked) names sync_lease_ms, a spec key,
    not max_slot_ms, which the spec does not have."""
    from hera.sync.client import SyncClient, slot_duration
    from hera.sync.election import Timing

    client = SyncClient(None, None, Timing(lease=0.3, max_slot=0.15))
    with pytest.raises(ValueError) as e:
        client.acquire("s", "h", slot_duration(0.5), timeout=1.0)
    message = str(e.value)
    assert "max_slot_ms" not in message
    assert "[cluster] sync_lease_ms" in message and "the longest slot is 0.12 s" in message


def test_every_sync_lease_the_spec_takes_is_one_the_sync_service_can_run():
    """The spec took sync_lease_ms up to 60000, but above 1650 the service's clock condition
    (its 50 ms margin against 1 % drift over lease + longest slot) failed at node start."""
    from hera.spec import SYNC_LEASE_MS_MAX
    from hera.sync.service import SyncService

    SyncService(None, None, "a", (), lease_ms=SYNC_LEASE_MS_MAX)
    with pytest.raises(ValueError, match="margin 0.05 s is too small"):
        SyncService(None, None, "a", (), lease_ms=SYNC_LEASE_MS_MAX + 1)
    runs({"cluster": {"name": "c", "sync_lease_ms": SYNC_LEASE_MS_MAX}, "nodes": [{"name": "a"}]})
    (line,) = problems_of(
        {"cluster": {"name": "c", "sync_lease_ms": SYNC_LEASE_MS_MAX + 1}, "nodes": [{"name": "a"}]}
    )
    assert line == "s.toml: [cluster]: sync_lease_ms must be an integer >= 20 and <= 1650, got 1651"


def test_a_slot_the_spec_leaves_to_the_class_is_checked_too():
    """sonar's own slot (0.06 s) asks for a 0.075 s lease: too long for a 100 ms sync lease."""
    data = {
        "cluster": {"name": "c", "sync_lease_ms": 100},
        "nodes": [{"name": "a", "sync_hosts": ["sonar"], "measures": [{"use": "sonar"}]}],
    }
    (line,) = problems_of(data)
    assert line.startswith(
        "s.toml: measure 'sonar' of node 'a': slot 0.06 s is too long for [cluster] "
        "sync_lease_ms = 100"
    ), line
    data["cluster"]["sync_lease_ms"] = 150
    runs(data)


def test_nodes_written_as_one_table_are_named_so():
    """[nodes] (one bracket) read as "a spec needs at least one [[nodes]] entry"."""
    from hera.spec import tomllib

    data = tomllib.loads('[cluster]\nname = "c"\n[nodes]\nname = "a"\n')
    assert problems_of(data) == [
        "s.toml: [nodes] is a table; nodes are a list of tables: write [[nodes]] (two "
        "brackets), one per node"
    ]
