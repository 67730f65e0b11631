"""Docstring examples of the public API run as tests, against the installed package.

Every function and class in the ``__all__`` of the modules in ``MODULES``
must have an ``Examples`` section, and its examples (and those of
the class's methods) run here with the options of ``setup.cfg``
(``NORMALIZE_WHITESPACE``, ``ELLIPSIS`` and pytest-doctestplus'
``FLOAT_CMP``). The examples are found through the objects themselves, so
the public names re-exported from private modules (``lensdual.photometry``,
``lensdual.sensitivity``) are covered, and nothing depends on where the
package is installed. Each example runs in a fresh namespace: it imports
what it uses.
"""

import doctest
import importlib
import inspect

import pytest

output_checker = pytest.importorskip("pytest_doctestplus.output_checker")

#: Modules whose public functions and classes must show an example.
MODULES = (
    "lensdual.estimators",
    "lensdual.duality",
    "lensdual.flux_field",
    "lensdual.pairing",
    "lensdual.photometry",
    "lensdual.sensitivity",
)

OPTIONFLAGS = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE | output_checker.FLOAT_CMP


def _public_objects():
    seen = {}
    for module_name in MODULES:
        module = importlib.import_module(module_name)
        for name in module.__all__:
            obj = getattr(module, name)
            if inspect.isfunction(obj) or inspect.isclass(obj):
                seen.setdefault(f"{module_name}.{name}", obj)
    return seen


PUBLIC = _public_objects()


def test_there_are_public_objects():
    assert len(PUBLIC) > 20


@pytest.mark.parametrize("name", sorted(PUBLIC))
def test_has_examples(name):
    doc = inspect.getdoc(PUBLIC[name]) or ""
    assert "\nExamples\n--------\n" in doc, f"{name} has no Examples section"


@pytest.mark.parametrize("name", sorted(PUBLIC))
def test_examples_run(name):
    obj = PUBLIC[name]
    # module: only the methods defined there, not those inherited (int's, for an IntFlag)
    found = doctest.DocTestFinder().find(obj, name, module=inspect.getmodule(obj), globs={})
    tests = [t for t in found if t.examples]
    assert tests, f"{name}: no doctest found"
    runner = doctest.DocTestRunner(checker=output_checker.OutputChecker(), optionflags=OPTIONFLAGS)
    report = []
    for test in tests:
        runner.run(test, out=report.append)
    assert runner.failures == 0, "".join(report)
