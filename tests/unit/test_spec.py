from pathlib import Path

import pytest

from hera.spec import SpecError, load_spec, parse_spec

ROOT = Path(__file__).resolve().parents[2]


def test_observers_spec_declares_five_nodes_with_four_counters_each():
    spec = load_spec(ROOT / "deploy" / "observers.toml")
    assert [n.name for n in spec.nodes] == ["n1", "n2", "n3", "n4", "n5"]
    for n in spec.nodes:
        assert [m.name for m in n.measures] == ["obs1", "obs2", "obs3", "obs4"]
        assert {m.use for m in n.measures} == {"counter"}


def test_resolved_json_round_trips(tmp_path):
    spec = load_spec(ROOT / "deploy" / "observers.toml").with_ports([1, 2, 3, 4, 5])
    (tmp_path / "cluster.json").write_text(spec.with_world(epoch=5.0).to_json())
    back = load_spec(tmp_path / "cluster.json")
    assert back.nodes == spec.nodes and back.world["epoch"] == 5.0
    assert back.endpoint("n3") == "tcp/127.0.0.1:3"


BASE = {"cluster": {"name": "c"}, "nodes": [{"name": "a"}]}
CHUNK = "must use only letters, digits, '_', '.' and '-' (no '/', '*', '$'), at most 64 of them"
MEASURE_KEYS = (
    "use, name, period, offset, thread, iterations, sync, sync_group, slot, restart, hang_factor, "
    "hang_min, seed, args"
)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"cluster": {"name": "a/b"}}, f"s.toml: [cluster]: name {CHUNK}, got 'a/b'"),
        (
            {"cluster": {}},
            "s.toml: [cluster]: name is required (cluster name: the key prefix `hera/<name>/`)",
        ),
        ({"nodes": []}, "s.toml: [[nodes]]: a spec needs at least one [[nodes]] entry"),
        ({"nodes": [{"name": "a"}, {"name": "a"}]}, "s.toml: [[nodes]]: two nodes are called 'a'"),
        (
            {"nodes": [{"nmae": "a"}]},
            (
                "s.toml: [[nodes]] #1: unknown key 'nmae' (did you mean 'name'?); known keys: "
                "name, port, sync_hosts, measures, host, mode, listen, connect, store",
                "s.toml: [[nodes]] #1: name is required (node name, the `<node>` of its keys)",
            ),
        ),
        (
            {"nodes": [{"name": "a", "sync_host": ["g"]}]},
            "s.toml: [[nodes]] #1 (a): unknown key 'sync_host' (did you mean 'sync_hosts'?); "
            "known keys: name, port, sync_hosts, measures, host, mode, listen, connect, store",
        ),
        (
            {"cluster": {"name": "c", "base_prot": 7000}},
            "s.toml: [cluster]: unknown key "
            "'base_prot' (did you mean 'base_port'?); known keys: name, host, base_port, lease_ms, "
            "sync_lease_ms, multicast_scouting, estimation_backend",
        ),
        (
            {"supervisor": {"intensty": 3}},
            "s.toml: [supervisor]: unknown key 'intensty' (did you "
            "mean 'intensity'?); known keys: strategy, intensity, period, shutdown",
        ),
        (
            {"measures": [{"name": "x"}]},
            "s.toml: [[measures]] #1: use is required (entry point of "
            "group `hera.measures`, or `package.module:Class`)",
        ),
        (
            {"measures": [{"use": "counter", "on": ["zz"]}]},
            "s.toml: [[measures]] #1: on names unknown node(s) ['zz']; nodes: a",
        ),
        (
            {"measures": [{"use": "counter", "period": -1}]},
            "s.toml: [[measures]] #1: period must be a number > 0, got -1",
        ),
        (
            {"measures": [{"use": "counter", "period": 0.1, "offset": 0.1}]},
            "s.toml: [[measures]] #1: measure 'counter': offset must be below the period "
            "(0.1 s), got 0.1",
        ),
        (
            {"measures": [{"use": "counter", "sync": True, "offset": 0.01}]},
            "s.toml: [[measures]] #1: measure 'counter': offset is for unsynchronised "
            "measures (sync = true)",
        ),
        (
            {"measures": [{"use": "counter", "restart": "sometimes"}]},
            "s.toml: [[measures]] #1: "
            "restart must be one of permanent, transient, temporary, got 'sometimes'",
        ),
        (
            {"measures": [{"use": "counter", "colour": 1}]},
            f"s.toml: [[measures]] #1: unknown key 'colour'; known keys: {MEASURE_KEYS}",
        ),
        (
            {"measures": [{"use": "counter"}, {"use": "counter"}]},
            "s.toml: node a: two measures publish as 'counter'",
        ),
        (
            {"cluster": {"name": "c", "base_port": 80}},
            "s.toml: [cluster]: base_port must be 0 "
            "(pick free ports) or an integer within [1024, 65000), got 80",
        ),
        ({"logging": {"node": "zz"}}, "s.toml: [logging]: node 'zz' is not a node of the spec"),
        (
            {"supervisor": {"strategy": "all_for_none"}},
            "s.toml: [supervisor]: strategy must be "
            "one of one_for_one, one_for_all, rest_for_one, got 'all_for_none'",
        ),
        (
            {"wat": {}},
            "s.toml: unknown table 'wat'; known tables: cluster, supervisor, logging, "
            "security, world, defaults, nodes, routers, measures",
        ),
    ],
)
def test_bad_specs_fail_with_one_sentence_naming_file_table_and_key(change, message):
    with pytest.raises(SpecError) as e:
        parse_spec({**BASE, **change}, "s.toml")
    assert e.value.problems == ([message] if isinstance(message, str) else list(message))


def test_every_problem_of_a_spec_is_reported_at_once():
    bad = {
        "cluster": {"name": "c", "lease_ms": "2s"},
        "nodes": [{"name": "a", "port": -1}],
        "measures": [{"use": "counter", "period": 0}],
    }
    with pytest.raises(SpecError) as e:
        parse_spec(bad, "s.toml")
    assert e.value.problems == [
        "s.toml: [cluster]: lease_ms must be an integer >= 100 and <= 600000, got '2s'",
        "s.toml: [[nodes]] #1 (a): port must be an integer >= 0 and <= 65535, got -1",
        "s.toml: [[measures]] #1: period must be a number > 0, got 0",
    ]


def test_unknown_node_lists_the_known_ones():
    spec = parse_spec(BASE)
    with pytest.raises(SpecError, match=r"no node 'b' .*nodes: a"):
        spec.node("b")


def test_count_expands_names_and_base_port_assigns_ports():
    spec = parse_spec(
        {
            "cluster": {"name": "c", "base_port": 7000},
            "nodes": [{"name": "a"}, {"name": "b"}],
            "measures": [{"use": "counter", "name": "o{i}", "count": 3, "on": ["b"]}],
        }
    )
    assert [m.name for m in spec.node("b").measures] == ["o1", "o2", "o3"]
    assert spec.node("a").measures == ()
    assert [n.port for n in spec.nodes] == [7000, 7001]


def test_parsing_declared_arguments_twice_gives_the_same():
    from hera.nodes.measures.sonar import Sonar

    once = Sonar.prepare_args({"max_range": 3})
    assert once["seed"] is None and once["crosstalk"] is True
    assert Sonar.prepare_args(once) == once


def test_ports_go_to_the_listeners_that_have_none():
    """A router with its port and client nodes (which listen on nothing) next to a peer
    without one: only the peer gets a port (hera bench scale's router topology)."""
    spec = parse_spec(
        {
            "cluster": {"name": "x"},
            "routers": [{"name": "r", "port": 7000}, {"name": "r2"}],
            "nodes": [
                {"name": "a", "mode": "client", "connect": ["tcp/127.0.0.1:7000"]},
                {"name": "b"},
            ],
        }
    )
    assert [p.name for p in spec.unported()] == ["b", "r2"]
    ported = spec.with_ports([9001, 9002])
    assert [(n.name, n.port) for n in ported.nodes] == [("a", 0), ("b", 9001)]
    assert [(r.name, r.port) for r in ported.routers] == [("r", 7000), ("r2", 9002)]
    with pytest.raises(ValueError, match="2 ports needed, 1 given"):
        spec.with_ports([9001])
