"""One-step contact solvers, by name: ``"enum"``, ``"lemke"``, ``"osqp"`` (and ``"auto"``).

Each solver takes a :class:`~lcp.contact.problem.ContactProblem` and returns a :class:`StepSolution`.
The base class owns the bookkeeping (the independent Coulomb residual check, the status); each
solver implements one method, ``_solve``.

- ``"enum"``: closed-form case analysis of a single planar contact (open, stick, slide+, slide-).
- ``"lemke"``: the exact LCP form (:meth:`ContactProblem.to_lcp`) by Lemke's pivoting method.
- ``"nsgs"``: nonsmooth Gauss-Seidel with exact local solves (:mod:`lcp.contact.nsgs`), warm-started.
- ``"newton"``: NSGS sweeps then semismooth Newton on sparse linear algebra (:mod:`lcp.contact.newton`).
- ``"osqp"``: the Tresca fixed point. For a friction bound s the problem is the convex QP
  min 1/2 p'W p + q'p  s.t.  p_N >= 0, |p_T| <= s, solved by OSQP; its active set names the branch
  (stick, slide+, slide-, open) and the branch's linear system then gives the exact Coulomb
  fixed point s = mu p_N directly (docs/numerical_methods.md: the map is piecewise affine). A single QP
  would be a convex relaxation, not Coulomb's law.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import functools

import numpy as np
from lcp.numerics.lazy import issparse
from lcp.numerics.lazy import sparse as sp

from lcp.contact.problem import OPEN, SLIDE_NEG, SLIDE_POS, STICK, ContactProblem, planar_enum
from lcp.contact.lemke import lemke

__all__ = ["StepSolution", "OneStepSolver", "EnumSolver", "LemkeSolver", "OsqpSolver", "NsgsSolver",
           "NewtonSolver", "SOLVERS", "make_solver"]


@dataclass
class StepSolution:
    """What a one-step solver returns.

    Attributes
    ----------
    p : ndarray, shape (2k,)
        Impulses (p_N, p_T).
    status : int
        0 success, < 0 failure (see ``message``).
    message : str
    iterations : int
        Solver iterations (pivots for Lemke, fixed-point iterations for OSQP, cases tried for enum).
    qp_solves : int
        OSQP solves (0 for the other solvers).
    residual : float
        Coulomb residual :meth:`ContactProblem.residual`, recomputed independently of the solver.
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
    """Base class: solve a ContactProblem, then check the Coulomb law independently.

    Every solution also carries its normalised natural-map error (``StepSolution.error``,
    Siconos's measure). An exact solver's answer above :attr:`error_target` (``error_tol`` where
    the solver takes one, else ``residual_tol``) has stopped short by that measure: status -1,
    with the error in the message. The two measures differ where the problem's impulse scale
    (``ContactProblem.scale``, the impulse that would cancel each contact's free velocity alone)
    is far above the impulses of the solution, as with redundant contacts.

    Parameters
    ----------
    residual_tol : float
        Largest accepted Coulomb residual, relative to the larger of the problem's impulse scale
        and the largest impulse of the solution.
    """

    name = "base"
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

    def applicable(self, problem: ContactProblem) -> bool:
        return True

    def solve(self, problem: ContactProblem) -> StepSolution:
        if problem.k == 0:
            return StepSolution(np.zeros(0))
        if not self.applicable(problem):
            return StepSolution(np.full(2 * problem.k, np.nan), -3,
                                f"solver '{self.name}' does not apply to {problem.k} contacts")
        sol = self._solve(problem)
        # (the contact-by-contact residual is the iterative solvers' stopping test: an exact
        # solver's pivoting rounds a contact whose free velocity is 1e-17 of the problem's to zero,
        # which that test, on the contact's own scale, would call a violation)
        if sol._checks is None:  # the same p and problem give the same checks: computed once
            sol._checks = problem.checks(sol.p)
        res, _, sol.error = sol._checks
        if sol.success:
            sol.residual = res
            # relative to the impulses at hand: an absolute floor would pass any answer to a problem
            # whose impulses are tiny (a file with |q| ~ 1e-15 once passed with a 38 % error)
            scale = max(problem.scale, float(np.max(np.abs(sol.p))) if sol.p.size else 0.0, 1e-300)
            if not np.isfinite(sol.residual) or sol.residual > self.residual_tol * scale:
                sol.status = -2
                sol.message = (f"solver '{self.name}' returned an impulse violating the Coulomb law "
                               f"(residual {sol.residual:.3g})")
            elif not sol.error <= self.error_target:
                sol.status = -1
                sol.message = (f"solver '{self.name}' stopped short: natural-map error {sol.error:.3g} > "
                               f"{self.error_target:.3g} (Coulomb residual {sol.residual:.3g})")
        return sol

    def _solve(self, problem: ContactProblem) -> StepSolution:  # pragma: no cover - abstract
        raise NotImplementedError


class EnumSolver(OneStepSolver):
    """Closed-form case analysis for one planar contact: open, stick, slide+, slide-, in that order."""

    name = "enum"

    def applicable(self, problem):
        return problem.k == 1

    def _solve(self, pb):
        W, q = pb.W, pb.q
        pN, pT, mode, n_distinct = planar_enum(float(W[0, 0]), float(W[0, 1]), float(W[1, 0]), float(W[1, 1]),
                                               float(q[0]), float(q[1]), float(pb.mu[0]))
        if mode < 0:
            return StepSolution(np.full(2, np.nan), -1, "enumeration found no admissible case", 4)
        return StepSolution(np.array([pN, pT]), 0, "solved", 4, ambiguous=n_distinct > 1)


class LemkeSolver(OneStepSolver):
    """Exact LCP form of the Coulomb problem solved by Lemke's method (:func:`lcp.contact.lemke.lemke`)."""

    name = "lemke"

    def __init__(self, residual_tol: float = 1e-10, max_pivots: int | None = None):
        super().__init__(residual_tol)
        self.max_pivots = max_pivots

    def _solve(self, pb):
        M, b = pb.to_lcp()
        res = lemke(M, b, max_pivots=self.max_pivots)
        if not res.success:
            return StepSolution(np.full(2 * pb.k, np.nan), -1, f"Lemke: {res.message}", res.pivots)
        p = pb.from_lcp(res.z)
        # Polish on the branch Lemke found: one linear solve removes pivoting round-off.
        modes = pb.modes(p)
        pb_ = pb.solve_branch(modes)
        if pb_ is not None and pb.admissible(pb_, modes) and pb.residual(pb_) <= pb.residual(p):
            p = pb_
        return StepSolution(p, 0, "solved", res.pivots)


_OSQP_INFTY = np.inf  # an unbounded side: OSQP's public setup/update map it to its own OSQP_INFTY


@functools.lru_cache(maxsize=None)
def _triu_csc(n: int):
    """Row and column indices of the full upper triangle of an n x n matrix, in CSC order."""
    rows, cols = np.triu_indices(n)
    order = np.lexsort((rows, cols))
    return rows[order], cols[order]


class OsqpSolver(OneStepSolver):
    """Tresca fixed point on the friction bound, each QP solved by OSQP, with exact branch solves.

    Parameters
    ----------
    eps_abs, eps_rel : float
        OSQP tolerances (passed explicitly: OSQP's defaults, 1e-3, are too loose to read an
        active set from).
    max_iter : int
        Largest number of fixed-point iterations (QP solves) per step.
    osqp_max_iter : int
        OSQP's own ADMM iteration limit per QP.
    residual_tol : float
        See :class:`OneStepSolver`.

    Notes
    -----
    QP(s): min 1/2 p'W p + q'p subject to p_N >= 0, -s <= p_T <= s. Its KKT conditions are Tresca's
    law with bound s; Coulomb's law is the fixed point s = mu p_N(s). While a contact slides the map
    is affine with slope kappa (docs/numerical_methods.md), so plain iteration crawls as kappa -> 1 and
    has no fixed point for kappa >= 1. Instead each QP only names the branch; the branch's linear
    system gives the exact fixed point of that branch, which is accepted when it satisfies the
    branch's inequalities. When a sliding branch has no admissible fixed point (the Painleve
    case), the bound is grown geometrically until the QP sticks. The OSQP workspace is set up once
    per W (cached on ``problem.key``) and only ``q``, ``l`` and ``u`` are updated, with warm start.
    """

    name = "osqp"

    def __init__(self, eps_abs: float = 1e-10, eps_rel: float = 1e-10, max_iter: int = 200,
                 osqp_max_iter: int = 20000, residual_tol: float = 1e-10):
        super().__init__(residual_tol)
        for nm, val in (("eps_abs", eps_abs), ("eps_rel", eps_rel)):
            if not (np.isfinite(val) and val > 0):
                raise ValueError(f"{nm} must be finite and > 0, got {val!r}")
        if int(max_iter) < 1 or int(osqp_max_iter) < 1:
            raise ValueError("max_iter and osqp_max_iter must be >= 1")
        self.settings = dict(eps_abs=eps_abs, eps_rel=eps_rel, max_iter=int(osqp_max_iter),
                             polishing=False, verbose=False, warm_starting=True,
                             eps_prim_inf=1e-12, eps_dual_inf=1e-12)
        self.max_iter = int(max_iter)
        self._cache: dict = {}
        self._last_s: dict = {}

    def _workspace(self, pb: ContactProblem):
        """The OSQP solver for this W: set up once, then only updated.

        With ``pb.key`` set, W is known to be the same as last time under that key and nothing is
        updated; without it, one workspace per problem size has its P values replaced.
        """
        import osqp

        n = 2 * pb.k
        if issparse(pb.W):
            return self._sparse_workspace(pb)
        key = pb.key if pb.key is not None else ("size", n)
        solver = self._cache.get(key)
        if solver is not None and pb.key is not None:
            return solver
        rows, cols = _triu_csc(n)
        if solver is not None:
            solver.update(Px=pb.W[rows, cols])
            return solver
        # the full triangle is kept as the pattern, explicit zeros included, so that later
        # Px updates stay valid whatever W's zeros are
        P = sp.csc_matrix((np.arange(1.0, rows.size + 1), (rows, cols)), shape=(n, n))
        P.data[:] = pb.W[rows, cols]
        solver = osqp.OSQP()
        l, u = self._bounds(pb, np.zeros(pb.k))
        solver.setup(P, pb.q, sp.identity(n, format="csc"), l, u, **self.settings)
        self._cache[key] = solver
        return solver

    def _sparse_workspace(self, pb: ContactProblem):
        """The workspace of a sparse W: P = triu(W) with W's own pattern (memory grows with nnz).

        Keyed problems set up once; unkeyed ones reuse the workspace of the same size when the
        pattern is unchanged (only P's values are updated) and set up anew otherwise.
        """
        import osqp

        n = 2 * pb.k
        key = pb.key if pb.key is not None else ("sparse", n)
        solver = self._cache.get(key)
        if solver is not None and pb.key is not None:
            return solver
        P = sp.triu(pb.W, format="csc")
        P.sort_indices()
        if solver is not None:
            indptr, indices = self._patterns[key]
            if np.array_equal(indptr, P.indptr) and np.array_equal(indices, P.indices):
                solver.update(Px=P.data)
                return solver
        solver = osqp.OSQP()
        l, u = self._bounds(pb, np.zeros(pb.k))
        solver.setup(P, pb.q, sp.identity(n, format="csc"), l, u, **self.settings)
        self._cache[key] = solver
        self._patterns = getattr(self, "_patterns", {})
        self._patterns[key] = (P.indptr.copy(), P.indices.copy())
        return solver

    @staticmethod
    def _bounds(pb, s):
        # no upper bound on p_N
        k = pb.k
        if k == 1:
            s0 = float(s[0])
            return np.array([0.0, -s0]), np.array([_OSQP_INFTY, s0])
        return (np.concatenate([np.zeros(k), -s]), np.concatenate([np.full(k, _OSQP_INFTY), s]))

    def _solve(self, pb):
        import osqp

        k = pb.k
        solver = self._workspace(pb)
        # first bound: the previous step's (same W) or the frictionless normal impulse
        s = self._last_s.get((pb.key, k))
        if s is None or s.shape != (k,):
            s = np.zeros(k)
        qp_solves = 0
        for it in range(1, self.max_iter + 1):
            l, u = self._bounds(pb, s)
            status_val, status, x = self._qp(solver, pb.q, l, u)
            qp_solves += 1
            if status_val != osqp.SolverStatus.OSQP_SOLVED:
                return StepSolution(np.full(2 * k, np.nan), -1,
                                    f"OSQP status '{status}' at fixed-point iteration {it} "
                                    f"(bound s = {s})", it, qp_solves)
            # the QP names a branch; a few exact active-set corrections finish it
            p, modes = pb.refine_branch(self._branch(pb, x, s))
            if p is not None:
                self._last_s[(pb.key, k)] = pb.mu * np.maximum(p[:k], 0.0)
                return StepSolution(p, 0, "solved", it, qp_solves)
            s_plain = pb.mu * np.maximum(x[:k], 0.0)
            sliding = np.isin(modes, (SLIDE_POS, SLIDE_NEG))
            if it > 10:
                # heuristics exhausted: damped plain fixed point, which cannot run away
                s_new = 0.5 * (s + s_plain)
            elif sliding.any() and np.all(s_plain >= s):
                # no admissible fixed point on the sliding branch (Painleve / kappa >= 1): grow the
                # bound geometrically until the QP sticks
                s_new = np.where(sliding, np.maximum(s_plain, 2.0 * s + (s == 0) * pb.mu * pb.scale), s_plain)
            else:
                s_new = s_plain
            if np.allclose(s_new, s, rtol=1e-15, atol=0):
                break  # the bound no longer moves, yet its QP names no admissible branch
            s = s_new
        return StepSolution(np.full(2 * k, np.nan), -1,
                            f"Tresca fixed point did not converge ({it} iterations, last bound s = {s})",
                            it, qp_solves)

    @staticmethod
    def _qp(solver, q, l, u):
        """Update and solve one QP through OSQP's public API: (status value, status text, x).

        Only the vectors change between QPs (``update(q=, l=, u=)``; the workspace, its
        factorization and the warm start are kept), and the status is checked by the caller every
        time.
        """
        solver.update(q=q, l=l, u=u)
        res = solver.solve(raise_error=False)
        return res.info.status_val, res.info.status, res.x

    @staticmethod
    def _branch(pb: ContactProblem, x: np.ndarray, s: np.ndarray) -> np.ndarray:
        """Read the branch from a QP solution: open, stick (bound inactive) or the bound's side."""
        k = pb.k
        xl, sl = x.tolist(), s.tolist()  # floats: a few comparisons per contact
        tol = 1e-7 * max(pb.scale, max(map(abs, xl)))
        modes = np.empty(k, dtype=np.int8)
        for j in range(k):
            pN, pT, sj = xl[j], xl[k + j], sl[j]
            if pN <= tol:
                modes[j] = OPEN
            elif sj > tol and pT >= sj - tol:  # p_T = +s opposes u_T < 0
                modes[j] = SLIDE_NEG
            elif sj > tol and pT <= -sj + tol:
                modes[j] = SLIDE_POS
            else:
                modes[j] = STICK
        return modes


class _Warm:
    """Per-operator data of the iterative solvers: the contact-by-contact operator and the last
    impulses (the warm start of the next step with the same W)."""

    def __init__(self, solver, pb):
        from lcp.contact.nsgs import InterleavedOperator

        key = pb.key if pb.key is not None else None
        hit = solver._cache.get(key) if key is not None else None
        if hit is not None and hit[0].k == pb.k:
            self.op, self.p = hit
        else:
            self.op, self.p = InterleavedOperator(pb.W), None
        self.key = key
        self.cache = solver._cache

    def store(self, p):
        if self.key is not None:
            if len(self.cache) > 64:  # active sets come and go: keep the cache bounded
                self.cache.clear()
            self.cache[self.key] = (self.op, p)


class _IterativeSolver(OneStepSolver):
    """Bookkeeping shared by the iterative solvers: warm start, tolerance, the optional error check.

    ``residual_tol`` bounds :meth:`ContactProblem.residual` relative to the problem's impulse
    scale (the iterations stop at a tenth of it). The normalised natural-map error
    (:func:`lcp.contact.law.natural_map_error`, Siconos's measure) must be below
    ``error_tol`` too (None: ``residual_tol``): the iterations go on with a tolerance tightened a
    hundredfold, up to three times, and a solve that still misses it reports status -1.
    """

    def __init__(self, residual_tol: float = 1e-10, error_tol: float | None = None, compiled: bool = True):
        super().__init__(residual_tol)
        if error_tol is not None and not (np.isfinite(error_tol) and error_tol > 0):
            raise ValueError(f"error_tol must be finite and > 0, got {error_tol!r}")
        self.error_tol, self.compiled = error_tol, bool(compiled)
        self._cache: dict = {}

    def _solve(self, pb):
        warm = _Warm(self, pb)
        # relative to the problem's own impulse scale, so that small-impulse problems (granular
        # files) reach the same normalised error as large ones
        tol = 0.1 * self.residual_tol * pb.scale
        p = None if warm.p is None else warm.p.copy()
        its = 0
        target, rtol = self.error_target, 0.1 * self.residual_tol
        rel, rel_scale = 0.0, 0.0
        checked = None  # (p, its checks): the last iterate checked
        for _ in range(4):
            p, n, res, msg = self._run(pb, warm.op, p, tol, rel_scale)
            its += n
            if res > tol:
                break
            # the problem's impulse scale can be far above some contacts' impulses (redundant
            # contacts, bodies of very different masses): the residual contact by contact, on each
            # contact's own scale, and the error in Siconos's units decide whether it has finished
            checked = (p, pb.checks(p))
            _, rel, err = checked[1]
            if rel > rtol:
                rel_scale = pb.scale  # go on with ContactProblem.stop_measure: every contact on its own scale
                continue
            if err <= target:
                break
            tol *= 1e-2
        warm.store(p)
        done = checked[1] if checked is not None and checked[0] is p else None
        if res > tol:
            return StepSolution(p, -1, f"{self.name}: {msg}; residual {res:.3g} > tolerance {tol:.3g}", its,
                                _checks=done)
        if not rel <= rtol:
            return StepSolution(p, -1, f"{self.name}: {msg}; a contact's residual is {rel:.3g} of its own impulse "
                                f"scale (> {rtol:.3g})", its, _checks=done)
        return StepSolution(p, 0, "solved", its, _checks=done)

    def _run(self, pb, op, p, tol, rel_scale):  # pragma: no cover - abstract
        raise NotImplementedError


class NsgsSolver(_IterativeSolver):
    """Nonsmooth Gauss-Seidel with exact closed-form local solves (:mod:`lcp.contact.nsgs`).

    Warm-started from the previous step's impulses when the problem's ``key`` recurs.

    Parameters
    ----------
    max_sweeps : int
        Largest number of sweeps; a solve that stops short reports status -1 naming its residual.
    residual_tol, error_tol : float
        See :class:`_IterativeSolver`.
    compiled : bool
        Use the numba sweeps when installed (False: the plain-Python ones, for tests).
    """

    name = "nsgs"

    def __init__(self, residual_tol: float = 1e-10, max_sweeps: int = 10000, compiled: bool = True,
                 error_tol: float | None = None):
        super().__init__(residual_tol, error_tol, compiled)
        if int(max_sweeps) < 1:
            raise ValueError(f"max_sweeps must be >= 1, got {max_sweeps!r}")
        self.max_sweeps = int(max_sweeps)

    def _run(self, pb, op, p, tol, rel_scale):
        from lcp.contact.nsgs import nsgs

        r0 = None if p is None else p[op.perm]
        r, sweeps, res, _ = nsgs(op, pb.q[op.perm], pb.mu, r0, tol, self.max_sweeps, self.compiled, rel_scale)
        p = np.empty_like(r)
        p[op.perm] = r
        return p, sweeps, res, f"NSGS stopped after {sweeps} sweeps"


class NewtonSolver(_IterativeSolver):
    """NSGS sweeps, then semismooth Newton (:mod:`lcp.contact.newton`) to rounding level.

    Rounds of NSGS sweeps (``sweeps``, doubling each round) and up to ``newton_iter`` Newton
    iterations alternate, each round starting from the better of the two, until the residual is
    below tolerance, ``max_rounds`` rounds are spent or two rounds in a row gain less than 10 %
    on the residual (status -1 then, with the residual reached). After a Newton phase that
    gains nothing, Newton waits until the sweeps have cut the residual a hundredfold.

    Parameters
    ----------
    sweeps : int
        NSGS sweeps before the first Newton phase (0: Newton alone).
    newton_iter, max_rounds : int
    residual_tol, error_tol : float
        See :class:`_IterativeSolver`.
    """

    name = "newton"

    def __init__(self, residual_tol: float = 1e-10, sweeps: int = 20, newton_iter: int = 30,
                 max_rounds: int = 10, compiled: bool = True, error_tol: float | None = None):
        super().__init__(residual_tol, error_tol, compiled)
        if int(sweeps) < 0 or int(newton_iter) < 1 or int(max_rounds) < 1:
            raise ValueError("sweeps must be >= 0, newton_iter and max_rounds >= 1")
        self.sweeps, self.newton_iter, self.max_rounds = int(sweeps), int(newton_iter), int(max_rounds)

    def _run(self, pb, op, p, tol, rel_scale):
        from lcp.contact.newton import newton_solve
        from lcp.contact.nsgs import nsgs

        # rel_scale > 0: ContactProblem.stop_measure, each contact also on its own scale
        measure = pb.residual if rel_scale == 0 else pb.stop_measure

        p = np.zeros(2 * pb.k) if p is None else p
        res = np.inf  # the sweeps below compute it
        its, msg = 0, "no rounds"
        qi = pb.q[op.perm]
        slow, res_failed, res_prev = 0, np.inf, np.inf
        for rnd in range(self.max_rounds):
            if res <= tol:
                break
            if rnd >= 2 and res > 0.9 * res_prev:
                slow += 1
                if slow >= 2:  # two rounds in a row (of doubling work) gaining < 10 %: stalled
                    msg = f"stalled after {rnd} rounds"
                    break
            else:
                slow = 0
            res_prev = res
            if not self.sweeps and rnd == 0:
                res = measure(p)
                if res <= tol:
                    break
            if self.sweeps:
                # where Newton stalls (degenerate contacts) NSGS does the work: its share doubles
                n_sw = self.sweeps * 2 ** min(rnd, 10)
                r, sw, res_s, _ = nsgs(op, qi, pb.mu, p[op.perm], tol, n_sw, self.compiled, rel_scale)
                its += sw
                p_s = np.empty_like(r)
                p_s[op.perm] = r
                if res_s <= res:  # the sweeps' measure is the same
                    p, res = p_s, res_s
                if res <= tol:
                    break
            if res > 0.01 * res_failed:  # Newton failed here before: sweeps first gain 100x
                continue
            p_n, it, _, msg = newton_solve(pb.W, pb.q, pb.mu, pb.rho, p, tol, self.newton_iter, measure)
            its += it
            res_n = measure(p_n)
            res_failed = res if res_n > 0.5 * res else np.inf
            if res_n <= res:
                p, res = p_n, res_n
        return p, its, res, f"NSGS + Newton stopped after {its} iterations ({msg})"


class AutoSolver(OneStepSolver):
    """The fastest exact solver for the problem at hand: the closed form for one contact; NSGS
    sweeps with a semismooth Newton finish (``"newton"``) for several, which on the measured
    scenes (block chains, independent copies, granular problems) beats Lemke from two contacts on
    and scales with nnz(W).

    Where the iteration stalls (nearly singular W: redundant contacts, a W stored with few digits
    and slightly indefinite), :func:`lcp.contact.core_pivot.core_pivot_solve` finishes from the stalled
    point: the settled contacts keep their modes and Lemke solves the small core around the
    near-null space exactly. Up to ``LEMKE_FALLBACK_MAX`` contacts a remaining failure is retried by
    Lemke on the whole problem; one contact's enumeration falls back on Lemke too."""

    name = "auto"
    #: largest number of contacts for which a failed iterative solve is retried by (dense) Lemke
    LEMKE_FALLBACK_MAX = 200

    def __init__(self, residual_tol: float = 1e-10, error_tol: float | None = None):
        super().__init__(residual_tol)
        self.enum = EnumSolver(residual_tol)
        self.lemke = LemkeSolver(residual_tol)
        self.iterative = NewtonSolver(residual_tol, error_tol=error_tol)
        self.error_tol = error_tol
        self.fallbacks = 0
        self.core_pivots = 0

    def _solve(self, pb):
        first = self.enum if pb.k == 1 else self.iterative
        sol = first.solve(pb)
        if sol.success:
            return sol
        if pb.k > 1 and np.all(np.isfinite(sol.p)):
            fin = self._core_pivot(pb, sol)
            if fin is not None:
                return fin
        if pb.k <= self.LEMKE_FALLBACK_MAX:
            sol2 = self.lemke.solve(pb)
            if sol2.success:
                self.fallbacks += 1
                sol2.message = f"fallback to lemke after: {sol.message}"
                return sol2
        return sol

    def _core_pivot(self, pb, sol):
        """The stalled iterate finished by the core pivot, or None; accepted on the iterative
        solver's own criteria (residual, and the normalised error when one is asked for)."""
        from lcp.contact.core_pivot import core_pivot_solve
        from lcp.contact.law import natural_map_error

        error_tol = self.iterative.error_tol
        fin = core_pivot_solve(pb, sol.p, error_tol=error_tol or 0.01 * self.residual_tol)
        if not fin.success or not pb.residual(fin.p) <= 0.1 * self.residual_tol * pb.scale:
            return None
        if error_tol is not None and not natural_map_error(pb.W, pb.q, pb.mu, fin.p) <= error_tol:
            return None
        # the warm start of the next step with this W is the finished impulses, not the stalled ones
        key = pb.key
        if key is not None and key in self.iterative._cache:
            self.iterative._cache[key] = (self.iterative._cache[key][0], fin.p.copy())
        self.core_pivots += 1
        return StepSolution(fin.p, 0, f"core pivot ({fin.core.size} contacts, {fin.pivots} pivots) after: {sol.message}",
                            sol.iterations + fin.pivots)


SOLVERS = {"auto": AutoSolver, "enum": EnumSolver, "lemke": LemkeSolver, "osqp": OsqpSolver,
           "nsgs": NsgsSolver, "newton": NewtonSolver}


def make_solver(name: str | OneStepSolver, **options) -> OneStepSolver:
    """A one-step solver by name (``"auto"``, ``"enum"``, ``"lemke"``, ``"osqp"``, ``"nsgs"``,
    ``"newton"``) or instance.

    Examples
    --------
    >>> from lcp.contact.solvers import make_solver
    >>> make_solver("lemke").name
    'lemke'
    """
    if isinstance(name, OneStepSolver):
        if options:
            raise ValueError("solver_options cannot be given with a solver instance")
        return name
    if not isinstance(name, str) or name not in SOLVERS:
        raise ValueError(f"unknown solver {name!r}; known solvers: {sorted(SOLVERS)}")
    try:
        return SOLVERS[name](**options)
    except TypeError as exc:
        raise ValueError(f"invalid solver_options for '{name}': {exc}") from exc

