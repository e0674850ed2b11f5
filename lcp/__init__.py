"""lcp: rigid-body contact dynamics with exact Coulomb friction (Moreau-Jean time stepping).

Main entry point: :func:`simulate`. Scenes with exact solutions: :mod:`lcp.scenes`. Parameter
sweeps, serial or on a Dask cluster: :func:`sweep`.

The names below are loaded on first use (PEP 562), so that ``import lcp`` costs next to nothing
and a script pays only for the parts it uses (CasADi for models, SciPy for sparse problems and
smooth phases, OSQP for its solver).
"""
from __future__ import annotations

import importlib

from lem._version import __version__ as __version__  # re-exported (one version for both packages)

#: public name -> (module, attribute); None as attribute: the module itself
_EXPORTS = {
    "simulate": ("lcp.simulation", "simulate"),
    "METHODS": ("lcp.simulation", "METHODS"),
    "scenes": ("lcp.scenes", None),
    "System": ("lcp.model.system", "System"),
    "Contact": ("lcp.model.system", "Contact"),
    "ContactProblem": ("lcp.contact.problem", "ContactProblem"),
    "JeanPrattExact": ("lcp.scenes.jean_pratt_exact", "JeanPrattExact"),
    "SimulationResult": ("lcp.result", "SimulationResult"),
    "SolverStats": ("lcp.result", "SolverStats"),
    "EventResult": ("lcp.events", "EventResult"),
    "SOLVERS": ("lcp.contact.solvers", "SOLVERS"),
    "make_solver": ("lcp.contact.solvers", "make_solver"),
    "interleave": ("lcp.contact.law", "interleave"),
    "sweep": ("lcp.sweeps.parameter_sweep", "sweep"),
    "ConeContactProblem": ("lcp.contact.spatial_problem", "ConeContactProblem"),
    "CONE_SOLVERS": ("lcp.contact.spatial_solvers", "CONE_SOLVERS"),
    "make_cone_solver": ("lcp.contact.spatial_solvers", "make_cone_solver"),
    "ControlSchedule": ("lcp.model.control", "ControlSchedule"),
    "forces": ("lcp.model.forces", None),
    "rigid_body": ("lcp.model.rigid_body", None),
    "events": ("lcp.events", None),
    "ocp": ("lcp.ocp", None),
    "fclib": ("lcp.fclib", None),
    "batch": ("lcp.batch", None),
    "classical": ("lcp.classical", None),
    "plotting": ("lcp.plotting", None),
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
