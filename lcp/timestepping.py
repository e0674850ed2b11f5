"""Moreau-Jean time stepping (the theta-method with impulses), docs/numerical_methods.md.

Per step of size h:

    W_h (v+ - v-) = h F_theta + G' lambda + H' p,   G v+ + phi_t = 0,
    q+ = q- + h ((1 - theta) v- + theta v+),

with the iteration matrix W_h = A + h theta C + h^2 theta^2 K (K = -dF/dq, C = -dF/dv, so forces
that depend on the state are treated implicitly), and p the contact impulses of the active
contacts, which solve the discrete Coulomb problem :class:`~lcp.contact_problem.ContactProblem`.

Which contacts take part in a step (the activation rule)
--------------------------------------------------------
A contact j is active in a step when the free motion closes its gap within the step, judged on the
predicted gap

    g_pred = g_j(q) + h ((1 - theta) u_N- + theta u_N,free),

with a tolerance at the rounding level of that sum and a hysteresis for loaded contacts:

- closing: active when g_pred <= CLOSE_ULPS eps s_j, where s_j = |g_j| + |H_N,j| |q| + |g_0,j|
  + h (|(1 - theta) u_N-| + |theta u_N,free|) is the size of the terms whose rounding g_pred carries
  (|H_N,j| |q| and |g_0,j| = |g_j(0)|: a gap y2 - y1 - d between stacked blocks rounds to +3e-17,
  not to 0, and the plain test g_pred <= 0 would drop that contact for a step and leave the upper
  block sunk by g h^2 for ever);
- staying: a contact that carried a normal impulse (p_N > 0) in the previous step stays active
  unless its gap predicted with the current velocity alone, g_j(q) + h (1 - theta) u_N-, exceeds
  the larger threshold OPEN_ULPS eps s_j. The free velocity is left out on purpose: it ignores the
  other contacts, and a box pushed on its two corners has a free motion that lifts its back corner
  long before the box tips (the contacts together hold it flat); predicting with it would drop that
  corner every other step and make it chatter.

Keeping a contact active costs nothing in accuracy: if the motion separates it, the contact
problem gives it p = 0 (mode OPEN), exactly as if it had been left out, and it leaves the active
set in the next step. A rounding residue never drops a loaded contact.

Position projection
-------------------
Where a constraint is nonlinear in q (or rheonomic), the velocity-level scheme drifts off it by
O(h) over a fixed time; ``projection="auto"`` (the default) then corrects the positions after each
step (:mod:`lcp.projection`). Constant systems never pay for it.

Impacts
-------
A step counts as an impact on contact j (``result.impacts``) when j carried no load in the previous
step, receives p_N > 0, and approached with u_N- < 0 faster than the free motion's velocity change
over the step, |u_N-| > |u_N,free - u_N-| (a velocity jump rather than a smooth landing; for
h -> 0 the two separate). Its time is the estimated closing time t_k + min(h, g_j / |u_N-|).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import compiled
from .assembly import StepAssembly, kahan_add
from .contact_problem import MODE_NAMES, STICK, ContactProblem, ModeArray
from .projection import PositionProjection, needs_projection, violation_function
from .result import STATUS_MESSAGES, Impact, SimulationResult, SolverStats
from .solvers import SOLVERS, OneStepSolver, make_solver

__all__ = ["CLOSE_ULPS", "OPEN_ULPS", "MoreauJeanOptions", "moreau_jean", "moreau_jean_from_model"]

#: closing tolerance of the activation rule, in units of eps times the size of the gap's terms
CLOSE_ULPS = 16.0
#: opening threshold for a contact loaded in the previous step (hysteresis), same units
OPEN_ULPS = 16384.0
_EPS = float(np.finfo(float).eps)


@dataclass(frozen=True)
class MoreauJeanOptions:
    """Validated options of the Moreau-Jean scheme.

    Parameters
    ----------
    h : float
        Step size, > 0.
    theta : float
        Theta of the theta-method, in [1/2, 1].
    solver : str
        One-step solver name (``"auto"``, ``"enum"``, ``"lemke"``, ``"osqp"``).
    solver_options : dict, optional
        Keyword arguments for the solver.
    fallback : bool
        When the chosen one-step solver fails on a step, retry that step with an exact one
        (enumeration for one contact, Lemke otherwise); every such step is counted in
        ``stats.fallbacks`` and named in the message. With False the run stops at the failure.
    save_every : int
        Keep every ``save_every``-th state (and the impulses of the step that reached it), so that
        long runs do not store what nobody asked for.
    fast : bool
        Use the compiled path (:mod:`lcp.compiled`) when it applies: a constant system with one
        contact and the closed-form solver (``"auto"`` or ``"enum"``). Same results, no Python
        per step.
    projection : {"auto", True, False}
        Project the positions onto the constraints after each step (:mod:`lcp.projection`).
        ``"auto"``: only where a constraint is nonlinear in q or time-dependent (where the
        velocity-level scheme drifts); True: always (if there are constraints or contacts);
        False: never.
    projection_tol : float
        Relative tolerance of the projection, in [1e-15, 1) (see :mod:`lcp.projection`).
    """

    h: float
    theta: float = 0.5
    solver: str = "auto"
    solver_options: dict | None = None
    fallback: bool = True
    save_every: int = 1
    fast: bool = True
    projection: bool | str = "auto"
    projection_tol: float = 1e-12

    def __post_init__(self):
        h = self.h
        if not isinstance(h, (int, float, np.floating)) or not np.isfinite(h) or h <= 0:
            raise ValueError(f"h must be finite and > 0, got {h!r}")
        th = self.theta
        if not isinstance(th, (int, float, np.floating)) or not np.isfinite(th) or not 0.5 <= th <= 1.0:
            raise ValueError(f"theta must lie in [1/2, 1], got {th!r}")
        for name in ("fallback", "fast"):
            # a bool, not anything with a truth value: fallback="no" would read as True
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"{name} must be True or False, got {getattr(self, name)!r}")
        if not isinstance(self.save_every, (int, np.integer)) or self.save_every < 1:
            raise ValueError(f"save_every must be an integer >= 1, got {self.save_every!r}")
        if isinstance(self.solver, str) and self.solver not in SOLVERS and self.solver not in _cone_solvers():
            raise ValueError(f"unknown solver {self.solver!r}; known solvers: {sorted(SOLVERS)} (planar contacts), "
                             f"{sorted(_cone_solvers())} (spatial contacts)")
        if not isinstance(self.solver, (str, OneStepSolver)):
            raise ValueError(f"solver must be a solver name or a OneStepSolver, got {self.solver!r}")
        if self.solver_options is not None and not isinstance(self.solver_options, dict):
            raise ValueError(f"solver_options must be a dict, got {self.solver_options!r}")
        if not (self.projection is True or self.projection is False or self.projection == "auto"):
            raise ValueError(f"projection must be True, False or 'auto', got {self.projection!r}")
        tol = self.projection_tol
        if not isinstance(tol, (int, float, np.floating)) or not 1e-15 <= tol < 1:
            raise ValueError(f"projection_tol must lie in [1e-15, 1), got {tol!r}")


def _cone_solvers() -> dict:
    """The registry of the spatial (Coulomb disk) one-step solvers, imported when first needed."""
    from .cone_solvers import CONE_SOLVERS

    return CONE_SOLVERS


def _spatial_solver(options):
    """The disk-law solver of a system with spatial contacts (ValueError for a planar-only name)."""
    from .cone_solvers import ConeSolver, make_cone_solver

    name = options.solver
    if isinstance(name, str) and name not in _cone_solvers():
        raise ValueError(f"solver {name!r} handles planar contacts only; the system has spatial contacts: "
                         f"use one of {sorted(_cone_solvers())}")
    if not isinstance(name, (str, ConeSolver)):
        raise ValueError(f"solver {getattr(name, 'name', name)!r} handles planar contacts only; the system "
                         f"has spatial contacts: use one of {sorted(_cone_solvers())}")
    return make_cone_solver(name, **(options.solver_options or {}))


def _fallback_for(solver, k: int):
    """The other exact solver that retries a step on which ``solver`` failed (k active contacts)."""
    if getattr(solver, "spatial", False):  # a disk-law solver (lcp.cone_solvers, already loaded)
        from .cone_solvers import make_cone_solver

        return make_cone_solver("nsgs" if solver.name == "newton" else "newton")
    name = {"auto": "osqp", "enum": "lemke", "lemke": "enum" if k == 1 else "osqp",
            "osqp": "enum" if k == 1 else "lemke"}.get(solver.name, "lemke")
    return make_solver(name)


def _projector(system, options):
    """The position projection of this run, or None (see MoreauJeanOptions.projection)."""
    if options.projection is False or system.n_bilateral + system.n_contacts == 0:
        return None
    # constant kinematics: every constraint and gap is affine in q, which is exactly when
    # needs_projection says no (decided here without its symbolic Jacobians)
    if options.projection == "auto" and (system.kinematics_is_constant or not needs_projection(system)):
        return None
    return PositionProjection(system, options.projection_tol)


class _Activation:
    """The activation rule with its hysteresis (module docstring): which contacts enter a step."""

    def __init__(self, asm, m):
        self.m = m
        self.loaded = np.zeros(m, dtype=bool)
        self.all_loaded = False  # every contact loaded in the previous step: no impact possible
        self.all = np.arange(m)
        # rounding size of g(q) = g0 + H_N q: constant |H_N| and |g0| when the kinematics are
        self.absHN = abs(asm.H[:m]) if asm.matrices_constant else None
        self.absg0 = np.abs(asm.gap0) if asm.matrices_constant else None

    def __call__(self, q, gap, H, uN_minus, uN_free, h, th):
        a = (h * (1 - th)) * uN_minus
        pred = gap + a + (h * th) * uN_free
        # every gap closes: no tolerance needed (the common case in contact); a list's max is faster
        # than NumPy's reduction for the few contacts of a Python-loop system
        if (max(pred.tolist()) if self.m <= 16 else pred.max()) <= 0.0:
            return self.all
        b = (h * th) * uN_free
        if self.absHN is not None:
            size = self.absHN @ np.abs(q) + self.absg0
        else:
            size = np.abs(H[: self.m]) @ np.abs(q)
        size = size + np.abs(gap) + np.abs(a) + np.abs(b)
        closing = pred <= (CLOSE_ULPS * _EPS) * size
        if self.loaded.any():
            closing |= self.loaded & (gap + a <= (OPEN_ULPS * _EPS) * size)
        return np.flatnonzero(closing)


def moreau_jean(system, q0, v0, t_end: float, options: MoreauJeanOptions) -> SimulationResult:
    """Integrate with Moreau-Jean time stepping; see :func:`lcp.simulate` for the public entry point."""
    if not (isinstance(t_end, (int, float, np.floating)) and np.isfinite(t_end) and t_end > 0):
        raise ValueError(f"t_end must be finite and > 0, got {t_end!r}")
    q0, v0 = system.check_state(q0, v0)
    h, th = float(options.h), float(options.theta)
    spatial = system.is_spatial
    solver = _spatial_solver(options) if spatial else make_solver(options.solver, **(options.solver_options or {}))
    n_steps = int(np.ceil(t_end / h * (1 - 1e-12)))
    if n_steps > 2_000_000_000:
        raise ValueError(f"h = {h!r} needs {n_steps} steps to reach t_end = {t_end!r}: too many")
    every = int(options.save_every)
    try:
        asm = StepAssembly(system, h, th)
    except FloatingPointError as exc:
        raise ValueError(str(exc)) from exc
    proj = _projector(system, options)
    if options.fast and proj is None and solver.name in ("auto", "enum") and compiled.applicable(system):
        return _moreau_jean_compiled(asm, q0, v0, n_steps, every, solver.name)
    if options.fast and proj is None and not spatial and system.n_contacts >= 2 and system.is_constant:
        # imported here: numba loads only where the compiled loop may run
        from . import compiled_loop

        if compiled_loop.applicable(asm, solver, options):
            return compiled_loop.moreau_jean_loop(asm, q0, v0, n_steps, every, solver, options.fallback,
                                                  (CLOSE_ULPS, OPEN_ULPS), _fallback_for, _ambiguity_note)
    if n_steps // every > 50_000_000:
        raise ValueError(f"{n_steps // every} saved states would not fit in memory: raise save_every")
    m, n = system.n_contacts, system.n
    mu, e = system.mu, system.e
    names = [c.name for c in system.contacts]
    if spatial:  # the disk law: the cone problem, its tangent rows laid out contact by contact
        from .cone_problem import ConeContactProblem

        dims, toff = system.tangent_dims, system.tangent_offsets

    n_saved = n_steps // every
    Q = np.empty((n_saved + 1, n))
    V = np.empty((n_saved + 1, n))
    PN = np.zeros((n_saved, m))
    PT = np.zeros((n_saved, system.n_tangent))  # tangent components, contact by contact
    modes = np.full((n_saved, m), -1, dtype=np.int8)
    Q[0], V[0] = q0, v0
    stats = SolverStats()
    status, message = 0, STATUS_MESSAGES[0]
    q, v = q0.copy(), v0.copy()
    cq, cv = np.zeros(n), np.zeros(n)
    keyed = asm.matrices_constant  # constant W: solvers and this loop may cache per active set
    cache = {}
    fallbacks = {}
    first_fallback = None
    first_ambiguous = None
    approx = (0, "", 0.0)  # steps solved by an approximate solver: count, its message, worst residual
    activation = _Activation(asm, m)
    closed = np.zeros(m, dtype=bool)  # contacts closed in the step, held at g = 0 by the projection
    impacts = []
    worst = violation_function(system)(q0[None, :], np.zeros(1)) if proj is not None else 0.0
    k_done = 0
    for k in range(n_steps):
        tk = k * h
        try:
            dvf, SHt, W, gap, H = asm.at(tk, q, v)
            vfree = v + dvf
        except FloatingPointError as exc:
            status = -2
            message = f"{STATUS_MESSAGES[-2]} Step {k} (t = {tk:.10g}): {exc}."
            break
        if m:
            uN_minus = H[:m] @ v
            uN_free = H[:m] @ vfree
            active = activation(q, gap, H, uN_minus, uN_free, h, th)
        else:
            active = np.zeros(0, dtype=int)
        row = (k + 1) // every - 1 if (k + 1) % every == 0 else -1
        if active.size == 0:
            dv = dvf
            stats.free_steps += 1
            if m:
                activation.loaded[:] = False
                activation.all_loaded = False
                closed[:] = False
        else:
            key = active.tobytes()
            local = cache.get(key) if keyed else None
            if local is None:  # the active set's slices of the (constant) operators, built once
                ea = e[active]
                if spatial:
                    idx = system.contact_rows(active)
                    cols = np.concatenate([np.arange(toff[j], toff[j + 1]) for j in active.tolist()])
                    template = ConeContactProblem(W[np.ix_(idx, idx)], np.zeros(idx.size), mu[active], dims[active],
                                                  key=tuple(active) if keyed else None)
                else:
                    idx = np.concatenate([active, m + active])
                    cols = active
                    template = ContactProblem(W[np.ix_(idx, idx)], np.zeros(idx.size), mu[active],
                                              key=tuple(active) if keyed else None)
                local = (idx, H[idx], SHt[:, idx], ea if np.any(ea) else None, template, cols)
                if keyed:
                    cache[key] = local
            idx, Ha, SHta, ea, template, cols = local
            qa = Ha @ vfree
            if ea is not None:
                # Newton restitution u_N+ >= -e u_N- acts only on approaching contacts: with a
                # separating one (u_N- > 0) it would pull the body back and create energy
                shift = ea * np.minimum(uN_minus[active], 0.0)
                qa[: active.size] += shift
            pb = template.with_q(qa)
            sol = solver.solve(pb)
            stats.solver_calls += 1
            stats.iterations += sol.iterations
            stats.max_iterations = max(stats.max_iterations, sol.iterations)
            stats.qp_solves += sol.qp_solves
            if not sol.success and options.fallback and sol.status != -3:  # -3: forced solver does not apply
                fb = fallbacks.setdefault(active.size, _fallback_for(solver, active.size))
                if fb is not None:
                    sol2 = fb.solve(pb)
                    if sol2.success:
                        stats.fallbacks += 1
                        if first_fallback is None:
                            first_fallback = (k, tk, sol.message, fb.name)
                        sol = sol2
            if not sol.success:
                status = -1
                message = (f"{STATUS_MESSAGES[-1]} Step {k} (t = {tk:.10g}), solver '{solver.name}': "
                           f"{sol.message}")
                break
            if sol.message.startswith("fallback"):
                stats.fallbacks += 1
            if sol.ambiguous and first_ambiguous is None:
                first_ambiguous = (k, tk)
            stats.ambiguous_steps += int(sol.ambiguous)
            if sol.status > 0:  # an approximation (the faceted disk): said in the message, never silent
                approx = (approx[0] + 1, approx[1] or sol.message, max(approx[2], sol.residual))
            stats.max_residual = max(stats.max_residual, sol.residual)
            p = sol.p
            if spatial:
                # the branch refinement of the disk law (a stuck contact's velocity to the last bit):
                # done by the solver when it reports the modes of its refined impulse
                md = getattr(sol, "modes", None)
                if md is None:
                    p, md = pb.refine_modes(p)
                dv = dvf + SHta @ p
                if md.size and np.all(md == STICK):
                    # every contact stuck: one correction on the velocities themselves, as in the
                    # planar branch (the refinement above works on W p + q, whose rounding in the
                    # generalized velocities would leave a stuck body at 1e-19 m/s for some steps)
                    r = Ha @ (v + dv)
                    if ea is not None:
                        r[: active.size] += shift
                    dp = pb.solve_linear(pb.W, -r)
                    if dp is not None:
                        p = p + dp
                        dv = dv + SHta @ dp
            else:
                dv = dvf + SHta @ p
                md = pb.modes(p)
                # one refinement on the branch: with an ill-conditioned mass matrix the solve leaves
                # cond(W) eps in the velocities, which would let a stuck block creep and a pressed one sink
                r = Ha @ (v + dv)
                if ea is not None:
                    r[: active.size] += shift
                dp = pb.with_q(r).solve_branch(md)
                if dp is not None and math.isfinite(float(dp.sum())):
                    p = p + dp
                    dv = dv + SHta @ dp
            pa = p[: active.size]
            loaded = activation.loaded
            now = pa > 0
            if not activation.all_loaded:  # a contact that carried no load: perhaps an impact
                pTa = p[active.size:]
                if spatial:  # each contact's tangent components (one or two)
                    ends = np.cumsum(dims[active])
                    pTa = [pTa[b - d:b] if d == 2 else float(pTa[b - 1]) for b, d in zip(ends.tolist(),
                                                                                     dims[active].tolist())]
                _record_impacts(impacts, tk, h, active, pa, pTa, loaded, gap, uN_minus, uN_free, names)
            if active.size < m:
                loaded[:] = False
            loaded[active] = now
            activation.all_loaded = active.size == m and all(now.tolist())
            if proj is not None:  # closed in this step: loaded, and not bounced off (restitution)
                closed[:] = False
                closed[active] = (pa > 0) & ((e[active] == 0) | (uN_minus[active] >= 0))
            if row >= 0:
                PN[row, active] = pa
                PT[row, cols] = p[active.size:]
                modes[row, active] = md
            for code in md:
                stats.mode_counts[MODE_NAMES[int(code)]] += 1
        # compensated (Kahan) sums: over 1e6 steps plain sums would drift by rounding
        v_new, cv = kahan_add(v, dv, cv)
        q, cq = kahan_add(q, h * ((1 - th) * v + th * v_new), cq)
        v = v_new
        if not math.isfinite(float(q.sum()) + float(v.sum())):  # one test for both (NaN/inf propagate)
            status = -2
            message = f"{STATUS_MESSAGES[-2]} Step {k} (t = {tk:.10g})."
            break
        if proj is not None:
            q_proj, ok, iters, viol = proj.project(tk + h, q, closed)
            stats.projections += 1
            stats.projection_iterations += iters
            if not ok or not math.isfinite(viol):
                status = -5
                message = (f"{STATUS_MESSAGES[-5]} Step {k} (t = {tk + h:.10g}): constraint violation "
                           f"{viol:.3g} after {iters} Newton iterations (tolerance {proj.tol:g} relative).")
                break
            q, cq = q_proj, np.zeros(n)  # the projection is accurate to its tolerance: no compensation left
            worst = max(worst, viol)
        if row >= 0:
            Q[row + 1], V[row + 1] = q, v
        k_done = k + 1
    stats.steps = k_done
    if first_fallback is not None and status == 0:
        k, tk, why, name = first_fallback
        message += (f" {stats.fallbacks} step(s) were solved by the fallback solver '{name}', the first at "
                    f"step {k} (t = {tk:.10g}) after: {why}")
    if status == 0:
        message += _ambiguity_note(stats.ambiguous_steps, first_ambiguous)
    if approx[0]:
        message += (f" {approx[0]} step(s) were solved approximately, not by the Coulomb law itself "
                    f"({approx[1]}); worst disk-law residual {approx[2]:.3g}.")
    # never return a trajectory past an unreported failure: cut at the last good state
    last = k_done // every
    t = every * h * np.arange(last + 1)
    Qc = Q[:last + 1]
    violation = worst if proj is not None else _lazy_violation(system, Qc, t)
    return SimulationResult(t=t, q=Qc, v=V[:last + 1], p_N=PN[:last], p_T=PT[:last],
                            modes=ModeArray.of(modes[:last]), status=status, message=message, stats=stats,
                            method="moreau-jean", solver=solver.name, h=h, theta=th, impacts=impacts,
                            violation=violation)


def _lazy_violation(system, Q, t):
    """The worst constraint violation over the saved states, computed when first asked for."""
    return lambda: violation_function(system)(Q, t)


def _ambiguity_note(n, first) -> str:
    """The sentence of ``message`` on steps whose contact problem had several solutions."""
    if not n:
        return ""
    where = f", the first at step {first[0]} (t = {first[1]:.10g})" if first is not None else ""
    return (f" {n} step(s) had several solutions of the contact problem{where}; the solver's choice was "
            "taken (stats.ambiguous_steps).")


def _record_impacts(impacts, tk, h, active, pN, pT, loaded, gap, uN_minus, uN_free, names):
    """Append the impacts of this step (module docstring: Impacts) to ``impacts``."""
    um = uN_minus[active]
    hit = (pN > 0) & ~loaded[active] & (um < 0) & (-um > np.abs(uN_free[active] - um))
    for i in np.flatnonzero(hit):
        j = int(active[i])
        dt = min(h, max(0.0, float(gap[j]) / -float(um[i])))
        impacts.append(Impact(tk + dt, j, names[j], float(pN[i]),
                              pT[i].copy() if isinstance(pT[i], np.ndarray) else float(pT[i])))


def _impacts_compiled(asm, Q, V, PN, PT, h, name):
    """The impacts of a compiled single-contact run with every step saved (same rule as the loop)."""
    HN = asm.H[0]
    uN = V @ HN
    pN = PN[:, 0]
    prev = np.concatenate([[0.0], pN[:-1]])
    cand = np.flatnonzero((pN > 0) & (prev <= 0) & (uN[:-1] < 0))
    out = []
    for k in cand:
        dvf = asm.at(k * h, Q[k], V[k])[0]
        um = float(uN[k])
        if -um > abs(float(HN @ dvf)):
            gap = float(asm.gap0[0] + HN @ Q[k])
            out.append(Impact(float(k * h + min(h, max(0.0, gap / -um))), 0, name, float(pN[k]), float(PT[k, 0])))
    return out


def moreau_jean_from_model(model, q0, v0, t_end: float, options: MoreauJeanOptions) -> SimulationResult:
    """The compiled single-contact step run from a :class:`~lcp.constant_model.ConstantModel`: the
    numbers go straight into the compiled kernel (keyed by the number of coordinates only), so a
    new parameter set costs no CasADi work. Same result as :func:`moreau_jean` on the System."""
    from .constant_model import NumericAssembly

    h, th = float(options.h), float(options.theta)
    n_steps = int(np.ceil(t_end / h * (1 - 1e-12)))
    if n_steps > 2_000_000_000:
        raise ValueError(f"h = {h!r} needs {n_steps} steps to reach t_end = {t_end!r}: too many")
    solver = options.solver if isinstance(options.solver, str) else options.solver.name
    return _moreau_jean_compiled(NumericAssembly(model, h, th), q0, v0, n_steps, int(options.save_every), solver,
                                 contact_name=model.contact_names[0], violation=lambda Q, t: model.violation(Q))


def _moreau_jean_compiled(asm, q0, v0, n_steps, every, solver_name, contact_name=None,
                          violation=None) -> SimulationResult:
    """The compiled fast path; same result contract as the Python loop."""
    Q, V, PN, PT, md, counts, max_res, n_amb, done, fail = compiled.simulate_compiled(asm, q0, v0, n_steps, every)
    stats = SolverStats()
    stats.steps = done
    stats.free_steps = counts.pop("inactive")
    stats.mode_counts.update(counts)  # the compiled kernel counts the planar modes; "slide" stays 0
    stats.solver_calls = done - stats.free_steps
    stats.iterations = 4 * stats.solver_calls  # the four cases of the closed form
    stats.max_iterations = 4 if stats.solver_calls else 0
    stats.max_residual = max_res
    stats.ambiguous_steps = n_amb
    h = asm.h
    if fail is None:
        status, message = 0, STATUS_MESSAGES[0] + _ambiguity_note(n_amb, None)
    else:
        status = -1
        message = (f"{STATUS_MESSAGES[-1]} Step {fail} (t = {fail * h:.10g}), solver '{solver_name}' "
                   "(compiled): no case of the contact problem is admissible")
    md = np.where(md == -2, -1, md).astype(np.int8)
    t = every * h * np.arange(Q.shape[0])
    PN, PT = PN[:, None], PT[:, None]
    if contact_name is None:
        contact_name = asm.sys.contacts[0].name
    impacts = _impacts_compiled(asm, Q, V, PN, PT, h, contact_name) if every == 1 else None
    return SimulationResult(t=t, q=Q, v=V, p_N=PN, p_T=PT, modes=ModeArray.of(md[:, None]),
                            status=status, message=message, stats=stats, method="moreau-jean",
                            solver=f"{solver_name} (compiled)", h=h, theta=asm.theta, impacts=impacts,
                            violation=(_lazy_violation(asm.sys, Q, t) if violation is None
                                       else (lambda: violation(Q, t))))
