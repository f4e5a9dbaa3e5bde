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


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"cluster": {"name": "a/b"}}, "[cluster] name"),
        ({"nodes": []}, "at least one [[nodes]]"),
        ({"nodes": [{"name": "a"}, {"name": "a"}]}, "duplicate node name"),
        ({"measures": [{"name": "x"}]}, "needs 'use'"),
        ({"measures": [{"use": "counter", "on": ["zz"]}]}, "'on' must be"),
        ({"measures": [{"use": "counter", "period": -1}]}, "period must be > 0"),
        ({"measures": [{"use": "counter", "restart": "sometimes"}]}, "restart must be"),
        ({"measures": [{"use": "counter", "colour": 1}]}, "unknown field(s) ['colour']"),
        ({"measures": [{"use": "counter"}, {"use": "counter"}]}, "two measures publish as"),
        ({"cluster": {"name": "c", "base_port": 80}}, "base_port"),
        ({"logging": {"node": "zz"}}, "[logging] node"),
        ({"supervisor": {"strategy": "all_for_none"}}, "strategy"),
        ({"wat": {}}, "unknown table"),
    ],
)
def test_bad_specs_fail_naming_the_field(change, message):
    with pytest.raises(SpecError) as e:
        parse_spec({**BASE, **change}, "s.toml")
    assert message in str(e.value) and str(e.value).startswith("s.toml:")


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
