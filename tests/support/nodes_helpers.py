"""Helpers for the tests of hera.nodes (a unique module name: test folders share sys.path)."""

from __future__ import annotations

from typing import Any

from hera.args import ArgsStore
from hera.keys import Keys
from hera.measure import MeasureContext, MeasureSpec
from hera.nodes import boards
from hera.resources import Resources
from hera.store import Store


class FakeClock:
    """A clock that advances by ``step`` seconds at each call."""

    def __init__(self, start: float = 1000.0, step: float = 0.01) -> None:
        self.t = start
        self.step = step

    def __call__(self) -> float:
        self.t += self.step
        return self.t


def make_ctx(
    name: str,
    world: dict[str, Any] | None = None,
    *,
    node: str = "n1",
    session: Any = None,
    args: ArgsStore | None = None,
    seed: int = 1,
    run_dir: str | None = None,
    period: float = 0.1,
    sync_group: str | None = None,
    resources: Resources | None = None,
    **spec: Any,
) -> MeasureContext:
    """A MeasureContext as the runtime would build it, for cluster "t" (``spec``: more
    MeasureSpec fields, e.g. iterations or restart). Contexts given the same ``resources``
    are measures of one node: they share its boards."""
    return MeasureContext(
        node=node,
        cluster="t",
        spec=MeasureSpec(name=name, period=period, sync_group=sync_group, **spec),
        store=Store(),
        args=args if args is not None else ArgsStore(node),
        session=session,
        keys=Keys("t"),
        world=world if world is not None else {"scenario": "still", "epoch": 0.0},
        seed=seed,
        run_dir=run_dir,
        resources=resources if resources is not None else Resources(),
    )


def boards_of(ctx: MeasureContext) -> boards.Boards:
    """The board registry of the node ``ctx`` belongs to."""
    return boards.of(ctx.resources)
