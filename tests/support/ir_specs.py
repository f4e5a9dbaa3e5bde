"""The seed-000 example specs, changed for a test: another world, more sensors, other model
settings. Imported by tests as ``ir_specs``."""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"


def toml_value(v: Any) -> str:
    """``v`` as a TOML value (numbers, strings, booleans, lists, inline tables)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, Mapping):
        return "{ " + ", ".join(f"{k} = {toml_value(x)}" for k, x in v.items()) + " }"
    return "[" + ", ".join(toml_value(x) for x in v) + "]"


def spec(name: str, world: Mapping[str, Any] | None = None, extra: str = "") -> str:
    """The text of ``deploy/<name>.toml`` with its ``[world]`` table replaced by ``world``
    (if given) and ``extra`` appended."""
    text = (DEPLOY / f"{name}.toml").read_text()
    if world is not None:
        body = "\n".join(f"{k} = {toml_value(v)}" for k, v in world.items())
        text, n = re.subn(r"\[world\]\n(?:.*\n)*?(?=\n\[)", f"[world]\n{body}\n", text, count=1)
        assert n == 1, "no [world] table"
    return text + extra


def replace(text: str, old: str, new: str) -> str:
    """``text`` with the first ``old`` replaced by ``new`` (AssertionError if absent)."""
    assert old in text, f"not in the spec: {old!r}"
    return text.replace(old, new, 1)
