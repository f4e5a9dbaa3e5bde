"""Run-time board faults of this node process: the API the control plane calls.

- :func:`set_fault` / :func:`clear_fault` / :func:`list_boards` return JSON-able dicts;
- :func:`handle_inject` serves the control plane's ``inject`` requests
  ``{"target": "board", "board": "<id>", "fault": "stuck|dropout|spikes|bias|disconnect|clear",
  ...params}``.

Board ids are ``"<node>/<board>"``; a bare ``"<board>"`` works when only one board of the
process has that name. Fault kinds and parameters: :mod:`hera.nodes.fault_model`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from hera.nodes import boards
from hera.nodes.fault_model import KINDS


def set_fault(board: str, kind: str, **params: Any) -> dict[str, Any]:
    """Switch fault ``kind`` on ``board`` (replacing any previous one); returns
    ``{"ok": True, "board": id, "fault": {...}}``. ValueError on a bad request."""
    bid, b = _simulated(board)
    fault = b.faults.set(kind, **params)
    return {"ok": True, "board": bid, "fault": fault.describe()}


def clear_fault(board: str) -> dict[str, Any]:
    """Remove any fault from ``board``; returns ``{"ok": True, "board": id, "fault": None}``."""
    bid, b = _simulated(board)
    b.faults.clear()
    return {"ok": True, "board": bid, "fault": None}


def list_boards() -> list[dict[str, Any]]:
    """Every board of this process with its counters and current fault (simulators), or
    just its id and type (real drivers)."""
    out = []
    for bid in boards.ids():
        b = boards.get(bid)
        describe = getattr(b, "describe", None)
        out.append(
            {**describe(), "board": bid}
            if describe is not None
            else {"board": bid, "kind": type(b).__name__, "fault": None}
        )
    return out


def _simulated(board: str) -> tuple[str, Any]:
    b = boards.get(board)
    if not hasattr(b, "faults"):
        raise ValueError(f"board {board!r} is a real driver: it cannot simulate faults")
    bid = next(k for k in boards.ids() if boards.get(k) is b)
    return bid, b


def handle_inject(request: Mapping[str, Any]) -> dict[str, Any]:
    """Apply an ``inject`` request aimed at a board (see the module doc).

    Raises ValueError with a clear message when the request is malformed, names an unknown
    board or fault, or carries parameters the fault does not take.
    """
    if not isinstance(request, Mapping):
        raise ValueError(f"inject request must be a map, got {type(request).__name__}")
    req = dict(request)
    target = req.pop("target", "board")
    if target != "board":
        raise ValueError(f"this handler injects board faults only, got target {target!r}")
    board = req.pop("board", None)
    if not isinstance(board, str) or not board:
        raise ValueError("inject request needs 'board': the board id, e.g. 'n1/nav'")
    kind = req.pop("fault", None)
    if kind == "clear":
        if req:
            raise ValueError(f"fault 'clear' takes no parameters, got {sorted(req)}")
        return clear_fault(board)
    if kind not in KINDS:
        raise ValueError(f"inject 'fault' must be one of {(*KINDS, 'clear')}, got {kind!r}")
    bad = [k for k in req if not isinstance(k, str)]
    if bad:
        raise ValueError(f"fault parameter names must be strings, got {bad!r}")
    return set_fault(board, kind, **req)
