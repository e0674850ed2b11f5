"""Deprecated: the LEM engine now lives in one module per concept.

``lem.truncation`` was the engine's single module. Its names moved:

- jets and monomial spaces: :mod:`lem.jets`
- vector fields and their expansions: :mod:`lem.fields`
- the truncated moment system: :mod:`lem.moments`
- options, statistics, results and statuses: :mod:`lem.result`
- one expansion segment (scaling, propagation, error estimate): :mod:`lem.segment`
- :func:`lem.solve` (restarts, error propagation): :mod:`lem.propagation`
- Taylor coefficients in x and in the initial data: :mod:`lem.taylor`
- the paper's equations as fields: :mod:`lem.paper_equations`

Importing a name from here still works and emits a ``DeprecationWarning`` naming its new home.
"""
from __future__ import annotations

import importlib
import warnings

_HOMES = {
    "STATUS_MESSAGES": "lem.result", "LEMWarning": "lem.result", "LEMOptions": "lem.result",
    "LEMStats": "lem.result", "LEMResult": "lem.result",
    "RADIUS_TRUST": "lem.jets", "Jet": "lem.jets",
    "PolynomialField": "lem.fields", "AnalyticField": "lem.fields", "as_field": "lem.fields",
    "MomentSystem": "lem.moments", "moment_system": "lem.moments",
    "solve": "lem.propagation",
    "taylor_coefficients": "lem.taylor", "initial_data_coefficients": "lem.taylor",
    "double_series": "lem.taylor",
    "bernoulli_numbers": "lem.paper_equations", "tanh_taylor_coefficients": "lem.paper_equations",
    "tanh_ode_field": "lem.paper_equations", "moment_rhs_3_16": "lem.paper_equations",
    "smooth_friction_field": "lem.paper_equations",
}
# private names that callers used before the split, and their public successors
_RENAMED = {"_space": ("lem.jets", "monomial_space")}

# the deprecated names, resolved lazily by __getattr__
__all__ = [
    "RADIUS_TRUST",
    "STATUS_MESSAGES",
    "AnalyticField",
    "Jet",
    "LEMOptions",
    "LEMResult",
    "LEMStats",
    "LEMWarning",
    "MomentSystem",
    "PolynomialField",
    "as_field",
    "bernoulli_numbers",
    "double_series",
    "initial_data_coefficients",
    "moment_rhs_3_16",
    "moment_system",
    "smooth_friction_field",
    "solve",
    "tanh_ode_field",
    "tanh_taylor_coefficients",
    "taylor_coefficients",
]


def __getattr__(name: str):
    if name in _HOMES:
        home, new = _HOMES[name], name
    elif name in _RENAMED:
        home, new = _RENAMED[name]
    else:
        raise AttributeError(f"module 'lem.truncation' has no attribute {name!r}")
    warnings.warn(f"lem.truncation.{name} is deprecated; import {new} from {home}",
                  DeprecationWarning, stacklevel=2)
    return getattr(importlib.import_module(home), new)


def __dir__():
    return sorted(set(globals()) | set(_HOMES) | set(_RENAMED))
