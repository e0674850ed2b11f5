"""One-step solvers of the spatial (Coulomb disk) contact problem, by name.

Each solver takes a :class:`~lcp.contact.spatial_problem.ConeContactProblem` and returns a
:class:`lcp.contact.solver_base.StepSolution` (impulses in the blocked order); the solvers are
registered, law ``"disk"``, in :data:`lcp.contact.solver_base.REGISTRY` (``make_solver(name,
law="disk")``; :data:`CONE_SOLVERS` and :func:`make_cone_solver` are this law's view). Imports
``lcp.contact`` modules below it (never :mod:`lcp.contact.solvers`) and :mod:`lcp.numerics`. The
base class :class:`ConeSolver` owns the bookkeeping of :class:`lcp.contact.solver_base.OneStepSolver`: the Coulomb residual
(:meth:`ConeContactProblem.residual`) is recomputed independently of the solver and an exact
solver's answer above ``residual_tol`` (relative to the problem's impulse scale and the largest
impulse) is rejected with status -2.

- ``"local"``: one contact, the exact local solve (:func:`lcp.contact.spatial_problem.local_disk`), then the
  branch refinement.
- ``"nsgs"``: nonsmooth Gauss-Seidel with exact local solves (:mod:`lcp.contact.spatial_nsgs`), warm-started
  on ``problem.key``, finished by a branch refinement (:meth:`ConeContactProblem.refine_modes`).

Polished solvers return a :class:`ConeStepSolution` whose ``modes`` are those of the refined
impulse, so a time stepper needs neither a second refinement nor a second classification. The
others:

- ``"newton"``: NSGS sweeps, then semismooth Newton on the Alart-Curnier function with its exact
  generalized Jacobian (sparse LU when W is sparse), Armijo line search, to rounding level.
- ``"tresca"``: the Tresca fixed point on the friction bound s = mu p_N: for fixed s the convex
  second-order-cone program min 1/2 p'W p + q'p, p_N >= 0, |p_T,j| <= s_j is solved by Clarabel
  (set up once per operator, only the bound vector updated), the bound updated with Anderson
  acceleration, and the fixed point polished by Newton. The spatial analogue of the planar
  ``"osqp"`` path.
- ``"faceted"``: an APPROXIMATION, the disk replaced by an inscribed polygon of ``n_facets``
  directions, solved exactly as an LCP by Lemke's method. Its status is 1 ("approximate"), its
  residual is the true disk law's, and the residual check does not apply; ``"auto"`` never uses it.
- ``"auto"``: ``"local"`` for one contact, ``"nsgs"`` up to 40 contacts, ``"newton"`` above (the
  fastest exact solvers in ``benchmarks/spatial_one_step.py``; measured crossover in
  :class:`ConeAutoSolver`), with ``"newton"`` and then
  ``"tresca"`` (when Clarabel is installed) as fallbacks.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lcp.numerics.lazy import issparse
from lcp.numerics.lazy import sparse as sp
from lcp.contact.spatial_problem import ConeContactProblem
from lcp.contact.kernels import local_disk3, local_planar
from lcp.contact.newton import armijo
from lcp.contact.solver_base import IterativeSolver, OneStepSolver, StepSolution, build_solver, register, sweep_blocked

__all__ = [
    "CONE_SOLVERS",
    "ConeAutoSolver",
    "ConeNewtonSolver",
    "ConeNsgsSolver",
    "ConeSolver",
    "ConeStepSolution",
    "FacetedSolver",
    "LocalSolver",
    "TrescaSolver",
    "cone_newton",
    "make_cone_solver",
]


@dataclass
class ConeStepSolution(StepSolution):
    """A :class:`lcp.contact.solvers.StepSolution` with the contact modes of a branch-refined impulse.

    ``modes`` (int8 codes of :class:`lcp.contact.problem.ContactMode`) is set when the solver
    finished with :meth:`ConeContactProblem.refine_modes`: p is then refined on its branch and a
    caller needs neither a second refinement nor a second mode classification. None otherwise.
    """

    modes: np.ndarray | None = None


class ConeSolver(OneStepSolver):
    """Base class of the disk-law solvers: :class:`lcp.contact.solver_base.OneStepSolver` for a
    :class:`ConeContactProblem` (p in the blocked order).

    The Coulomb residual (:meth:`ConeContactProblem.residual`) and the natural-map error are
    recomputed from (W, q, mu, p) for every answer, failures included (NaN for a p that is not
    finite or not of the problem's size).
    """

    name = "cone-base"
    law = "disk"
    #: solves the disk law (the time stepper picks the fallback among the spatial solvers by this)
    spatial = True

    def _record_checks(self, problem, sol):
        p = sol.p
        if p.shape == (problem.n,) and math.isfinite(p.sum()):  # NaN/inf propagate into the sum
            sol.residual = problem.residual(p)
            sol.error = problem.error(p)
        else:
            sol.residual = sol.error = float("nan")


# ----------------------------------------------------------------- local
class LocalSolver(ConeSolver):
    """One contact (disk or planar): the exact local solve (:func:`lcp.contact.spatial_problem.local_disk`),
    then, with ``polish``, the branch refinement (:meth:`ConeContactProblem.refine_modes`: a stuck
    contact's velocity to rounding level of W p + q)."""

    name = "local"

    def __init__(self, residual_tol: float = 1e-10, polish: bool = True):
        super().__init__(residual_tol)
        self.polish = bool(polish)

    def applicable(self, pb):
        return pb.k == 1

    def _solve(self, pb):
        # the problem is validated: the kernels directly (local_disk checks its arguments again)
        W = pb._dense_W()
        mu = float(pb.mu[0])
        if pb.n == 3:
            qN, qT0, qT1 = pb.q.tolist()
            pN, pT0, pT1, mode, _ = local_disk3(W, qN, qT0, qT1, mu, 0.0, 0.0)
            p = np.array([pN, pT0, pT1])
        else:
            qN, qT = pb.q.tolist()
            (W00, W01), (W10, W11) = W.tolist()
            pN, pT, mode = local_planar(W00, W01, W10, W11, qN, qT, mu)
            p = np.array([float(pN), float(pT)])
        if mode < 0:
            return ConeStepSolution(np.full(pb.n, np.nan), -1, "no admissible case (open, stick, slide) for this "
                                    "contact: a Painleve-type local problem", 1)
        if not self.polish:
            return ConeStepSolution(p, 0, "solved", 1)
        p, md = pb.refine_modes(p)
        return ConeStepSolution(p, 0, "solved", 1, modes=md)


# ----------------------------------------------------------------- NSGS
class ConeIterativeSolver(IterativeSolver, ConeSolver):
    """The disk law's iterative solvers: warm start, tolerance, final branch refinement."""

    def __init__(self, residual_tol: float = 1e-10, compiled: bool = True, polish: bool = True):
        super().__init__(residual_tol, compiled)
        self.polish = bool(polish)

    def _finish(self, pb, p, its, res, tol, msg, warm=None):
        md = None
        if self.polish and res <= tol:
            p, md = pb.refine_modes(p)
        if warm is not None and np.all(np.isfinite(p)):
            warm.store(p)
        if not res <= tol:
            return ConeStepSolution(p, -1, f"{self.name}: {msg}; residual {res:.3g} > tolerance {tol:.3g}", its)
        return ConeStepSolution(p, 0, "solved", its, modes=md)


class ConeNsgsSolver(ConeIterativeSolver):
    """Nonsmooth Gauss-Seidel with exact local disk/planar solves (:mod:`lcp.contact.spatial_nsgs`).

    Parameters
    ----------
    residual_tol : float
        Accepted residual relative to the impulse scale (the sweeps stop at a tenth of it).
    max_sweeps : int
    compiled : bool
        numba sweeps when installed (False: the plain-Python sweep, for tests).
    polish : bool
        Finish with :meth:`ConeContactProblem.refine` (one branch Newton correction).
    """

    name = "nsgs"

    def __init__(self, residual_tol: float = 1e-10, max_sweeps: int = 10000, compiled: bool = True,
                 polish: bool = True):
        super().__init__(residual_tol, compiled, polish)
        if int(max_sweeps) < 1:
            raise ValueError(f"max_sweeps must be >= 1, got {max_sweeps!r}")
        self.max_sweeps = int(max_sweeps)

    def _solve(self, pb):
        warm = self.warm_start(pb)
        tol = 0.1 * self.residual_tol * pb.scale
        p, n, res = sweep_blocked(warm.op, pb.q[warm.op.perm], pb.mu, warm.p, tol, self.max_sweeps, self.compiled)
        return self._finish(pb, p, n, res, tol, f"NSGS stopped after {n} sweeps", warm)


# ----------------------------------------------------------------- Newton
def cone_newton(pb: ConeContactProblem, p0, tol: float, max_iter: int = 50, max_damped: int = 8):
    """Semismooth Newton on the Alart-Curnier function of ``pb`` from p0 until residual <= tol.

    Each iteration solves J d = -Phi with the exact generalized Jacobian of the piece
    (:meth:`ConeContactProblem.newton_system`, compiled; dense LU or SuperLU), and takes the largest step
    2^-i that decreases ||Phi||^2 (Armijo).

    Returns
    -------
    p, iterations, residual (:meth:`ConeContactProblem.residual`), message
    """
    p = np.array(p0, dtype=float)
    res = pb.residual(p)
    if res <= tol:
        return p, 0, res, "converged"
    phi, J = pb.newton_system(p)
    merit = float(phi @ phi)
    damped = 0
    shifted = False  # redundant contacts stay redundant: once singular, shift at once (one LU, not two)
    for it in range(1, max_iter + 1):
        if J is None:
            phi, J = pb.newton_system(p)
        d = None if shifted else pb.solve_linear(J, -phi)
        if d is None:
            # a singular piece (redundant contacts): a tiny Levenberg shift keeps a direction
            shifted = True
            shift = 1e-12 * max(1.0, float(abs(J).max()))
            J = J + shift * (sp.identity(pb.n, format="csc") if issparse(J) else np.eye(pb.n))
            d = pb.solve_linear(J, -phi)
            if d is None:
                return p, it, res, f"singular Newton matrix at iteration {it}"
        # the line search needs Phi only
        step = armijo(lambda x: pb.newton_system(x, jacobian=False), p, d, merit)
        if step is None:
            return p, it, res, f"line search failed at iteration {it} (merit {merit:.3g})"
        t, p, merit, (phi, *_) = step
        J = None
        res = pb.residual(p)
        if res <= tol:
            return p, it, res, "converged"
        damped = damped + 1 if t < 1.0 else 0
        if damped >= max_damped:
            return p, it, res, f"{damped} damped steps in a row at iteration {it} (residual {res:.3g})"
    return p, max_iter, res, f"no convergence in {max_iter} Newton iterations (residual {res:.3g})"


class ConeNewtonSolver(ConeIterativeSolver):
    """NSGS sweeps, then semismooth Newton (:func:`cone_newton`) to rounding level.

    Rounds of ``sweeps`` NSGS sweeps (doubling each round) and up to ``newton_iter`` Newton
    iterations alternate, each round starting from the better iterate, until the residual is below
    tolerance or ``max_rounds`` rounds are spent (status -1 then, naming the residual reached).

    Parameters
    ----------
    residual_tol : float
    sweeps : int
        NSGS sweeps before the first Newton phase (0: Newton alone from the warm start or zero).
    newton_iter, max_rounds : int
    compiled, polish : bool
        See :class:`ConeNsgsSolver`.
    """

    name = "newton"

    def __init__(self, residual_tol: float = 1e-10, sweeps: int = 10, newton_iter: int = 30,
                 max_rounds: int = 8, compiled: bool = True, polish: bool = True):
        super().__init__(residual_tol, compiled, polish)
        if int(sweeps) < 0 or int(newton_iter) < 1 or int(max_rounds) < 1:
            raise ValueError("sweeps must be >= 0, newton_iter and max_rounds >= 1")
        self.sweeps, self.newton_iter, self.max_rounds = int(sweeps), int(newton_iter), int(max_rounds)

    def _solve(self, pb):
        warm = self.warm_start(pb)
        # Newton converges to rounding once on the right piece: aim at the round-off floor
        tol = 0.1 * self.residual_tol * pb.scale
        p = np.zeros(pb.n) if warm.p is None else warm.p.copy()
        res = pb.residual(p)
        its, msg = 0, "no rounds"
        for rnd in range(self.max_rounds):
            if res <= tol:
                break
            if self.sweeps:
                p_s, n, res_s = sweep_blocked(warm.op, pb.q[warm.op.perm], pb.mu, p, tol,
                                              self.sweeps * 2 ** min(rnd, 10), self.compiled)
                its += n
                if res_s <= res:
                    p, res = p_s, res_s
                if res <= tol:
                    break
            p_n, it, res_n, msg = cone_newton(pb, p, tol, self.newton_iter)
            its += it
            if res_n <= res:
                p, res = p_n, res_n
        return self._finish(pb, p, its, res, tol, f"NSGS + Newton stopped after {its} iterations ({msg})", warm)


# ----------------------------------------------------------------- Tresca + Clarabel
def _import_clarabel():
    try:
        import clarabel
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError("the 'tresca' cone solver needs Clarabel: pip install 'lcp-lem[conic]'") from exc
    return clarabel


class TrescaSolver(ConeSolver):
    """Tresca fixed point on the friction bound, each convex SOCP solved by Clarabel, then Newton.

    For a bound s (one per contact) the program

        min 1/2 p'W p + q'p   s.t.  p_N >= 0,  |p_T,j| <= s_j

    has Tresca's law with bound s as its KKT conditions; Coulomb's law is the fixed point
    s = mu p_N(s). The map is contractive with a rate kappa that approaches 1 near the Painleve
    limit, so plain iteration crawls: the iterates are accelerated by Anderson mixing (depth
    ``anderson``), and once the bound moves by less than ``fixed_point_tol`` (relative) the
    solution is polished by semismooth Newton (:func:`cone_newton`) to rounding level.

    The Clarabel workspace (P = triu(W), the cone rows) is set up once per operator (cached on
    ``problem.key``; unkeyed problems reuse it when W is unchanged) and only the bound vector b
    is updated; every solve's status is checked.

    Parameters
    ----------
    tol : float
        Clarabel's gap and feasibility tolerances (passed explicitly).
    max_iter : int
        Largest number of fixed-point iterations (SOCP solves).
    fixed_point_tol : float
        Stop the fixed point when max |s_new - s| <= fixed_point_tol * impulse scale.
    anderson : int
        Anderson depth (0: plain fixed point).
    residual_tol : float
        See :class:`ConeSolver`.
    """

    name = "tresca"

    def __init__(self, tol: float = 1e-10, max_iter: int = 100, fixed_point_tol: float = 1e-7,
                 anderson: int = 5, residual_tol: float = 1e-10):
        super().__init__(residual_tol)
        for nm, val in (("tol", tol), ("fixed_point_tol", fixed_point_tol)):
            if not (np.isfinite(val) and val > 0):
                raise ValueError(f"{nm} must be finite and > 0, got {val!r}")
        if int(max_iter) < 1 or int(anderson) < 0:
            raise ValueError("max_iter must be >= 1 and anderson >= 0")
        self.tol, self.max_iter = float(tol), int(max_iter)
        self.fixed_point_tol, self.anderson = float(fixed_point_tol), int(anderson)
        self._cache: dict = {}
        self._last_s: dict = {}

    def _settings(self, clarabel):
        s = clarabel.DefaultSettings()
        s.verbose = False
        s.presolve_enable = False  # keeps every row, so that b can be updated in place
        s.tol_gap_abs = s.tol_gap_rel = s.tol_feas = self.tol
        s.tol_ktratio = 1e-8
        s.max_iter = 200
        return s

    def _structure(self, pb):
        """A, the cones and the map s -> b of ``pb``'s layout (depends on dims only)."""
        clarabel = _import_clarabel()
        k, n = pb.k, pb.n
        planar = np.flatnonzero(pb.dims == 1)
        disk = np.flatnonzero(pb.dims == 2)
        rows, cols, vals = [np.arange(k)], [np.arange(k)], [-np.ones(k)]  # -p_N + slack = 0
        m = k
        tp = pb.R[planar, 1]
        # planar: s - p_T >= 0 and s + p_T >= 0
        rows += [m + np.arange(planar.size), m + planar.size + np.arange(planar.size)]
        cols += [tp, tp]
        vals += [np.ones(planar.size), -np.ones(planar.size)]
        b_index = [m + np.arange(planar.size), m + planar.size + np.arange(planar.size)]
        b_contact = [planar, planar]
        m += 2 * planar.size
        # disk: (s_j, p_T,j) in the second-order cone: slack = (s_j, p_T0, p_T1) = b - A p
        base = m + 3 * np.arange(disk.size)
        rows += [base + 1, base + 2]
        cols += [pb.R[disk, 1], pb.R[disk, 2]]
        vals += [-np.ones(disk.size), -np.ones(disk.size)]
        b_index.append(base)
        b_contact.append(disk)
        m += 3 * disk.size
        A = sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(m, n))
        cones = [clarabel.NonnegativeConeT(k + 2 * planar.size)] + [clarabel.SecondOrderConeT(3)] * disk.size
        return A, cones, np.concatenate(b_index), np.concatenate(b_contact), m

    def _workspace(self, pb):
        clarabel = _import_clarabel()
        key = pb.key if pb.key is not None else ("unkeyed", pb.n, pb.dims.tobytes())
        hit = self._cache.get(key)
        P = sp.triu(sp.csc_matrix(pb.W), format="csc")
        if hit is not None:
            if pb.key is not None:
                return hit
            if (hit[5].shape == P.data.shape and np.array_equal(hit[5], P.data)
                    and np.array_equal(hit[6], P.indices)):
                return hit
        A, cones, b_index, b_contact, m = self._structure(pb)
        b = np.zeros(m)
        solver = clarabel.DefaultSolver(P, pb.q, A, b, cones, self._settings(clarabel))
        entry = (solver, b_index, b_contact, m, cones, P.data.copy(), P.indices.copy())
        if len(self._cache) > 16:
            self._cache.clear()
        self._cache[key] = entry
        return entry

    def _qp(self, entry, q, s):
        clarabel = _import_clarabel()
        solver, b_index, b_contact, m = entry[:4]
        b = np.zeros(m)
        b[b_index] = s[b_contact]
        solver.update(q=q, b=b)
        res = solver.solve()
        # AlmostSolved (reduced tolerances) is enough to name the next bound: Newton polishes anyway
        ok = res.status in (clarabel.SolverStatus.Solved, clarabel.SolverStatus.AlmostSolved)
        return ok, str(res.status), np.asarray(res.x, dtype=float)

    def _solve(self, pb):
        k = pb.k
        entry = self._workspace(pb)
        s = self._last_s.get(pb.key) if pb.key is not None else None
        if s is None or s.shape != (k,):
            s = np.zeros(k)
        # Anderson mixing on g(s) = T(s) - s, T(s) = mu max(p_N(s), 0)
        S_hist, G_hist = [], []
        tol_s = self.fixed_point_tol * pb.scale * max(1.0, float(np.max(pb.mu)))
        x = None
        for it in range(1, self.max_iter + 1):
            ok, status, x = self._qp(entry, pb.q, s)
            if not ok:
                return StepSolution(np.full(pb.n, np.nan), -1,
                                    f"Clarabel status '{status}' at fixed-point iteration {it}", it, it)
            Ts = pb.mu * np.maximum(x[:k], 0.0)
            g = Ts - s
            if float(np.max(np.abs(g))) <= tol_s:
                break
            S_hist.append(s.copy())
            G_hist.append(g.copy())
            if self.anderson and len(S_hist) >= 2:
                S_hist, G_hist = S_hist[-(self.anderson + 1):], G_hist[-(self.anderson + 1):]
                dG = np.diff(np.array(G_hist), axis=0).T
                dS = np.diff(np.array(S_hist), axis=0).T
                gamma = np.linalg.lstsq(dG, g, rcond=None)[0]
                s_new = s + g - (dS + dG) @ gamma
            else:
                s_new = Ts
            s = np.maximum(s_new, 0.0) if np.all(np.isfinite(s_new)) else Ts
        else:
            it = self.max_iter
        qp_solves = it
        p, n_it, res, msg = cone_newton(pb, x, 0.1 * self.residual_tol * pb.scale, 30)
        p, md = pb.refine_modes(p)
        res = pb.residual(p)
        if pb.key is not None:
            self._last_s[pb.key] = pb.mu * np.maximum(p[:k], 0.0)
        if res > 0.1 * self.residual_tol * max(pb.scale, float(np.max(np.abs(p)))):
            return ConeStepSolution(p, -1, f"Tresca fixed point + Newton polish stopped ({it} SOCP solves; "
                                    f"Newton: {msg})", it + n_it, qp_solves)
        return ConeStepSolution(p, 0, "solved", it + n_it, qp_solves, modes=md)


# ----------------------------------------------------------------- faceted (approximation)
class FacetedSolver(ConeSolver):
    """APPROXIMATION: each disk replaced by an inscribed polygon of ``n_facets`` directions and
    the resulting LCP (Stewart-Trinkle form) solved exactly by Lemke's method.

    p_T,j = sum_i beta_i t_i with t_i = (cos 2 pi i/n, sin 2 pi i/n), beta >= 0, and per contact
    0 <= beta_i perp t_i'u_T + lambda >= 0, 0 <= lambda perp mu p_N - sum beta >= 0. Planar
    contacts keep their two directions (+-t: exact). The answer is the polygon law's, not the
    disk's: status 1, the message says "approximate", and ``residual`` is the disk law's
    (it falls like 1 - cos(pi / n_facets) while sliding).

    Parameters
    ----------
    n_facets : int
        Directions per disk (>= 3).
    max_pivots : int, optional
        Lemke's pivot limit.
    """

    name = "faceted"
    exact = False

    def __init__(self, n_facets: int = 8, max_pivots: int | None = None, residual_tol: float = 1e-10):
        super().__init__(residual_tol)
        if int(n_facets) != n_facets or int(n_facets) < 3:
            raise ValueError(f"n_facets must be an integer >= 3, got {n_facets!r}")
        self.n_facets, self.max_pivots = int(n_facets), max_pivots

    def lcp(self, pb):
        """(M, b, D): the LCP of the polygon law, z = (p_N, beta, lambda), p = D (p_N, beta)."""
        k, n = pb.k, pb.n
        nf = self.n_facets
        ang = 2 * np.pi * np.arange(nf) / nf
        counts = np.where(pb.dims == 2, nf, 2)
        nb = int(counts.sum())
        D = np.zeros((n, k + nb))
        D[np.arange(k), np.arange(k)] = 1.0
        E = np.zeros((nb, k))
        col = k
        for j in range(k):
            c = int(counts[j])
            if pb.dims[j] == 1:
                D[pb.R[j, 1], col:col + 2] = (1.0, -1.0)
            else:
                D[pb.R[j, 1], col:col + c] = np.cos(ang)
                D[pb.R[j, 2], col:col + c] = np.sin(ang)
            E[col - k:col - k + c, j] = 1.0
            col += c
        W = pb.W.toarray() if issparse(pb.W) else pb.W
        m = k + nb + k
        M = np.zeros((m, m))
        M[:k + nb, :k + nb] = D.T @ W @ D
        M[k:k + nb, k + nb:] = E
        M[k + nb:, :k] = np.diag(pb.mu)
        M[k + nb:, k:k + nb] = -E.T
        b = np.concatenate([D.T @ pb.q, np.zeros(k)])
        return M, b, D

    def _solve(self, pb):
        from lcp.contact.lemke import lemke

        M, b, D = self.lcp(pb)
        res = lemke(M, b, max_pivots=self.max_pivots)
        nb = D.shape[1]
        if not res.success:
            return StepSolution(np.full(pb.n, np.nan), -1, f"faceted (approximate) Lemke: {res.message}", res.pivots)
        p = D @ res.z[:nb]
        return StepSolution(p, 1, f"approximate: disk replaced by a {self.n_facets}-gon (faceted LCP, Lemke)",
                            res.pivots)


# ----------------------------------------------------------------- auto
class ConeAutoSolver(ConeSolver):
    """The fastest exact solver for the problem at hand (never the faceted approximation): the
    local solve for one contact; NSGS (at most ``NSGS_SWEEPS`` sweeps) up to ``NSGS_MAX_CONTACTS``
    contacts; NSGS with a Newton finish (``"newton"``) above. A failure is retried by ``"newton"``
    and then by ``"tresca"`` when Clarabel is installed.

    The crossover is measured on the box-row scene of ``benchmarks/spatial_one_step.py`` (cold
    solves, compiled kernels, load about 5 on 2 cores), median ms NSGS / Newton: 5 contacts
    0.04 / 0.08, 10: 0.49 / 0.84, 20: 1.4 / 6.4, 30: 12 / 16, 50: 35 / 21, 70: 42 / 31,
    100: 186 / 34. NSGS wins up to 30 contacts, Newton from 50 (NSGS needs 1000-4300 sweeps
    there): the switch is at 40."""

    name = "auto"
    #: largest number of contacts solved by NSGS first
    NSGS_MAX_CONTACTS = 40
    NSGS_SWEEPS = 1000

    def __init__(self, residual_tol: float = 1e-10):
        super().__init__(residual_tol)
        self.local = LocalSolver(residual_tol)
        self.nsgs = ConeNsgsSolver(residual_tol, max_sweeps=self.NSGS_SWEEPS)
        self.newton = ConeNewtonSolver(residual_tol)
        self._tresca = None
        self.fallbacks = 0

    def solve(self, problem: ConeContactProblem) -> StepSolution:
        # the chosen solver (and every fallback) checks its own answer with the same tolerance
        self.check_law(problem)
        if problem.k == 0:
            return StepSolution(np.zeros(0))
        return self._solve(problem)

    def _solve(self, pb):
        first = self.local if pb.k == 1 else (self.nsgs if pb.k <= self.NSGS_MAX_CONTACTS else self.newton)
        sol = first.solve(pb)
        if sol.success:
            return sol
        backups = [self.newton] if first is not self.newton else []
        try:
            _import_clarabel()
            if self._tresca is None:
                self._tresca = TrescaSolver(residual_tol=self.residual_tol)
            backups.append(self._tresca)
        except ImportError:  # pragma: no cover - depends on the environment
            pass
        for backup in backups:
            sol2 = backup.solve(pb)
            if sol2.success:
                self.fallbacks += 1
                sol2.message = f"fallback to {backup.name} after: {sol.message}"
                return sol2
        return sol


#: the disk law's solvers by name (its view of :data:`lcp.contact.solver_base.REGISTRY`)
CONE_SOLVERS = register(ConeAutoSolver, LocalSolver, ConeNsgsSolver, ConeNewtonSolver, TrescaSolver, FacetedSolver)


def make_cone_solver(name: str | ConeSolver, **options) -> ConeSolver:
    """A spatial one-step solver by name (``"auto"``, ``"local"``, ``"nsgs"``, ``"newton"``,
    ``"tresca"``, ``"faceted"``) or instance: :func:`lcp.contact.solvers.make_solver` with
    ``law="disk"``.

    Examples
    --------
    >>> import numpy as np
    >>> from lcp.contact.spatial_problem import ConeContactProblem
    >>> from lcp.contact.spatial_solvers import make_cone_solver
    >>> pb = ConeContactProblem(np.eye(3), np.array([-1.0, 0.0, 2.0]), [0.5], [2])
    >>> sol = make_cone_solver("auto").solve(pb); sol.p, sol.status
    (array([ 1. ,  0. , -0.5]), 0)
    """
    return build_solver(name, "disk", **options)
