"""Train runs without a cluster: the boards simulated offline (hera.nodes.offline), the
models replayed over the recordings (hera.replay, chained), scored by the application
(hera.evaluate): the same code paths as `hera up` + `hera replay` + `hera eval`, minus
the processes. For accuracy over many seeds and worlds."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hera.application import EvalOptions
from hera.evaluate import by_model, evaluate
from hera.nodes.offline import simulate
from hera.replay import model_args_from_spec, replay
from hera.spec import load_spec

ROOT = Path(__file__).resolve().parents[2]


def train_run(
    spec: str | Path,
    tmp: Path,
    *,
    seed: int,
    duration: float,
    world: dict[str, Any] | None = None,
    models: dict[str, Any] | None = None,
    options: EvalOptions | None = None,
) -> dict[tuple[str, str], dict[str, Any]]:
    """Scores by (model, "replay") of one offline run of ``spec`` (a path, or a name under
    deploy/) with world seed ``seed`` (plus ``world`` keys); ``models``: {model: {setting:
    value}} overrides."""
    path = Path(spec) if Path(spec).exists() else ROOT / "deploy" / f"{spec}.toml"
    s = load_spec(path)
    sim = simulate(s, tmp / "sim", duration, world={"seed": seed, **(world or {})}, seed=seed)
    chosen = model_args_from_spec(s)
    for name, extra in (models or {}).items():
        use, params = chosen[name]
        chosen[name] = (use, {**params, **extra})
    out = tmp / "replay"
    replay(sim, out, chosen)
    return by_model(evaluate(out, options or EvalOptions()))
