"""Hot code reload on one node (``hera reload PACKAGE_OR_MODULE``; the original's
``update_code``, thesis ch. 4.6.2 and app. F).

What :func:`reload_code` does on the node that receives the ``reload`` control verb:

1. **Load the new code.** The target module (a package: every loaded module under it) is
   loaded again, into a new module object, and so is every loaded module that refers to
   one of them (a measure module that imported the model class from the reloaded model
   module), each after the modules it refers to. The old module objects are not touched:
   the measures still running the old code keep seeing their own globals. The runtime's
   own modules (:func:`is_runtime`: those loaded with the runtime, the fusion and
   estimation modules included, their submodules, and the node services' packages) are
   never reloaded: new runtime code needs a restart.
2. **Blue/green replacement.** Every measure whose class now loads as a different class
   is replaced under the supervisor: a new worker of the new class (green) is created and
   ``init`` run while the old one (blue) keeps publishing; then, at blue's next deadline
   (at once for a period over :data:`SWITCH_WAIT`), blue ends instead of stepping, closes
   its measure and, in its own thread, hands over: green takes its place under the
   supervisor, receives blue's attributes through
   :meth:`hera.measure.Measure.code_change` and steps in that deadline's place, so the
   output goes on at its period (a blue stuck in a step is abandoned and replaced without
   handing over). The rest of the node is untouched; a measure that is not running gets
   the new code at its next start.
3. **Rollback.** If the new code fails to import, or a green fails to ``init``, to take
   the handover or to complete its first step, the old modules are put back, every
   measure already replaced in this reload is replaced again by its old code (with the
   state handed back) and the reply says why.
"""

from __future__ import annotations

import importlib
import importlib.util
import logging
import sys
import threading
import time
from types import ModuleType
from typing import TYPE_CHECKING, Any

from hera import handover
from hera.plugins import find_measure

if TYPE_CHECKING:  # pragma: no cover
    from hera.node import Node
    from hera.worker import Worker

log = logging.getLogger("hera.reload")

_runtime: frozenset[str] = frozenset()
_packages: tuple[str, ...] = ()


LAZY_RUNTIME = ("hera.estimation", "hera.fusion", "hera.handover", "numpy", "numba")
"""Packages of the runtime that a node loads only when a measure needs them (a node that
runs no filter never loads numpy: about 15 MB): theirs too, loaded or not."""


def freeze_runtime() -> None:
    """Remember the modules loaded now, with the packages of :data:`LAZY_RUNTIME` (fusion,
    estimation, numpy), as the runtime's. :mod:`hera.node` calls it once its own imports are
    done, before a node loads any measure (the first reload does, if nothing did)."""
    global _runtime, _packages
    _runtime = frozenset(sys.modules) | frozenset(LAZY_RUNTIME)
    _packages = tuple(
        name + "." for name in sys.modules if "." in name and hasattr(sys.modules[name], "__path__")
    ) + tuple(p + "." for p in LAZY_RUNTIME)


def is_runtime(name: str, services: tuple[str, ...] = ()) -> bool:
    """Whether module ``name`` belongs to the runtime (never reloaded): loaded with it,
    a submodule of one of its packages (the root package aside), or in the package of a
    node service (``services``: their packages, e.g. the sync service's)."""
    if not _runtime:
        freeze_runtime()
    if name in _runtime or name.startswith(_packages):
        return True
    return any(name == p or name.startswith(p + ".") for p in services)


def service_packages(node: Node) -> tuple[str, ...]:
    """The packages of the node's services (where their classes live)."""
    modules = (type(service).__module__ for service in node.services.values())
    return tuple(m.rsplit(".", 1)[0] if "." in m else m for m in modules)


START_TIMEOUT = 10.0
"""Seconds a new worker has to run ``init`` and to complete its first step."""
SWITCH_WAIT = 0.5
"""Seconds: a measure of a longer period is replaced at once, not at its next deadline."""


class ReloadError(ValueError):
    """The new code could not be loaded or started; everything was rolled back."""

    resume: Any = None
    """For a measure whose new code failed after it was swapped in: the function that runs
    its old code again (once the old modules are back)."""


# -- modules ------------------------------------------------------------------------------
def target_modules(target: str, services: tuple[str, ...] = ()) -> list[str]:
    """The loaded modules a target names: the module, or a package and its loaded
    submodules. ValueError when it names no importable module or a runtime module."""
    try:
        spec = importlib.util.find_spec(target)
    except (ImportError, ValueError) as e:
        raise ValueError(f"cannot find module {target!r}: {e}") from None
    if spec is None:
        raise ValueError(f"no module called {target!r} is installed")
    if is_runtime(target, services):
        raise ValueError(f"{target!r} is part of the runtime: restart the nodes to load its code")
    return sorted(
        m
        for m in list(sys.modules)
        if (m == target or m.startswith(target + ".")) and not is_runtime(m, services)
    )


def _refers_to(module: ModuleType, names: set[str]) -> set[str]:
    """The modules among ``names`` whose objects (classes, functions, the module itself)
    ``module``'s globals hold; a package's own submodules aside (a new submodule is set on
    its package when it is loaded)."""
    out = set()
    for value in list(vars(module).values()):
        try:
            owner = value.__name__ if isinstance(value, ModuleType) else value.__module__
        except Exception:  # objects with exotic attribute access
            continue
        if not isinstance(owner, str) or owner not in names or owner == module.__name__:
            continue
        if isinstance(value, ModuleType) and owner.startswith(module.__name__ + "."):
            continue
        out.add(owner)
    return out


def reload_order(targets: list[str], services: tuple[str, ...] = ()) -> list[str]:
    """``targets`` and every loaded non-runtime module that refers to one of them
    (transitively), each after the modules of the set it refers to."""
    chosen = set(targets)
    grew = True
    while grew:
        grew = False
        for name, module in list(sys.modules.items()):
            if name in chosen or is_runtime(name, services) or not isinstance(module, ModuleType):
                continue
            if _refers_to(module, chosen):
                chosen.add(name)
                grew = True
    order: list[str] = []
    visiting: set[str] = set()

    def visit(name: str) -> None:
        if name in order or name in visiting:
            return
        visiting.add(name)
        for dep in sorted(_refers_to(sys.modules[name], chosen)):
            visit(dep)
        order.append(name)

    for name in sorted(chosen):
        visit(name)
    return order


def reload_modules(order: list[str]) -> dict[str, ModuleType]:
    """Load the new code of ``order`` into new module objects, in that order (so a module
    that imports from an earlier one gets the new one); return the old modules (for
    :func:`restore`). The old module objects are left as they were, so code still running
    from them keeps its own globals. ReloadError naming the module when one fails (the old
    ones are put back first)."""
    saved = {name: sys.modules[name] for name in order}
    importlib.invalidate_caches()
    with handover.reloading():  # a checkpoint pickled meanwhile may fail: skipped
        for name in order:
            sys.modules.pop(name, None)
        try:
            for name in order:
                importlib.import_module(name)
        except BaseException as e:
            restore(saved)
            raise ReloadError(
                f"the new code of {name} does not load ({type(e).__name__}: {e}); "
                "nothing was changed"
            ) from None
    return saved


def restore(saved: dict[str, ModuleType]) -> None:
    """Put the old modules back (in ``sys.modules`` and on their packages)."""
    for name, module in saved.items():
        sys.modules[name] = module
        parent, _, child = name.rpartition(".")
        if parent in sys.modules:
            setattr(sys.modules[parent], child, module)


# -- blue/green ---------------------------------------------------------------------------
def swap(node: Node, name: str, cls: type, timeout: float = START_TIMEOUT) -> dict[str, Any]:
    """Replace the running measure ``name`` of ``node`` by one of class ``cls`` (see the
    module docstring, step 2); ReloadError saying why when the new one does not start, in
    which case the measure runs its previous class again. Returns ``running``, ``handover``
    (whether green took blue's state) and ``switch_ms``: ms from blue giving up the step of
    its deadline (woken for it, as late as any step may be; for a blue switched at once or
    abandoned, from the hand-over) to the start of green's first step, in that step's place:
    under the period, no step was lost to the reload."""
    sup = node.supervisor
    child = sup.children[name]
    decl = node.decls[name]
    blue = child.worker
    if blue is None or child.state != "running":
        old_make = child.start
        child.start = node.measure_factory(decl, cls)
        return {"running": False, "undo": lambda: setattr(child, "start", old_make)}
    old_cls, old_make = blue.measure_cls, child.start
    make = node.measure_factory(decl, cls, blue.ctx.counters)
    committed = threading.Event()
    failed: list[str] = []

    def on_exit(worker, error) -> None:
        if committed.is_set():
            sup.exited(worker, error)
        else:
            failed.append(worker.error or "it ended before its first step")

    gate = threading.Event()
    green = make(on_exit, gate)
    green.start()
    deadline = time.monotonic() + timeout
    while not green.ready.wait(0.005):
        if failed or time.monotonic() > deadline:
            green.stop()
            trouble = green.ctx.trouble  # a measure that waits to start says why
            why = failed[0] if failed else f"init took over {timeout:g} s"
            if not failed and trouble:
                why += f", {trouble}"
            raise ReloadError(f"measure {name}: the new code does not start ({why}); rolled back")
    handed = threading.Event()
    switched: list[float] = []

    def hand(old: Worker) -> None:
        """In blue's thread, at its deadline, its measure closed: green takes its place."""
        try:
            sup.replace(name, green, make)
            if old.measure is not None:
                state = dict(vars(old.measure))
                green.handover = (getattr(old.measure_cls, "version", ""), state)
        finally:
            switched.append(time.monotonic())
            handed.set()
            gate.set()

    period = blue.spec.period
    blue.retire(hand, now=period > SWITCH_WAIT)
    if not handed.wait(max(1.0, 3 * period)):
        if blue.cancel_retire():  # blue is stuck in a step: replaced without its state
            switched.append(time.monotonic())
            sup.replace(name, green, make)
            gate.set()
        else:
            handed.wait()  # blue is handing over right now
    # from blue giving up its deadline's step (retired at once: from the hand-over) to
    # green's first step: what the reload costs, not how late the thread woke for it
    t_switch = switched[0] if blue.retired_at is None else blue.retired_at
    while green.stats.steps < 1:
        if failed or time.monotonic() > deadline:
            break
        time.sleep(0.001)
    if green.stats.steps >= 1 and not failed:
        committed.set()
        first = green.first_step_at or time.monotonic()
        return {
            "running": True,
            "handover": green.handover is not None,
            "switch_ms": round((first - t_switch) * 1e3, 3),
            "undo": lambda: swap(node, name, old_cls),
        }
    reason = failed[0] if failed else f"no first step within {timeout:g} s"
    green.abandoned = True
    green.stop()

    def resume() -> None:
        """The previous code again, with the state the new one was handed."""
        again = node.measure_factory(decl, old_cls, green.ctx.counters)(sup.exited)
        again.handover = green.handover
        sup.replace(name, again, old_make)
        again.start()

    error = ReloadError(f"measure {name}: the new code does not start ({reason}); rolled back")
    error.resume = resume
    raise error


def reload_code(node: Node, target: str) -> dict[str, Any]:
    """Load the new code of ``target`` on ``node`` and replace the measures it changes
    (see the module docstring); ValueError (ReloadError) saying why, after rolling back."""
    services = service_packages(node)
    order = reload_order(target_modules(target, services), services)
    if not order:
        return {"modules": [], "replaced": {}, "note": f"{target} is not loaded on this node"}
    saved = reload_modules(order)
    done: dict[str, dict[str, Any]] = {}
    try:
        for name, decl in list(node.decls.items()):
            child = node.supervisor.children.get(name)
            if child is None:
                continue
            running = child.worker.measure_cls if child.worker is not None else None
            try:
                cls = find_measure(decl.use)
            except (LookupError, TypeError) as e:
                raise ReloadError(f"measure {name}: the new code has no measure: {e}") from None
            if running is not None and cls is running:
                continue
            done[name] = swap(node, name, cls)
    except ReloadError as e:
        restore(saved)  # first: the old code is found again by name
        for undo in [e.resume, *(i["undo"] for i in reversed(done.values()))]:
            try:
                if undo is not None:
                    undo()
            except Exception:
                log.exception("rolling back a replaced measure failed")
        raise
    log.info("reloaded %s; replaced %s", ", ".join(order), ", ".join(done) or "no measure")
    return {
        "modules": order,
        "replaced": {n: {k: v for k, v in i.items() if k != "undo"} for n, i in done.items()},
    }
