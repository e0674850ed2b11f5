"""The Linear Equivalence Method (LEM) and the paper's series.

The engine (truncated moment systems, i.e. Carleman linearization, for polynomial and analytic
vector fields, with restarts, a-posteriori error estimates and series generation), one module per
concept:

- :mod:`lem.jets`: truncated power series giving exact Taylor coefficients of analytic fields;
- :mod:`lem.fields`: :class:`PolynomialField`, :class:`AnalyticField` and their expansions;
- :mod:`lem.moments`: the truncated moment system (:func:`lem.moments.moment_system`), its
  cached structure;
- :mod:`lem.segment`: one expansion segment (scaling, propagation, truncation differences);
- :mod:`lem.propagation`: :func:`solve`, the entry point (restarts, error propagation);
- :mod:`lem.result`: options, statistics, results, statuses and :class:`LEMWarning`;
- :mod:`lem.taylor`: Taylor coefficients in x and in the initial data;
- :mod:`lem.paper_equations`: the paper's equations as fields (corrected (3.13), (3.16)).

Beside the engine: :mod:`lem.series` (the paper's printed formulas (3.20), (4.1), (4.2) and the
true series beside them), :mod:`lem.troesch` (Troesch's problem by shooting over the engine) and
:mod:`lem.jean_pratt`. :mod:`lem.truncation` is the engine's former single module, kept as a
deprecated alias.
"""
import importlib

# one distribution (lcp-lem) ships both packages: one version, written in lem/_version.py
from lem._version import __version__ as __version__  # re-exported

# The engine (and numba behind it) loads on first use: ``lcp`` needs only lem.jean_pratt at import.
_LAZY = {"AnalyticField": "fields", "PolynomialField": "fields", "solve": "propagation",
         "LEMResult": "result", "LEMWarning": "result", "solve_troesch": "troesch"}
_SUBMODULES = {"jean_pratt", "series", "troesch", "truncation", "jets", "fields", "moments", "segment",
               "propagation", "result", "taylor", "paper_equations", "expmv", "validation"}


def __getattr__(name):
    if name in _LAZY:
        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    if name in _SUBMODULES:
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module 'lem' has no attribute {name!r}")


__all__ = [
           "AnalyticField",
           "LEMResult",
           "LEMWarning",
           "PolynomialField",
           "jean_pratt",
           "series",
           "solve",
           "solve_troesch",
           "troesch",
]
