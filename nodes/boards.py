"""The boards of one node, shared by the measures that read them.

Each node has one :class:`Boards` registry, kept in its resources (``ctx.resources``, see
:mod:`hera.resources`): nothing is process-global, so two nodes (or two tests) in one
process never share a board. A board is identified by ``"<node>/<board>"`` (``board`` is
the measure arg ``board``, default ``"nav"`` for a Pmod NAV and ``"sonar"`` for a MaxSonar).
Several measures of one node naming the same board share it, like measures sharing one
physical Pmod. A board outlives the measures reading it: a restarted measure finds the same
board, with any fault still on.

Which driver a board gets:

- a driver already registered under its id (:meth:`Boards.register`, e.g. by a test);
- the measure arg ``driver = "package.module:Class"`` (a real board's driver, made with
  ``Class(**driver_args)``; it must satisfy :class:`~hera.nodes.driver.NavDriver` or
  :class:`~hera.nodes.driver.SonarDriver`);
- else the simulator, built from the world table.

Board seed of a simulator: ``stable_seed(kind, node, board, seed)`` where ``seed`` is the
measure arg ``seed`` if given, else ``ctx.seed`` (and the world's ``seed``, when the world
table has one, is mixed in: one key draws a new rig); the first measure to open a board
fixes it, so measures sharing a board should agree on it (true by default: the spec's
seeds). A simulator's error-model defaults are its world's (``Scenario.nav_model`` /
``sonar_model``, e.g. a preset of real-rig imperfections), under the measure's ``model``.
"""

from __future__ import annotations

import importlib
import inspect
import logging
import math
import threading
from collections.abc import Callable, Mapping
from typing import Any

from hera.keys import Keys, check_chunk
from hera.measure import Measure, MeasureContext
from hera.nodes import geometry as gm
from hera.nodes.air import Air
from hera.nodes.driver import NavDriver, SonarDriver
from hera.nodes.driver_args import problems_of
from hera.nodes.imu_model import NavModel
from hera.nodes.noise import stable_seed
from hera.nodes.sim_nav import SimNavBoard
from hera.nodes.sim_sonar import SimMaxSonar
from hera.nodes.sonar_model import SonarModel
from hera.nodes.world import SonarMount, environment, epoch_of, make_scenario
from hera.resources import Resources
from hera.schema import BOOL, STR, TABLE, Setting, did_you_mean, number

log = logging.getLogger(__name__)

Board = Any
"""A registered board: a simulator or any driver satisfying the protocols of
:mod:`hera.nodes.driver`."""

RESOURCE = "hera.nodes.boards"
CLOCK = "hera.nodes.clock"
"""Resource key of a clock (``() -> epoch s``) the node's simulated boards read instead of
the wall clock, and with which a simulated sonar does not wait out its ping: an offline
simulation's virtual time (:mod:`hera.nodes.offline`)."""

BOARD_ARGS = (
    Setting("model", TABLE, {}, "error model of the simulated board (its model's fields)"),
    Setting("seed", number(integer=True), None, "board seed (default: the measure's seed)"),
    Setting("driver", STR, None, "`package.module:Class` of a real board's driver"),
    Setting("driver_args", TABLE, {}, "keyword arguments of that driver"),
    Setting("truth", BOOL, False, "record the ground truth under `<run_dir>/truth`"),
)
"""The arguments every board measure takes besides ``board`` (see the module docstring)."""


def board_id(node: str, board: str) -> str:
    """The id of a board: ``"<node>/<board>"``."""
    return f"{check_chunk(node, 'node name')}/{check_chunk(board, 'board name')}"


class Boards:
    """The boards of one node, and the simulated air its sonars share (thread-safe)."""

    def __init__(self) -> None:
        self._lock = threading.RLock()
        self._boards: dict[str, Board] = {}
        self._airs: dict[tuple[str, str], Air] = {}

    @property
    def lock(self) -> threading.RLock:
        """Held while a board is looked up and created, so two measures make one board."""
        return self._lock

    def register(self, board: Board, board_id: str | None = None) -> Board:
        """Add (or replace) a board under ``board_id`` (default ``board.id``). A driver
        registered as ``"<node>/nav"`` before the measures start is used by them."""
        bid = board_id if board_id is not None else board.id
        with self._lock:
            self._boards[bid] = board
        return board

    def find(self, bid: str) -> Board | None:
        """The board with exactly this id, or None."""
        with self._lock:
            return self._boards.get(bid)

    def get(self, board: str) -> Board:
        """The board with id ``"<node>/<board>"``, or with the bare name ``board`` if exactly
        one board has it; ValueError naming the known ids otherwise."""
        with self._lock:
            if board in self._boards:
                return self._boards[board]
            matches = [b for k, b in self._boards.items() if k.split("/", 1)[1] == board]
            known = sorted(self._boards)
        if len(matches) == 1:
            return matches[0]
        if not matches:
            raise ValueError(f"no board {board!r} on this node; boards: {known or 'none'}")
        raise ValueError(f"board name {board!r} is ambiguous; use one of {known}")

    def id_of(self, board: Board) -> str:
        """The id a board is registered under."""
        with self._lock:
            return next(k for k, b in self._boards.items() if b is board)

    def ids(self) -> list[str]:
        """The ids of every board, sorted."""
        with self._lock:
            return sorted(self._boards)

    def all(self) -> list[Board]:
        """Every board, by id."""
        with self._lock:
            return [self._boards[k] for k in sorted(self._boards)]

    def air(self, session: Any, keys: Keys, group: str) -> Air:
        """The one simulated :class:`Air` of ``group`` on this node."""
        with self._lock:
            air = self._airs.get((keys.cluster, group))
            if air is None:
                air = self._airs[(keys.cluster, group)] = Air(session, keys, group)
            return air

    def close(self) -> None:
        """Close the airs and every board that has a ``close`` (a real driver's port), and
        forget them (the node is stopping); a board that fails to close is logged, not
        raised, so the others still close."""
        with self._lock:
            airs = list(self._airs.values())
            boards = list(self._boards.values())
            self._airs.clear()
            self._boards.clear()
        for air in airs:
            air.close()
        for board in boards:
            close = getattr(board, "close", None)
            if callable(close):
                try:
                    close()
                except Exception:
                    log.exception("closing board %r failed", getattr(board, "id", board))


def of(resources: Resources) -> Boards:
    """The :class:`Boards` of the node that owns ``resources`` (made on first use)."""
    return resources.get_or_create(RESOURCE, Boards)


def _seed(ctx: MeasureContext, args: Mapping[str, Any], kind: str, name: str) -> int:
    seed = args.get("seed")
    seed = ctx.seed if seed is None else seed
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise ValueError(f"seed must be an integer, got {seed!r}")
    world_seed = ctx.world.get("seed")
    if world_seed is None:
        return stable_seed(kind, ctx.node, name, seed)
    if isinstance(world_seed, bool) or not isinstance(world_seed, int):
        raise ValueError(f"world 'seed' must be an integer, got {world_seed!r}")
    return stable_seed(kind, ctx.node, name, seed, world_seed)


def _clock(ctx: MeasureContext, **virtual: Any) -> dict[str, Any]:
    """Keyword arguments that put a simulated board on the node's :data:`CLOCK`, if any
    (with ``virtual``, the board's settings for virtual time)."""
    clock = ctx.resources.get(CLOCK)
    return {} if clock is None else {"clock": clock, **virtual}


def _driver_class(target: str) -> type:
    """The class ``package.module:Class`` names; ValueError saying why it cannot be had."""
    module, _, attr = str(target).partition(":")
    try:
        return getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError, ValueError) as e:
        raise ValueError(f"driver {target!r} cannot be loaded: {e}") from None


def _driver_args_problems(cls: type, target: str, kwargs: Mapping[str, Any]) -> list[str]:
    """What is wrong with ``kwargs`` for ``cls``'s constructor: unknown or missing keys
    (from its signature), then the values, when the class has a ``check_args(all_args)``
    classmethod (all its arguments, defaults filled in; one sentence per problem)."""
    params = inspect.signature(cls).parameters.values()
    if any(p.kind is p.VAR_KEYWORD for p in params):
        return []  # takes anything: only the constructor can say
    named = [p.name for p in params if p.kind is p.POSITIONAL_OR_KEYWORD]
    takes = f"{target} takes {', '.join(named) or 'none'}"
    unknown = [
        f"driver_args: unknown key {k!r}{did_you_mean(str(k), named)}; {takes}"
        for k in kwargs
        if k not in named
    ]
    missing = [
        f"driver_args: {p.name} is required by {target}"
        for p in params
        if p.default is p.empty and p.kind is p.POSITIONAL_OR_KEYWORD and p.name not in kwargs
    ]
    if missing:
        return unknown + missing
    known = {k: v for k, v in kwargs.items() if k in named}
    return unknown + [f"driver_args: {p}" for p in problems_of(cls, known)]


def driver_problems(args: Mapping[str, Any], where: str) -> list[str]:
    """Problems with a board measure's ``driver`` and ``driver_args``, one sentence each
    starting with ``where``, found before any node starts. A driver that cannot be imported
    here is left to its node (it may be installed only on the board's host)."""
    target, kwargs = args.get("driver"), args.get("driver_args") or {}
    if not isinstance(target, str) or not isinstance(kwargs, Mapping):
        return []  # none, or the schema's problem
    module, sep, attr = target.partition(":")
    if not (module and sep and attr):
        return [f"{where}: driver must be 'package.module:Class', got {target!r}"]
    try:
        cls = _driver_class(target)
    except ValueError:
        return []
    return [f"{where}: {p}" for p in _driver_args_problems(cls, target, kwargs)]


def load_driver(args: Mapping[str, Any], protocol: type, what: str) -> Board | None:
    """The real driver the args name (``driver``, ``driver_args``), or None; ValueError when
    it does not load, its arguments are wrong (:func:`driver_problems`) or it does not
    implement ``protocol`` (named ``what``). Board families in their own packages use it
    too."""
    target = args.get("driver")
    if target is None:
        return None
    cls = _driver_class(str(target))
    kwargs = dict(args.get("driver_args") or {})
    problems = _driver_args_problems(cls, str(target), kwargs)
    if problems:
        raise ValueError(f"driver {target!r}: {'; '.join(problems)}")
    board = cls(**kwargs)
    if not isinstance(board, protocol):
        raise ValueError(f"driver {target!r} does not implement the {what} driver protocol")
    return board


class BoardMeasure(Measure):
    """A measure that reads a board: its arguments' check (:meth:`Measure.check_args`, run
    before any node starts) covers its driver's arguments too (:func:`driver_problems`)."""

    @classmethod
    def check_args(cls, args: Mapping[str, Any], where: str) -> list[str]:
        return super().check_args(args, where) + driver_problems(args, where)


def open_board(
    ctx: MeasureContext,
    args: Mapping[str, Any],
    default: str,
    protocol: type,
    what: str,
    make: Callable[[str, int], Board],
    kind: str | None = None,
) -> Any:
    """The board ``args["board"]`` (default ``default``) of ``ctx.node``, for board
    families in their own packages: the one registered under that id (ValueError unless it
    implements ``protocol``: "board ... is not ``what``"), else the real driver the args
    name (:func:`load_driver`), else ``make(board_id, seed)``, a simulator seeded from the
    node, the board name and the arg ``seed`` (default: the node's) under ``kind`` (default
    ``default``). A new board is registered in the node's registry (faults, listing)."""
    name = str(args.get("board") or default)
    bid = board_id(ctx.node, name)
    registry = of(ctx.resources)
    with registry.lock:
        b = registry.find(bid)
        if b is not None:
            if not isinstance(b, protocol):
                raise ValueError(f"board {bid!r} is not {what}")
            return b
        board = load_driver(args, protocol, protocol.__name__)
        if board is None:
            seed = ctx.seed if args.get("seed") is None else args["seed"]
            board = make(bid, stable_seed(kind or default, ctx.node, name, seed))
        return registry.register(board, bid)


def open_nav(ctx: MeasureContext, args: Mapping[str, Any]) -> NavDriver:
    """The Pmod NAV ``args["board"]`` (default "nav") of ``ctx.node`` (see the module
    docstring for which driver it is); a simulator is built from ``ctx.world`` and the
    args ``model`` (a :class:`NavModel` table) and ``seed``."""
    name = str(args.get("board") or "nav")
    bid = board_id(ctx.node, name)
    boards = of(ctx.resources)
    with boards.lock:
        b = boards.find(bid)
        if b is not None:
            if not isinstance(b, NavDriver):
                raise ValueError(f"board {bid!r} is not a Pmod NAV driver")
            return b
        board = load_driver(args, NavDriver, "NavDriver")
        if board is None:
            scenario = make_scenario(ctx.world)
            board = SimNavBoard(
                bid,
                scenario,
                environment(ctx.world),
                epoch_of(ctx.world),
                NavModel.from_args({**scenario.nav_model, **(args.get("model") or {})}),
                _seed(ctx, args, "pmod_nav", name),
                **_clock(ctx),
            )
        return boards.register(board, bid)


def sonar_mount(ctx: MeasureContext, args: Mapping[str, Any]) -> SonarMount:
    """Where a sonar is: args ``position``/``direction``, else ``world.sonars[<node>]``, else
    the scenario's default placement number ``args["index"]`` (default 0)."""
    placed = ctx.world.get("sonars", {})
    if not isinstance(placed, Mapping):
        raise ValueError("world 'sonars' must be a table of node -> {position, direction}")
    mine = placed.get(ctx.node, {})
    pos = args.get("position") or mine.get("position")
    direction = args.get("direction") or mine.get("direction")
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
    """The MaxSonar ``args["board"]`` (default "sonar") of ``ctx.node`` (see the module
    docstring for which driver it is).

    Simulator args: ``position``, ``direction``, ``index`` (see :func:`sonar_mount`),
    ``model`` (a :class:`SonarModel` table), ``ping_ms``, ``half_angle_deg``, ``seed``,
    ``fire_log`` (path), ``air_group`` (default: the spec's sync group), ``crosstalk``
    (default true: the simulated air carries pings between the group's sonars).
    """
    name = str(args.get("board") or "sonar")
    bid = board_id(ctx.node, name)
    boards = of(ctx.resources)
    with boards.lock:
        b = boards.find(bid)
        if b is not None:
            if not isinstance(b, SonarDriver):
                raise ValueError(f"board {bid!r} is not a MaxSonar driver")
            return b
        real = load_driver(args, SonarDriver, "SonarDriver")
        if real is not None:
            return boards.register(real, bid)
        scenario = make_scenario(ctx.world)
        table = {**scenario.sonar_model, **(args.get("model") or {})}
        for key in ("ping_ms", "half_angle_deg"):
            if args.get(key) is not None:
                table[key] = args[key]
        model = SonarModel.from_args(table)
        if not math.isfinite(model.half_angle_deg) or model.half_angle_deg >= 90:
            raise ValueError("sonar half_angle_deg must be < 90")
        group = str(args.get("air_group") or ctx.spec.group)
        crosstalk = args.get("crosstalk", True)
        air = boards.air(ctx.session, ctx.keys, group) if crosstalk else None
        fire_log = args.get("fire_log")
        board = SimMaxSonar(
            bid,
            bid,
            scenario,
            epoch_of(ctx.world),
            sonar_mount(ctx, args),
            model,
            _seed(ctx, args, "maxsonar", name),
            air=air,
            fire_log=str(fire_log) if fire_log else None,
            node=ctx.node,
            **_clock(ctx, block=False),
        )
        return boards.register(board, bid)
