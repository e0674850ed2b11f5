"""The scene type: a system with its initial state, a default horizon and (where known) the exact solution.

Holds :class:`Scene` and the parameter check shared by the scene builders. Imports the model
only; every scene module imports this one.
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np

from lcp.model.system import System

__all__ = ["Scene", "check_params"]


class Scene:
    """A system with its initial state.

    Attributes
    ----------
    system : System
        The CasADi model. A scene may build it on first access (``build_system``): the paths that
        run from the scene's :class:`~lcp.timestepping.constant_model.ConstantModel` never need it.
    q0, v0 : ndarray, shape (n,)
    t_end : float
        Default horizon.
    name : str
    params : dict
        The parameters the scene was built from.
    solution : JeanPrattExact or None
        Exact solution, if known (:meth:`exact` evaluates it).
    model : ConstantModel or None
        The numbers of a constant system, where the builder knows them in closed form.
    """

    def __init__(self, system: System | None, q0, v0, t_end: float, name: str, params: dict | None = None,
                 solution=None, no_exact_reason: str = "", model=None,
                 build_system: Callable[[], System] | None = None):
        if system is None and build_system is None:
            raise ValueError("a Scene needs a system or a build_system callable")
        self._system, self._build_system = system, build_system
        self.q0, self.v0, self.t_end, self.name = q0, v0, t_end, name
        self.params = {} if params is None else params
        self.solution, self.no_exact_reason, self.model = solution, no_exact_reason, model

    @property
    def system(self) -> System:
        if self._system is None:
            self._system = self._build_system()
        return self._system

    @system.setter
    def system(self, value: System):
        self._system = value

    @property
    def system_built(self) -> bool:
        """Whether the CasADi System exists already (it is built on first access otherwise)."""
        return self._system is not None

    def __repr__(self):
        return f"Scene(name={self.name!r}, params={self.params!r}, t_end={self.t_end!r})"

    def exact(self, t) -> dict:
        """Exact x, xdot, N, f (and y = 0) at times t; see :class:`lcp.scenes.jean_pratt_exact.JeanPrattExact`."""
        if self.solution is None:
            raise ValueError(f"scene '{self.name}' has no exact solution"
                             + (f": {self.no_exact_reason}" if self.no_exact_reason else ""))
        return self.solution(t)

    def __getattr__(self, name):
        # kappa, N0, B, tau0, x_stop, shocks ... of the exact solution, as scene attributes
        sol = self.__dict__.get("solution")
        if name in ("kappa", "N0", "B", "tau0", "x_stop", "shocks", "A", "tan", "consistent", "impulse",
                    "switch_times"):
            if sol is not None:
                return getattr(sol, name)
            raise AttributeError(f"{name}: scene '{self.__dict__.get('name')}' has no exact solution "
                                 f"({self.__dict__.get('no_exact_reason', '')})")
        raise AttributeError(name)


def check_params(**kw):
    for k, val in kw.items():
        if type(val) is float and math.isfinite(val):
            continue  # the common case, without NumPy's scalar call
        if not isinstance(val, (int, float, np.floating, np.integer)) or not np.isfinite(val):
            raise ValueError(f"{k} must be a finite number, got {val!r}")
