"""The live estimates panel of ``hera up``: each fusion model's latest estimate next to the
truth of the simulated world and its error (when the world is a scenario we can score)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from hera.evaluate import alias


def _truth(world: Mapping[str, Any], t: float) -> dict[str, float] | None:
    if world.get("scenario") != "train":
        return None
    from hera.models.train import truth_columns

    return truth_columns(dict(world), t)


def render_estimates(
    models: Mapping[str, Sequence[str]],
    samples: Sequence[Mapping[str, Any]],
    world: Mapping[str, Any],
) -> str:
    """A table of the latest estimate of each model (name -> its columns) on each node.

    ``samples`` are the ``store`` control verb's samples (name, node, t, values).
    """
    rows = [s for s in samples if s["name"] in models]
    if not rows:
        return "estimates: none yet (models start when their inputs arrive)"
    head = (
        f"{'model':<22} {'node':<9} {'omega rad/s':>11} {'err %':>7} {'radius m':>9} "
        f"{'err cm':>7} {'x m':>7} {'y m':>7} {'pos err cm':>10}"
    )
    lines = ["estimates (truth from the simulated world):", head]
    truth_line = None
    for s in sorted(rows, key=lambda s: (s["name"], s["node"])):
        cols = list(models[s["name"]])
        v = dict(zip(cols, s["values"], strict=False))
        tr = _truth(world, s["t"])
        w, r = v.get("omega [rad/s]"), v.get("radius [m]")
        x, y = v.get("x [m]"), v.get("y [m]")

        def cell(val, width, fmt):
            if val is None:
                return f"{'-':>{width}}"
            sign, rest = ("+", fmt[1:]) if fmt.startswith("+") else ("", fmt)
            return format(val, f">{sign}{width}{rest}")

        w_err = (
            None
            if w is None or tr is None
            else 100 * (w - tr["omega [rad/s]"]) / tr["omega [rad/s]"]
        )
        r_err = None if r is None or tr is None else 100 * (r - tr["radius [m]"])
        p_err = (
            None
            if x is None or y is None or tr is None
            else 100 * math.hypot(x - tr["x [m]"], y - tr["y [m]"])
        )
        lines.append(
            f"{alias(s['name']):<22} {s['node']:<9} {cell(w, 11, '.4f')} {cell(w_err, 7, '+.2f')} "
            f"{cell(r, 9, '.3f')} {cell(r_err, 7, '+.1f')} {cell(x, 7, '.3f')} {cell(y, 7, '.3f')} "
            f"{cell(p_err, 10, '.1f')}"
        )
        if tr is not None:
            truth_line = (
                f"{'truth':<22} {'':<9} {tr['omega [rad/s]']:>11.4f} {'':>7} "
                f"{tr['radius [m]']:>9.3f} {'':>7} {tr['x [m]']:>7.3f} "
                f"{tr['y [m]']:>7.3f}"
            )
    if truth_line:
        lines.append(truth_line + "   (at the last estimate's time)")
    return "\n".join(lines)
