"""The scale benchmark's clusters are valid specs; staggered, the nodes take turns."""

from __future__ import annotations

import tomllib

from hera.bench.scale import PERIOD, STREAMS, main, spec_text
from hera.spec import parse_spec


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


def test_an_unknown_phases_value_is_refused(capsys):
    assert main(["--phases", "grid,random"]) == 2
    assert "--phases: unknown 'random'" in capsys.readouterr().err
