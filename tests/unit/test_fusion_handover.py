"""A model's state across a hot reload: ``adopt_model`` carries the old model's attributes
over with the old model's methods held in them bound to the new model (``rebind``), and
``superseded`` tells an object whose class its module no longer names (pickle refuses it;
the old code's checkpoint is then skipped)."""

from __future__ import annotations

import pickle
import sys
import types

import pytest

from hera.fusion import adopt_model
from hera.handover import reloading, reloads, superseded

NAME = "superseded_probe"


@pytest.fixture
def module():
    """The probe module's name in ``sys.modules``; each :func:`_define` loads it anew."""
    yield NAME
    sys.modules.pop(NAME, None)


MODEL = """
import collections
import dataclasses
import types  # its SimpleNamespace stands for a filter of hera.estimation (never reloaded)

def _g(x):
    return {code} * x


@dataclasses.dataclass(frozen=True)
class Part:
    gain: float = 1.0

    def version(self):
        return {code}


class Model:
    code = {code}

    class Inner:
        pass

    def __init__(self):
        self.filter = types.SimpleNamespace(f=self._f, h=self._h)
        self.callbacks = {{"f": [self._f], "pair": (self._h, 1.0)}}
        self.queue = collections.deque([self._f])
        self.looped = self.filter  # the same object twice: visited once
        self.filter.back = self.filter  # a cycle
        self.kind = self.make
        self.parts = [Part()]
        self.filter.g = _g  # a module function, as a filter's f may be

    def _f(self, x):
        return (self.code, x)

    def _h(self, x):
        return -x

    @classmethod
    def make(cls):
        return cls.code
"""


def _define(name: str, code: int = 1) -> type:
    """Load the probe module (anew, as ``hera reload`` does: a new module object in
    ``sys.modules``) with ``code`` in its functions' results; its Model class."""
    mod = types.ModuleType(name)
    sys.modules[name] = mod
    exec(compile(MODEL.format(code=code), name, "exec"), mod.__dict__)
    return mod.Model


def test_an_object_of_a_reloaded_class_is_superseded_and_pickle_refuses_it(module):
    old = _define(module)
    model, inner = old(), old.Inner()
    assert not superseded(model) and not superseded(inner)
    pickle.dumps(model)
    _define(module)  # the module's code loaded again: new class objects, the same names
    assert superseded(model) and superseded(inner)
    with pytest.raises(pickle.PicklingError, match="not the same object"):
        pickle.dumps(model)
    assert not superseded(sys.modules[module].Model())


def test_a_pickle_failing_while_a_reload_has_the_module_out_is_skipped_not_given_up(module):
    """CI once saw it: ``hera reload`` of code that does not load had the model's module
    out of ``sys.modules`` while the old model's checkpoint was pickled; pickle imported the
    module's (new, broken) source itself and failed, and the checkpoints were given up."""
    model = _define(module)()
    before = reloads()
    with reloading():
        held = sys.modules.pop(module)
        with pytest.raises(pickle.PicklingError, match="import of module"):
            pickle.dumps(model)
        assert superseded(model, before)  # failed during the reload
        sys.modules[module] = held  # the reload put the old module back
    assert superseded(model, before)  # failed before the reload ended, checked after
    assert not superseded(model, reloads()) and not superseded(model)  # no reload since
    pickle.dumps(model)


def test_a_lambda_in_a_model_is_not_mistaken_for_a_reload(module):
    model = _define(module)()
    model.f = lambda x: x
    assert not superseded(model)  # the warning about lambdas stays for it
    with pytest.raises((pickle.PicklingError, AttributeError)):
        pickle.dumps(model)


def test_the_old_models_methods_held_in_its_state_are_bound_to_the_new_model(module):
    old = _define(module, code=1)()
    old.filter.x = [3.0]
    new = _define(module, code=2)()
    assert adopt_model(new, old)
    assert new.filter is old.filter and new.filter.x == [3.0]  # the state, carried over
    assert new.filter.f(5) == (2, 5)  # the new code, on the new instance
    assert new.filter.f.__self__ is new and new.filter.h.__self__ is new
    assert new.callbacks["f"][0].__self__ is new and new.callbacks["pair"][0].__self__ is new
    assert new.callbacks["pair"][1] == 1.0 and new.queue[0].__self__ is new
    assert new.kind() == 2  # a class method of the new class
    now = sys.modules[module]
    assert type(new.parts[0]) is now.Part and new.parts[0].version() == 2  # upgraded
    assert new.filter.g is now._g and new.filter.g(3) == 6
    pickle.dumps(new)  # nothing of the old code is left in it
    with pytest.raises(pickle.PicklingError):
        pickle.dumps(old)


class SetOnce(dict):
    """A dict that refuses a key set twice (as numba's dispatchers keep theirs)."""

    def __setitem__(self, key, value):
        if key in self:
            raise AssertionError(f"key already in dictionary: {key!r}")
        super().__setitem__(key, value)


def test_what_holds_no_old_method_is_not_written_to(module):
    old = _define(module)()
    old.table = SetOnce(a=1, b=[2.0])
    with pytest.raises(AssertionError, match="already in dictionary"):
        old.table["a"] = 1
    new = _define(module, code=2)()
    assert adopt_model(new, old)  # walked, never written: nothing in it to rebind
    assert new.table == {"a": 1, "b": [2.0]} and new.filter.f.__self__ is new
