"""The scale benchmark's clusters are valid specs; staggered, the nodes take turns."""

from __future__ import annotations

import pytest

from hera.bench.scale import PERIOD, STREAMS, main, spec_text
from hera.bench.security import secure
from hera.spec import parse_spec, tomllib


def _offsets(text: str) -> dict[str, set]:
    spec = parse_spec(tomllib.loads(text), "scale.toml")
    return {n.name: {m.offset for m in n.measures if m.name != "reader"} for n in spec.nodes}


def test_on_the_grid_every_stream_takes_the_default_phase():
    offsets = _offsets(spec_text(4, "mesh", 1.0, "grid"))
    assert offsets == {f"n{i}": {None} for i in range(1, 5)}


def test_staggered_the_nodes_spread_over_the_period():
    text = spec_text(4, "routers", 1.0, "staggered")
    offsets = _offsets(text)
    assert offsets == {f"n{i + 1}": {round(PERIOD * i / 4, 6)} for i in range(4)}
    assert text.count("offset =") == 4 * STREAMS


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["--phases", "grid,random"], "--phases: must be one of grid, staggered, got 'random'"),
        (["--topologies", "star"], "--topologies: must be one of mesh, routers, got 'star'"),
        (["--nodes", "8,1"], "--nodes: must be a whole number >= 4, got '1'"),
        (["--nodes", "x"], "--nodes: must be a whole number, got 'x'"),
    ],
)
def test_an_option_outside_what_the_benchmark_can_lay_out_is_refused(capsys, argv, says):
    with pytest.raises(SystemExit) as refused:  # before any node starts
        main(argv)
    assert refused.value.code == 2
    assert capsys.readouterr().err.splitlines()[-1].endswith(f"error: argument {says}")


def test_an_unknown_security_mode_is_refused(capsys):
    assert main(["--security", "auth,ssh"]) == 2
    assert "--security: unknown 'ssh'; use none, auth, tls" in capsys.readouterr().err


def test_tls_mode_makes_a_certificate_for_every_node_and_router(tmp_path):
    text = secure(spec_text(4, "routers", 1.0, "staggered"), "tls", tmp_path / "certs")
    spec = parse_spec(tomllib.loads(text), "scale.toml")
    assert spec.tls and spec.certs == (tmp_path / "certs").as_posix()
    made = {p.stem for p in (tmp_path / "certs").glob("*.crt")} | {
        p.stem for p in (tmp_path / "certs").glob("*.pem")
    }
    assert {"n1", "n2", "n3", "n4", "r1"} <= made, made
    assert secure("x", "auth", tmp_path / "unused") == "x"
    assert not (tmp_path / "unused").exists()


def test_with_ports_every_mesh_peer_gets_its_own_and_clients_none():
    mesh = parse_spec(tomllib.loads(spec_text(4, "mesh", 1.0, ports=True)), "scale.toml")
    ports = [n.port for n in mesh.nodes]
    assert all(ports) and len(set(ports)) == 4, ports
    routed = parse_spec(tomllib.loads(spec_text(4, "routers", 1.0, ports=True)), "scale.toml")
    assert [n.port for n in routed.nodes] == [0] * 4 and routed.routers[0].port
