"""Every example in the package's docstrings runs and prints what it shows."""

import doctest
import importlib
import pkgutil

import pytest

import catgraph


def _modules_with_examples() -> list[str]:
    names = [catgraph.__name__]
    names += [m.name for m in pkgutil.walk_packages(catgraph.__path__, prefix=f"{catgraph.__name__}.")]
    out = []
    for name in names:
        module = importlib.import_module(name)
        if any(t.examples for t in doctest.DocTestFinder().find(module)):
            out.append(name)
    return out


MODULES = _modules_with_examples()


def test_the_examples_are_found():
    # the modules whose docstrings show examples: finding none would pass every case below vacuously
    assert {"catgraph.sequence", "catgraph.hubs", "catgraph.live", "catgraph.differences"} <= set(MODULES)


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    result = doctest.testmod(importlib.import_module(name), optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE,
                             verbose=False, report=False)
    assert result.attempted > 0
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples in {name} failed (run: python -m " \
                               f"pytest --doctest-modules {name.replace('.', '/')}.py)"
