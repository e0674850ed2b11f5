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
from . import jean_pratt, series, troesch
from .fields import AnalyticField, PolynomialField
from .propagation import solve
from .result import LEMResult, LEMWarning
from .troesch import solve_troesch

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
