"""The compiled Moreau-Jean loop for general systems: generated C step data, a numba loop.

Systems whose operators change from step to step (a q-dependent mass matrix, curved gaps, moving
contacts, time-dependent forces, nonlinear bilateral constraints) run here instead of the Python
loop when ``fast`` is set: the step's data come from CasADi's C code of the one-step Function
(:mod:`lcp.timestepping.codegen`, compiled once per structure into the compiled-code cache), and
the steps run in one numba function (:mod:`lcp.timestepping.general_kernels`). Holds
:func:`applicable` (whether it runs a simulation, and why not) and :func:`run_general_loop` (the
run and its result, the result contract of :func:`lcp.timestepping.python_loop.run_python_loop`).
Imports the kernel, the code generator, the contact step, the activation constants and the outcome
of :mod:`lcp.timestepping`, and :mod:`lcp.result`; never the path choice
(:mod:`lcp.timestepping.moreau_jean`), the Python loop or anything above :mod:`lcp.timestepping`.

What runs compiled: the step data, the force check, the activation rule, free steps, one active
planar contact under ``"auto"``/``"enum"`` (closed form, modes, branch refinement), one active disk
contact under the disk law's ``"auto"``/``"local"`` (local solve, branch refinement, the stuck
correction), two to 40 active disk-law contacts under ``"auto"`` (NSGS, branch refinement, the
solver's acceptance test, the all-stick correction: :mod:`lcp.timestepping.multi_kernels`; the Python
loop's results to the solver's tolerance, counted in ``stats.kernel_multi_steps``), two to 40 active
planar contacts under ``"auto"`` or ``"nsgs"`` (and one under ``"nsgs"`` by name on a system without
bilateral constraints) (the Python solver's NSGS rounds and Newton, its tests,
modes and branch refinement: :mod:`lcp.timestepping.planar_multi_kernels`; the Python loop's bits where no
Newton iteration was needed, else to rounding; on constant matrices to rounding, the Python solver
warm-starting there (:func:`_planar_multi`); also counted in ``stats.kernel_multi_steps``; steps
handed back to Python are counted in ``stats.python_steps``), impacts, Kahan
sums, the position update of Newton-Euler kinematics qdot = T(q) v
(unit quaternions by the exponential map, as the Python loop), the position projection (its Newton update compiled from
:attr:`PositionProjection.function <lcp.timestepping.projection.PositionProjection>`, the
working-set rule in the kernel), saving. The other contact steps are solved by the Python loop's
own :class:`~lcp.timestepping.contact_step.ContactStep` on the step's data and handed back (same
solver objects, fallbacks and notes). The kernel's products are those NumPy computes, so the
results are the Python loop's (bit for bit on the tested scenes, to rounding at worst). Control
schedules run here: with B(t) each step's correction of the control's impulse is computed before
the run, with B(t, q) depending on q the kernel computes it each step from the control's compiled
C function (:mod:`lcp.timestepping.compiled_control`); either is added as S c_k (on constant
matrices, a drift F(t), a B(t) or spatial contacts: to rounding, :func:`applicable`). Not run here (the
Python loop then runs): a projection of moving contacts (the message says so), control schedules
with a constant planar drift and a constant B (the constant compiled loop runs those; where it
does not, the message says why), ``scheme="order2"``, systems without numba or without a
C compiler (a :class:`RuntimeWarning` names the compiler).
"""
from __future__ import annotations

import contextlib

import numpy as np

from lcp.contact.problem import MODE_NAMES
from lcp.numerics.jit import HAVE_NUMBA
from lcp.result import STATUS_MESSAGES, Impact
from lcp.timestepping.activation import CLOSE_ULPS, EPS, OPEN_ULPS
from lcp.timestepping.compiled_control import control_library, step_impulses
from lcp.timestepping.contact_step import ContactStep
from lcp.timestepping.force_check import ForceStepCheck, StepRejected, nonfinite_cause
from lcp.timestepping.general_kernels import (BAD_DATA, BUFFER_FULL, DONE, NEEDS_PYTHON, NONFINITE,
                                              PROJECTION_FAILED, REJECTED, run_general)
from lcp.timestepping.outcome import (RunNotes, free_velocity_overflows, loop_result, nonfinite_message,
                                      projection_failure, record_impacts)
from lcp.timestepping.projection import NEWTON_PER_EVAL, violation_function

__all__ = ["PROJECTION_NOTE", "applicable", "run_general_loop"]

#: appended to the message of a run that the compiled general loop could have run but for the projection
PROJECTION_NOTE = (" (Python loop: the compiled general loop does not project systems with moving contacts; "
                   "projection=False runs it)")

#: impacts held by the kernel between two flushes
_IMPACT_BUFFER = 4096


#: above this many velocities, a system with constant matrices (a force of t, a scheduled control)
#: runs the Python loop: it reuses the assembly's constant S, while this loop rebuilds the dense
#: n x n step data every step. Measured (block chains pushed by a force of t, 1e-3 s steps, one
#: run): n = 60: 93 against 456 us/step; n = 100: 676 against 608; n = 200: 2144 against 1762.
CONSTANT_MATRICES_MAX_N = 80

#: the note of a run that keeps the Python loop for that reason
LARGE_NOTE = (" (Python loop: constant matrices with more than {} velocities; it reuses their constant step "
              "matrix, faster than the compiled general loop's dense per-step data)")


def applicable(system, asm, proj) -> str | None:
    """None where the compiled general loop runs this simulation, else the reason it does not:
    a constant system (the constant paths serve it), numba missing, a control schedule on a
    constant planar drift with a constant B (``"control"``: the constant compiled loop's, or the
    Python loop's with a note), a position projection on moving contacts (``"projection"``: its
    opening test needs the contacts' rates at the projected state), constant matrices of more than
    :data:`CONSTANT_MATRICES_MAX_N` velocities (``"large"``: the Python loop is faster there).

    A control schedule on constant matrices otherwise (a drift F(t), a B(t), spatial contacts) runs
    here: the Python loop computes those steps by the assembly's S products (``StepAssembly.at``),
    this loop by the step Function's generated C code plus S c_k, the same equations in another
    rounding (measured: 4e-16 of max |q| and |v|, 7e-14 of the largest tangential impulse; as an
    uncontrolled F(t) on constant matrices). Where contacts are redundant (two pucks joined by a
    bar, both sticking along it) only the sum of their tangential impulses is determined: it
    agrees to rounding, their split is the solver's in both loops (tests/test_compiled_routes.py)."""
    if system.is_constant and not system.is_spatial:  # constant spatial systems reach here only where
        return "constant"                               # compiled_spatial does not take them
    if not HAVE_NUMBA:
        return "numba"
    if getattr(system, "is_controlled", False) or (asm.schedule is not None and asm.matrices_constant
                                                   and asm.control_matrix is not None and not system.is_spatial):
        return "control"
    if proj is not None and system.contacts_depend_on_t:
        return "projection"
    if getattr(asm, "matrices_constant", False) and system.n > CONSTANT_MATRICES_MAX_N:
        return "large"
    return None


def _control_q_free(system) -> bool:
    """Whether the control matrix B(t, q) of a scheduled control does not depend on q (then each
    step's control correction is computed before the run)."""
    fn = getattr(system, "control_matrix_fn", None)
    return fn is not None and fn.sparsity_jac(1, 0).nnz() == 0


def _control_rows(system, asm, q0, h, th, n_steps) -> np.ndarray:
    """Per step k the control correction c_k = B int u - h ((1 - theta) B u(t) + theta B u(t + h))
    at t = k h, with :meth:`StepAssembly._control_correction
    <lcp.timestepping.assembly.StepAssembly>`'s arithmetic (B independent of q: evaluated at q0);
    no rows without a schedule."""
    n = system.n
    if asm.schedule is None:
        return np.zeros((0, n))
    # the same elementwise operations on all steps at once (CasADi's map evaluates each column as
    # the single call); the products B_k u_k one by one, as the Python loop's
    t = np.arange(n_steps) * h
    Q = np.repeat(np.asarray(q0, dtype=float)[:, None], n_steps, axis=1)
    cf = system.control_force_fn.map(n_steps)
    seen = h * ((1 - th) * np.array(cf(t[None, :], Q), dtype=float).T
                + th * np.array(cf((t + h)[None, :], Q), dtype=float).T)
    Bs = np.array(system.control_matrix_fn.map(n_steps)(t[None, :], Q), dtype=float)
    Bs = np.ascontiguousarray(Bs.reshape(n, n_steps, -1).transpose(1, 0, 2))
    imp = asm.schedule.integral(t + h) - asm.schedule.integral(t)
    out = np.empty((n_steps, n))
    for k in range(n_steps):
        out[k] = Bs[k] @ imp[k] - seen[k]
    return out


def _closed_form(solver) -> bool:
    """Whether one active planar contact is solved by the closed form in the kernel: the plain
    ``"auto"`` or ``"enum"`` solver without an error target of its own."""
    from lcp.contact.solvers import AutoSolver, EnumSolver

    if type(solver) is AutoSolver:
        return solver.error_tol is None
    return type(solver) is EnumSolver and getattr(solver, "error_tol", None) is None


def _disk_local(solver) -> bool:
    """Whether one active disk contact is solved in the kernel: the plain ``"auto"`` disk-law solver
    or ``"local"`` with its polish (the local solve and branch refinement of both)."""
    from lcp.contact.spatial_solvers import ConeAutoSolver, LocalSolver

    return type(solver) is ConeAutoSolver or (type(solver) is LocalSolver and solver.polish)


def _cone_multi(solver) -> tuple[int, int]:
    """(largest number of active disk-law contacts solved in the kernel, NSGS sweeps): the plain
    ``"auto"`` disk-law solver's NSGS range (its compiled, polished NSGS without an error target
    of its own); (0, 0) for any other solver."""
    from lcp.contact.spatial_solvers import ConeAutoSolver

    if type(solver) is not ConeAutoSolver or solver.error_tol is not None:
        return 0, 0
    nsgs = solver.nsgs
    if not (nsgs.compiled and nsgs.polish) or nsgs.error_tol is not None or nsgs.residual_tol != solver.residual_tol:
        return 0, 0
    return int(solver.NSGS_MAX_CONTACTS), int(nsgs.max_sweeps)


#: the most active planar contacts one step solves in the kernel (planar_multi_kernels: dense 2k x 2k)
PLANAR_MULTI_MAX = 40


def _planar_multi(solver, asm) -> np.ndarray:
    """(largest number of active planar contacts solved in the kernel, NSGS sweeps, Newton iterations,
    rounds) of the plain ``"auto"`` solver (its NewtonSolver: compiled sweeps, no error target of its
    own, the same residual_tol) or ``"nsgs"`` (compiled, no error target: its sweeps, no Newton, one
    round); zeros otherwise.

    On constant matrices (a force of t, a control schedule) the Python solver warm-starts each
    problem from the last impulses of the same active set, the kernel starts from zero: the two
    solves differ within the solver's tolerance, and the branch refinement (the same in both) makes
    them exact on the branch, so the runs agree to rounding there, not bit for bit (measured on
    block chains of 3 to 30 blocks pushed by sin 3t: 1.2e-15 of max |v|, 6.7e-13 of the largest
    tangential impulse, the same modes; tests/test_compiled_routes.py)."""
    from lcp.contact.solvers import AutoSolver, NewtonSolver, NsgsSolver

    off = np.zeros(4, dtype=np.int64)
    if type(solver) is NsgsSolver:
        if not solver.compiled or solver.error_tol is not None:
            return off
        return np.array([PLANAR_MULTI_MAX, solver.max_sweeps, 0, 1], dtype=np.int64)
    if type(solver) is not AutoSolver or solver.error_tol is not None:
        return off
    it = solver.iterative
    if (type(it) is not NewtonSolver or not it.compiled or it.error_tol is not None
            or it.residual_tol != solver.residual_tol):
        return off
    return np.array([PLANAR_MULTI_MAX, it.sweeps, it.newton_iter, it.max_rounds], dtype=np.int64)


def run_general_loop(system, asm, lib, q0, v0, h: float, th: float, n_steps: int, every: int, solver,
                     fallback: bool, proj=None, plib=None, klib=None):
    """Moreau-Jean by the compiled general loop (module docstring); ``lib`` is the system's
    :class:`~lcp.timestepping.codegen.CompiledFunction` of the step, ``proj`` the run's
    :class:`~lcp.timestepping.projection.PositionProjection` or None and ``plib`` its compiled
    update, ``klib`` the compiled position increment of a system with kinematics qdot = T(q) v
    (:func:`lcp.timestepping.codegen.kinematics_library`; required for such a system). Same
    arguments and result as the Python loop."""
    if getattr(system, "has_kinematics", False) and klib is None:
        raise ValueError("a system with kinematics needs its compiled position increment (klib)")
    # a control whose B(t, q) depends on q: its C function, called by the kernel each step
    clib = control_library(system) if asm.schedule is not None and not _control_q_free(system) else None
    if clib is None and asm.schedule is not None and not _control_q_free(system):
        raise RuntimeError("the control B(t, q) of this system could not be compiled: run it with fast=False")
    with contextlib.ExitStack() as held:
        for found in (lib, plib, klib, clib):
            if found is not None:
                held.enter_context(found.lock)
        return _run(system, asm, lib, q0, v0, h, th, n_steps, every, solver, fallback, proj, plib, klib, clib)


def _run(system, asm, lib, q0, v0, h, th, n_steps, every, solver, fallback, proj, plib, klib, clib=None):
    """The body of :func:`run_general_loop`, its libraries' buffers held."""
    if n_steps // every > 50_000_000:
        raise ValueError(f"{n_steps // every} saved states would not fit in memory: raise save_every")
    m, n = system.n_contacts, system.n
    nq = lib.args[1].size
    names = [c.name for c in system.contacts]
    spatial = system.is_spatial
    dims = system.tangent_dims if spatial else None
    n_saved = n_steps // every
    Q = np.empty((n_saved + 1, nq))
    V = np.empty((n_saved + 1, n))
    PN = np.zeros((n_saved, m))
    PT = np.zeros((n_saved, system.n_tangent))
    modes = np.full((n_saved, m), -1, dtype=np.int8)
    Q[0], V[0] = q0, v0
    notes = RunNotes()
    stats = notes.stats
    status, message = 0, STATUS_MESSAGES[0]
    q, v = np.array(q0, dtype=float), np.array(v0, dtype=float)
    cq, cv = np.zeros(nq), np.zeros(n)
    loaded = np.zeros(m, dtype=np.bool_)
    istate = np.zeros(19, dtype=np.int64)
    fstate = np.zeros(3)
    lin = np.full(1 + nq + 2 * n + 2 * n * n, np.nan)
    imp_t, imp_j = np.zeros(_IMPACT_BUFFER), np.zeros(_IMPACT_BUFFER, dtype=np.int64)
    imp_p = np.zeros((_IMPACT_BUFFER, 3))
    dvf, vfree, uNm, uNf = np.zeros(n), np.zeros(n), np.zeros(m), np.zeros(m)
    act = np.zeros(max(m, 1), dtype=np.int64)
    fdv = np.zeros(n)
    o = lib.outs
    a_t, a_q, a_v, a_h, a_th = lib.args
    a_h[0], a_th[0] = h, th
    mu, e = np.asarray(system.mu, dtype=float), np.asarray(system.e, dtype=float)
    closed_form = (not spatial) and _closed_form(solver)
    disk_local = spatial and _disk_local(solver)
    cone_multi, max_sweeps = _cone_multi(solver) if spatial else (0, 0)
    planar_multi = np.zeros(4, dtype=np.int64) if spatial else _planar_multi(solver, asm)
    tdims = np.asarray(system.tangent_dims, dtype=np.int64)
    toff = np.asarray(system.tangent_offsets, dtype=np.int64)
    res_tol = float(getattr(solver, "residual_tol", 1e-10))
    step = ContactStep(system, asm, solver, fallback, notes)
    moving = system.contacts_depend_on_t
    project = proj is not None
    ploaded = np.zeros(m, dtype=np.bool_)
    worst = 0.0
    if project:
        from lcp.model.start import system_length

        ell = system_length(system, q0)
        worst = violation_function(system)(q0[None, :], np.zeros(1))
        pf = plib
        pargs = pf.args
        pouts = [pf.outs[k] for k in ("q_new", "r", "s", "pull")]
        ptol, max_evals = proj.tol, proj.max_evals
    else:  # placeholders of the kernel's arguments (never used)
        ell, pf, ptol, max_evals = 1.0, lib, 1.0, 0
        pargs = [np.zeros(1), np.zeros(nq), np.zeros(m), np.zeros(n)]
        pouts = [np.zeros(nq), np.zeros(1), np.zeros(1), np.zeros(1)]

    kin = klib is not None
    if kin:
        kargs, kf = klib.args, klib
        krate, kB = klib.outs["rate"], klib.outs["B"]
        quats = np.asarray(system.unit_quaternions, dtype=np.int64)
    else:  # placeholders of the kernel's arguments (never used)
        kargs, kf = [np.zeros(1), np.zeros(nq), np.zeros(n)], lib
        krate, kB, quats = np.zeros(nq), np.zeros(0), np.zeros(0, dtype=np.int64)

    def flush():
        c = int(istate[12])
        for i in range(c):
            j = int(imp_j[i])
            pT = imp_p[i, 1:3].copy() if tdims[j] == 2 else float(imp_p[i, 1])
            notes.impacts.append(Impact(float(imp_t[i]), j, names[j], float(imp_p[i, 0]), pT))
        istate[12] = 0

    ctrl = _control_rows(system, asm, q0, h, th, n_steps) if clib is None else np.zeros((0, n))
    cargs = () if clib is None else (clib.cfunc, clib.argp, clib.resp, clib.iw, clib.w, *clib.args[:2],
                                     clib.outs["B"], clib.outs["f0"], clib.outs["f1"],
                                     step_impulses(asm.schedule, h, n_steps))
    if clib is not None:
        clib.args[2][0] = h
    k, forced = 0, False
    while True:
        k, reason = run_general(lib.cfunc, lib.argp, lib.resp, lib.iw, lib.w, a_t, a_q, a_v, o["vfree"], o["S"],
                                o["SHt"], o["W"], o["gap"], o["H"], o["b0"], o["b1"], o["F0"], o["F1"], o["K1"],
                                o["C1"], kin, kf.cfunc, kf.argp, kf.resp, kf.iw, kf.w, *kargs, krate, kB, quats,
                                k, n_steps, every, h, th, CLOSE_ULPS * EPS, OPEN_ULPS * EPS,
                                res_tol, mu, e, tdims, toff, closed_form, disk_local, cone_multi, max_sweeps,
                                planar_multi, q, v, cq, cv, loaded, istate,
                                fstate, lin, Q, V, PN, PT, modes, imp_t, imp_j, imp_p, dvf, vfree, uNm, uNf, act,
                                forced, fdv, project, pf.cfunc, pf.argp, pf.resp, pf.iw, pf.w, *pargs, *pouts,
                                system.n_bilateral, ptol, max_evals, ell, ploaded, ctrl, *cargs)
        forced = False
        tk = k * h
        if reason == DONE:
            break
        if reason == BUFFER_FULL:
            flush()
            continue
        if reason == NONFINITE:
            status, message = -2, f"{STATUS_MESSAGES[-2]} Step {k} (t = {tk:.10g})."
            break
        if reason == BAD_DATA:
            S = lib.view("S")
            status = -2
            message = f"{STATUS_MESSAGES[-2]} Step {k} (t = {tk:.10g}): {nonfinite_cause(system, h, tk, q, v, S)}."
            break
        if reason == PROJECTION_FAILED:
            status = -5
            message = projection_failure(k, tk + h, float(fstate[2]), int(istate[17]) * NEWTON_PER_EVAL, ptol)
            break
        if reason == REJECTED:
            why = _rejection(system, h, lin, n, nq, tk, q, v)
            if why is None:  # NumPy's sums let the step pass: the kernel repeats it without the check
                istate[14] = 1
                continue
            status, message = -7, f"{STATUS_MESSAGES[-7]} Step {k} (t = {tk:.10g}): {why}."
            break
        assert reason == NEEDS_PYTHON
        if free_velocity_overflows(vfree):  # as the Python loop: no solver for infinities
            status, message = -2, nonfinite_message(k, h)
            break
        na = int(istate[13])
        stats.python_steps += 1
        active = act[:na].copy()
        b1 = o["b1"] if moving else None
        # C-ordered copies, as the Python loop's operators (NumPy's products round by layout)
        dv, p, md, cols, sol = step.solve(k, tk, active, v, vfree.copy(), dvf.copy(),
                                          np.ascontiguousarray(lib.view("SHt")), np.ascontiguousarray(lib.view("W")),
                                          np.ascontiguousarray(lib.view("H")), uNm.copy(), b1)
        if dv is None:
            status = -1
            message = f"{STATUS_MESSAGES[-1]} Step {k} (t = {tk:.10g}), solver '{solver.name}': {sol.message}"
            break
        pa = p[:na]
        if not istate[0]:  # a contact that carried no load: perhaps an impact
            flush()
            record_impacts(notes.impacts, tk, h, active, pa, p[na:], loaded, o["gap"], uNm, uNf, names, dims)
        now = pa > 0
        if na < m:
            loaded[:] = False
        loaded[active] = now
        istate[0] = int(na == m and bool(np.all(now)))
        if project:  # loaded in this step, and not bounced off (restitution)
            ploaded[:] = False
            ploaded[active] = now & ((e[active] == 0) | (uNm[active] >= 0))
        row = (k + 1) // every - 1 if (k + 1) % every == 0 else -1
        if row >= 0:
            PN[row, active] = pa
            PT[row, cols] = p[na:]
            modes[row, active] = md
        for code in md:
            stats.mode_counts[MODE_NAMES[int(code)]] += 1
        fdv[:] = dv
        forced = True
    flush()
    _merge_counters(notes, istate, fstate, h)
    notes.stats.projections += int(istate[15])
    notes.stats.projection_iterations += int(istate[16]) * NEWTON_PER_EVAL
    if project:
        worst = max(worst, float(fstate[1]))
    return loop_result(system, Q, V, PN, PT, modes, k, every, h, th, status, message, notes, solver.name, worst,
                       project)


def _rejection(system, h, lin, n, nq, tk, q, v) -> str | None:
    """The Python check's message for a step the kernel rejected, or None where it passes."""
    check = ForceStepCheck(system, h)
    b = 1 + nq + 2 * n
    check._linearised = (lin[0], lin[1:1 + nq].copy(), lin[1 + nq:1 + nq + n].copy(), lin[1 + nq + n:b].copy(),
                         lin[b:b + n * n].reshape(n, n).T.copy(), lin[b + n * n:].reshape(n, n).T.copy())
    try:
        check(tk, q, v)
    except StepRejected as exc:
        return str(exc)
    return None


def _merge_counters(notes, istate, fstate, h):
    """Add the kernel's counters to the run's (the steps the Python side solved wrote their own)."""
    stats = notes.stats
    stats.free_steps += int(istate[1])
    stats.solver_calls += int(istate[2])
    stats.iterations += int(istate[3])
    stats.max_iterations = max(stats.max_iterations, int(istate[4]))
    for code in range(5):
        if istate[5 + code]:
            stats.mode_counts[MODE_NAMES[code]] += int(istate[5 + code])
    stats.ambiguous_steps += int(istate[10])
    if istate[10] and (notes.first_ambiguous is None or notes.first_ambiguous[0] > istate[11]):
        notes.first_ambiguous = (int(istate[11]), int(istate[11]) * h)
    stats.max_residual = max(stats.max_residual, float(fstate[0]))
    stats.kernel_multi_steps += int(istate[18])
