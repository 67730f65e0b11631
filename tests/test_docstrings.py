"""Docstring gate: every public callable documents its parameters and returns.

numpydoc's validator on every name in the ``__all__`` of every public module
of lensdual (private modules excluded, re-exports counted once): no missing
docstring (GL08), no undocumented parameter (PR01), no documented parameter
that does not exist (PR02), no function without a Returns section (RT01).
Enum classes are left out (their "parameters" are the Enum machinery's).
"""

import enum
import importlib
import inspect
import pkgutil

import pytest

import lensdual

numpydoc_validate = pytest.importorskip("numpydoc.validate")

CHECKS = {"GL08", "PR01", "PR02", "RT01"}


def _public_callables():
    names = ["lensdual"] + [
        f"lensdual.{m.name}" for m in pkgutil.walk_packages(lensdual.__path__)
        if not any(part.startswith("_") for part in m.name.split("."))]
    seen = {}
    for module_name in names:
        module = importlib.import_module(module_name)
        for name in getattr(module, "__all__", ()):
            obj = getattr(module, name)
            if not (inspect.isfunction(obj) or inspect.isclass(obj)):
                continue
            if inspect.isclass(obj) and issubclass(obj, enum.Enum):
                continue
            seen.setdefault(f"{obj.__module__}.{obj.__qualname__}", obj)
    return sorted(seen)


PUBLIC = _public_callables()


def test_there_are_public_callables():
    assert len(PUBLIC) > 80


@pytest.mark.parametrize("name", PUBLIC)
def test_docstring_documents_parameters_and_returns(name):
    result = numpydoc_validate.validate(name)
    errors = [f"{code}: {msg}" for code, msg in result["errors"] if code in CHECKS]
    assert not errors, f"{name}: " + "; ".join(errors)
