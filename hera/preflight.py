"""Checks of a spec that need the installed plugins, done before any process starts.

:func:`check_spec` loads every measure the spec uses and checks its arguments against the
measure's declaration (a fusion model's settings against the model's), that every
synchronised measure's group is hosted by some node and its slot fits the sync lease, and
asks the applications whose measures the spec uses to check its ``[world]`` table. Every
problem is reported at once, one sentence each naming the file, the measure and the key
(:class:`hera.spec.SpecError`).
"""

from __future__ import annotations

from hera.measure import MeasureSpecError
from hera.plugins import AppIndex, PluginError, find_measure
from hera.spec import ClusterSpec, SpecError, slot_problem


def spec_problems(spec: ClusterSpec) -> list[str]:
    """Every problem :func:`check_spec` would report, in spec order, without repeats."""
    problems: list[str] = []
    groups = spec.sync_groups()
    index = AppIndex()
    apps = {}
    for node, m in spec.measures():
        where = f"{spec.source}: measure {m.name!r} of node {node!r}"
        try:
            cls = find_measure(m.use)
        except (LookupError, TypeError, PluginError) as e:
            problems.append(f"{where}: {e}")
            continue
        app = index.app_of(cls)
        if app is not None:
            apps.setdefault(app.name, app)
        problems.extend(cls.check_args(m.args, f"{where}: args"))
        try:  # the class's defaults may break a rule (an offset past its period)
            resolved = m.resolve(cls)
        except MeasureSpecError as e:
            problems.append(f"{where}: {e.sentence}")
            continue
        if resolved.sync and resolved.group not in groups:
            problems.append(
                f"{where}: it is synchronised (sync = true) in group {resolved.group!r}, but "
                f"no node hosts that group: add {resolved.group!r} to some node's sync_hosts"
            )
        if resolved.sync and (why := slot_problem(resolved.slot, spec.sync_lease_ms)):
            problems.append(f"{where}: {why}")
    for app in apps.values():
        problems.extend(f"{spec.source}: [world]: {p}" for p in app.check_world(spec.world))
    return list(dict.fromkeys(problems))


def check_spec(spec: ClusterSpec) -> ClusterSpec:
    """``spec`` if it can run; :class:`SpecError` listing every problem otherwise."""
    problems = spec_problems(spec)
    if problems:
        raise SpecError(problems)
    return spec
