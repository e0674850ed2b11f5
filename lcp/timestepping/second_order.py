"""The order-two scheme (``scheme="order2"``): RATTLE where no contact acts, Moreau-Jean where one does.

Holds :func:`run_second_order`, a Python loop that takes each step by one of two one-step methods:

- **smooth steps** (no contact closes in the step, none carried a load in the previous one): a
  RATTLE step (:class:`~lcp.timestepping.rattle.RattleStep`: velocity Verlet with the bilateral
  constraints at the position level by SHAKE and at the velocity level by RATTLE), of order two
  for q-dependent mass matrices, velocity-dependent forces and nonlinear or rheonomic
  constraints, and symplectic for conservative systems with a constant mass matrix (no secular
  energy drift, the period of a pendulum to O(h^2));
- **contact steps** (a contact closes, or stays loaded by the activation rule): exactly the
  Moreau-Jean step of :mod:`lcp.timestepping.python_loop` (free velocity, activation, the one-step
  contact problem, impulses at the velocity level, restitution, Kahan sums, position projection).

The choice: a step first tries RATTLE unless a contact carried a load in the previous step; where
a contact's gap at RATTLE's end point closes (g_j(q1) <= CLOSE_ULPS eps s_j, the activation rule's
tolerance), the step is discarded and taken by Moreau-Jean from the same state, with those
contacts active besides the ones Moreau-Jean's own rule activates. A step after a loaded one asks
Moreau-Jean's rule first (its hysteresis keeps a resting contact active); where it activates
nothing, the step is a RATTLE step again. So impacts, sticking, sliding and restitution are
Moreau-Jean's, and a run whose contacts stay closed (Jean-Pratt, a sliding block) is Moreau-Jean's
run to the last bit; the scheme is of order two only on the stretches without active contacts (a
ball rolling on a curved floor stays of order one). Imports the step modules of
:mod:`lcp.timestepping` (as :mod:`~lcp.timestepping.python_loop` does), :mod:`lcp.contact` and
:mod:`lcp.result`; never the path choice or anything above :mod:`lcp.timestepping`.
"""
from __future__ import annotations

import math

import numpy as np

from lcp.contact.problem import MODE_NAMES
from lcp.result import STATUS_MESSAGES, SimulationResult
from lcp.timestepping.activation import CLOSE_ULPS, EPS, Activation
from lcp.timestepping.assembly import kahan_add
from lcp.timestepping.contact_step import ContactStep
from lcp.timestepping.outcome import RunNotes, loop_result, projection_failure, record_impacts
from lcp.timestepping.projection import violation_function
from lcp.timestepping.rattle import RattleStep

__all__ = ["SCHEMES", "run_second_order"]

#: the time-stepping schemes of MoreauJeanOptions.scheme
SCHEMES = ("moreau-jean", "order2")


def run_second_order(system, asm, q0, v0, h: float, th: float, n_steps: int, every: int, solver, fallback: bool,
                     proj, tol: float) -> SimulationResult:
    """The order-two scheme (module docstring); arguments as :func:`lcp.timestepping.python_loop.run_python_loop`,
    and ``tol`` the relative tolerance of SHAKE (``projection_tol``).

    The contact steps are theta-method steps with the run's ``theta`` (1/2 by default).
    """
    if getattr(system, "control_schedule", None) is not None:
        raise ValueError("scheme='order2' does not take a control schedule yet: use scheme='moreau-jean'")
    if n_steps // every > 50_000_000:
        raise ValueError(f"{n_steps // every} saved states would not fit in memory: raise save_every")
    m, n = system.n_contacts, system.n
    e = system.e
    names = [c.name for c in system.contacts]
    dims = system.tangent_dims if system.is_spatial else None
    rattle = RattleStep(system, tol)
    # |g_j(0)|: the constant term of a gap, whose rounding the closing test must allow for
    g0 = np.abs(system.gaps(np.zeros(n))) if m else np.zeros(0)

    n_saved = n_steps // every
    Q = np.empty((n_saved + 1, n))
    V = np.empty((n_saved + 1, n))
    PN = np.zeros((n_saved, m))
    PT = np.zeros((n_saved, system.n_tangent))
    modes = np.full((n_saved, m), -1, dtype=np.int8)
    Q[0], V[0] = q0, v0
    notes = RunNotes()
    stats, impacts = notes.stats, notes.impacts
    status, message = 0, STATUS_MESSAGES[0]
    q, v = q0.copy(), v0.copy()
    cq, cv = np.zeros(n), np.zeros(n)
    step = ContactStep(system, asm, solver, fallback, notes)
    activation = Activation(asm, m)
    closed = np.zeros(m, dtype=bool)
    if proj is not None:
        from lcp.model.start import system_length

        ell = system_length(system, q0)  # the system's length, part of the projection's tolerance
    viol_fn = violation_function(system)
    worst = viol_fn(q0[None, :], np.zeros(1)) if system.n_bilateral else 0.0
    k_done = 0
    for k in range(n_steps):
        tk = k * h
        row = (k + 1) // every - 1 if (k + 1) % every == 0 else -1
        data = None  # Moreau-Jean's step data, once computed
        forced = None  # contacts RATTLE's end point closed
        if m and activation.loaded.any():
            data = _mj_data(asm, tk, q, v, activation, h, th)
            if isinstance(data, str):
                status, message = -2, f"{STATUS_MESSAGES[-2]} Step {k} (t = {tk:.10g}): {data}."
                break
            if data[-1].size == 0:
                activation.release()
                closed[:] = False
                data = None
        if data is None:
            q1, v1, gap1, gsize1, ok, iters, viol = rattle(tk, q, v, h)
            stats.projection_iterations += iters
            if not ok:
                status = -5
                message = (f"{STATUS_MESSAGES[-5]} Step {k} (t = {tk + h:.10g}): SHAKE left a constraint "
                           f"violation {viol:.3g} after {iters} Newton iterations (tolerance {tol:g} relative).")
                break
            closing = gap1 <= (CLOSE_ULPS * EPS) * (gsize1 + g0) if m else None
            if m and closing.any():
                forced = np.flatnonzero(closing)
                data = _mj_data(asm, tk, q, v, activation, h, th)
                if isinstance(data, str):
                    status, message = -2, f"{STATUS_MESSAGES[-2]} Step {k} (t = {tk:.10g}): {data}."
                    break
            else:
                stats.free_steps += 1
                worst = max(worst, viol)
                q, v = q1, v1
                cq, cv = np.zeros(n), np.zeros(n)
        if data is not None:  # the Moreau-Jean step, as in the Python loop
            dvf, SHt, W, gap, H, uN_minus, uN_free, active = data
            if forced is not None:
                active = np.union1d(active, forced)
            vfree = v + dvf
            dv, p, md, cols, sol = step.solve(k, tk, active, v, vfree, dvf, SHt, W, H, uN_minus)
            if dv is None:
                status = -1
                message = (f"{STATUS_MESSAGES[-1]} Step {k} (t = {tk:.10g}), solver '{solver.name}': "
                           f"{sol.message}")
                break
            pa = p[: active.size]
            if not activation.all_loaded:
                record_impacts(impacts, tk, h, active, pa, p[active.size:], activation.loaded, gap, uN_minus,
                               uN_free, names, dims)
            activation.carried(active, pa)
            closed[:] = False
            closed[active] = (pa > 0) & ((e[active] == 0) | (uN_minus[active] >= 0))
            if row >= 0:
                PN[row, active] = pa
                PT[row, cols] = p[active.size:]
                modes[row, active] = md
            for code in md:
                stats.mode_counts[MODE_NAMES[int(code)]] += 1
            # compensated sums over a run of Moreau-Jean steps, as in the Python loop (a RATTLE step
            # or a projection restarts them)
            v_new, cv = kahan_add(v, dv, cv)
            q, cq = kahan_add(q, h * ((1 - th) * v + th * v_new), cq)
            v = v_new
            if proj is not None and math.isfinite(float(q.sum())):
                # as in the Python loop: a contact separating after the step is opening, neither held
                # nor pushed; closed in this step: loaded and not opening
                HN = H[:m]
                opening = HN @ v > (CLOSE_ULPS * EPS) * (np.abs(HN) @ np.abs(v))
                np.logical_and(closed, ~opening, out=closed)  # closed: loaded, not bounced (above)
                q_proj, ok, iters, viol = proj.project(tk + h, q, closed, opening, ell + h * np.abs(v))
                stats.projections += 1
                stats.projection_iterations += iters
                if not ok or not math.isfinite(viol):
                    status, message = -5, projection_failure(k, tk + h, viol, iters, proj.tol)
                    break
                q, cq = q_proj, np.zeros(n)
                worst = max(worst, viol)
        if not math.isfinite(float(q.sum()) + float(v.sum())):
            status = -2
            message = f"{STATUS_MESSAGES[-2]} Step {k} (t = {tk:.10g})."
            break
        if row >= 0:
            Q[row + 1], V[row + 1] = q, v
        k_done = k + 1
    # the violation: measured where every step was projected or SHAKE'n, else from the saved states
    return loop_result(system, Q, V, PN, PT, modes, k_done, every, h, th, status, message, notes, solver.name,
                       worst, bool(proj is not None or (system.n_bilateral and not m)))


def _mj_data(asm, tk, q, v, activation, h, th):
    """Moreau-Jean's step data and active set at (tk, q, v): (dv_free, S H', W, gaps, H, u_N-,
    u_N,free, active), or the error message of a singular iteration matrix."""
    try:
        dvf, SHt, W, gap, H = asm.at(tk, q, v)
    except FloatingPointError as exc:
        return str(exc)
    m = activation.m
    uN_minus = H[:m] @ v
    uN_free = H[:m] @ (v + dvf)
    active = activation(q, gap, H, uN_minus, uN_free, h, th)
    return dvf, SHt, W, gap, H, uN_minus, uN_free, active
