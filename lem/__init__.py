"""The Linear Equivalence Method (LEM) and the paper's series.

- :mod:`lem.series`: the paper's printed formulas (3.20), (4.1), (4.2) and the true series beside
  them (physics.md section 5).
- :mod:`lem.truncation`: the LEM engine (truncated moment systems, i.e. Carleman linearization) for
  polynomial and analytic vector fields, with restarts, a-posteriori error estimates and series
  generation; :func:`lem.truncation.solve` is its entry point.
- :mod:`lem.troesch`: Troesch's problem by shooting over the engine's propagator.
"""
from . import jean_pratt, series, troesch, truncation
from .troesch import solve_troesch
from .truncation import AnalyticField, LEMResult, LEMWarning, PolynomialField, solve

__all__ = ["series", "truncation", "troesch", "solve", "solve_troesch", "LEMResult", "LEMWarning",
           "PolynomialField", "AnalyticField"]
