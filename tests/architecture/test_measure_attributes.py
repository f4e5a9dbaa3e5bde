"""A measure class keeps out of its bases' private state: a private attribute (``self._x =
...``) that two classes of one measure's MRO both assign is one they share by mistake.
(``models/tof/measures.py`` once kept its forecast time in ``_last_t``, FusionMeasure's
newest-sample time, so every reading after a forecast counted as given late.)"""

from __future__ import annotations

import ast
import inspect
import textwrap

import pytest

from hera.fusion import FusionMeasure
from hera.plugins import find_measure, known_measures


def _assigned(cls: type) -> set[str]:
    """Private attributes of ``self`` that the methods in ``cls``'s own body assign."""
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    except (OSError, TypeError):  # no source (a builtin): nothing to compare
        return set()
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign):
            targets = node.targets
        elif isinstance(node, ast.AnnAssign | ast.AugAssign):
            targets = [node.target]
        else:
            continue
        for target in targets:
            for t in ast.walk(target):
                if (
                    isinstance(t, ast.Attribute)
                    and isinstance(t.value, ast.Name)
                    and t.value.id == "self"
                    and t.attr.startswith("_")
                ):
                    out.add(t.attr)
    return out


def clashes(cls: type) -> dict[str, tuple[str, str]]:
    """Private attribute -> (class, base class) for each one two classes of ``cls``'s MRO
    both assign."""
    mro = [c for c in cls.__mro__ if c is not object]
    own = {c: _assigned(c) for c in mro}
    out = {}
    for i, c in enumerate(mro):
        for base in mro[i + 1 :]:
            for name in own[c] & own[base]:
                out.setdefault(name, (c.__name__, base.__name__))
    return out


@pytest.mark.parametrize("use", sorted(known_measures()))
def test_no_measure_shares_a_private_attribute_with_its_bases(use):
    assert clashes(find_measure(use)) == {}


def test_the_check_finds_a_shared_attribute():
    class Forecasting(FusionMeasure):
        def measure(self):
            self._last_t = 0.0  # FusionMeasure's newest-sample time
            self._own = 1

    assert clashes(Forecasting) == {"_last_t": ("Forecasting", "FusionMeasure")}
