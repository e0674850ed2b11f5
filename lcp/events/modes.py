"""Mode selection at the acceleration level: which contacts open, stick or slide after an event.

With the closed contacts c (gap 0, normal velocity 0), the contact accelerations are affine in the
contact forces,

    a = H_c qdd + Hdot_c v = W lam + b,    qdd = qdd_free + S H_c' lam,

with S the inverse mass matrix with the bilateral constraints eliminated (the first block of
[[A, G'], [G, 0]]^-1), qdd_free the free acceleration and W = H_c S H_c'. The Coulomb law at the
acceleration level is, per closed contact j:

- normal: 0 <= N_j  perp  a_N,j >= 0;
- if u_T,j = 0 (stick candidate): |f_j| <= mu_j N_j and f_j = -mu_j N_j sign(a_T,j) if a_T,j != 0,
  i.e. exactly the complementarity structure of :class:`~lcp.contact.problem.ContactProblem`
  with impulses replaced by forces and velocities by accelerations;
- if u_T,j != 0 (sliding): f_j = -mu_j N_j sign(u_T,j), whatever a_T,j.

The sliding contacts are folded into the same ContactProblem: their friction force is carried by
the normal force's generalized direction ``d_j = H_N,j' - mu_j sign(u_T,j) H_T,j'`` (the column of
W is ``H_c S d_j``, computed by one solve with d_j so that no W_NN - mu W_NT cancellation is left to
rounding), and their friction coefficient in the problem is 0, which pins their tangential unknown
to 0 and leaves only the normal complementarity. So the Coulomb law itself stays in one place
(``solve_branch``, ``admissible``, ``residual``); this module only changes variables.

The problem is solved by enumerating every branch (open / stick / slide+ / slide- for stick
candidates, open / closed for sliding contacts), which finds *all* solutions, or by Lemke's method
for many contacts. Solutions with the same acceleration are one motion (ties at a mode boundary,
broken by looking a short time ahead).

Contacts that do not interact at the acceleration level (separate bodies, or a chain of blocks
tied by springs: forces, not constraints) make W block-diagonal, and the enumeration is then done
per connected component of W's coupling graph (:func:`coupling_components`: contacts i and j
coupled where W has a non-zero entry in the rows of one and the columns of the other). This is
exact, not an approximation: the enumeration reads the ContactProblem (W, q, mu) only; with W
block-diagonal every branch's equations, its inequalities
(:func:`~lcp.events.indeterminate.admissibility_rows`, contact by contact) and its forces' norm
split into the components, so a whole branch has admissible forces iff each component's branch
has, and its least-norm admissible forces are the components' put together. The admissible
branches are therefore the product of the components' (7 x 4 branch solves for seven blocks
instead of 4^7). The test is W's exact zeros, not a tolerance: an exact zero decouples the problem
the enumeration reads whatever its origin, and a small coupling is never dropped. Each combination
is then solved once more on the whole problem, so the solutions (forces, accelerations, nullity,
motion_depends) and their order are the plain enumeration's. The sub-problems carry the whole
problem's impulse scale (the floor of the contacts' tolerances); where a component's rank or
consistency decision could differ from the whole problem's (a singular value between the two rank
cuts, which differ by the ratio of the blocks' scales) the whole problem is enumerated instead.
What is left to floating point is a branch whose inequality sits on its tolerance to rounding
(1e-11 of the contact's scale in ``admissible``, 1e-12 of the largest force in the least-distance
step of ``branch_forces``, there the component's largest instead of the whole problem's): the
plain enumeration's answer there is rounding's choice as well.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from itertools import product

import numpy as np

from lcp.contact.problem import OPEN, SLIDE_NEG, SLIDE_POS, STICK, ContactProblem
from lcp.contact.planar_branches import dense_branch_solution
from lcp.contact.solvers import make_solver
from lcp.events.indeterminate import RANK_RTOL, branch_forces
from lcp.numerics.lazy import issparse
from lcp.events.model import EPS, StateData
from lcp.events.options import ModeSolver

__all__ = ["AccelProblem", "ModeSolution", "PhaseBranch", "ModeSelector", "enumerate_branches", "coupling_components",
           "SPLIT_MIN_BRANCHES", "boundary_alternatives",
           "closed_variant", "redundant_solution", "null_space_moves",
           "group_motions"]


class AccelProblem:
    """The acceleration-level problem of the closed contacts ``idx``, sliding ones folded in.

    ``slide[j]`` is the sign of the sliding velocity of closed contact j (0 for a stick
    candidate). The ContactProblem is (W', b, mu') with W' = H_c S D, D = H_c' except that a
    sliding contact's normal column is d_j = H_N,j' - mu_j slide_j H_T,j', and mu'_j = 0 for
    sliding contacts. Its unknowns are p = (N, f) with f_j = 0 for sliding contacts, whose friction
    force is -mu_j slide_j N_j.
    """

    def __init__(self, data: StateData, idx, slide, mu, flush: bool = False):
        self.idx = idx = np.asarray(idx, dtype=int)
        self.slide = slide = np.asarray(slide, dtype=float)
        self.k = k = idx.size
        m = data.H.shape[0] // 2
        self.mu = mu[idx]
        rows = np.concatenate([idx, m + idx])
        Hc = data.H[rows]
        D = Hc.T.copy()
        sl = np.flatnonzero(slide != 0)
        D[:, sl] = Hc[sl].T - (self.mu[sl] * slide[sl]) * Hc[k + sl].T
        self.SD = data.solve_dirs(D)
        W = Hc @ self.SD
        if flush and sl.size:
            # A folded column is a difference; entries at the rounding level of its two terms are
            # zero (kappa = 1 exactly must not be decided by rounding).
            SH = data.solve_dirs(Hc[np.concatenate([sl, k + sl])].T)
            ref = np.abs(Hc @ SH[:, : sl.size]) + self.mu[sl] * np.abs(Hc @ SH[:, sl.size:])
            Wc = W[:, sl]
            Wc[np.abs(Wc) <= 16 * EPS * ref] = 0.0
            W[:, sl] = Wc
        self.qdd_free = data.qdd_free
        b = Hc @ self.qdd_free + data.Hdv[rows]
        mu_p = np.where(slide != 0, 0.0, self.mu)
        self.pb = ContactProblem(W, b, mu_p)

    def forces(self, p) -> tuple[np.ndarray, np.ndarray]:
        """Physical (N, f) of the closed contacts from the problem's unknowns p."""
        k = self.k
        N = p[:k]
        f = np.where(self.slide != 0, -self.mu * self.slide * N, p[k:])
        return N, f

    def qdd(self, p) -> np.ndarray:
        return self.qdd_free + self.SD @ p

    def branch_modes(self, modes, slide=None) -> list:
        """Modes for ``solve_branch``: a closed sliding contact solves with p_T = 0 (its mu' is 0).
        ``slide``: the signs of the contacts of ``modes`` when they are a subset (default: all)."""
        slide = self.slide if slide is None else slide
        return [SLIDE_POS if (s != 0 and md != OPEN) else md for md, s in zip(modes, slide)]

    def check_modes(self, modes, slide=None) -> list:
        """Modes for ``admissible``: a closed sliding contact is checked as 'stick' with mu' = 0,
        i.e. p_T = 0 and p_N >= 0, with no condition on a_T (the slide direction is the velocity's)."""
        slide = self.slide if slide is None else slide
        return [STICK if (s != 0 and md != OPEN) else md for md, s in zip(modes, slide)]


class PhaseBranch:
    """:class:`AccelProblem` and its branch solve for one smooth phase's closed contacts, slide
    signs and friction, which stay fixed over the phase: what depends on them alone is set up once,
    and a state costs only its numbers (the same operations in the same order as
    ``AccelProblem(data, idx, slide, mu)`` with ``pb.solve_branch`` on its branch modes: the same
    bits). An ODE phase evaluates this at every stage of every step; building the problem objects
    there cost the cart-pole's replays half their time. Not for indeterminate phases (redundant
    contacts), whose forces come from :func:`~lcp.events.indeterminate.branch_forces`."""

    def __init__(self, m: int, idx, slide, mu):
        idx = np.asarray(idx, dtype=int)
        self.slide = slide = np.asarray(slide, dtype=float)
        self.k = k = idx.size
        self.rows = np.concatenate([idx, m + idx])
        self.mu = mu[idx]
        self.sl = sl = np.flatnonzero(slide != 0)
        self.fold = self.mu[sl] * slide[sl]
        self.k_sl = k + sl
        self.mu_p = np.where(slide != 0, 0.0, self.mu)
        self.modes = [SLIDE_POS if s != 0 else STICK for s in slide.tolist()]
        self.f_slide = -self.mu * self.slide

    def __call__(self, data: StateData):
        """(qdd, N, f) at a state (its data); None where the branch is singular."""
        rows, sl, k = self.rows, self.sl, self.k
        Hc = data.H[rows]
        D = Hc.T.copy()
        if sl.size:
            D[:, sl] = Hc[sl].T - self.fold * Hc[self.k_sl].T
        SD = data.solve_dirs(D)
        W = Hc @ SD
        qdd_free = data.qdd_free
        b = Hc @ qdd_free + data.Hdv[rows]
        p = dense_branch_solution(W, b, self.mu_p, self.modes)
        if p is None:
            return None
        N = p[:k]
        f = np.where(self.slide != 0, self.f_slide * N, p[k:])
        return qdd_free + SD @ p, N, f


@dataclass(eq=False)
class ModeSolution:
    modes: tuple  # per closed contact: OPEN / STICK / SLIDE_POS / SLIDE_NEG (sliding: SLIDE_*)
    p: np.ndarray
    qdd: np.ndarray
    #: closed-form phase data of this solution (ClosedFormPhase.ready), per closed set
    ready: dict = field(default_factory=dict, repr=False)
    #: dimension of the set of forces giving this motion (0: unique; > 0: redundant contacts,
    #: p is the least-norm admissible choice)
    nullity: int = 0
    #: redundant contacts whose forces along the null space change the accelerations: a sliding
    #: contact's friction grows with the squeeze between opposed contacts, so the motion depends
    #: on the choice of forces (the least squeeze is taken); False when the motion is unique
    motion_depends: bool = False


def null_space_moves(acc: AccelProblem, Z) -> bool:
    """Whether forces along the null space Z of a branch change the accelerations (S D Z != 0):
    then the motion depends on the choice of forces, not only the forces on the motion."""
    if Z.shape[1] == 0:
        return False
    # frictionless redundancy: S D Z is rounding (2e-16 of S D on the slider-crank's corner
    # pairs); a sliding contact's friction makes it mu-sized (6e-5 of S D at mu = 0.01)
    return bool(np.max(np.abs(acc.SD @ Z)) > 1e-9 * max(float(np.max(np.abs(acc.SD))), 1e-300))


def redundant_solution(acc: AccelProblem, modes, bf) -> ModeSolution:
    """The ModeSolution of a branch solved by :func:`~lcp.events.indeterminate.branch_forces`,
    with whether its forces' null space moves the body (``motion_depends``)."""
    return ModeSolution(modes, bf.p, acc.qdd(bf.p), nullity=bf.nullity,
                        motion_depends=null_space_moves(acc, bf.Z))


def enumerate_branches(acc: AccelProblem, allowed=None) -> tuple[list, int]:
    """Every branch of the acceleration problem that satisfies the Coulomb law; (solutions, tried).

    The solutions come in the order of the product of the contacts' modes (the first contact
    slowest); ``allowed``, a set of mode tuples, restricts the branches to those. Contacts in
    separate components of W's coupling (:func:`coupling_components`) are enumerated component by
    component (module docstring); ``tried`` counts the branches solved."""
    pb = acc.pb
    choices = []
    for j in range(acc.k):
        if acc.slide[j] != 0:
            s = SLIDE_POS if acc.slide[j] > 0 else SLIDE_NEG
            choices.append((OPEN, s))
        else:
            choices.append((OPEN, STICK, SLIDE_POS, SLIDE_NEG))
    sols, tried = [], 0
    if allowed is None:
        candidates = product(*choices)
    else:
        # the allowed mode sets in the product's order, without walking the product: it has 4^k
        # entries, 1e12 for 20 closed contacts (a column of beads at rest), where a few are allowed
        candidates = sorted((md for md in allowed
                             if len(md) == acc.k and all(x in c for x, c in zip(md, choices))),
                            key=_product_order(choices))
    whole = len(candidates) if allowed is not None else int(np.prod([len(c) for c in choices]))
    if acc.k > 1 and whole > SPLIT_MIN_BRANCHES:
        comps = coupling_components(acc)
        if len(comps) > 1:
            found, tried = _enumerate_components(acc, choices, comps, None if allowed is None else candidates,
                                                 whole)
            if found is not None:
                return found, tried
    for modes in candidates:
        tried += 1
        branch, check = acc.branch_modes(modes), acc.check_modes(modes)
        p = pb.solve_branch(branch) if acc.k == 1 else None
        if p is not None:
            if pb.admissible(p, check):
                sols.append(ModeSolution(modes, p, acc.qdd(p)))
            continue
        # several contacts, or one singular contact: a singular branch has a set of forces
        bf = branch_forces(pb, check, branch)
        if bf is not None and bf.admissible:
            sols.append(redundant_solution(acc, modes, bf))
    return sols, tried


def _product_order(choices, J=None):
    """Sort key of mode tuples (of the contacts J, default all) in the product order of ``choices``."""
    cs = choices if J is None else [choices[j] for j in J]
    return lambda md: tuple(c.index(x) for x, c in zip(md, cs))


#: below this many branches the whole problem is enumerated without looking for components (their
#: search and sub-problems cost about as much as 16 branch solves: benchmarks/mode_components.py)
SPLIT_MIN_BRANCHES = 16


def coupling_components(acc: AccelProblem) -> list:
    """The closed contacts grouped by the coupling of the acceleration problem: contacts i and j
    are coupled when an entry of W (= H_c S D, folded columns included) in the rows of one and
    the columns of the other is not exactly 0; a list of index arrays, the connected components
    of that graph, ordered by their first contact."""
    k, W = acc.k, acc.pb.W
    Wd = W.toarray() if issparse(W) else W
    # not a tolerance: the enumeration reads W, q and mu only, so an exact zero decouples it exactly,
    # and a coupling however small is kept (NaN is not zero: kept too)
    nz = Wd != 0.0
    C = nz[:k, :k] | nz[:k, k:] | nz[k:, :k] | nz[k:, k:]
    if C.all():  # every pair coupled (one body, say): one component, without the graph search
        return [np.arange(k)]
    from scipy.sparse.csgraph import connected_components  # only where some pair is not coupled

    n, labels = connected_components(C | C.T, directed=False)
    comps = [np.flatnonzero(labels == c) for c in range(n)]
    comps.sort(key=lambda J: int(J[0]))
    return comps


def _sub_problem(pb: ContactProblem, W, J) -> ContactProblem:
    """The problem of the contacts J alone (``W``: the whole problem's W, dense), with the whole
    problem's impulse scale (the floor of every contact's tolerance in ``admissible`` and
    ``branch_forces``)."""
    rows = np.concatenate([J, pb.k + J])
    sub = ContactProblem(W[np.ix_(rows, rows)], pb.q[rows], pb.mu[J])
    sub.scale = pb.scale
    return sub


def _enumerate_components(acc: AccelProblem, choices, comps, candidates, whole: int):
    """:func:`enumerate_branches` component by component: (solutions, branches solved), with
    solutions None where the split would not save branch solves or where a sub-problem's rank or
    consistency decision might differ from the whole problem's (the caller then enumerates the
    whole problem).

    Each component's admissible branches are found on its own problem; their combinations are
    the whole problem's candidates, each solved once more on the whole problem (so that a
    returned solution is exactly the one the plain enumeration gives for that branch)."""
    k = acc.k
    if candidates is None:
        sub_cands = [list(product(*(choices[j] for j in J))) for J in comps]
    else:
        sub_cands = [sorted({tuple(md[j] for j in J) for md in candidates}, key=_product_order(choices, J))
                     for J in comps]
    # a component's sub-problem costs about two branch solves (benchmarks/mode_components.py)
    if sum(len(c) for c in sub_cands) + 2 * len(comps) >= whole:
        return None, 0
    W = acc.pb.W.toarray() if issparse(acc.pb.W) else acc.pb.W
    tried, per, infos = 0, [], []
    for J, cands in zip(comps, sub_cands):
        sub, slide = _sub_problem(acc.pb, W, J), acc.slide[J]
        ok = []
        for mc in cands:
            tried += 1
            info = {}
            bf = branch_forces(sub, acc.check_modes(mc, slide), acc.branch_modes(mc, slide), info)
            infos.append(info)
            if bf is not None and bf.admissible:
                ok.append(mc)
        per.append(ok)
    if not _decided_as_whole(infos):
        return None, tried
    allowed = None if candidates is None else {md: md for md in candidates}
    combos = []
    for pick in product(*per):
        modes = [None] * k
        for J, mc in zip(comps, pick):
            for j, x in zip(J.tolist(), mc):
                modes[j] = x
        modes = tuple(modes)
        if allowed is not None:
            modes = allowed.get(modes)  # the caller's own tuple, as the plain enumeration returns it
            if modes is None:
                continue
        combos.append(modes)
    combos.sort(key=_product_order(choices))
    sols, pb = [], acc.pb
    for modes in combos:
        tried += 1
        bf = branch_forces(pb, acc.check_modes(modes), acc.branch_modes(modes))
        if bf is not None and bf.admissible:
            sols.append(redundant_solution(acc, modes, bf))
    return sols, tried


def _decided_as_whole(infos) -> bool:
    """Whether the rank and consistency decisions of the components' branches (``info`` of
    :func:`~lcp.events.indeterminate.branch_forces`) are those of any whole branch made of them.

    The whole branch's matrix is block-diagonal (after permuting its rows and columns) with these
    blocks: its singular values are theirs, its largest ``smax`` is at most the largest of all,
    its residual and right-hand side are the largest of theirs. Its rank is cut at RANK_RTOL *
    smax >= a block's own cut, and its consistency scale is at least a block's own: a block's
    decision holds for the whole unless one of its singular values lies between its own cut and
    the largest possible one, or it was found inconsistent below the largest possible scale."""
    smax = max(i["smax"] for i in infos)
    scale = max(max(i["r_max"] for i in infos), smax * max(i["p0_max"] for i in infos), 1e-300)
    cut = RANK_RTOL * max(smax, 1e-300)
    for i in infos:
        s = i["s"]
        if np.any((s > RANK_RTOL * max(i["smax"], 1e-300)) & (s <= cut)):
            return False
        if not i["consistent"] and i["res"] <= 1e-9 * scale:
            return False
    return True


def closed_variant(acc: AccelProblem, sol: ModeSolution, rtol: float = 1e-9) -> ModeSolution | None:
    """``sol`` with its open contacts that touch with zero normal acceleration closed instead
    (sticking, or sliding the way their tangential acceleration points), if that is admissible;
    None otherwise. Lemke's method may call such contacts open (redundant contacts: a table's
    legs), and an open contact at zero gap would end its phase at once."""
    pb, k = acc.pb, acc.k
    a = pb.velocity(sol.p)
    tol = rtol * max(pb.scale, float(np.max(np.abs(sol.p))) if k else 0.0)
    modes = list(sol.modes)
    for j, md in enumerate(sol.modes):
        if md != OPEN or abs(a[j]) * pb.rho[j] > tol:
            continue
        if acc.slide[j] != 0:
            modes[j] = SLIDE_POS if acc.slide[j] > 0 else SLIDE_NEG
        else:
            aT = a[k + j] * pb.rho[k + j]
            modes[j] = SLIDE_POS if aT > tol else (SLIDE_NEG if aT < -tol else STICK)
    modes = tuple(modes)
    if modes == tuple(sol.modes):
        return None
    bf = branch_forces(pb, acc.check_modes(modes), acc.branch_modes(modes))
    if bf is None or not bf.admissible:
        return None
    return redundant_solution(acc, modes, bf)


def boundary_alternatives(acc: AccelProblem, modes, p, rtol: float = 1e-9) -> list:
    """Per closed contact, the modes that describe the same solution p when p is on a boundary
    between modes (stick force on the friction bound, zero tangential or normal acceleration,
    zero normal force)."""
    pb, k = acc.pb, acc.k
    a = pb.velocity(p)
    tol = rtol * max(pb.scale, float(np.max(np.abs(p))) if k else 0.0)
    alts = []
    for j, md in enumerate(modes):
        alt = {md}
        sliding = acc.slide[j] != 0
        closed_mode = (SLIDE_POS if acc.slide[j] > 0 else SLIDE_NEG) if sliding else STICK
        if md == OPEN:
            if abs(a[j]) * pb.rho[j] <= tol:
                alt.add(closed_mode)
        else:
            if p[j] <= tol:
                alt.add(OPEN)
            if not sliding and acc.mu[j] > 0:
                # (a frictionless contact has no friction force whatever its tangential mode: its
                # stick and slip labels are one motion, and offering them as alternatives would
                # enumerate 2^k equal branches for k frictionless contacts at rest)
                aT = a[k + j] * pb.rho[k + j]
                if md == STICK and acc.mu[j] * p[j] - abs(p[k + j]) <= tol:
                    alt.add(SLIDE_POS if p[k + j] < 0 else SLIDE_NEG)
                if md in (SLIDE_POS, SLIDE_NEG) and abs(aT) <= tol:
                    alt.add(STICK)
        alts.append(tuple(sorted(alt)))
    return alts


def group_motions(sols: list, qdd_scale: float) -> list:
    """Group solutions by motion: equal accelerations are one motion (ties at a mode boundary)."""
    if len(sols) <= 1:
        return [list(sols)] if sols else []
    groups = []
    for s in sols:
        for g in groups:
            if np.max(np.abs(g[0].qdd - s.qdd)) <= 1e-9 * qdd_scale:
                g.append(s)
                break
        else:
            groups.append([s])
    return groups


class ModeSelector:
    """Solves the acceleration-level problems of one integration and keeps their statistics.

    ``used`` collects the names of the solvers that ran; ``stats`` (a SolverStats) is updated.
    """

    def __init__(self, model, options, mu, stats, scales, t_end, gap_tol, vel_tol):
        self.model, self.o, self.mu, self.stats, self.scales = model, options, mu, stats, scales
        self.t_end, self.gap_tol, self.vel_tol = t_end, gap_tol, vel_tol
        self.m = model.m
        self.used = set()
        self.breakpoints = ()  # times where the forces jump (set by the integrator)

    def solve_modes(self, data, closed, slide, allowed=None):
        """Distinct motions of the acceleration problem: list of groups of ModeSolution.

        ``closed`` (contact indices) and ``slide`` (signs) are tuples. For a polynomial system
        the problem depends on them only: its solutions are kept per system
        (``SystemModel.mode_memo``) and the solver statistics replayed.
        """
        n_branches = 1
        for s in slide:
            n_branches *= 2 if s != 0 else 4
        use_enum = (self.o.mode_solver is ModeSolver.ENUMERATE
                    or (self.o.mode_solver is ModeSolver.AUTO and n_branches <= self.o.max_branches))
        if self.model.polynomial:
            key = (closed, slide, None if allowed is None else frozenset(allowed), use_enum)
            memo = self.model.mode_memo
            entry = memo.get(key)
            if entry is None:
                entry = memo[key] = self._solve_modes(data, closed, slide, allowed, use_enum)
        else:
            entry = self._solve_modes(data, closed, slide, allowed, use_enum)
        sols, acc, used, iterations, max_iterations, max_residual = entry
        st = self.stats
        st.solver_calls += 1
        self.used.add(used)
        st.iterations += iterations
        st.max_iterations = max(st.max_iterations, max_iterations)
        if max_residual is not None:
            st.max_residual = max(st.max_residual, max_residual)
        return group_motions(sols, self.scales["A"]), acc

    def _solve_modes(self, data, closed, slide, allowed, use_enum):
        """(solutions, problem, solver name, iterations, max iterations candidate, max residual)."""
        closed, slide = np.array(closed, dtype=int), np.array(slide, dtype=float)
        acc = AccelProblem(data, closed, slide, self.mu, flush=True)
        if use_enum or allowed is not None:
            used = "enumerate"
            sols, tried = enumerate_branches(acc, allowed)
            iterations = max_iterations = tried
        else:
            used = "lemke"
            res = make_solver("lemke").solve(acc.pb)
            iterations = max_iterations = res.iterations
            sols = []
            if res.success:
                md = acc.pb.modes(res.p)
                modes = tuple(OPEN if md[j] == OPEN else (md[j] if slide[j] == 0 else
                                                          (SLIDE_POS if slide[j] > 0 else SLIDE_NEG))
                              for j in range(acc.k))
                sols = [ModeSolution(modes, res.p, acc.qdd(res.p))]
                alts = boundary_alternatives(acc, modes, res.p)
                if any(len(a) > 1 for a in alts):
                    # Lemke returns one solution; at a mode boundary its neighbours are the same
                    # motion, and the tie must be seen to be broken (else the phase chatters)
                    sols, tried = enumerate_branches(acc, set(product(*alts)))
                    iterations += tried
                closed = closed_variant(acc, sols[0]) if sols else None
                if closed is not None and all(s.modes != closed.modes for s in sols):
                    sols.append(closed)  # the same motion with the unloaded contacts kept closed
        max_residual = None
        for s in sols:
            r = acc.pb.residual(s.p)
            max_residual = r if max_residual is None else max(max_residual, r)
            s.p.setflags(write=False)
            s.qdd.setflags(write=False)
        return sols, acc, used, iterations, max_iterations, max_residual

    def slide_signs(self, closed, ul) -> tuple:
        """Sign of the sliding velocity of each closed contact (0.0 for a stick candidate)."""
        m, vtol = self.m, self.vel_tol
        return tuple(0.0 if abs(x) <= vtol else (1.0 if x > 0 else -1.0) for x in (ul[m + j] for j in closed))

    def lookahead(self, t, q, v, closed, slide, group):
        """Break a tie (one motion, several mode sets) by the problem a short time later."""
        groups, _ = self.solve_modes(self._later(t, q, v, group[0].qdd), closed, slide,
                                     allowed={s.modes for s in group})
        if len(groups) == 1 and len(groups[0]) >= 1:
            group = groups[0]
        # Still a tie: prefer the contacts closed. A contact at rest with a zero normal force and
        # zero normal acceleration may be called open as well, but an open contact at zero gap
        # would end its phase at once (a table's legs, a box's corners).
        return min(group, key=lambda s: sum(md == OPEN for md in s.modes))

    def _later(self, t, q, v, qdd):
        """The state data a short time after t (1e-6 of the horizon, and not past the next jump of
        the forces), the state advanced with the accelerations qdd: where :meth:`lookahead` and
        :meth:`leaving` read the problem that follows a decision."""
        dt = 1e-6 * self.t_end
        later = [b for b in self.breakpoints if b > t]
        if later:  # not past a jump of the forces
            dt = min(dt, 0.5 * (later[0] - t))
        if self.model.polynomial:
            return self.model.data(t + dt, q, v)  # the same at every state
        q1 = self.model.advance(t, q, dt * v + 0.5 * dt * dt * qdd)  # q + T dx (kinematics)
        return self.model.data(t + dt, q1, v + dt * qdd)

    def leaving(self, t, q, v, closed, slide, sol, acc):
        """``sol``, or its variant with contacts opened that it keeps closed under a normal force at
        the rounding level of the event tests (``tol`` times the force scale) when the problem a
        short time later (as :meth:`lookahead`, every mode allowed) has one motion, which opens
        those contacts and changes nothing else. A lift-off located where the force is +1.8e-15
        (the root of g - s''(t) on a table that decelerates, summed from terms of 9.81) was
        otherwise decided to stick, and the phase after it ended 8e-12 s later in a second lift-off
        (12 of 75 tables swept in amplitude and frequency)."""
        k = len(closed)
        if not k or sol.nullity:
            return sol
        ftol = self.o.tol * self.scales.get("F", 0.0)
        low = {jj for jj, md in enumerate(sol.modes) if md != OPEN and sol.p[jj] <= ftol}
        if not low:
            return sol
        groups, _ = self.solve_modes(self._later(t, q, v, sol.qdd), closed, slide)
        if len(groups) != 1:
            return sol
        modes = min(groups[0], key=lambda s: sum(md == OPEN for md in s.modes)).modes
        opened = {jj for jj in range(k) if modes[jj] != sol.modes[jj]}
        if not opened or any(jj not in low or modes[jj] != OPEN for jj in opened):
            return sol
        p = acc.pb.solve_branch(acc.branch_modes(modes))
        if p is None or not np.all(np.isfinite(p)):
            return sol
        return ModeSolution(tuple(modes), p, acc.qdd(p))

    def memo_decision(self, q, v):
        """The decision of a polynomial system in its common case: no contact approaching and
        an acceleration problem already solved (``SystemModel.mode_memo``) with a unique solution.
        The same steps as classify, slide_signs and solve_modes, inlined; None otherwise
        (nothing done: decide then takes its general path)."""
        model, m = self.model, self.m
        gtol, vtol = self.gap_tol, self.vel_tol
        gap = (model.gap0 + model.HN @ q).tolist()  # model.gaps(q)
        ul = (model.H @ v).tolist()
        closed = []
        for j in range(m):
            if gap[j] <= gtol:
                if abs(ul[j]) <= vtol:
                    closed.append(j)
                elif ul[j] < -vtol:
                    return None  # an impact first
        closed = tuple(closed)
        if not closed:
            return q, v, closed, None, None
        slide = tuple([0.0 if abs(x) <= vtol else (1.0 if x > 0 else -1.0) for x in [ul[m + j] for j in closed]])
        n_branches = 1
        for s in slide:
            n_branches *= 2 if s != 0 else 4
        o = self.o
        use_enum = (o.mode_solver is ModeSolver.ENUMERATE
                    or (o.mode_solver is ModeSolver.AUTO and n_branches <= o.max_branches))
        entry = model.mode_memo.get((closed, slide, None, use_enum))
        if entry is None or len(entry[0]) != 1:
            return None
        sols, acc, used, iterations, max_iterations, max_residual = entry
        st = self.stats  # as solve_modes
        st.solver_calls += 1
        self.used.add(used)
        st.iterations += iterations
        st.max_iterations = max(st.max_iterations, max_iterations)
        st.max_residual = max(st.max_residual, max_residual)
        return q, v, closed, sols[0], acc

