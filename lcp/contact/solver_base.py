"""The one-step solver interface, for both Coulomb laws: what a solver returns, how its answer is
checked, the one registry of solvers by name and law, and the scaffolding of the iterative ones.

A solver solves the problems of one law (its ``law``: ``"planar"``, :class:`~lcp.contact.problem.
ContactProblem`; ``"disk"``, :class:`~lcp.contact.spatial_problem.ConeContactProblem`), and
:data:`REGISTRY` names, for each solver name, the class that solves it for each law
(``REGISTRY["nsgs"]`` has both). :func:`build_solver` makes one by name and law; the per-law
modules (:mod:`lcp.contact.solvers`, :mod:`lcp.contact.spatial_solvers`) register their classes
and keep their historical views (``SOLVERS``, ``CONE_SOLVERS``).

Law-independent only: this module must not import the problems or solvers of either law (they
import it); it imports NumPy.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["LAWS", "REGISTRY", "IterativeSolver", "OneStepSolver", "StepSolution", "WarmStart", "build_solver",
           "register", "sweep_blocked"]

#: the laws and the problem type each one is posed as
LAWS = {"planar": "ContactProblem", "disk": "ConeContactProblem"}
#: solver name -> {law: solver class}: which laws each name handles
REGISTRY: dict[str, dict[str, type]] = {}


@dataclass
class StepSolution:
    """What a one-step solver returns.

    Attributes
    ----------
    p : ndarray, shape (n,)
        Impulses in the problem's blocked order (normals, then tangents).
    status : int
        0 success, 1 approximate (the faceted disk), < 0 failure (see ``message``).
    message : str
    iterations : int
        Solver iterations (pivots for Lemke, fixed-point iterations for OSQP, cases tried for enum).
    qp_solves : int
        QP / SOCP solves (0 for the other solvers).
    residual : float
        Coulomb residual (the problem's ``residual``), recomputed independently of the solver.
    ambiguous : bool
        More than one solution was found (enumeration only): the first admissible case is used.
    error : float
        Normalised natural-map error of ``p`` (Siconos's measure,
        :func:`lcp.contact.law.natural_map_error`), recomputed from (W, q, mu, p) apart from
        the solver; NaN when ``p`` is not finite.
    """

    p: np.ndarray
    status: int = 0
    message: str = "solved"
    iterations: int = 0
    qp_solves: int = 0
    residual: float = 0.0
    ambiguous: bool = False
    error: float = float("nan")
    #: ContactProblem.checks of ``p`` where the solver computed them already (its stopping test):
    #: OneStepSolver.solve reuses them instead of a second pass over W
    _checks: tuple | None = field(default=None, repr=False, compare=False)

    @property
    def success(self) -> bool:
        return self.status >= 0


class OneStepSolver:
    """Base class: solve a problem of the solver's law, then check the Coulomb law independently.

    Every solution also carries its normalised natural-map error (``StepSolution.error``,
    Siconos's measure). An exact solver's answer above :attr:`error_target` (``error_tol`` where
    the solver takes one, else ``residual_tol``) has stopped short by that measure: status -1,
    with the error in the message. The two measures differ where the problem's impulse scale
    (``problem.scale``, the impulse that would cancel each contact's free velocity alone) is far
    above the impulses of the solution, as with redundant contacts. An inexact solver
    (``exact = False``, the faceted approximation) reports its residual without rejection.

    A subclass sets ``name``, ``law`` (the law of the problems it takes; ``"planar"`` by default)
    and implements ``_solve``.

    Parameters
    ----------
    residual_tol : float
        Largest accepted Coulomb residual, relative to the larger of the problem's impulse scale
        and the largest impulse of the solution.
    """

    name = "base"
    law = "planar"
    exact = True
    error_tol: float | None = None

    def __init__(self, residual_tol: float = 1e-10):
        if not (np.isfinite(residual_tol) and residual_tol > 0):
            raise ValueError(f"residual_tol must be finite and > 0, got {residual_tol!r}")
        self.residual_tol = residual_tol

    @property
    def error_target(self) -> float:
        """Largest accepted natural-map error: ``error_tol`` when given, else ``residual_tol``."""
        return self.residual_tol if self.error_tol is None else self.error_tol

    def applicable(self, problem) -> bool:
        return True

    def check_law(self, problem) -> None:
        """TypeError unless ``problem`` is posed in this solver's law."""
        if problem.law != self.law:
            self._wrong_law(problem)

    def _wrong_law(self, problem):
        raise TypeError(f"problem must be a {LAWS[self.law]} (solver '{self.name}' solves the {self.law} law), "
                        f"got {type(problem).__name__}")

    def solve(self, problem) -> StepSolution:
        if problem.law != self.law:  # (check_law, without a call: solve runs once per time step)
            self._wrong_law(problem)
        if problem.k == 0:
            return StepSolution(np.zeros(0))
        if not self.applicable(problem):
            return StepSolution(np.full(problem.n, np.nan), -3,
                                f"solver '{self.name}' does not apply to {problem.k} contacts")
        sol = self._solve(problem)
        self._record_checks(problem, sol)
        if sol.success and self.exact:
            # relative to the impulses at hand: an absolute floor would pass any answer to a problem
            # whose impulses are tiny (a file with |q| ~ 1e-15 once passed with a 38 % error)
            p = sol.p
            scale = max(problem.scale, float(np.max(np.abs(p))) if p.size else 0.0, 1e-300)
            if not np.isfinite(sol.residual) or sol.residual > self.residual_tol * scale:
                sol.status = -2
                sol.message = (f"solver '{self.name}' returned an impulse violating the Coulomb law "
                               f"(residual {sol.residual:.3g})")
            elif not sol.error <= self.error_target:
                sol.status = -1
                sol.message = (f"solver '{self.name}' stopped short: natural-map error {sol.error:.3g} > "
                               f"{self.error_target:.3g} (Coulomb residual {sol.residual:.3g})")
        return sol

    def _record_checks(self, problem, sol: StepSolution) -> None:
        """Set ``sol.error`` (and ``sol.residual`` of a success) from ``problem.checks`` of sol.p."""
        # (the contact-by-contact residual is the iterative solvers' stopping test: an exact
        # solver's pivoting rounds a contact whose free velocity is 1e-17 of the problem's to zero,
        # which that test, on the contact's own scale, would call a violation)
        if sol._checks is None:  # the same p and problem give the same checks: computed once
            sol._checks = problem.checks(sol.p)
        res, _, sol.error = sol._checks
        if sol.success:
            sol.residual = res

    def _solve(self, problem) -> StepSolution:  # pragma: no cover - abstract
        raise NotImplementedError


def register(*classes: type) -> dict[str, type]:
    """Enter solver classes in :data:`REGISTRY` under their ``name`` and ``law``; returns the view
    {name: class} of the classes given (in their order)."""
    view = {}
    for cls in classes:
        REGISTRY.setdefault(cls.name, {})[cls.law] = cls
        view[cls.name] = cls
    return view


def build_solver(name, law: str, **options) -> OneStepSolver:
    """A solver of ``law`` by name (or an instance of one, returned as it is).

    The law's solver module must be imported (its classes registered): :func:`lcp.contact.solvers.
    make_solver` sees to it.
    """
    if law not in LAWS:
        raise ValueError(f"unknown law {law!r}; known laws: {sorted(LAWS)}")
    planar = law == "planar"
    if isinstance(name, OneStepSolver) and name.law == law:
        if options:
            raise ValueError(("solver_options" if planar else "solver options")
                             + " cannot be given with a solver instance")
        return name
    if not isinstance(name, str) or law not in REGISTRY.get(name, ()):
        known = sorted(n for n, by_law in REGISTRY.items() if law in by_law)
        if planar:
            raise ValueError(f"unknown solver {name!r}; known solvers: {known}")
        raise ValueError(f"unknown cone solver {name!r}; known: {known}")
    try:
        return REGISTRY[name][law](**options)
    except TypeError as exc:
        where = f"solver_options for '{name}'" if planar else f"options for cone solver '{name}'"
        raise ValueError(f"invalid {where}: {exc}") from exc


# ----------------------------------------------------------------- iterative solvers
class WarmStart:
    """Per-operator data of an iterative solver: the problem's contact-by-contact operator
    (``problem.operator()``) and the last impulses, the warm start of the next step with the same W
    (cached on ``problem.key``; an operator that does not fit the problem is rebuilt)."""

    def __init__(self, cache: dict, pb):
        key = pb.key
        hit = cache.get(key) if key is not None else None
        if hit is not None and hit[0].fits(pb):
            self.op, self.p = hit
        else:
            self.op, self.p = pb.operator(), None
        self.key, self.cache = key, cache

    def store(self, p):
        if self.key is not None:
            if len(self.cache) > 64:  # active sets come and go: keep the cache bounded
                self.cache.clear()
            self.cache[self.key] = (self.op, p)


class IterativeSolver(OneStepSolver):
    """What the iterative solvers of both laws share: the compiled switch and the warm starts."""

    def __init__(self, residual_tol: float = 1e-10, compiled: bool = True):
        super().__init__(residual_tol)
        self.compiled = bool(compiled)
        self._cache: dict = {}

    def warm_start(self, pb) -> WarmStart:
        return WarmStart(self._cache, pb)

    def replace_warm_start(self, key, p) -> None:
        """Replace the stored warm start of ``key`` (when there is one) by the impulses p."""
        if key is not None and key in self._cache:
            self._cache[key] = (self._cache[key][0], p)


def sweep_blocked(op, q_i, mu, p, tol: float, max_sweeps: int, compiled: bool, rel_scale: float = 0.0):
    """NSGS sweeps of the operator ``op`` from p (blocked order; None: zero) with the free velocity
    ``q_i`` in ``op``'s contact-by-contact order: (p, sweeps done, stopping measure)."""
    r0 = None if p is None else p[op.perm]
    r, n, res, _ = op.sweeps(q_i, mu, r0, tol, max_sweeps, compiled, rel_scale)
    out = np.empty_like(r)
    out[op.perm] = r
    return out, n, res
