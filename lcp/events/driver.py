"""The driver of the event-driven integrator: :func:`event_driven` and its output on a time grid."""
from __future__ import annotations

import math

import numpy as np

from lcp.events.integrator import Integrator
from lcp.events.model import check_state
from lcp.model.start import consistent_start
from lcp.events.options import EventOptions
from lcp.events.phases import closed_form_output
from lcp.events.records import EventResult

__all__ = ["event_driven"]


def _transposed(rows):
    """C-contiguous copy of rows.T (column by column when there are few: faster than NumPy's)."""
    k, N = rows.shape
    if k > 8:
        return np.ascontiguousarray(rows.T)
    out = np.empty((N, k))
    for i in range(k):
        out[:, i] = rows[i]
    return out


def event_driven(system, q0, v0, t_end: float, scene=None, **options) -> EventResult:
    """Integrate a :class:`~lcp.model.system.System` event by event, with exact mode switches.

    Usually called as ``lcp.simulate(scene, t_end, method="event", **options)``.

    Parameters
    ----------
    system : System
    q0, v0 : array_like, shapes (n_q,) and (n,)
        Initial state (consistent with the bilateral constraints, no penetration); n_q = n unless
        the System has Newton-Euler kinematics (qdot = T(q) v, :mod:`lcp.model.kinematics`).
    t_end : float
        Horizon, > 0.
    scene : Scene, optional
        Only used to name the scene in messages.
    **options
        See :class:`EventOptions` (``t_eval``, ``n_eval``, ``smooth``, ``ode_method``, ``rtol``,
        ``atol``, ``mode_solver``, ``impact_solver``, ``max_branches``, ``max_events``, ``tol``).

    Returns
    -------
    EventResult
        ``t`` (n_points,), ``q`` (n_points, n_q) and ``v`` (n_points, n) at the output times, impulses ``p_N``,
        ``p_T`` and ``modes`` (n_points - 1, m) per output interval, ``force_N`` and ``force_T``
        (n_points, m), ``t_events``, ``events``, ``impulses``, ``impacts``, ``accumulations``,
        ``phases`` (with the integrator of each), ``nonunique_forces``, ``mode_sequence``,
        ``status``, ``message``, ``success`` and ``stats``.

    Examples
    --------
    The Jean-Pratt block slides and sticks at tau0 = 0.152905... s (the exact solution,
    :mod:`lcp.scenes.jean_pratt_exact`):

    >>> import lcp
    >>> sc = lcp.scenes.jean_pratt()
    >>> res = lcp.simulate(sc, 0.3, method="event")
    >>> res.success, res.mode_sequence, res.integrators
    (True, [('slide+',), ('stick',)], ['closed-form'])
    >>> abs(res.t_events[0] - sc.tau0) < 1e-15
    True

    Past the shock limit (kappa = 1.25) the block stops by a tangential impact at t = 0:

    >>> res = lcp.simulate(lcp.scenes.jean_pratt(R=2.5), 0.3, method="event")
    >>> imp = res.impulses[0]
    >>> imp.t, round(imp.P_N, 12), round(imp.P_T, 12), res.mode_sequence
    (0.0, 1.0, -2.0, [('stick',)])

    A ball dropped from 1 m with restitution 0.8 bounces infinitely often before
    t_inf = sqrt(2/g) (1 + 2 e / (1 - e)) = 4.0637... s, then rests exactly on the floor:

    >>> import casadi as ca
    >>> from lcp.model.system import Contact, System
    >>> q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    >>> ball = System(q, v, mass=ca.SX.eye(2), force=ca.vertcat(0, -9.81),
    ...               contacts=[Contact(gap=q[1], tangent=q[0], mu=0.3, e=0.8, name="floor")])
    >>> res = event_driven(ball, [0.0, 1.0], [0.0, 0.0], 1e6, t_eval=[0.0, 10.0, 1e6])
    >>> acc = res.accumulations[0]
    >>> round(acc.t, 12), acc.method, acc.n_impacts == len(res.impacts), res.q[1:, 1].tolist()
    (4.063712768872, 'closed-form', True, [0.0, 0.0])
    """
    opts = EventOptions.from_kwargs(**options)
    if not (isinstance(t_end, (int, float, np.floating)) and math.isfinite(t_end) and t_end > 0):
        raise ValueError(f"t_end must be finite and > 0, got {t_end!r}")
    t_end = float(t_end)
    if getattr(system, "has_kinematics", False) and not (system.n_contacts or system.n_bilateral):
        # qdot = T(q) v and nothing to collide with: one smooth phase (lcp.events.kinematic_ode)
        from lcp.events.kinematic_ode import kinematic_event_driven

        return kinematic_event_driven(system, q0, v0, t_end, opts, scene)
    if getattr(system, "is_spatial", False):  # the Coulomb disk: its own integrator (lcp.events.spatial)
        from lcp.events.spatial import spatial_event_driven

        return spatial_event_driven(system, q0, v0, t_end, opts, frozenset(options), scene)
    q0, v0 = check_state(system, q0, v0)
    # the one check of a start for both methods (lcp.model.start): projected within its tolerance
    q0, v0, start_note = consistent_start(system, q0, v0)
    t_out = opts.output_times(t_end)
    try:
        integ = Integrator(system, q0, v0, t_end, opts)
        integ.model.state_checked = integ.model.constant  # the mass matrix is the same at every state
    except FloatingPointError as exc:  # the start itself: bad input, named
        raise ValueError(f"the initial state cannot be integrated: {exc}") from None
    phases, status, message, t_fail = integ.run(q0, v0)
    if start_note is not None:
        message = f"{message} {start_note}"
    n, m, nq = system.n, system.n_contacts, system.n_q  # n_q != n under Newton-Euler kinematics
    for note in integ.notes:
        message = f"{message} {note}"
    if integ.nonunique and not integ.choice_moves:
        message = (f"{message} Contact forces are not unique in {integ.nonunique} phase(s) (redundant "
                   "contacts): the least-norm admissible forces are reported; the motion is unique.")
    elif integ.nonunique:
        message = (f"{message} Contact forces are not unique in {integ.nonunique} phase(s) (redundant "
                   "contacts): the least-norm admissible forces are reported; in "
                   f"{integ.choice_moves} of them the friction of sliding contacts grows with the "
                   "squeeze between opposed contacts, which rigid contacts leave undetermined, so the "
                   "motion depends on this choice (the least squeeze, the least friction).")
    if status < 0:
        t_out = t_out[t_out <= t_fail]
        if scene is not None:
            message = f"{message} (scene '{scene.name}')"
    N_out = t_out.size
    # rows q (n_q), v (n), cumulative impulses (2m); one column per output time
    Y = np.empty((nq + n + 2 * m, N_out))
    FN = np.empty((N_out, m))
    FT = np.empty((N_out, m))
    MD = np.empty((N_out, m), dtype=np.int8)

    def blank(a, b):  # output times no phase covers: no state, no force, no mode
        Y[:nq + n, a:b] = np.nan
        Y[nq + n:, a:b] = 0.0
        FN[a:b] = FT[a:b] = 0.0
        MD[a:b] = -1

    # output times in [t0, t1) of each phase, [t0, t1] for the last (t_out is increasing)
    bounds = np.searchsorted(t_out, [ph.t0 for ph in phases] + [ph.t1 for ph in phases]).tolist()
    n_ph = len(phases)
    if n_ph and bounds[-1] < N_out and t_out[bounds[-1]] == phases[-1].t1:
        bounds[-1] += 1
    # the phases are consecutive in time: their output times are the columns [start, stop)
    start = bounds[0] if n_ph else 0
    stop = max(start, bounds[-1]) if n_ph else 0
    if start > 0:
        blank(0, start)
    if stop < N_out:
        blank(stop, N_out)
    spans = [(ph, a, b) for ph, a, b in zip(phases, bounds[:n_ph], bounds[n_ph:]) if a < b]
    if spans and integ.closed_form:
        ph_s = [ph for ph, _, _ in spans]
        closed_form_output(ph_s, t_out[start:stop], [b - a for _, a, b in spans], Y[:, start:stop])
        for ph, a, b in spans:
            FN[a:b], FT[a:b] = ph.N, ph.f
            MD[a:b] = ph.full_modes
    else:
        for ph, a, b in spans:
            FN[a:b], FT[a:b] = ph.output(t_out[a:b], Y[:, a:b])
            MD[a:b] = ph.full_modes
    # impulses over [t_i, t_{i+1}): the left-limit cumulative impulse, shocks at t_s < t included
    for imp in integ.impulses:
        after = int(np.searchsorted(t_out, imp.t, "right"))  # t_out > imp.t
        Y[nq + n + imp.contact, after:] += imp.P_N
        Y[nq + n + m + imp.contact, after:] += imp.P_T
    if m and N_out:
        # no silent success: a reported normal force that pulls (redundant contacts whose force
        # polytope the phase left without its event, say) is named in the message
        worst = int(np.argmin(FN.min(axis=1)))
        j_w = int(np.argmin(FN[worst]))
        if FN[worst, j_w] < -1e-9 * float(np.max(np.abs(FN))):
            message = (f"{message} At t = {t_out[worst]:.10g} the normal force of contact "
                       f"{system.contacts[j_w].name!r} is {FN[worst, j_w]:.3g} < 0: the reported forces "
                       "there violate the contact law.")
    Q, V = _transposed(Y[:nq]), _transposed(Y[nq:nq + n])
    Pc = Y[nq + n:]
    dP = (Pc[:, 1:] - Pc[:, :-1]).T  # np.diff
    integ.stats.steps = len(phases)
    used = sorted(integ.selector.used)
    return EventResult(t=t_out, q=Q, v=V, p_N=dP[:, :m], p_T=dP[:, m:], modes=MD[:-1] if t_out.size else MD,
                       status=status, message=message, stats=integ.stats, method="event",
                       solver="+".join(used) if used else "none",
                       t_events=[ev.t for ev in integ.events], force_N=FN, force_T=FT,
                       events=integ.events, impulses=integ.impulses,
                       phases=integ.phases, impacts=integ.impact_list, accumulations=integ.accumulations,
                       nonunique_forces=integ.nonunique)
