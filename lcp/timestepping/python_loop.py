"""The Python loop of Moreau-Jean: every step in Python, for any system the compiled paths skip.

Holds :func:`run_python_loop`: per step, the assembly's operators (:meth:`StepAssembly.at
<lcp.timestepping.assembly.StepAssembly.at>`), the active set (:class:`~lcp.timestepping.activation.Activation`),
the contact solve (:class:`~lcp.timestepping.contact_step.ContactStep`), the impacts
(:func:`~lcp.timestepping.outcome.record_impacts`), the compensated (Kahan) sums of v and q, the position
projection (:mod:`lcp.timestepping.projection`) and the saved states; then the result. Imports the
step's modules of :mod:`lcp.timestepping`, :mod:`lcp.contact` and :mod:`lcp.result`; never the
path choice (:mod:`lcp.timestepping.moreau_jean`), the compiled paths or anything above
:mod:`lcp.timestepping`.
"""
from __future__ import annotations

import math

import numpy as np

from lcp.contact.problem import MODE_NAMES
from lcp.result import STATUS_MESSAGES, SimulationResult
from lcp.timestepping.activation import CLOSE_ULPS, EPS, Activation
from lcp.timestepping.assembly import kahan_add
from lcp.timestepping.force_check import StepRejected
from lcp.timestepping.contact_step import ContactStep
from lcp.timestepping.outcome import (RunNotes, free_velocity_overflows, loop_result, nonfinite_message,
                                      projection_failure, record_impacts)
from lcp.timestepping.projection import violation_function

__all__ = ["run_python_loop"]


def run_python_loop(system, asm, q0, v0, h: float, th: float, n_steps: int, every: int, solver, fallback: bool,
                    proj) -> SimulationResult:
    """Moreau-Jean by the Python loop (module docstring).

    Parameters
    ----------
    system : lcp.model.system.System
    asm : lcp.timestepping.assembly.StepAssembly
        The run's assembly.
    q0, v0 : ndarray
        Checked initial state.
    h, th : float
        Step size and theta.
    n_steps, every : int
        Number of steps, and the saving period (``save_every``).
    solver : OneStepSolver or ConeSolver
    fallback : bool
        MoreauJeanOptions.fallback.
    proj : lcp.timestepping.projection.PositionProjection or None
        The position projection after each step, if any.
    """
    if n_steps // every > 50_000_000:
        raise ValueError(f"{n_steps // every} saved states would not fit in memory: raise save_every")
    m, n = system.n_contacts, system.n
    nq = getattr(system, "n_q", n)
    # Newton-Euler kinematics: q+ = q + h T(q) v_theta, unit quaternions by the exponential map
    # (lcp.model.kinematics.advance_positions)
    advance = None
    if getattr(system, "has_kinematics", False):
        from lcp.model.kinematics import advance_positions as advance
    e = system.e
    names = [c.name for c in system.contacts]
    dims = system.tangent_dims if system.is_spatial else None

    n_saved = n_steps // every
    Q = np.empty((n_saved + 1, nq))
    V = np.empty((n_saved + 1, n))
    PN = np.zeros((n_saved, m))
    PT = np.zeros((n_saved, system.n_tangent))  # tangent components, contact by contact
    modes = np.full((n_saved, m), -1, dtype=np.int8)
    Q[0], V[0] = q0, v0
    notes = RunNotes()
    stats, impacts = notes.stats, notes.impacts
    status, message = 0, STATUS_MESSAGES[0]
    q, v = q0.copy(), v0.copy()
    cq, cv = np.zeros(nq), np.zeros(n)
    step = ContactStep(system, asm, solver, fallback, notes)
    activation = Activation(asm, m)
    closed = np.zeros(m, dtype=bool)  # contacts closed in the step, held at g = 0 by the projection
    loaded = np.zeros(m, dtype=bool)  # loaded in the step and not bounced off (restitution)
    if proj is not None:
        from lcp.model.start import system_length

        ell = system_length(system, q0)  # the system's length, part of the projection's tolerance
    moving = system.contacts_depend_on_t  # gaps or tangents of t: u = H v + b (lcp.model.system)
    b1 = None
    worst = violation_function(system)(q0[None, :], np.zeros(1)) if proj is not None else 0.0
    k_done = 0
    for k in range(n_steps):
        tk = k * h
        try:
            dvf, SHt, W, gap, H = asm.at(tk, q, v)
            vfree = v + dvf
        except FloatingPointError as exc:
            status = -7 if isinstance(exc, StepRejected) else -2
            message = f"{STATUS_MESSAGES[status]} Step {k} (t = {tk:.10g}): {exc}."
            break
        if moving:
            # moving contacts: u = H v + b(t, q); b at the step's start for u-, at its end for the
            # free (and the unknown) velocity u+, as u+ is the end-of-step velocity
            b1 = system.contact_rates(q, tk + h)
            uN_minus = H[:m] @ v + system.contact_rates(q, tk)[:m]
            uN_free = H[:m] @ vfree + b1[:m]
            active = activation(q, gap, H, uN_minus, uN_free, h, th)
        elif m:
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
                activation.release()
                loaded[:] = False
        else:
            if free_velocity_overflows(vfree):
                status, message = -2, nonfinite_message(k, h)
                break
            dv, p, md, cols, sol = step.solve(k, tk, active, v, vfree, dvf, SHt, W, H, uN_minus, b1)
            if dv is None:
                status = -1
                message = (f"{STATUS_MESSAGES[-1]} Step {k} (t = {tk:.10g}), solver '{solver.name}': "
                           f"{sol.message}")
                break
            pa = p[: active.size]
            if not activation.all_loaded:  # a contact that carried no load: perhaps an impact
                record_impacts(impacts, tk, h, active, pa, p[active.size:], activation.loaded, gap, uN_minus,
                               uN_free, names, dims)
            activation.carried(active, pa)
            if proj is not None:  # loaded in this step, and not bounced off (restitution)
                loaded[:] = False
                loaded[active] = (pa > 0) & ((e[active] == 0) | (uN_minus[active] >= 0))
            if row >= 0:
                PN[row, active] = pa
                PT[row, cols] = p[active.size:]
                modes[row, active] = md
            for code in md:
                stats.mode_counts[MODE_NAMES[int(code)]] += 1
        # compensated (Kahan) sums: over 1e6 steps plain sums would drift by rounding
        v_new, cv = kahan_add(v, dv, cv)
        if advance is None:
            q, cq = kahan_add(q, h * ((1 - th) * v + th * v_new), cq)
        else:
            q, cq = advance(system, tk, q, (1 - th) * v + th * v_new, h, cq)
        v = v_new
        # one test for both (NaN/inf propagate); a sum that overflows on finite entries is looked at
        # entry by entry (as the compiled loops test)
        if not math.isfinite(float(q.sum()) + float(v.sum())) and not (np.isfinite(q).all() and np.isfinite(v).all()):
            status = -2
            message = f"{STATUS_MESSAGES[-2]} Step {k} (t = {tk:.10g})."
            break
        if proj is not None:
            # a contact whose normal velocity separates after the step (beyond rounding) is opening:
            # the projection neither holds it nor pushes it (its motion opens it); closed in this
            # step: loaded and not opening
            if m:
                HN = H[:m]
                uN = HN @ v + system.contact_rates(q, tk + h)[:m] if moving else HN @ v
                opening = uN > (CLOSE_ULPS * EPS) * (np.abs(HN) @ np.abs(v))
                np.logical_and(loaded, ~opening, out=closed)
            else:
                opening = None
            reach = ell + h * np.abs(v) if advance is None else ell + h * float(np.max(np.abs(v)))  # n_q != n_v
            q_proj, ok, iters, viol = proj.project(tk + h, q, closed, opening, reach)
            stats.projections += 1
            stats.projection_iterations += iters
            if not ok or not math.isfinite(viol):
                status, message = -5, projection_failure(k, tk + h, viol, iters, proj.tol)
                break
            q, cq = q_proj, np.zeros(nq)  # the projection is accurate to its tolerance: no compensation left
            worst = max(worst, viol)
        if row >= 0:
            Q[row + 1], V[row + 1] = q, v
        k_done = k + 1
    return loop_result(system, Q, V, PN, PT, modes, k_done, every, h, th, status, message, notes, solver.name,
                       worst, proj is not None)
