"""What a Moreau-Jean run reports besides its trajectory: impacts, notes, the result.

Holds the impact rule (:func:`record_impacts`, :func:`compiled_step_impacts`), the notes of a run
(:class:`RunNotes`: its counters, the first fallback and ambiguous step, approximate steps, and the
sentences they add to ``message``; :func:`ambiguity_note`) and the assembly of the
:class:`~lcp.result.SimulationResult` of the compiled single-contact path
(:func:`compiled_step_result`). Imports :mod:`lcp.result`, :mod:`lcp.contact.problem` and
:mod:`lcp.timestepping.projection` (the violation measure) only; never the step, the loops or
anything above :mod:`lcp.timestepping`.

Impacts
-------
A step counts as an impact on contact j (``result.impacts``) when j carried no load in the previous
step, receives p_N > 0, and approached with u_N- < 0 faster than the free motion's velocity change
over the step, |u_N-| > |u_N,free - u_N-| (a velocity jump rather than a smooth landing; for
h -> 0 the two separate). Its time is the estimated closing time t_k + min(h, g_j / |u_N-|).
"""
from __future__ import annotations

import math

import numpy as np

from lcp.contact.problem import ModeArray
from lcp.result import STATUS_MESSAGES, Impact, SimulationResult, SolverStats
from lcp.timestepping.projection import violation_function

__all__ = ["RunNotes", "ambiguity_note", "free_velocity_overflows", "lazy_violation", "loop_result", "nonfinite_message",
           "projection_failure", "record_impacts",
           "compiled_step_impacts",
           "compiled_step_result"]


class RunNotes:
    """The counters and notes of a Python-loop run, filled in step by step (the contact step and
    the loop write the attributes directly: no call per step for what is a counter)."""

    def __init__(self):
        self.stats = SolverStats()
        self.impacts = []
        self.first_fallback = None  # (step, time, why, fallback solver's name)
        self.first_ambiguous = None  # (step, time)
        self.approx = (0, "", 0.0)  # steps solved by an approximate solver: count, its message, worst residual

    def message(self, status: int, message: str) -> str:
        """``message`` with the notes of the run appended (fallbacks, ambiguity, approximations)."""
        stats = self.stats
        if self.first_fallback is not None and status == 0:
            k, tk, why, name = self.first_fallback
            message += (f" {stats.fallbacks} step(s) were solved by the fallback solver '{name}', the first at "
                        f"step {k} (t = {tk:.10g}) after: {why}")
        if status == 0:
            message += ambiguity_note(stats.ambiguous_steps, self.first_ambiguous)
        approx = self.approx
        if approx[0]:
            message += (f" {approx[0]} step(s) were solved approximately, not by the Coulomb law itself "
                        f"({approx[1]}); worst disk-law residual {approx[2]:.3g}.")
        return message


def lazy_violation(system, Q, t):
    """The worst constraint violation over the saved states, computed when first asked for."""
    return lambda: violation_function(system)(Q, t)


def ambiguity_note(n, first) -> str:
    """The sentence of ``message`` on steps whose contact problem had several solutions."""
    if not n:
        return ""
    where = f", the first at step {first[0]} (t = {first[1]:.10g})" if first is not None else ""
    return (f" {n} step(s) had several solutions of the contact problem{where}; the solver's choice was "
            "taken (stats.ambiguous_steps).")


def record_impacts(impacts, tk, h, active, pN, pT, loaded, gap, uN_minus, uN_free, names, dims=None):
    """Append the impacts of this step (module docstring: Impacts) to ``impacts``.

    ``pN`` and ``pT`` are the active contacts' impulses (``pT`` laid out contact by contact);
    ``dims`` the tangent dimensions of every contact for spatial contacts (None: planar).
    """
    if dims is not None:  # each contact's tangent components (one or two)
        ends = np.cumsum(dims[active])
        pT = [pT[b - d:b] if d == 2 else float(pT[b - 1]) for b, d in zip(ends.tolist(), dims[active].tolist())]
    um = uN_minus[active]
    hit = (pN > 0) & ~loaded[active] & (um < 0) & (-um > np.abs(uN_free[active] - um))
    for i in np.flatnonzero(hit):
        j = int(active[i])
        dt = min(h, max(0.0, float(gap[j]) / -float(um[i])))
        impacts.append(Impact(tk + dt, j, names[j], float(pN[i]),
                              pT[i].copy() if isinstance(pT[i], np.ndarray) else float(pT[i])))


def compiled_step_impacts(asm, Q, V, PN, PT, h, name):
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


def compiled_step_result(asm, raw, every, solver_name, contact_name=None, violation=None) -> SimulationResult:
    """The result of the compiled single-contact path from the kernel's output ``raw``
    (:func:`lcp.timestepping.compiled_step.simulate_compiled`); same contract as the Python loop's."""
    Q, V, PN, PT, md, counts, max_res, n_amb, done, fail, overflow = raw
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
        status, message = 0, STATUS_MESSAGES[0] + ambiguity_note(n_amb, None)
    elif overflow:  # as the Python loop: the state (or the step's free velocity) overflowed
        status, message = -2, nonfinite_message(fail, h)
    else:
        status = -1
        message = (f"{STATUS_MESSAGES[-1]} Step {fail} (t = {fail * h:.10g}), solver '{solver_name}' "
                   "(compiled): no case of the contact problem is admissible")
    md = np.where(md == -2, -1, md).astype(np.int8)
    t = every * h * np.arange(Q.shape[0])
    PN, PT = PN[:, None], PT[:, None]
    if contact_name is None:
        contact_name = asm.sys.contacts[0].name
    impacts = compiled_step_impacts(asm, Q, V, PN, PT, h, contact_name) if every == 1 else None
    return SimulationResult(t=t, q=Q, v=V, p_N=PN, p_T=PT, modes=ModeArray.of(md[:, None]),
                            status=status, message=message, stats=stats, method="moreau-jean",
                            solver=f"{solver_name} (compiled)", h=h, theta=asm.theta, impacts=impacts,
                            violation=(lazy_violation(asm.sys, Q, t) if violation is None
                                       else (lambda: violation(Q, t))))


def free_velocity_overflows(vfree) -> bool:
    """Whether a step's free velocity is not finite (a state or a force that overflowed): the step
    cannot end in a finite state, and every loop stops there with status -2
    (:func:`nonfinite_message`) instead of handing infinities to a contact solver. The sum is the
    quick test; a sum that overflows on finite entries is looked at entry by entry."""
    return not math.isfinite(float(vfree.sum())) and not np.isfinite(vfree).all()


def nonfinite_message(k: int, h: float) -> str:
    """The message of a run stopped at step k by a non-finite state (status -2)."""
    return f"{STATUS_MESSAGES[-2]} Step {k} (t = {k * h:.10g})."


def projection_failure(k: int, t: float, viol: float, iters: int, tol: float) -> str:
    """The message of a run stopped by a projection that did not converge (status -5)."""
    return (f"{STATUS_MESSAGES[-5]} Step {k} (t = {t:.10g}): constraint violation {viol:.3g} after {iters} "
            f"Newton iterations (tolerance {tol:g} relative).")


def loop_result(system, Q, V, PN, PT, modes, k_done: int, every: int, h: float, th: float, status: int,
                message: str, notes: RunNotes, solver_name: str, worst, measured: bool) -> SimulationResult:
    """The result of a Python loop over steps: cut at the last good state (never a trajectory past an
    unreported failure), the notes added to the message, the constraint violation as measured in
    the steps (``measured``) or from the saved states."""
    stats = notes.stats
    stats.steps = k_done
    message = notes.message(status, message)
    last = k_done // every
    t = every * h * np.arange(last + 1)
    Qc = Q[:last + 1]
    violation = worst if measured else lazy_violation(system, Qc, t)
    return SimulationResult(t=t, q=Qc, v=V[:last + 1], p_N=PN[:last], p_T=PT[:last],
                            modes=ModeArray.of(modes[:last]), status=status, message=message, stats=stats,
                            method="moreau-jean", solver=solver_name, h=h, theta=th, impacts=notes.impacts,
                            violation=violation)
