"""Every example in the package's docstrings runs and prints what it shows (doctest)."""
from __future__ import annotations

import doctest
import importlib
import pkgutil

import numpy as np
import pytest

import lcp
import lem


def _modules():
    for pkg in (lcp, lem):
        yield pkg.__name__
        for info in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + "."):
            yield info.name


@pytest.mark.parametrize("name", sorted(_modules()))
def test_docstring_examples(name):
    module = importlib.import_module(name)
    finder = doctest.DocTestFinder(exclude_empty=True)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    # a facade module re-exports another module's objects: their examples run with their own module
    tests = [t for t in finder.find(module, name) if t.examples and t.filename == module.__file__]
    for t in tests:
        runner.run(t)
    result = runner.summarize(verbose=False)
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples failed in {name}"


def test_the_examples_are_found():
    # the finder sees the examples of a module that has them (the test above is not vacuous)
    import lcp.simulation

    found = [t for t in doctest.DocTestFinder().find(lcp.simulation, "lcp.simulation") if t.examples]
    assert found and sum(len(t.examples) for t in found) >= 3
