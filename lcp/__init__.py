"""lcp: rigid-body contact dynamics with exact Coulomb friction (Moreau-Jean time stepping).

Main entry point: :func:`simulate`. Scenes with exact solutions: :mod:`lcp.scenes`. Parameter
sweeps, serial or on a Dask cluster: :func:`sweep`.

The names below are loaded on first use (PEP 562), so that ``import lcp`` costs next to nothing
and a script pays only for the parts it uses (CasADi for models, SciPy for sparse problems and
smooth phases, OSQP for its solver).
"""
from __future__ import annotations

import importlib

from ._version import __version__ as __version__  # re-exported

#: public name -> (module, attribute); None as attribute: the module itself
_EXPORTS = {
    "simulate": ("lcp.simulation", "simulate"),
    "METHODS": ("lcp.simulation", "METHODS"),
    "scenes": ("lcp.scenes", None),
    "System": ("lcp.system", "System"),
    "Contact": ("lcp.system", "Contact"),
    "ContactProblem": ("lcp.contact_problem", "ContactProblem"),
    "JeanPrattExact": ("lcp.exact", "JeanPrattExact"),
    "SimulationResult": ("lcp.result", "SimulationResult"),
    "SolverStats": ("lcp.result", "SolverStats"),
    "EventResult": ("lcp.events", "EventResult"),
    "SOLVERS": ("lcp.solvers", "SOLVERS"),
    "make_solver": ("lcp.solvers", "make_solver"),
    "sweep": ("lcp.parameter_sweep", "sweep"),
}

__all__ = sorted(_EXPORTS)


def __getattr__(name):
    try:
        module, attr = _EXPORTS[name]
    except KeyError:
        raise AttributeError(f"module 'lcp' has no attribute {name!r}") from None
    value = importlib.import_module(module)
    if attr is not None:
        value = getattr(value, attr)
    globals()[name] = value  # later lookups are plain attribute reads
    return value


def __dir__():
    return sorted(set(globals()) | set(_EXPORTS))
