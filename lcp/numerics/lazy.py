"""Deferred imports, so that ``import lcp`` stays cheap.

SciPy's sparse package costs about 0.1 s to import (it pulls in NumPy's testing machinery), more than
everything else ``lcp`` needs at start-up; most runs (one contact, small dense problems) never touch
it. :data:`sparse` stands for ``scipy.sparse`` and imports it on first attribute access;
:func:`issparse` answers without importing it, since no object can be a SciPy sparse matrix
before SciPy's sparse package has been imported.
"""
from __future__ import annotations

import importlib
import sys

__all__ = ["LazyModule", "sparse", "issparse"]


class LazyModule:
    """A module imported on first attribute access.

    Examples
    --------
    >>> from lcp.numerics.lazy import LazyModule
    >>> m = LazyModule("json")
    >>> m.dumps([1])
    '[1]'
    """

    def __init__(self, name: str):
        self._name = name

    def __getattr__(self, attr):
        module = importlib.import_module(self.__dict__["_name"])
        return getattr(module, attr)

    def __repr__(self):
        return f"<deferred module {self._name!r}>"


sparse = LazyModule("scipy.sparse")


def issparse(x) -> bool:
    """``scipy.sparse.issparse(x)``, without importing SciPy when it was never imported."""
    sp = sys.modules.get("scipy.sparse")
    return sp is not None and sp.issparse(x)
