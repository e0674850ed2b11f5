"""The event method for systems with Newton-Euler kinematics (qdot = T(q) v) and no contacts.

Holds :func:`kinematic_event_driven`, which :func:`lcp.events.driver.event_driven` calls for a
System with ``kinematics`` (:mod:`lcp.model.kinematics`): a free rigid body, several of them, any
system whose velocities are not the rates of its coordinates. Without contacts or bilateral
constraints there is no event: the motion is one smooth phase,

    qdot = T(t, q^) v,    A(t, q) vdot = F(t, q, v),

with q^ the coordinates with their unit quaternions normalised, integrated by SciPy's explicit
Runge-Kutta stepper (``ode_method``, DOP853 by default; ``rtol``, ``atol`` of the options), a phase
between consecutive force breakpoints (``System.breakpoints``, seen from the left at a phase's end),
step by step: after every accepted step the unit quaternions are projected back onto the sphere (divided by
their norm) and the stepper continues from there; the output times are interpolated by the step's
dense output and projected the same way. Systems with kinematics and contacts or bilateral
constraints go to the event method's contact integrators instead (:mod:`lcp.events.integrator`,
:mod:`lcp.events.spatial`), whose phases use :func:`normalising_method` for the same projection.

Imports :mod:`lcp.events.options`, :mod:`lcp.events.records`, :mod:`lcp.model` and
:mod:`lcp.result`; never the contact phases of the event method, time stepping, scenes or sweeps.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from lcp.events.options import EVENT_STATUS_MESSAGES
from lcp.events.records import Phase, new_event_result
from lcp.model.kinematics import normalize_quaternions, normalized_expr
from lcp.model.start import consistent_start
from lcp.result import SolverStats

__all__ = ["kinematic_event_driven", "normalising_method"]

_NORMALISING: dict = {}


def normalising_method(system, method: str):
    """SciPy's stepper ``method`` (a name of ``solve_ivp``) as an OdeSolver class that divides the
    unit quaternions of y[:n_q] by their norms after every accepted step, for the event method's
    phases of a system with kinematics (their right-hand sides evaluate everything at the
    normalised quaternions, so the stepper's derivative at the step's end is unchanged). LSODA
    keeps its state in Fortran: it is returned as it is (the phase ends renormalise)."""
    starts = tuple(system.unit_quaternions)
    if not starts or method == "LSODA":
        return method
    key = (starts, method)
    cls = _NORMALISING.get(key)
    if cls is None:
        import scipy.integrate as si

        base = getattr(si, method)

        def _step_impl(self):
            ok, msg = base._step_impl(self)
            if ok:
                for i in starts:
                    p = self.y[i:i + 4]
                    p /= np.sqrt(p @ p)
            return ok, msg

        cls = _NORMALISING[key] = type(f"Normalising{method}", (base,), {"_step_impl": _step_impl})
    return cls


def _refuse(system) -> None:
    if system.n_contacts or system.n_bilateral:
        what = "contacts" if system.n_contacts else "bilateral constraints"
        raise ValueError(f"the event method handles systems with Newton-Euler kinematics (System(..., "
                         f"kinematics=T)) without contacts or bilateral constraints only; this one has {what}: "
                         "use method='moreau-jean'")


def _rhs(system):
    """y = (q, v) -> ydot, one CasADi Function with the quaternions of q normalised inside it (for T,
    A and F alike: a body's quaternion enters them through R(p), whose formula holds for unit
    quaternions only); A vdot = F solved symbolically (a few velocities) or by CasADi's LU."""
    t, q, v = system.t_sym, system.q_sym, system.v_sym
    qn = normalized_expr(system, q)
    A, F, qdot = (ca.substitute(x, q, qn) for x in (system.mass_expr, system.force_expr,
                                                    ca.mtimes(system.kinematics_expr, v)))
    n = system.n
    if n <= 30:  # a symbolic solve grows like n^3: a few bodies only
        fn = ca.Function("kinematic_rhs", [t, ca.vertcat(q, v)], [ca.vertcat(qdot, ca.solve(A, F))])

        def f(tt, y):
            return np.array(fn(tt, y), dtype=float).ravel()

        return f
    parts = ca.Function("kinematic_rhs_parts", [t, ca.vertcat(q, v)], [qdot, A, F])

    def f_large(tt, y):
        qd, Am, Fm = (np.array(x, dtype=float) for x in parts(tt, y))
        return np.concatenate([qd.ravel(), np.linalg.solve(Am.reshape(n, n), Fm.ravel())])

    return f_large


class _Segment:
    """One smooth phase [ta, tb] by a SciPy stepper, the quaternions normalised after every step."""

    def __init__(self, system, rhs, stepper_cls, ta, y0, tb, t_left, rtol, atol):
        self.system, self.nq = system, system.n_q
        self.rhs = (lambda t, y: rhs(min(t, t_left), y)) if t_left < np.inf else rhs
        self.stepper = stepper_cls(self.rhs, ta, y0, tb, rtol=rtol, atol=atol)
        self.steps, self.t, self.y = 0, ta, y0

    @property
    def nfev(self) -> int:
        return self.stepper.nfev

    def run(self, t_out, Y, k, method):
        """Step to tb, writing the output times it passes into Y from row k: (k, status, message)."""
        stepper, nq, system = self.stepper, self.nq, self.system
        while stepper.status == "running":
            msg = stepper.step()
            if stepper.status == "failed":
                return k, -2, f"{EVENT_STATUS_MESSAGES[-2]} {method} failed at t = {stepper.t:.10g}: {msg}."
            self.steps += 1
            t1 = stepper.t
            if k < t_out.size and t_out[k] <= t1:
                dense = stepper.dense_output()
                while k < t_out.size and t_out[k] <= t1:
                    Y[k] = stepper.y if t_out[k] == t1 else dense(t_out[k])
                    normalize_quaternions(system, Y[k, :nq])
                    k += 1
            # the accepted state projected back onto the sphere; the stepper's derivative follows it
            normalize_quaternions(system, stepper.y[:nq])
            stepper.f = self.rhs(t1, stepper.y)
            self.t, self.y = t1, stepper.y.copy()
            if not np.all(np.isfinite(stepper.y)):
                return k, -2, f"{EVENT_STATUS_MESSAGES[-2]} The state is not finite at t = {t1:.10g}."
        return k, 0, EVENT_STATUS_MESSAGES[0]


def kinematic_event_driven(system, q0, v0, t_end: float, opts, scene=None):
    """The event method on a system with kinematics and no contacts (module docstring).

    Returns
    -------
    EventResult
        One phase per interval between the force's breakpoints (each integrated by
        ``opts.ode_method``), no contact data (m = 0 columns).
    """
    _refuse(system)
    from scipy.integrate import RK23, RK45, DOP853

    steppers = {"DOP853": DOP853, "RK45": RK45, "RK23": RK23}
    if opts.ode_method not in steppers:
        raise ValueError(f"ode_method {opts.ode_method!r} is not available for systems with kinematics: "
                         f"use one of {sorted(steppers)}")
    q0, v0 = system.check_state(q0, v0)
    q0, v0, note = consistent_start(system, q0, v0)
    nq = system.n_q
    t_out = opts.output_times(t_end)
    y0 = np.concatenate([q0, v0])
    scale = np.concatenate([np.full(nq, max(1.0, float(np.max(np.abs(q0))))),
                            np.full(system.n, max(1.0, float(np.max(np.abs(v0)))) if system.n else 1.0)])
    rhs = _rhs(system)
    Y = np.empty((t_out.size, y0.size))
    k = 0
    while k < t_out.size and t_out[k] <= 0.0:
        Y[k] = y0
        k += 1
    status, message, steps, phases = 0, EVENT_STATUS_MESSAGES[0], 0, []
    # phases end at the forces' breakpoints (System.breakpoints: a control schedule's switches),
    # each seeing the forces' left limit at its end, as the event method's other phases do
    bps = [float(b) for b in system.breakpoints if 0.0 < b < t_end]
    ta, y = 0.0, y0
    for tb in bps + [t_end]:
        t_left = float(np.nextafter(tb, -np.inf)) if tb < t_end else np.inf
        seg = _Segment(system, rhs, steppers[opts.ode_method], ta, y, tb, t_left, opts.rtol, opts.atol * scale)
        k, status, message = seg.run(t_out, Y, k, opts.ode_method)
        steps += seg.steps
        phases.append(Phase(ta, seg.t, (), opts.ode_method, seg.nfev))
        if status < 0:
            break
        ta, y = tb, seg.y
    t_out, Y = t_out[:k], Y[:k]
    if note is not None:
        message = f"{message} {note}"
    if status < 0 and scene is not None:
        message = f"{message} (scene '{scene.name}')"
    stats = SolverStats()
    stats.steps = steps
    N = t_out.size
    empty = np.zeros((max(N - 1, 0), 0))
    return new_event_result(t=t_out, q=np.ascontiguousarray(Y[:, :nq]), v=np.ascontiguousarray(Y[:, nq:]),
                            p_N=empty, p_T=empty.copy(), modes=np.zeros((max(N - 1, 0), 0), dtype=np.int8),
                            status=status, message=message, stats=stats, method="event", solver="none",
                            t_events=[], force_N=np.zeros((N, 0)), force_T=np.zeros((N, 0)), events=[], impulses=[],
                            phases=phases,
                            impacts=[], accumulations=[], nonunique_forces=0)
