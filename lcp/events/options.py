"""Options of the event-driven integrator: how phases are integrated and modes are selected."""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from enum import Enum

import numpy as np

from lcp.result import STATUS_MESSAGES
from lcp.contact.solvers import make_solver

__all__ = ["CASCADE_ROUNDS", "EVENT_STATUS_MESSAGES", "EventOptions", "ModeSolver", "SmoothIntegrator", "cascade_round",
           "checked_times", "times_inside"]

#: status codes of the event integrator (the package's one table, :data:`lcp.result.STATUS_MESSAGES`)
EVENT_STATUS_MESSAGES = STATUS_MESSAGES

#: impacts at one instant solved round by round (each on the contacts then closed or approaching,
#: as Moreau-Jean's steps do in the limit h -> 0) before the rest of the cascade is solved at once
#: over every contact at the surface: a column of 10 beads (e = 0.5) needs up to 75 rounds
CASCADE_ROUNDS = 1000


def cascade_round(rounds: int, cap: int, t: float, closed, approaching, separating, notes):
    """The contacts of impact round ``rounds`` of a cascade at t (sorted) and why, or (None, the
    reason to stop): round by round on the closed and approaching contacts up to ``cap`` rounds,
    then at once over every contact at the surface (the coupled Delassus matrix; after it no contact
    at the surface approaches), noted once in ``notes``; past 8 such solves, give up. Shared by the
    planar and the spatial integrators."""
    if rounds <= cap:
        return sorted(closed + approaching), "gap closed with approach velocity"
    if rounds <= cap + 8:
        if rounds == cap + 1:
            notes.append(f"At t = {t:.10g} an impact cascade did not end after {cap} rounds; its rest was "
                         "solved at once over every contact at the surface.")
        return sorted(closed + approaching + separating), f"impact cascade not ended after {cap} rounds: finished at once"
    return None, f"at t = {t:.17g}: contacts still approach after an impact cascade of {rounds - 1} rounds"


class SmoothIntegrator(str, Enum):
    """How smooth phases are integrated."""

    AUTO = "auto"  #: closed form when the phase dynamics is polynomial in t, SciPy otherwise
    CLOSED_FORM = "closed-form"  #: closed form only (ValueError if the system does not allow it)
    SCIPY = "scipy"  #: solve_ivp with event functions, always


class ModeSolver(str, Enum):
    """How the acceleration-level contact problem is solved at events."""

    AUTO = "auto"  #: enumeration while the number of branches is <= max_branches, else Lemke
    ENUMERATE = "enumerate"  #: every branch: finds all solutions (detects non-uniqueness)
    LEMKE = "lemke"  #: Lemke's method on the LCP form (one solution; no uniqueness check)


_ODE_METHODS = ("DOP853", "RK45", "RK23", "Radau", "BDF", "LSODA")


def _enum_value(enum, name, value):
    member = _ENUM_MEMBERS[enum].get(value) if isinstance(value, str) else None
    if member is not None:
        return member
    try:
        return enum(value)
    except ValueError:
        raise ValueError(f"{name} must be one of {[e.value for e in enum]}, got {value!r}") from None


#: members by value (a str Enum member is its own value): Enum(value) without the metaclass call
_ENUM_MEMBERS = {enum: {e.value: e for e in enum} for enum in (SmoothIntegrator, ModeSolver)}


@dataclass(frozen=True, eq=False)
class EventOptions:
    """Validated options of the event-driven integrator.

    Parameters
    ----------
    t_eval : array_like, optional
        Output times, increasing, inside [0, t_end]. Default: ``n_eval`` equally spaced times
        from 0 to t_end.
    n_eval : int
        Number of default output times (>= 2).
    smooth : {"auto", "closed-form", "scipy"}
        Integrator of the smooth phases (:class:`SmoothIntegrator`).
    ode_method : str
        ``solve_ivp`` method for non-polynomial phases (DOP853, RK45, RK23, Radau, BDF, LSODA).
    rtol, atol : float
        ``solve_ivp`` tolerances.
    mode_solver : {"auto", "enumerate", "lemke"}
        Solver of the acceleration-level problem (:class:`ModeSolver`).
    impact_solver : str
        One-step solver of the velocity-level impact problem (``"auto"``, ``"enum"``, ``"lemke"``,
        ``"osqp"``; see :func:`lcp.contact.solvers.make_solver`).
    max_branches : int
        Largest number of branches enumerated by ``mode_solver="auto"``.
    max_events : int
        Largest number of events before the integration stops with status -4.
    tol : float
        Relative tolerance of the zero tests (a velocity, a gap or a force "is zero"), relative
        to the scene's velocity, length and force scales.
    rhs : {"compiled", "numpy"}
        Right-hand side of the planar DOP853 phases: one compiled CasADi evaluation per state
        (:mod:`lcp.events.compiled_branch`, systems of up to 12 coordinates; larger ones take the
        NumPy path), about 5 us against 40 to 90 us; or the system's data and the phase's branch
        solved by NumPy (LAPACK), the same arithmetic as the mode decisions. The two agree to
        rounding (whole simulations 10 to 1000 times inside the integration error, with the same
        events); the event functions, the reported forces and the end accelerations use the NumPy
        path in either case.
    """

    t_eval: object = None
    n_eval: int = 1000
    smooth: str = "auto"
    ode_method: str = "DOP853"
    rtol: float = 1e-12
    atol: float = 1e-14
    mode_solver: str = "auto"
    impact_solver: str = "auto"
    max_branches: int = 4096
    max_events: int = 10_000
    tol: float = 1e-10
    rhs: str = "compiled"

    def __post_init__(self):
        set_ = object.__setattr__
        set_(self, "smooth", _enum_value(SmoothIntegrator, "smooth", self.smooth))
        set_(self, "mode_solver", _enum_value(ModeSolver, "mode_solver", self.mode_solver))
        if self.rhs not in ("numpy", "compiled"):
            raise ValueError(f"rhs must be 'compiled' or 'numpy', got {self.rhs!r}")
        if self.ode_method not in _ODE_METHODS:
            raise ValueError(f"ode_method must be one of {list(_ODE_METHODS)}, got {self.ode_method!r}")
        defaults = _OPTION_DEFAULTS
        for name in ("rtol", "atol", "tol"):
            val = getattr(self, name)
            if val is defaults[name]:
                continue  # the default, valid
            if not isinstance(val, (int, float, np.floating)) or not math.isfinite(val) or val <= 0:
                raise ValueError(f"{name} must be finite and > 0, got {val!r}")
        for name, low in (("n_eval", 2), ("max_branches", 1), ("max_events", 1)):
            val = getattr(self, name)
            if val is defaults[name]:
                continue
            if not isinstance(val, (int, np.integer)) or isinstance(val, bool) or val < low:
                raise ValueError(f"{name} must be an integer >= {low}, got {val!r}")
        if not (isinstance(self.impact_solver, str) and self.impact_solver in _VALID_SOLVER_NAMES):
            make_solver(self.impact_solver)  # raises ValueError naming the known solvers
            if isinstance(self.impact_solver, str):
                _VALID_SOLVER_NAMES.add(self.impact_solver)
        if self.t_eval is not None:
            te = checked_times(self.t_eval)
            te.setflags(write=False)
            set_(self, "t_eval", te)

    @classmethod
    def from_kwargs(cls, **options) -> EventOptions:
        """Build from keyword arguments; unknown names raise ValueError listing the known ones."""
        known = _OPTION_NAMES
        if not known.issuperset(options):
            names = [f.name for f in fields(cls)]
            unknown = sorted(set(options) - known)
            raise ValueError(f"unknown option(s) {unknown} for method 'event'; known options: {names}")
        return cls(**options)

    def output_times(self, t_end: float) -> np.ndarray:
        if self.t_eval is None:
            return np.linspace(0.0, t_end, self.n_eval)
        return np.array(times_inside(self.t_eval, t_end))


def checked_times(t_eval) -> np.ndarray:
    """A new float array of the output times ``t_eval`` (flattened), checked: non-empty, finite,
    strictly increasing and >= 0 (ValueError naming ``t_eval`` otherwise).

    Examples
    --------
    >>> checked_times([0.0, 0.5, 1.0])
    array([0. , 0.5, 1. ])
    """
    te = np.array(t_eval, dtype=float).ravel()
    # strictly increasing with finite ends: all finite (a NaN fails every comparison)
    ok = (te.size and math.isfinite(te[0]) and math.isfinite(te[-1])
          and np.count_nonzero(te[1:] > te[:-1]) == te.size - 1)
    if not ok and (te.size == 0 or not np.isfinite(te).all()):
        raise ValueError("t_eval must be a non-empty array of finite times")
    if not ok or te[0] < 0:
        raise ValueError("t_eval must be strictly increasing and >= 0")
    return te


def times_inside(te: np.ndarray, t_end: float) -> np.ndarray:
    """``te`` (checked output times) if its last time is <= t_end, else ValueError."""
    if te[-1] > t_end:
        raise ValueError(f"t_eval must lie inside [0, t_end = {t_end!r}], got a last time {te[-1]!r}")
    return te


_OPTION_NAMES = frozenset(f.name for f in fields(EventOptions))
_OPTION_DEFAULTS = {f.name: f.default for f in fields(EventOptions)}
_VALID_SOLVER_NAMES: set = set()  # impact-solver names make_solver accepted (no need to build one again)

