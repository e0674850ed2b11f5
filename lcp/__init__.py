"""lcp: rigid-body contact dynamics with exact Coulomb friction (Moreau-Jean time stepping).

Main entry point: :func:`simulate`. Scenes with exact solutions: :mod:`lcp.scenes`.
"""
from . import scenes
from .contact_problem import ContactProblem
from .events import EventResult
from .exact import JeanPrattExact
from .result import SimulationResult, SolverStats
from .simulation import METHODS, simulate
from .solvers import SOLVERS, make_solver
from .system import Contact, System

__all__ = ["simulate", "scenes", "System", "Contact", "ContactProblem", "JeanPrattExact",
           "SimulationResult", "EventResult", "SolverStats", "SOLVERS", "METHODS", "make_solver"]
