"""Moreau-Jean time stepping (the theta-method with impulses), docs/numerical_methods.md.

Per step of size h:

    W_h (v+ - v-) = h F_theta + G' lambda + H' p,   G v+ + phi_t = 0,
    q+ = q- + h ((1 - theta) v- + theta v+),

with the iteration matrix W_h = A + h theta C + h^2 theta^2 K (K = -dF/dq, C = -dF/dv, so forces
that depend on the state are treated implicitly), and p the contact impulses of the active
contacts, which solve the discrete Coulomb problem :class:`~lcp.contact_problem.ContactProblem`.
"""
from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from . import compiled
from .assembly import StepAssembly, kahan_add
from .contact_problem import MODE_NAMES, ContactProblem
from .result import STATUS_MESSAGES, SimulationResult, SolverStats
from .solvers import SOLVERS, OneStepSolver, make_solver

__all__ = ["MoreauJeanOptions", "moreau_jean"]


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
    """

    h: float
    theta: float = 0.5
    solver: str = "auto"
    solver_options: dict | None = None
    fallback: bool = True
    save_every: int = 1
    fast: bool = True

    def __post_init__(self):
        h = self.h
        if not isinstance(h, (int, float, np.floating)) or not np.isfinite(h) or h <= 0:
            raise ValueError(f"h must be finite and > 0, got {h!r}")
        th = self.theta
        if not isinstance(th, (int, float, np.floating)) or not np.isfinite(th) or not 0.5 <= th <= 1.0:
            raise ValueError(f"theta must lie in [1/2, 1], got {th!r}")
        if not isinstance(self.save_every, (int, np.integer)) or self.save_every < 1:
            raise ValueError(f"save_every must be an integer >= 1, got {self.save_every!r}")
        if isinstance(self.solver, str) and self.solver not in SOLVERS:
            raise ValueError(f"unknown solver {self.solver!r}; known solvers: {sorted(SOLVERS)}")
        if not isinstance(self.solver, (str, OneStepSolver)):
            raise ValueError(f"solver must be a solver name or a OneStepSolver, got {self.solver!r}")
        if self.solver_options is not None and not isinstance(self.solver_options, dict):
            raise ValueError(f"solver_options must be a dict, got {self.solver_options!r}")


def _fallback_for(solver, k: int):
    """The other exact solver that retries a step on which ``solver`` failed (k active contacts)."""
    name = {"auto": "osqp", "enum": "lemke", "lemke": "enum" if k == 1 else "osqp",
            "osqp": "enum" if k == 1 else "lemke"}.get(solver.name, "lemke")
    return make_solver(name)


def moreau_jean(system, q0, v0, t_end: float, options: MoreauJeanOptions) -> SimulationResult:
    """Integrate with Moreau-Jean time stepping; see :func:`lcp.simulate` for the public entry point."""
    if not (isinstance(t_end, (int, float, np.floating)) and np.isfinite(t_end) and t_end > 0):
        raise ValueError(f"t_end must be finite and > 0, got {t_end!r}")
    q0, v0 = system.check_state(q0, v0)
    h, th = float(options.h), float(options.theta)
    solver = make_solver(options.solver, **(options.solver_options or {}))
    n_steps = int(np.ceil(t_end / h * (1 - 1e-12)))
    if n_steps > 2_000_000_000:
        raise ValueError(f"h = {h!r} needs {n_steps} steps to reach t_end = {t_end!r}: too many")
    every = int(options.save_every)
    try:
        asm = StepAssembly(system, h, th)
    except FloatingPointError as exc:
        raise ValueError(str(exc)) from exc
    if options.fast and solver.name in ("auto", "enum") and compiled.applicable(system):
        return _moreau_jean_compiled(asm, q0, v0, n_steps, every, solver.name)
    if n_steps // every > 50_000_000:
        raise ValueError(f"{n_steps // every} saved states would not fit in memory: raise save_every")
    m, n = system.n_contacts, system.n
    mu, e = system.mu, system.e

    n_saved = n_steps // every
    Q = np.empty((n_saved + 1, n))
    V = np.empty((n_saved + 1, n))
    PN = np.zeros((n_saved, m))
    PT = np.zeros((n_saved, m))
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
            # Active when the free motion closes the gap within this step. Unlike "gap <= 0", a
            # rounding residue (y = +1e-21 after a stop) cannot drop a loaded contact.
            gap_pred = gap + h * ((1 - th) * uN_minus + th * (H[:m] @ vfree))
            active = np.flatnonzero(gap_pred <= 0.0)
        else:
            active = np.zeros(0, dtype=int)
        row = (k + 1) // every - 1 if (k + 1) % every == 0 else -1
        if active.size == 0:
            dv = dvf
            stats.free_steps += 1
        else:
            key = active.tobytes()
            local = cache.get(key) if keyed else None
            if local is None:  # the active set's slices of the (constant) operators, built once
                idx = np.concatenate([active, m + active])
                ea = e[active]
                local = (idx, H[idx], SHt[:, idx], ea if np.any(ea) else None,
                         ContactProblem(W[np.ix_(idx, idx)], np.zeros(idx.size), mu[active],
                                        key=tuple(active) if keyed else None))
                if keyed:
                    cache[key] = local
            idx, Ha, SHta, ea, template = local
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
            stats.ambiguous_steps += int(sol.ambiguous)
            stats.max_residual = max(stats.max_residual, sol.residual)
            p = sol.p
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
            if row >= 0:
                PN[row, active] = p[: active.size]
                PT[row, active] = p[active.size:]
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
        if row >= 0:
            Q[row + 1], V[row + 1] = q, v
        k_done = k + 1
    stats.steps = k_done
    if first_fallback is not None and status == 0:
        k, tk, why, name = first_fallback
        message += (f" {stats.fallbacks} step(s) were solved by the fallback solver '{name}', the first at "
                    f"step {k} (t = {tk:.10g}) after: {why}")
    # never return a trajectory past an unreported failure: cut at the last good state
    last = k_done // every
    t = every * h * np.arange(last + 1)
    return SimulationResult(t=t, q=Q[:last + 1], v=V[:last + 1], p_N=PN[:last], p_T=PT[:last],
                            modes=modes[:last], status=status, message=message, stats=stats,
                            method="moreau-jean", solver=solver.name, h=h, theta=th)


def _moreau_jean_compiled(asm, q0, v0, n_steps, every, solver_name) -> SimulationResult:
    """The compiled fast path; same result contract as the Python loop."""
    Q, V, PN, PT, md, counts, max_res, n_amb, done, fail = compiled.simulate_compiled(asm, q0, v0, n_steps, every)
    stats = SolverStats()
    stats.steps = done
    stats.free_steps = counts.pop("inactive")
    stats.mode_counts = counts
    stats.solver_calls = done - stats.free_steps
    stats.iterations = 4 * stats.solver_calls  # the four cases of the closed form
    stats.max_iterations = 4 if stats.solver_calls else 0
    stats.max_residual = max_res
    stats.ambiguous_steps = n_amb
    h = asm.h
    if fail is None:
        status, message = 0, STATUS_MESSAGES[0]
    else:
        status = -1
        message = (f"{STATUS_MESSAGES[-1]} Step {fail} (t = {fail * h:.10g}), solver '{solver_name}' "
                   "(compiled): no case of the contact problem is admissible")
    md = np.where(md == -2, -1, md).astype(np.int8)
    t = every * h * np.arange(Q.shape[0])
    return SimulationResult(t=t, q=Q, v=V, p_N=PN[:, None], p_T=PT[:, None], modes=md[:, None],
                            status=status, message=message, stats=stats, method="moreau-jean",
                            solver=f"{solver_name} (compiled)", h=h, theta=asm.theta)
