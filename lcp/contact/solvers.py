"""One-step contact solvers, by name: ``"enum"``, ``"lemke"``, ``"osqp"`` (and ``"auto"``).

Each solver takes a :class:`~lcp.contact.problem.ContactProblem` and returns a :class:`StepSolution`.
The interface shared with the disk law's solvers is :mod:`lcp.contact.solver_base` (the base class
owns the bookkeeping: the independent Coulomb residual check, the status; each solver implements
one method, ``_solve``); this module registers the planar solvers in its one registry and gives
:func:`make_solver` for both laws. Imports the planar problem and the methods' modules of
``lcp.contact`` (the disk law's solvers only when asked for); it must not import anything above
``lcp.contact``.

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

import functools

import numpy as np
from lcp.numerics.lazy import issparse
from lcp.numerics.lazy import sparse as sp

from lcp.contact.problem import OPEN, SLIDE_NEG, SLIDE_POS, STICK, ContactProblem, planar_enum
from lcp.contact.lemke import lemke
from lcp.contact.solver_base import (REGISTRY, IterativeSolver, OneStepSolver, StepSolution, build_solver, register,
                                     sweep_blocked)

__all__ = ["StepSolution", "OneStepSolver", "EnumSolver", "LemkeSolver", "OsqpSolver", "NsgsSolver",
           "NewtonSolver", "AutoSolver", "REGISTRY", "SOLVERS", "make_solver"]


class EnumSolver(OneStepSolver):
    """Closed-form case analysis for one planar contact: open, stick, slide+, slide-, in that order."""

    name = "enum"

    def applicable(self, problem):
        return problem.k == 1

    def _solve(self, pb):
        W, q = pb.W, pb.q
        if not (W[0, 0] > 0 and W[1, 1] > 0):  # a zero (or overflowed) contact row: the cases divide by them
            return StepSolution(np.full(2, np.nan), -1, "enumeration: a diagonal entry of W is not positive "
                                f"(W_NN = {float(W[0, 0]):.3g}, W_TT = {float(W[1, 1]):.3g})", 4)
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


class PlanarIterativeSolver(IterativeSolver):
    """The planar iterative solvers' stopping rule: tolerance and the optional error check.

    ``residual_tol`` bounds :meth:`ContactProblem.residual` relative to the problem's impulse
    scale (the iterations stop at a tenth of it). The normalised natural-map error
    (:func:`lcp.contact.law.natural_map_error`, Siconos's measure) must be below
    ``error_tol`` too (None: ``residual_tol``): the iterations go on with a tolerance tightened a
    hundredfold, up to three times, and a solve that still misses it reports status -1.
    """

    def __init__(self, residual_tol: float = 1e-10, error_tol: float | None = None, compiled: bool = True):
        super().__init__(residual_tol, compiled)
        if error_tol is not None and not (np.isfinite(error_tol) and error_tol > 0):
            raise ValueError(f"error_tol must be finite and > 0, got {error_tol!r}")
        self.error_tol = error_tol

    def _solve(self, pb):
        warm = self.warm_start(pb)
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


class NsgsSolver(PlanarIterativeSolver):
    """Nonsmooth Gauss-Seidel with exact closed-form local solves (:mod:`lcp.contact.nsgs`).

    Warm-started from the previous step's impulses when the problem's ``key`` recurs.

    Parameters
    ----------
    max_sweeps : int
        Largest number of sweeps; a solve that stops short reports status -1 naming its residual.
    residual_tol, error_tol : float
        See :class:`PlanarIterativeSolver`.
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
        p, sweeps, res = sweep_blocked(op, pb.q[op.perm], pb.mu, p, tol, self.max_sweeps, self.compiled, rel_scale)
        return p, sweeps, res, f"NSGS stopped after {sweeps} sweeps"


class NewtonSolver(PlanarIterativeSolver):
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
        See :class:`PlanarIterativeSolver`.
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
                p_s, sw, res_s = sweep_blocked(op, qi, pb.mu, p, tol, n_sw, self.compiled, rel_scale)
                its += sw
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
        self.iterative.replace_warm_start(pb.key, fin.p.copy())
        self.core_pivots += 1
        return StepSolution(fin.p, 0, f"core pivot ({fin.core.size} contacts, {fin.pivots} pivots) after: {sol.message}",
                            sol.iterations + fin.pivots)


#: the planar law's solvers by name (its view of :data:`lcp.contact.solver_base.REGISTRY`)
SOLVERS = register(AutoSolver, EnumSolver, LemkeSolver, OsqpSolver, NsgsSolver, NewtonSolver)


def make_solver(name: str | OneStepSolver, law: str = "planar", **options) -> OneStepSolver:
    """A one-step solver by name and law, or an instance (returned as it is).

    Planar names: ``"auto"``, ``"enum"``, ``"lemke"``, ``"osqp"``, ``"nsgs"``, ``"newton"``;
    ``law="disk"`` (the spatial problem, :mod:`lcp.contact.spatial_solvers`): ``"auto"``,
    ``"local"``, ``"nsgs"``, ``"newton"``, ``"tresca"``, ``"faceted"``. :data:`REGISTRY` says which
    laws each name handles.

    Examples
    --------
    >>> from lcp.contact.solvers import make_solver
    >>> make_solver("lemke").name
    'lemke'
    >>> make_solver("nsgs", law="disk").law
    'disk'
    """
    if law == "disk":
        # the disk law's solvers register when their module loads (numba with it): only when asked
        from lcp.contact import spatial_solvers  # noqa: F401

    return build_solver(name, law, **options)
