"""``superseded``: an object whose class its module no longer names (``hera reload`` loaded
the module anew), which pickle refuses; the fusion measure then skips its checkpoint."""

from __future__ import annotations

import pickle
import sys
import types

import pytest

from hera.fusion import superseded


@pytest.fixture
def module():
    mod = types.ModuleType("superseded_probe")
    sys.modules[mod.__name__] = mod
    yield mod
    del sys.modules[mod.__name__]


def _define(mod: types.ModuleType) -> type:
    code = "class Model:\n    class Inner:\n        pass\n"
    exec(compile(code, mod.__name__, "exec"), mod.__dict__)
    for cls in (mod.Model, mod.Model.Inner):
        cls.__module__ = mod.__name__
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
    assert not superseded(module.Model())


def test_a_lambda_in_a_model_is_not_mistaken_for_a_reload(module):
    model = _define(module)()
    model.f = lambda x: x
    assert not superseded(model)  # the warning about lambdas stays for it
    with pytest.raises((pickle.PicklingError, AttributeError)):
        pickle.dumps(model)
