"""Complementarity handling: the Scholtes relaxation homotopy, the polishing solve, and the checks.

The pairs a perp w of the transcription (:mod:`lcp.ocp.transcription`) are relaxed as in Scholtes
(2001): a >= 0, w >= 0, a w <= sigma. The relaxation parameter goes down geometrically; each NLP
(one IPOPT instance, built once, sigma a parameter) is warm-started from the previous solution,
until the Coulomb residual, recomputed independently from the optimizer's states with
:meth:`~lcp.contact.problem.ContactProblem.residual`, is below the requested tolerance. A final
polishing solve fixes, pair by pair, the smaller member at zero (the active set the homotopy has
identified), which makes the complementarity exact; it is kept only if IPOPT converges and the
residual does not grow. Where IPOPT stops there at its acceptable level with a dynamics residual
above its tolerance, the point is projected onto its constraints (:func:`projected`), as is such a
fixed-phase solution that a solve returns.

Under the velocity law every contact is treated as active at every step. Moreau-Jean also skips a
contact whose predicted gap is positive; ``inactive_conflicts`` counts the steps where that would
change the step (a positive predicted gap with a nonzero normal impulse). The gap law
(:mod:`lcp.ocp.transcription`) lets contacts open and close. On free steps IPOPT sees a small
penalty on uneven steps (:func:`step_penalty`), never in the cost reported.

References
----------
S. Scholtes, Convergence properties of a regularization scheme for mathematical programs with
complementarity constraints, SIAM J. Optim. 11 (2001) 918-936.
"""
from __future__ import annotations

import time
import weakref
from dataclasses import replace

import casadi as ca
import numpy as np
from scipy import sparse
from scipy.sparse.linalg import spsolve

from lcp.contact.problem import OPEN, ContactProblem
from lcp.ocp.options import OCP_STATUS_MESSAGES, HomotopyOptions
from lcp.ocp.pairs import fix_pairs, pair_residual
from lcp.ocp.results import HomotopyStage
from lcp.ocp.transcription import IMPULSE_PAIRS, PAIRS

__all__ = ["diagnose", "diagnose_contacts", "feasible", "fixed_mode_bounds", "fixed_mode_bounds_contacts",
           "ipopt_solver", "projected", "run_fixed_modes", "run_homotopy", "run_phases", "step_penalty"]

#: weight of the free steps' regularization (:func:`step_penalty`), in units of T
STEP_REGULARIZATION = 1e-6


def step_penalty(tr, cache: dict):
    """The term added to the objective that IPOPT sees on free steps, as a Function of the NLP
    variables (None on fixed steps), built once per transcription (kept in ``cache``):
    ``STEP_REGULARIZATION T mean_k (h_k / (T / N) - 1)^2`` (T the problem's T, or the variable T
    when it is free).

    Why: on free steps the optimum is not unique. Within a phase in which the theta step is exact
    (constant forces, or affine ones under the affine hold), any split of the phase into its steps
    gives the same cost, and IPOPT stalls on that flat valley: it stops at its acceptable level
    short of its tolerance, or a homotopy stage ends infeasible. The term picks the most even split.
    It is used by every homotopy stage on free steps (not the relaxed tail after a fixed-phase
    solve, which starts from a solution) and by the repeat of a fixed-phase solve that IPOPT did not
    converge fully (:func:`run_fixed_modes`); a fixed-phase solve that converges keeps the steps at
    their length bounds that the merges of squeezed phases look for. Measured at N = 40 with every
    default (gap law), the gap to the closed-form optimum without and with it: Jean-Pratt minimum
    time at R = 0.3, 1.4e-4 and 5.8e-9; at R = 0.7, 4.8e-7 and 4.2e-8; the move-and-hold on
    [0.42, 0.6] s, T = 1.15 s, 1.0e-5 and 2.6e-12 (replay misses 1.0e-8 and 2.3e-12, the hold kept
    to 3.3e-8 and 1.7e-13); minimum time with the constant hold at R = 0.2, 1.2e-5 and 7.7e-10 (the penalty
    against T / N of the initial guess, not of the variable T, left R = 0.3 at 6.3e-5).
    The cost reported is the problem's own (the term subtracted). The term can hold a solution
    above the problem's optimum by at most its own value there, below 3e-6 T with steps within the
    default ``step_bounds``.
    """
    if "step_penalty" not in cache:
        pb, fn = tr.pb, None
        if pb.steps == "free" and "h" in tr.ix:
            x = tr.nlp["x"]
            h = x[tr.ix["h"].ravel().tolist()]
            # a free T is the variable's (against the initial guess's T / N, the minimum time at
            # R = 1, T* = 1.63 from T = 0.5, would push every step shorter)
            T = x[int(np.ravel(tr.ix["T"])[0])] if pb.free_time else pb.T
            fn = ca.Function("step_penalty", [x],
                             [STEP_REGULARIZATION * T * ca.sumsqr(h / (T / pb.N) - 1.0) / pb.N])
        cache["step_penalty"] = fn
    return cache["step_penalty"]


def ipopt_solver(tr, options: HomotopyOptions, warm: bool, cache: dict, regularized: bool = False) -> ca.Function:
    """IPOPT on the transcription's NLP (cold, or warm-started with a small barrier; with the step
    penalty of :func:`step_penalty` added to its objective where ``regularized``), cached."""
    key = (warm, options.max_iter, options.ipopt_tol, tuple(sorted((options.ipopt_options or {}).items())),
           regularized)
    if key not in cache:
        pen = step_penalty(tr, cache) if regularized else None
        nlp = tr.nlp if pen is None else dict(tr.nlp, f=tr.nlp["f"] + pen(tr.nlp["x"]))
        ip = {"print_level": 0, "sb": "yes", "tol": options.ipopt_tol, "constr_viol_tol": options.ipopt_tol,
              "max_iter": int(options.max_iter), "mu_strategy": "adaptive", "bound_relax_factor": 0.0}
        if warm:
            # the previous stage's solution is close: pushes of 1e-9 keep the warm start near its
            # bounds (mu_init is inert under the adaptive barrier: set per stage to 0.1, 0.01 or
            # 0.001 sigma, the motor's and the two-block chain's stages took the same iterations;
            # every warm-start push and fraction at 1e-5 cut the seven blocks' homotopy from 1729
            # to 1264 iterations, but the hopper from the defaults (N = 20) then failed, and a
            # Jean-Pratt affine-hold row replayed to 1.1e-8 instead of 1e-10: not used)
            ip.update({"warm_start_init_point": "yes", "mu_init": 1e-6,
                       "warm_start_bound_push": 1e-9, "warm_start_mult_bound_push": 1e-9})
        ip.update(options.ipopt_options or {})
        # IPOPT may try points (in multi-starts and failing stages, from finite starting points)
        # where a constraint or the cost evaluates to NaN; it backs off from them by itself (a
        # solve that cannot recover ends with a failed status, reported in the result). CasADi
        # would print a warning for every such trial (25 in a quick optimal_control study), which
        # says nothing about the result.
        cache[key] = ca.nlpsol("ocp_warm" if warm else "ocp", "ipopt", nlp,
                               {"print_time": False, "show_eval_warnings": False, "ipopt": ip})
    return cache[key]


#: a relaxation stage in the first half of the schedule (sigma above the geometric mean of sigma0
#: and sigma_min) that IPOPT ends infeasible or in a failed step (:data:`RETRIED`) is solved again
#: from the last converged stage at the geometric midpoint of the two relaxations, at most this
#: many times per stage. Measured on the hopper at N = 40 under OpenBLAS's AVX-512 kernels (the
#: start from sigma0 = 1): the stage at sigma = 0.01 ended infeasible, the homotopy stopped at 0.1,
#: and four exact-phase shootings from there ran into their iteration limit (381 s; success False,
#: replay miss 3.3). With the retry the stage at 10^-1.5 converged, the homotopy went on to
#: 10^-4.5, and the shooting from there succeeded (cost 39.167, replay 6.0e-10). Not retried:
#:
#: - a stage that runs into the iteration limit: IPOPT was crawling, not lost, and another 3000
#:   iterations cost tens of seconds (the same hopper: 35 to 56 s per such retry);
#: - a stage in the second half: the relaxation is then small, and the polishing solve and the
#:   exact-phase shooting finish from the last converged stage. Retried there, the hopper at N = 20
#:   (AVX-512 kernels) spent 60 s more in four retries for the same result (cost 14.1927), and at
#:   N = 40 (AVX2 kernels) 27 s more in one, for the same cost 38.7916.
STAGE_RETRIES = 2
#: IPOPT's return statuses after which a stage is retried (:data:`STAGE_RETRIES`)
RETRIED = ("Infeasible_Problem_Detected", "Error_In_Step_Computation", "Restoration_Failed")


def run_homotopy(tr, x0, P0, options: HomotopyOptions, cache: dict, regularized: bool = True):
    """The relaxation stages and the polishing solve. Returns (x, cost, diag, status, message, history).
    On free steps every stage carries the step penalty (:func:`step_penalty`; the costs reported
    are without it) unless not ``regularized``. A failed stage early in the schedule is retried at
    a smaller step of the relaxation (:data:`STAGE_RETRIES`); every solve, failed or not, is in the
    history."""
    pen = step_penalty(tr, cache) if regularized else None
    reg = pen is not None
    cold, warm = ipopt_solver(tr, options, False, cache, reg), ipopt_solver(tr, options, True, cache, reg)
    x, lam_x, lam_g = x0, None, None
    history, best = [], None
    status, message = -2, OCP_STATUS_MESSAGES[-2]
    sigma = float(options.sigma0)
    prev, retries, i = None, 0, 0
    while i < options.n_stages:
        P0[0] = sigma
        args = {"x0": x, "lbx": tr.lbx, "ubx": tr.ubx, "lbg": tr.lbg, "ubg": tr.ubg, "p": P0}
        t0 = time.perf_counter()
        solver = cold if lam_x is None else warm
        sol = solver(**args) if lam_x is None else solver(lam_x0=lam_x, lam_g0=lam_g, **args)
        st = solver.stats()
        dt = time.perf_counter() - t0
        xs = np.array(sol["x"]).ravel()
        diag = diagnose(tr, xs)
        ok = _converged(st)
        f = float(sol["f"]) - (float(pen(xs)) if reg else 0.0)
        history.append(HomotopyStage(sigma, int(st["iter_count"]), diag["residual"], diag["max_product"],
                                     f, st["return_status"], ok, dt))
        if not ok and prev is not None and retries < STAGE_RETRIES and st["return_status"] in RETRIED \
                and sigma * sigma > (1 + 1e-6) * options.sigma0 * options.sigma_min:  # (rounding of 0.1^k)
            retries += 1  # (the failed solve stays in the history)
            sigma = float(np.sqrt(prev * sigma))
            continue
        if not ok:
            status = -1
            again = (f" (after {retries} smaller relaxation step{'s' if retries > 1 else ''} from sigma = "
                     f"{prev:.3g})" if retries else "")
            message = (f"{OCP_STATUS_MESSAGES[-1]} Stage {i} (sigma = {sigma:.3g}): IPOPT returned "
                       f"{st['return_status']}{again}{_at(diag)}.")
            break
        x, lam_x, lam_g = xs, np.array(sol["lam_x"]).ravel(), np.array(sol["lam_g"]).ravel()
        best = (x, f, diag)
        if _within_tol(diag, options.tol):
            status, message = 0, OCP_STATUS_MESSAGES[0]
            break
        prev, retries, i = sigma, 0, i + 1
        sigma = max(sigma * options.factor, options.sigma_min)
    if best is not None and status == -2:
        message = (f"{OCP_STATUS_MESSAGES[-2]} Residual {best[2]['residual']:.3g} > tol = {options.tol:.3g} "
                   f"at sigma = {history[-1].sigma:.3g}{_at(best[2])}.")
    if best is not None and options.polish and tr.pb.system.n_contacts:
        xp, fp, diagp, st, dt = _polish(tr, best[0], lam_x, lam_g, P0, warm, pen, project=options.ipopt_tol)
        okp = bool(st["success"])
        history.append(HomotopyStage(0.0, int(st["iter_count"]), diagp["residual"], diagp["max_product"],
                                     fp, st["return_status"], okp, dt))
        if okp and diagp["residual"] <= max(best[2]["residual"], options.tol) and \
                diagp["cross"] <= max(best[2]["cross"], options.tol):
            best = (xp, fp, diagp)
            if _within_tol(diagp, options.tol) and status != 0:
                # the last converged stage identified the active set; polishing finished it
                message = f"{OCP_STATUS_MESSAGES[0]} (By the polishing solve; before it: {message})"
                status = 0
            elif status == -2:  # the polished point is kept: the message must quote its residual
                message = (f"{OCP_STATUS_MESSAGES[-2]} Residual {diagp['residual']:.3g} > tol = {options.tol:.3g} "
                           f"after the polishing solve (before it {history[-2].residual:.3g} at sigma = "
                           f"{history[-2].sigma:.3g}){_at(diagp)}.")
        elif status == 0:
            status, message = 1, OCP_STATUS_MESSAGES[1]
    if best is None:
        return x, float("nan"), diagnose(tr, np.asarray(x)), status, message, history
    return best[0], best[1], best[2], status, message, history


def _fixed_mode_bounds_velocity(tr, x):
    """Variable bounds with, pair by pair (cross and rate pairs included), the smaller member of
    each complementarity pair at ``x`` fixed at zero: the mode of every step frozen as at ``x``."""
    ix = tr.ix
    lbx, ubx = tr.lbx.copy(), tr.ubx.copy()
    pairs = [(ix[a].reshape(-1), ix[w].reshape(-1)) for a, w in PAIRS]
    if tr.cross:  # step k's multipliers against step k-1's slacks (k >= 1)
        pairs += [(ix[a][1:].reshape(-1), ix[w][:-1].reshape(-1))
                  for a, w in (("pN", "wN"), ("bp", "wp"), ("bm", "wm"), ("wl", "lam"))]
    for ia, iw in pairs:
        a_small = x[ia] <= x[iw]
        ubx[ia[a_small]] = 0.0
        ubx[iw[~a_small]] = 0.0
    for ia, iw in _rate_pairs(tr):  # a >= 0 against a signed rate: the smaller (in magnitude) is zero
        # a multiplier at rounding level counts as zero: a guess without rates (a staircase) would
        # otherwise freeze every rate at zero, sliding steps included
        tiny = 1e-9 * max(float(np.max(np.abs(x[ia]), initial=0.0)), 1.0)
        a_small = x[ia] <= np.maximum(np.abs(x[iw]), tiny)
        ubx[ia[a_small]] = 0.0
        lbx[iw[~a_small]] = ubx[iw[~a_small]] = 0.0
    return lbx, ubx


def _normal_start_gap(tr):
    """The scaled gap of every contact at node 0 (a number: q0 is given)."""
    pb = tr.pb
    return pb.system.gaps(pb.q0) / tr.gap_scale


def fixed_mode_bounds(tr, x):
    """:func:`fixed_mode_bounds_contacts` (or the transcription's own ``fixed_mode_bounds_law``),
    with the smaller member of each user pair (:mod:`lcp.ocp.pairs`) fixed at zero too."""
    own = getattr(tr, "fixed_mode_bounds_law", None)
    lbx, ubx = own(x) if own is not None else fixed_mode_bounds_contacts(tr, x)
    fix_pairs(tr, x, ubx)
    return lbx, ubx


def fixed_mode_bounds_contacts(tr, x):
    """Variable bounds with, pair by pair (start-gap, impulse, cross, signed and rate pairs included),
    the smaller member of each complementarity pair at ``x`` fixed at zero: the mode of every step
    frozen as at ``x``.

    Only what the mode does not already imply is fixed (dependent equalities would leave IPOPT a
    rank-deficient Jacobian): no friction pair of a contact whose normal force (impulse) is fixed
    at zero (its friction then vanishes by mu N - beta+ - beta- >= 0), and no signed pair of a step
    that continues a contact phase without an impulse (its start velocity follows from the gaps).
    """
    if not tr.gap_law:
        return _fixed_mode_bounds_velocity(tr, x)
    ix = tr.ix
    lbx, ubx = tr.lbx.copy(), tr.ubx.copy()
    pb = tr.pb
    N, m = pb.N, pb.system.n_contacts
    if m:
        def fix(ia, iw, w=None):  # True where the multiplier is fixed at zero
            ia = ia.reshape(-1)
            wv = x[iw.reshape(-1)] if w is None else w
            small = x[ia] <= wv
            ubx[ia[small]] = 0.0
            if w is None:
                ubx[iw.reshape(-1)[~small]] = 0.0
            return small.reshape(-1, m)

        g0 = _normal_start_gap(tr)
        off = fix(ix["pN"], ix["wN"])
        off[:1] |= fix(ix["pN"][:1], None, g0)
        off_i = fix(ix["PN"][:1], None, g0)
        if N > 1:
            off[1:] |= fix(ix["pN"][1:], ix["wN"][:-1])
            off_i = np.vstack([off_i, fix(ix["PN"][1:], ix["wN"][:-1])])
        on, on_i = ~off.reshape(-1), ~off_i.reshape(-1)
        pairs = [(ix[a].reshape(-1)[on], ix[w].reshape(-1)[on]) for a, w in PAIRS[1:]]
        pairs += [(ix[a].reshape(-1)[on_i], ix[w].reshape(-1)[on_i]) for a, w in IMPULSE_PAIRS[1:]]
        if tr.cross and N > 1:  # step k's friction multipliers against step k-1's slacks (k >= 1)
            both = (~off[1:] & ~off[:-1]).reshape(-1)
            pairs += [(ix[a][1:].reshape(-1)[both], ix[w][:-1].reshape(-1)[both])
                      for a, w in (("bp", "wp"), ("bm", "wm"), ("wl", "lam"))]
        for ia, iw in pairs:
            a_small = x[ia] <= x[iw]
            ubx[ia[a_small]] = 0.0
            ubx[iw[~a_small]] = 0.0
        # signed pairs: a contact with a force starts its step at rest (unless the previous step
        # already held it closed and no impulse acted in between); an impulse meets Newton's law
        implied = np.zeros_like(off)
        implied[1:] = ~off[:-1] & off_i[1:]
        s_u = ix["sU"].reshape(N, m)[~off & ~implied]
        lbx[s_u] = ubx[s_u] = 0.0
        s_i = ix["sI"].reshape(N, m)[~off_i]
        lbx[s_i] = ubx[s_i] = 0.0
    for ia, iw in _rate_pairs(tr):  # a >= 0 against a signed rate: the smaller (in magnitude) is zero
        # a multiplier at rounding level counts as zero: a guess without rates (a staircase) would
        # otherwise freeze every rate at zero, sliding steps included
        tiny = 1e-9 * max(float(np.max(np.abs(x[ia]), initial=0.0)), 1.0)
        a_small = x[ia] <= np.maximum(np.abs(x[iw]), tiny)
        ubx[ia[a_small]] = 0.0
        lbx[iw[~a_small]] = ubx[iw[~a_small]] = 0.0
    return lbx, ubx


def _polish(tr, x, lam_x, lam_g, P, solver, pen=None, project=None):
    """Fix the smaller member of each complementarity pair (cross pairs included) at zero and re-solve;
    with ``project`` (a dynamics residual), a point where IPOPT stopped at its acceptable level with
    a larger dynamics residual is projected onto its constraints (:func:`feasible`)."""
    lbx, ubx = fixed_mode_bounds(tr, x)
    t0 = time.perf_counter()
    warm = {} if lam_x is None else {"lam_x0": lam_x, "lam_g0": lam_g}
    sol = solver(x0=np.clip(x, lbx, ubx), lbx=lbx, ubx=ubx, lbg=tr.lbg, ubg=tr.ubg, p=P, **warm)
    st = solver.stats()
    xs = np.array(sol["x"]).ravel()
    # the problem's own cost: IPOPT's objective without the step penalty of a regularized solver
    f = float(sol["f"]) - (float(pen(xs)) if pen is not None else 0.0)
    xs, f, diag = (feasible(tr, xs, f, st["return_status"], lbx, ubx, P, project) if project
                   else (xs, f, diagnose(tr, xs)))
    return xs, f, diag, st, time.perf_counter() - t0


def feasible(tr, x, f, status, lbx, ubx, P, above):
    """(x, cost, diagnosis): where IPOPT (its return status ``status``) stopped at its acceptable
    level with a dynamics residual above ``above`` (IPOPT's tolerance: a point within it is left as
    IPOPT gave it), ``x`` projected onto its constraints (:func:`projected`) when that lowers the dynamics
    residual and raises neither complementarity residual; else ``x`` as it is."""
    diag = diagnose(tr, x)
    if status == "Solved_To_Acceptable_Level" and diag["dynamics"] > above:
        xq = projected(tr, x, lbx, ubx, P)
        if xq is not None:
            dq = diagnose(tr, xq)
            if dq["dynamics"] < diag["dynamics"] and dq["residual"] <= diag["residual"] and \
                    dq["cross"] <= diag["cross"]:
                return xq, float(_constraints(tr)(xq, P)[2]), dq
    return x, f, diag


#: Gauss-Newton steps of :func:`projected` at most
PROJECTION_STEPS = 4


def projected(tr, x, lbx, ubx, P):
    """``x`` moved, least-norm (Gauss-Newton), onto its equality constraints and its active
    inequalities (within 1e-8 of a bound), the variables at or within 1e-12 of a bound held; None
    when the result leaves a bound of ``x`` or ``g`` by more than 1e-12, or moves a variable by more
    than 1e-6 (relative to max(1, |x|)).

    Why: IPOPT stops at its acceptable level when it stalls short of its tolerance; its constraint
    violation there is limited only by ``acceptable_constr_viol_tol`` (1e-2). Measured on the
    Jean-Pratt block (velocity law, free steps, affine hold): the polishing solve of the minimum
    effort at N = 40 stopped with a dynamics residual of 5.3e-9, a cost 1.3e-9 below the optimum and
    a replay miss of 1.3e-9; the fixed-phase solve of the minimum time at N = 20, 1.35e-10. A point
    that close to its constraints is a Newton step from them: after it the dynamics hold to
    rounding, the cost moves by the constraint violation's order.
    """
    fn = _constraints(tr)
    x_in, x = x, np.array(x, dtype=float)
    scale = np.maximum(1.0, np.abs(x))
    free = (x > lbx + 1e-12 * scale) & (x < ubx - 1e-12 * scale)
    g, J, _ = fn(x, P)
    g = np.array(g).ravel()
    near = 1e-8 * np.maximum(1.0, np.abs(g))
    up, low = g >= tr.ubg - near, g <= tr.lbg + near
    rows = up | low
    target = np.where(up, tr.ubg, tr.lbg)[rows]
    if not rows.any() or not free.any():
        return None
    n_free, n_rows = int(np.sum(free)), int(np.sum(rows))
    for _ in range(PROJECTION_STEPS):  # (g and J at the current x)
        r = g[rows] - target
        if np.max(np.abs(r)) <= 1e-15 * max(1.0, float(np.max(np.abs(target)))):
            break
        A = J.sparse().tocsr()[rows][:, free]
        # least norm: min |dx| subject to A dx = -r, as the (slightly regularized) KKT system, sparse
        K = sparse.bmat([[sparse.identity(n_free), A.T], [A, -1e-14 * sparse.identity(n_rows)]], format="csc")
        dx = spsolve(K, np.concatenate([np.zeros(n_free), -r]))[:n_free]
        if not np.all(np.isfinite(dx)):
            return None
        x[free] += dx
        g, J, _ = fn(x, P)
        g = np.array(g).ravel()
    if np.max(np.abs(x - x_in) / scale) > 1e-6:  # not a point near its constraints: not a projection
        return None
    if np.any(x < lbx - 1e-12 * scale) or np.any(x > ubx + 1e-12 * scale) or \
            np.any(g < tr.lbg - 1e-12) or np.any(g > tr.ubg + 1e-12):
        return None
    return np.clip(x, lbx, ubx)


#: (x, p) -> (g, dg/dx, f) of a transcription's NLP, built on first use
_CONSTRAINTS = weakref.WeakKeyDictionary()


def _constraints(tr) -> ca.Function:
    if tr not in _CONSTRAINTS:
        x, p, g = tr.nlp["x"], tr.nlp["p"], tr.nlp["g"]
        _CONSTRAINTS[tr] = ca.Function("constraints", [x, p], [g, ca.jacobian(g, x), tr.nlp["f"]])
    return _CONSTRAINTS[tr]


def run_fixed_modes(tr, x0, P0, options: HomotopyOptions, cache: dict):
    """The phase-structure solve: every step's mode frozen as in the guess ``x0`` (the smaller member of
    each pair at zero), one smooth NLP. Returns the tuple of :func:`run_homotopy`.

    With free steps the step lengths stay unknowns, so the switch times move freely while the
    sequence of modes (the phases) is the guess's: a guess from a solution with the right phase
    sequence (e.g. a uniform-step solve) gives the exact optimum without the relaxation homotopy.
    A guess with the wrong sequence makes the NLP infeasible or leaves its complementarity violated;
    status -1 or -2 says so. Where IPOPT does not converge fully (it stops at its acceptable level,
    or fails), the solve is repeated from ``x0`` with the step penalty (:func:`step_penalty`), and
    that result kept when it is solved and better.
    """
    P0 = P0.copy()
    P0[0] = 0.0
    x0 = np.asarray(x0, dtype=float)
    x, f, diag, st, dt, iterations, merged = _fixed_merged(tr, x0, P0, options, cache, False)
    note = ""
    if st["return_status"] != "Solve_Succeeded" and step_penalty(tr, cache) is not None:
        xa, fa, diag_a, st_a, dt_a, it_a, merged_a = _fixed_merged(tr, x0, P0, options, cache, True)
        dt, iterations = dt + dt_a, iterations + it_a
        if _solved(st_a, diag_a, options) and (not _solved(st, diag, options)
                                               or fa < f - TAIL_GAIN * max(1.0, abs(f))):
            note = (f" With the step penalty: IPOPT returned {st['return_status']} without it (cost {f:.10g}, "
                    f"Coulomb residual {diag['residual']:.3g}).")
            x, f, diag, st, merged = xa, fa, diag_a, st_a, merged_a
    ok = _converged(st)
    history = [HomotopyStage(0.0, iterations, diag["residual"], diag["max_product"], f,
                             st["return_status"], ok, dt)]
    if not ok:
        msg = (f"{OCP_STATUS_MESSAGES[-1]} The fixed-phase solve (the guess's mode sequence): IPOPT returned "
               f"{st['return_status']} (dynamics residual {diag['dynamics']:.3g}).")
        return x, f, diag, -1, msg, history
    if not _within_tol(diag, options.tol):
        msg = (f"{OCP_STATUS_MESSAGES[-2]} Residual {diag['residual']:.3g}, cross {diag['cross']:.3g} > "
               f"tol = {options.tol:.3g} after the fixed-phase solve{_at(diag)}.")
        return x, f, diag, -2, msg, history
    return x, f, diag, 0, (f"{OCP_STATUS_MESSAGES[0]} (Fixed-phase solve: the guess's mode sequence.{merged}"
                           f"{note})"), history


def _converged(st) -> bool:
    """Whether IPOPT converged, fully or to its acceptable level."""
    return bool(st["success"]) or st["return_status"] == "Solved_To_Acceptable_Level"


def _solved(st, diag, options) -> bool:
    """Whether a fixed-phase solve ended solved: IPOPT converged and the complementarity within
    tolerance."""
    return _converged(st) and _within_tol(diag, options.tol)


def _within_tol(diag, tol) -> bool:
    """Whether the complementarity residual and the cross residual of ``diag`` are within ``tol``."""
    return diag["residual"] <= tol and diag["cross"] <= tol


def _fixed_merged(tr, x0, P0, options, cache, regularized):
    """The fixed-phase solve from ``x0`` and the merges of the phases it leaves on minimum-length
    steps (:data:`SQUEEZE_ROUNDS`). Returns (x, cost, diag, IPOPT stats, time, iterations, note)."""
    solver = ipopt_solver(tr, options, False, cache, regularized)
    pen = step_penalty(tr, cache) if regularized else None
    x, f, diag, st, dt, iterations = _fixed_solve(tr, x0, P0, solver, pen)
    ok = _converged(st)
    squeezed = getattr(tr, "squeezed_phases_law", None)  # (Radau collocation: lcp.ocp.collocation)
    merged, f_first = 0, f
    # a phase left on minimum-length steps: once more without it, kept if better; repeated while it
    # helps (the move-and-hold at N = 40 on [0.42, 0.6] s, T = 1.15 s, has one such step per move)
    for _ in range(SQUEEZE_ROUNDS if ok and squeezed is not None else 0):
        x_alt = squeezed(x)
        if x_alt is None:
            break
        x2, f2, diag2, st2, dt2, it2 = _fixed_solve(tr, x_alt, P0, solver, pen)
        dt, iterations = dt + dt2, iterations + it2
        if not (_converged(st2) and f2 < f and diag2["residual"] <= max(diag["residual"], options.tol) and
                diag2["cross"] <= max(diag["cross"], options.tol)):
            break
        merged += 1
        x, f, diag, st = x2, f2, diag2, st2
    note = (f" {'A phase' if merged == 1 else f'{merged} phases'} left on minimum-length steps "
            f"{'was' if merged == 1 else 'were'} merged into {'its neighbour' if merged == 1 else 'their neighbours'} "
            f"(cost was {f_first:.10g})." if merged else "")
    return x, f, diag, st, dt, iterations, note


#: at most this many merges of phases left on minimum-length steps after a fixed-phase solve
SQUEEZE_ROUNDS = 4


def _fixed_solve(tr, x0, P0, solver, pen=None):
    """One fixed-phase solve from ``x0`` (the modes of ``x0``), repeated once from an acceptable point
    (``pen``: the step penalty of a regularized ``solver``, for the cost)."""
    x, f, diag, st, dt = _polish(tr, x0, None, None, P0, solver, pen)
    iterations = int(st["iter_count"])
    if st["return_status"] == "Solved_To_Acceptable_Level":
        # IPOPT's acceptable level is looser than its tolerance (the dynamics to ~1e-8, a replay miss of
        # ~1e-7 through the phases): once more from that point, and kept if it converges fully
        # (CasADi's ``success`` also holds at the acceptable level: a second acceptable point may be
        # worse than the first, dynamics 5.5e-9 against 2.3e-13 on the minimum-time problem, N = 20)
        x2, f2, diag2, st2, dt2 = _polish(tr, x, None, None, P0, solver, pen)
        dt += dt2
        iterations += int(st2["iter_count"])
        if st2["return_status"] == "Solve_Succeeded":
            x, f, diag, st = x2, f2, diag2, st2
    return x, f, diag, st, dt, iterations


def run_phases(tr, x0, P0, options: HomotopyOptions, cache: dict):
    """:func:`run_fixed_modes`, and the homotopy if it fails: from the fixed-phase iterate with
    sigma0 <= 1e-4 when that iterate already satisfies the dynamics and the Coulomb law (IPOPT
    stopped on a degenerate but nearly optimal point), else from ``x0`` with ``options``. Returns the
    tuple of :func:`run_homotopy`, the message saying when the fixed-phase solve failed first."""
    x, cost, diag, status, message, history = run_fixed_modes(tr, x0, P0, options, cache)
    if status >= 0:
        out = _relaxed_tail(tr, x, cost, diag, status, message, history, P0, options, cache)
        if out[0] is x:
            # the fixed-phase solution kept: where IPOPT left it at its acceptable level, projected
            # onto its constraints, after the tail (which starts from IPOPT's point: from the
            # projected one, the tail of the minimum time at R = 0.7, N = 40 no longer lowered the
            # cost from 4.0e-4 above T* to 4e-8)
            out = feasible(tr, x, cost, history[0].return_status, *fixed_mode_bounds(tr, x), P0,
                           options.ipopt_tol) + out[3:]
        return out
    if np.all(np.isfinite(x)) and diag["dynamics"] <= 1e-8 and diag["residual"] <= options.tol:
        start = x  # a nearly optimal start: only the tail of the homotopy
        options = replace(options, sigma0=max(min(options.sigma0, 1e-4), options.sigma_min),
                          factor=min(options.factor, 1e-2))
    else:  # the guess's phase sequence does not fit: the whole homotopy from the guess
        start = x0
    x, cost, diag, status, msg, more = run_homotopy(tr, start, P0, options, cache)
    return x, cost, diag, status, f"{msg} (The fixed-phase solve failed first: {message})", history + more


#: first relaxation of the tail after a fixed-phase solve (W): small enough to stay near the
#: phases found, large enough to let a pair whose both members vanish choose its side
TAIL_SIGMA0 = 1e-6
#: the relative decrease of the cost for which the tail's solution is kept
TAIL_GAIN = 1e-8


def _at(diag) -> str:
    """"; the Coulomb residual <where>" when the residual is not zero (a failed solve's message)."""
    return f"; the Coulomb residual is {diag['where']}" if diag.get("where") else ""


def _relaxed_tail(tr, x, cost, diag, status, message, history, P0, options, cache):
    """A short homotopy (sigma0 = :data:`TAIL_SIGMA0`) from a fixed-phase solution, kept when it
    lowers the cost and ends solved. The fixed-phase NLP fixes one member of every pair, also of a
    pair whose members both vanish at the guess (a slide that ends at rest at a node): its KKT
    point is then a stationary point of that choice, not necessarily of the MPCC. Measured: the
    Jean-Pratt minimum time at N = 6, R = 0.5625 (gap law) ends 8.0e-5 above T* after the fixed
    phases and 1.3e-10 above after the tail."""
    tail = replace(options, sigma0=max(min(options.sigma0, TAIL_SIGMA0), options.sigma_min),
                   factor=min(options.factor, 1e-2))
    # (without the step penalty: the tail starts from a solution, and only a lower cost is kept)
    xt, ct, dt, st, mt, more = run_homotopy(tr, x, P0.copy(), tail, cache, regularized=False)
    history = history + more
    # a decrease of more than 1e-8: within the tolerances, the relaxed pairs can buy a few 1e-9 (the
    # minimum effort at N = 6, affine hold: 2e-9 below the exact optimum, complementarity 2.8e-9)
    if st >= 0 and np.isfinite(ct) and ct < cost - TAIL_GAIN * max(1.0, abs(cost)):
        # the fixed-phase solution stays at hand: if the tail's fails its replay, the solve keeps it
        dt = {**dt, "before_tail": (x, cost, diag, status, message)}
        return xt, ct, dt, st, f"{mt} (A relaxed tail from the fixed-phase solve lowered the cost from {cost:.10g}.)", \
            history
    return x, cost, diag, status, message, history


def _rate_pairs(tr):
    """(index of a >= 0, index of its signed rate) of the affine hold's rate complementarity."""
    if "sN" not in tr.ix:
        return []
    return [(tr.ix["pN"].reshape(-1), tr.ix["sN"].reshape(-1)), (tr.ix["wl"].reshape(-1), tr.ix["sT"].reshape(-1))]


def diagnose(tr, x) -> dict:
    """The contacts' diagnosis (:func:`diagnose_contacts`, or the transcription's own
    ``diagnose_law`` where it has one: spatial contacts), with the user's complementarity pairs
    (:mod:`lcp.ocp.pairs`) counted among the cross pairs."""
    own = getattr(tr, "diagnose_law", None)
    d = own(x) if own is not None else diagnose_contacts(tr, x)
    res, prod = pair_residual(tr, x)
    if res or prod:
        d["cross"] = max(d["cross"], res)
        d["max_product"] = max(d["max_product"], prod)
    return d


def diagnose_contacts(tr, x) -> dict:
    """Coulomb residual, dynamics residual and modes per step, recomputed in NumPy.

    ``residual`` (impulse units) is the largest of: the Coulomb residual
    (:meth:`~lcp.contact.problem.ContactProblem.residual`) of each step's velocity-level problem on
    the contacts in contact over the step (a force, or the gap closed at both ends), the impulses of
    the others, a force where the gap is open (min(p_N, g / (theta h W_jj))) or the normal
    velocity is not zero at the start (min(p_N, |u_N+| / W_jj)), a penetration at a node
    (g / (theta h W_jj) below zero), and the Coulomb residual of each node's impulse (Newton's law)
    on the contacts closed there.
    """
    if not tr.gap_law:
        return _diagnose_velocity(tr, x)
    pb = tr.pb
    _, hs, q, v, u, pN, pT = tr.unpack(x)
    N, n, m, nb = pb.N, pb.system.n, pb.system.n_contacts, pb.system.n_bilateral
    th, mu, e = pb.theta, pb.system.mu, pb.system.e
    ua, ub = {"constant": (u, u), "linear": (u[:-1], u[1:]), "affine": (u[0::2], u[1::2])}[pb.hold]
    ubar = 0.5 * (ua + ub)
    tk = np.concatenate([[0.0], np.cumsum(hs)])[:-1]
    vs = np.array(tr.aux(x, np.concatenate([[0.0], pb.q0, pb.v0])), dtype=float).T  # after the impulses
    out = tr.step.map(N)(tk[None, :], hs[None, :], q[:-1].T, vs.T, ua.T, ubar.T, (ub - ua).T)

    def blocks(a, r, c):  # (r, c N) -> (N, r, c)
        return np.array(a, dtype=float).reshape(r, N, c).transpose(1, 0, 2)

    def kkt(A, G):
        K = np.zeros((N, n + nb, n + nb))
        K[:, :n, :n] = A
        K[:, :n, n:] = G.transpose(0, 2, 1)
        K[:, n:, :n] = G
        return K

    Wh, r, H = blocks(out[0], n, n), blocks(out[1], n, 1)[..., 0], blocks(out[2], 2 * m, n)
    G, phi_t1, gap = blocks(out[3], nb, n), blocks(out[4], nb, 1)[..., 0], blocks(out[5], m, 1)[..., 0]
    KKT = kkt(Wh, G)
    rhs = np.concatenate([r, -phi_t1 - np.einsum("kij,kj->ki", G, vs)], axis=1)
    vfree = vs + np.linalg.solve(KKT, rhs[..., None])[:, :n, 0]
    res, conflicts = 0.0, 0
    modes = np.full((N, m), OPEN, dtype=np.int8)
    max_product = lcp_res = cross = 0.0
    if not m:
        return {"residual": res, "dynamics": float(np.max(np.abs(vfree - v[1:]), initial=0.0)), "modes": modes,
                "conflicts": conflicts, "max_product": max_product, "lcp": lcp_res, "cross": cross, "where": ""}
    PN, PT = tr.impulses(x)
    HL = HF = H
    if getattr(tr, "curved", np.zeros(0)).size:  # a curved gap's force acts along the mean of the
        # normals at the step's ends and meets the velocity along the end's (lcp.ocp.transcription)
        HL, HF, rows = H.copy(), H.copy(), np.concatenate([tr.curved, m + tr.curved])
        H1 = blocks(tr.kin.map(N)((tk + hs)[None, :], q[1:].T)[1], 2 * m, n)
        HL[:, rows] = H1[:, rows]
        HF[:, rows] = 0.5 * (H[:, rows] + H1[:, rows])
    Ht = np.concatenate([HF.transpose(0, 2, 1), np.zeros((N, nb, 2 * m))], axis=1)
    SHt = np.linalg.solve(KKT, Ht)[:, :n]
    W = HL @ SHt
    Mq = blocks(tr.kin.map(N)(tk[None, :], q[:-1].T)[0], n, n)
    # the impulses' Delassus operator: a node's impulse acts along H(q_k) (not along the step's
    # mean Jacobian of a curved contact)
    H0t = np.concatenate([H.transpose(0, 2, 1), np.zeros((N, nb, 2 * m))], axis=1)
    W0 = H @ np.linalg.solve(kkt(Mq, G), H0t)[:, :n]
    gaps = np.array([pb.system.gaps(qk) for qk in q])  # (N + 1, m)
    gtol = 1e-9 * max(1.0, float(np.max(np.abs(q))))
    uN_minus = np.einsum("kij,kj->ki", H[:, :m], vs)
    qf = np.einsum("kij,kj->ki", H, vfree)
    qfl = np.einsum("kij,kj->ki", HL, vfree)
    gap_pred = gap + hs[:, None] * ((1 - th) * uN_minus + th * qf[:, :m])
    p = np.concatenate([pN, pT], axis=1)
    P = np.concatenate([PN, PT], axis=1)
    u_pre = np.einsum("kij,kj->ki", H, v[:-1])
    step_res = np.zeros(N)
    for k in range(N):
        before, res = res, 0.0
        wd = np.maximum(np.diag(W[k])[:m], 1e-300)
        closed0, closed1 = gaps[k] <= gtol, gaps[k + 1] <= gtol
        act = (pN[k] > 0) | (closed0 & closed1)
        rows = np.concatenate([np.flatnonzero(act), m + np.flatnonzero(act)])
        if act.any():
            cp = ContactProblem(W[k][np.ix_(rows, rows)], qfl[k][rows], mu[act])
            res = max(res, cp.residual(p[k][rows]))
            modes[k, act] = cp.modes(p[k][rows], rtol=1e-6)
        if (~act).any():
            res = max(res, float(np.max(np.abs(p[k][np.concatenate([~act, ~act])]))))
        scaled = np.maximum(gaps[k], gaps[k + 1]) / (th * hs[k] * wd)
        res = max(res, float(np.max(np.minimum(pN[k], scaled))), float(np.max(-gaps[k + 1] / (th * hs[k] * wd))),
                  float(np.max(np.minimum(pN[k], np.abs(uN_minus[k]) / wd))))
        # the impulse at node k: Newton's law on the contacts closed there, none elsewhere
        qi = u_pre[k].copy()
        qi[:m] += e * np.minimum(u_pre[k][:m], 0.0)
        rows = np.concatenate([np.flatnonzero(closed0), m + np.flatnonzero(closed0)])
        if closed0.any():
            res = max(res, ContactProblem(W0[k][np.ix_(rows, rows)], qi[rows], mu[closed0]).residual(P[k][rows]))
        if (~closed0).any():
            res = max(res, float(np.max(np.abs(P[k][np.concatenate([~closed0, ~closed0])]))))
        conflicts += int(np.any((gap_pred[k] > 0) & (pN[k] > 1e-9 * max(1.0, float(np.max(np.abs(p[k])))))))
        step_res[k], res = res, max(before, res)
    where = _where(tr, step_res, hs, W, qf, mu, p)
    vplus = vfree + np.einsum("kij,kj->ki", SHt, p)
    ix = tr.ix
    g0 = pb.system.gaps(pb.q0) / tr.gap_scale
    a = np.concatenate([x[ix[nm]].ravel() for nm, _ in PAIRS] + [x[ix["PN"]].ravel()]
                       + [x[ix[nm]].ravel() for nm, _ in IMPULSE_PAIRS[1:]])
    w = np.concatenate([x[ix[nm]].ravel() for _, nm in PAIRS] + [np.concatenate([g0, x[ix["wN"][:-1]].ravel()])]
                       + [x[ix[nm]].ravel() for _, nm in IMPULSE_PAIRS[1:]])
    # the normal force against the start gap, the signed pairs and the cross pairs: "cross"
    ca_ = [x[ix["pN"]].ravel(), x[ix["pN"]].ravel(), x[ix["PN"]].ravel()]
    cw_ = [np.concatenate([g0, x[ix["wN"][:-1]].ravel()]), np.abs(x[ix["sU"]].ravel()), np.abs(x[ix["sI"]].ravel())]
    if tr.cross:
        ca_ += [x[ix[nm][1:]].ravel() for nm in ("bp", "bm", "wl")]
        cw_ += [x[ix[nm][:-1]].ravel() for nm in ("wp", "wm", "lam")]
    ca_, cw_ = np.concatenate(ca_), np.concatenate(cw_)
    max_product = float(max(np.max(a * w), np.max(ca_ * cw_, initial=0.0)))
    lcp_res = float(np.max(np.abs(np.minimum(a, w))))
    cross = float(np.max(np.abs(np.minimum(ca_, cw_)), initial=0.0))
    for ia, iw in _rate_pairs(tr):  # the affine hold's rate pairs count as cross pairs
        cross = max(cross, float(np.max(np.minimum(x[ia], np.abs(x[iw])), initial=0.0)))
    return {"residual": res, "dynamics": float(np.max(np.abs(vplus - v[1:]))), "modes": modes,
            "conflicts": conflicts, "max_product": max_product, "lcp": lcp_res, "cross": cross, "where": where}


def _contact_residuals(W, q, mu, p):
    """Each contact's term of the natural map of :meth:`ContactProblem.residual` (planar layout:
    normals, then tangents): max(|min(p_N, rho_N u_N)|, |p_T - proj(p_T - rho_T u_T)|)."""
    m = len(mu)
    u = W @ p + q
    rho = 1.0 / np.maximum(np.abs(np.diag(W)), 1e-300)
    s = mu * np.maximum(p[:m], 0.0)
    rT = p[m:] - np.clip(p[m:] - rho[m:] * u[m:], -s, s)
    return np.maximum(np.abs(np.minimum(p[:m], rho[:m] * u[:m])), np.abs(rT))


def _where(tr, step_res, hs, W, qf, mu, p) -> str:
    """Where the Coulomb residual is largest: the step, its start time and the contact (by its
    natural-map term in that step), for the messages of a solve that misses its tolerance."""
    if not step_res.size or not np.any(step_res > 0):
        return ""
    k = int(np.argmax(step_res))
    names = [c.name for c in tr.pb.system.contacts]
    j = int(np.argmax(_contact_residuals(W[k], qf[k], mu, p[k])))
    t = float(np.sum(hs[:k]))
    name = names[j] if names and names[j] else str(j)
    return f"largest in step {k} (t = {t:.6g}), contact {name!r}: {step_res[k]:.3g}"


def _diagnose_velocity(tr, x) -> dict:
    """Coulomb residual (ContactProblem.residual), dynamics residual and modes per step, in NumPy."""
    pb = tr.pb
    _, hs, q, v, u, pN, pT = tr.unpack(x)
    N, n, m, nb = pb.N, pb.system.n, pb.system.n_contacts, pb.system.n_bilateral
    th, mu, e = pb.theta, pb.system.mu, pb.system.e
    ua, ub = {"constant": (u, u), "linear": (u[:-1], u[1:]), "affine": (u[0::2], u[1::2])}[pb.hold]
    ubar = 0.5 * (ua + ub)
    tk = np.concatenate([[0.0], np.cumsum(hs)])[:-1]
    out = tr.step.map(N)(tk[None, :], hs[None, :], q[:-1].T, v[:-1].T, ua.T, ubar.T, (ub - ua).T)

    def blocks(a, r, c):  # (r, c N) -> (N, r, c)
        return np.array(a, dtype=float).reshape(r, N, c).transpose(1, 0, 2)

    Wh, r, H = blocks(out[0], n, n), blocks(out[1], n, 1)[..., 0], blocks(out[2], 2 * m, n)
    G, phi_t1, gap = blocks(out[3], nb, n), blocks(out[4], nb, 1)[..., 0], blocks(out[5], m, 1)[..., 0]
    KKT = np.zeros((N, n + nb, n + nb))
    KKT[:, :n, :n] = Wh
    KKT[:, :n, n:] = G.transpose(0, 2, 1)
    KKT[:, n:, :n] = G
    rhs = np.concatenate([r, -phi_t1 - np.einsum("kij,kj->ki", G, v[:-1])], axis=1)
    vfree = v[:-1] + np.linalg.solve(KKT, rhs[..., None])[:, :n, 0]
    res, conflicts = 0.0, 0
    modes = np.full((N, m), -1, dtype=np.int8)
    if m:
        SHt = np.linalg.solve(KKT, np.concatenate([H.transpose(0, 2, 1), np.zeros((N, nb, 2 * m))], axis=1))[:, :n]
        W = H @ SHt
        uN_minus = np.einsum("kij,kj->ki", H[:, :m], v[:-1])
        qf = np.einsum("kij,kj->ki", H, vfree)
        gap_pred = gap + hs[:, None] * ((1 - th) * uN_minus + th * qf[:, :m])
        qf[:, :m] += e * np.minimum(uN_minus, 0.0)  # restitution of approaching contacts only
        p = np.concatenate([pN, pT], axis=1)
        step_res = np.zeros(N)
        for k in range(N):
            cp = ContactProblem(W[k], qf[k], mu)
            step_res[k] = cp.residual(p[k])
            res = max(res, step_res[k])
            modes[k] = cp.modes(p[k], rtol=1e-6)
            conflicts += int(np.any((gap_pred[k] > 0) & (pN[k] > 1e-9 * max(1.0, cp.scale))))
        where = _where(tr, step_res, hs, W, qf, mu, p)
        vplus = vfree + np.einsum("kij,kj->ki", SHt, p)
        a = np.concatenate([x[tr.ix[nm]].ravel() for nm, _ in PAIRS])
        w = np.concatenate([x[tr.ix[nm]].ravel() for _, nm in PAIRS])
        if tr.cross:
            ix = tr.ix
            a = np.concatenate([a] + [x[ix[nm][1:]].ravel() for nm in ("pN", "bp", "bm", "wl")])
            w = np.concatenate([w] + [x[ix[nm][:-1]].ravel() for nm in ("wN", "wp", "wm", "lam")])
        max_product = float(np.max(a * w))
        lcp_res = float(np.max(np.abs(np.minimum(a, w))))
        n_own = N * m * len(PAIRS)  # the cross pairs follow the steps' own pairs
        cross = float(np.max(np.abs(np.minimum(a[n_own:], w[n_own:])), initial=0.0))
        for ia, iw in _rate_pairs(tr):  # the affine hold's rate pairs count as cross pairs
            cross = max(cross, float(np.max(np.minimum(x[ia], np.abs(x[iw])), initial=0.0)))
    else:
        vplus = vfree
        max_product = lcp_res = cross = 0.0
        where = ""
    return {"residual": res, "dynamics": float(np.max(np.abs(vplus - v[1:]))), "modes": modes,
            "conflicts": conflicts, "max_product": max_product, "lcp": lcp_res, "cross": cross, "where": where}
