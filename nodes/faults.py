"""Run-time board faults of a node: the ``board`` control verb of the simulator.

``hera/<cluster>/ctl/<node>/board`` with a JSON request:

- ``{}``: list the node's boards with their counters and current fault;
- ``{"board": "<id>", "fault": "stuck|dropout|spikes|bias|disconnect|field", ...params}``:
  switch that fault on (replacing any previous one);
- ``{"board": "<id>", "fault": "clear"}``: remove it.

Board ids are ``"<node>/<board>"``; a bare ``"<board>"`` works when only one board of the
node has that name. Fault kinds and parameters: :mod:`hera.nodes.fault_model`. Only
simulated boards take faults; a real driver is listed but refuses them.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from hera.application import VerbContext
from hera.nodes import boards as board_registry
from hera.nodes.boards import Boards
from hera.nodes.fault_model import KINDS


def set_fault(boards: Boards, board: str, kind: str, **params: Any) -> dict[str, Any]:
    """Switch fault ``kind`` on ``board``; returns ``{"board": id, "fault": {...}}``.
    ValueError on a bad request."""
    bid, b = _simulated(boards, board)
    fault = b.faults.set(kind, **params)
    return {"board": bid, "fault": fault.describe()}


def clear_fault(boards: Boards, board: str) -> dict[str, Any]:
    """Remove any fault from ``board``; returns ``{"board": id, "fault": None}``."""
    bid, b = _simulated(boards, board)
    b.faults.clear()
    return {"board": bid, "fault": None}


def list_boards(boards: Boards) -> list[dict[str, Any]]:
    """Every board of the node with its counters and current fault (simulators), or just
    its id and type (real drivers)."""
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


def _simulated(boards: Boards, board: str) -> tuple[str, Any]:
    b = boards.get(board)
    if not hasattr(b, "faults"):
        raise ValueError(f"board {board!r} is a real driver: it cannot simulate faults")
    return boards.id_of(b), b


def board_verb(request: Mapping[str, Any], ctx: VerbContext) -> dict[str, Any]:
    """The ``board`` control verb (see the module docstring).

    Raises ValueError with a clear message when the request is malformed, names an unknown
    board or fault, or carries parameters the fault does not take.
    """
    boards = board_registry.of(ctx.resources)
    req = dict(request)
    if not req:
        return {"boards": list_boards(boards)}
    board = req.pop("board", None)
    if not isinstance(board, str) or not board:
        raise ValueError("a board request needs 'board': the board id, e.g. 'n1/nav'")
    kind = req.pop("fault", None)
    if kind == "clear":
        if req:
            raise ValueError(f"fault 'clear' takes no parameters, got {sorted(req)}")
        return clear_fault(boards, board)
    if kind not in KINDS:
        raise ValueError(
            f"board 'fault' must be one of {', '.join((*KINDS, 'clear'))}, got {kind!r}"
        )
    return set_fault(boards, board, kind, **req)
