"""The simulated boards of this node process, shared by the measures that read them.

A board is identified by ``"<node>/<board>"`` (``board`` is the measure arg ``board``,
default ``"nav"`` for a Pmod NAV and ``"sonar"`` for a MaxSonar). Several measures of one node
naming the same board share it, like measures sharing one physical Pmod. A board outlives the
measures reading it: a restarted measure finds the same board, with any fault still on.

Board seed: ``stable_seed(kind, node, board, seed)`` where ``seed`` is the measure arg
``seed`` if given, else ``ctx.seed``; the first measure to open a board fixes it, so measures
sharing a board should agree on it (true by default: the spec's seeds).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Mapping
from typing import Any

from hera.nodes import geometry as gm
from hera.nodes.air import Air
from hera.nodes.driver import NavDriver, SonarDriver
from hera.nodes.imu_model import NavModel
from hera.nodes.noise import stable_seed
from hera.nodes.sim_nav import SimNavBoard
from hera.nodes.sim_sonar import SimMaxSonar
from hera.nodes.sonar_model import SonarModel
from hera.nodes.world import SonarMount, environment, epoch_of, make_scenario

from hera.keys import Keys, check_chunk
from hera.measure import MeasureContext

Board = Any
"""A registered board: a simulator (:class:`SimNavBoard`, :class:`SimMaxSonar`) or any real
driver satisfying :class:`hera.nodes.driver.NavDriver` or ``SonarDriver``."""

_lock = threading.RLock()
_boards: dict[str, Board] = {}
_sessions: dict[str, Any] = {}
_airs: list[tuple[Any, str, str, Air]] = []


def board_id(node: str, board: str) -> str:
    """The process-wide id of a board: ``"<node>/<board>"``."""
    return f"{check_chunk(node, 'node name')}/{check_chunk(board, 'board name')}"


def get(board: str) -> Board:
    """The board with id ``"<node>/<board>"``, or with the bare name ``board`` if exactly one
    board of this process has it; ValueError otherwise."""
    with _lock:
        if board in _boards:
            return _boards[board]
        matches = [b for k, b in _boards.items() if k.split("/", 1)[1] == board]
        known = sorted(_boards)
    if len(matches) == 1:
        return matches[0]
    if not matches:
        raise ValueError(f"no board {board!r} in this process; boards: {known}")
    raise ValueError(f"board name {board!r} is ambiguous; use one of {known}")


def all_boards() -> list[Board]:
    with _lock:
        return [_boards[k] for k in sorted(_boards)]


def register(board: Board, session: Any = None, board_id: str | None = None) -> Board:
    """Add (or replace) a board under ``board_id`` (default ``board.id``).

    A real driver registered as ``"<node>/nav"`` (or ``"<node>/sonar"``) before the measures
    start is used by them instead of the simulator.
    """
    bid = board_id if board_id is not None else board.id
    with _lock:
        _boards[bid] = board
        _sessions[bid] = session
    return board


def ids() -> list[str]:
    """The ids of every registered board."""
    with _lock:
        return sorted(_boards)


def air_for(session: Any, keys: Keys, group: str) -> Air:
    """The one :class:`Air` of (session, cluster, group) in this process."""
    with _lock:
        for s, cluster, grp, air in _airs:
            if s is session and cluster == keys.cluster and grp == group:
                return air
        air = Air(session, keys, group)
        _airs.append((session, keys.cluster, group, air))
        return air


def reset() -> None:
    """Forget every board and close every air (tests; a node process never needs it)."""
    with _lock:
        for *_, air in _airs:
            air.close()
        _airs.clear()
        _boards.clear()
        _sessions.clear()


def _seed(ctx: MeasureContext, args: Mapping[str, Any], kind: str, name: str) -> int:
    seed = args.get("seed", ctx.seed)
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise ValueError(f"seed must be an integer, got {seed!r}")
    return stable_seed(kind, ctx.node, name, seed)


def open_nav(ctx: MeasureContext, args: Mapping[str, Any]) -> NavDriver:
    """The simulated Pmod NAV ``args["board"]`` (default "nav") of ``ctx.node``, created on
    first use from ``ctx.world`` and the args ``model`` (a :class:`NavModel` table) and
    ``seed``."""
    name = str(args.get("board", "nav"))
    bid = board_id(ctx.node, name)
    with _lock:
        b = _boards.get(bid)
        if b is not None:
            if not isinstance(b, NavDriver):
                raise ValueError(f"board {bid!r} is not a Pmod NAV driver")
            return b
        board = SimNavBoard(
            bid,
            make_scenario(ctx.world),
            environment(ctx.world),
            epoch_of(ctx.world),
            NavModel.from_args(args.get("model")),
            _seed(ctx, args, "pmod_nav", name),
        )
        return register(board, ctx.session)  # type: ignore[return-value]


def sonar_mount(ctx: MeasureContext, args: Mapping[str, Any]) -> SonarMount:
    """Where a sonar is: args ``position``/``direction``, else ``world.sonars[<node>]``, else
    the scenario's default placement number ``args["index"]`` (default 0)."""
    placed = ctx.world.get("sonars", {})
    if not isinstance(placed, Mapping):
        raise ValueError("world 'sonars' must be a table of node -> {position, direction}")
    mine = placed.get(ctx.node, {})
    pos = args.get("position", mine.get("position"))
    direction = args.get("direction", mine.get("direction"))
    if pos is None or direction is None:
        defaults = make_scenario(ctx.world).default_sonars()
        index = args.get("index", 0)
        if not isinstance(index, int) or not 0 <= index < len(defaults):
            raise ValueError(f"sonar index must be within [0, {len(defaults)}), got {index!r}")
        d = defaults[index]
        pos = d.position if pos is None else pos
        direction = d.direction if direction is None else direction
    return SonarMount(gm.vec3(pos, "sonar position"), gm.unit(gm.vec3(direction, "direction")))


def open_sonar(ctx: MeasureContext, args: Mapping[str, Any]) -> SonarDriver:
    """The simulated MaxSonar ``args["board"]`` (default "sonar") of ``ctx.node``.

    Args used: ``position``, ``direction``, ``index`` (see :func:`sonar_mount`), ``model``
    (a :class:`SonarModel` table), ``ping_ms``, ``half_angle_deg``, ``seed``, ``fire_log``
    (path), ``air_group`` (default: the spec's sync group), ``crosstalk`` (default true: use
    the air).
    """
    name = str(args.get("board", "sonar"))
    bid = board_id(ctx.node, name)
    with _lock:
        b = _boards.get(bid)
        if b is not None and not isinstance(b, SonarDriver):
            raise ValueError(f"board {bid!r} is not a MaxSonar driver")
        if b is not None and (not isinstance(b, SimMaxSonar) or _sessions.get(bid) is ctx.session):
            return b  # a simulator bound to another (closed) session is rebuilt
        table = dict(args.get("model") or {})
        for key in ("ping_ms", "half_angle_deg"):
            if key in args:
                table[key] = args[key]
        model = SonarModel.from_args(table)
        if not math.isfinite(model.half_angle_deg) or model.half_angle_deg >= 90:
            raise ValueError("sonar half_angle_deg must be < 90")
        group = str(args.get("air_group", ctx.spec.group))
        air = air_for(ctx.session, ctx.keys, group) if args.get("crosstalk", True) else None
        fire_log = args.get("fire_log")
        board = SimMaxSonar(
            bid,
            bid,
            make_scenario(ctx.world),
            epoch_of(ctx.world),
            sonar_mount(ctx, args),
            model,
            _seed(ctx, args, "maxsonar", name),
            air=air,
            fire_log=str(fire_log) if fire_log else None,
            node=ctx.node,
        )
        return register(board, ctx.session)  # type: ignore[return-value]
