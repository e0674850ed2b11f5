"""Accumulations of impacts in the spatial event integrator (:mod:`lcp.events.spatial`).

A ball bouncing on a spatial contact (two tangent directions) has the same infinitely many impacts
before t_inf as on a planar one: they are watched and summed up as in
:mod:`lcp.events.accumulation` (its :class:`~lcp.events.accumulation.BounceSequence`, Aitken
extrapolation of the states, the tail's impulse by the momentum balance). The accumulation time
is in closed form, t_inf = t_k + Delta_k / (1 - e), when the flights between impacts have constant
accelerations (constant mass and kinematics, a force constant in t, q and v, no sliding contact in
the flight); otherwise Aitken's extrapolation of the impact times.

This module must not import :mod:`lcp.events.spatial` (which imports it), nor anything above
``lcp.events``.
"""
from __future__ import annotations

import numpy as np

from lcp.contact.problem import STICK
from lcp.events.accumulation import TailPhase, kinematic_accumulation, tail_impulse
from lcp.events.records import Accumulation, Event, Impulse

__all__ = ["watch_bounces"]


def _impacts_at(integ, t):
    """The contacts with an impact at time t (the last impulses recorded)."""
    at = set()
    for imp in reversed(integ.impulses):
        if imp.t != t:
            break
        if imp.kind == "impact":
            at.add(imp.contact)
    return tuple(sorted(at))


def watch_bounces(integ, t, q, v, P, idx, modes, flight):
    """After an impact at t ((q, v) its right limit; ``idx``/``modes`` the closed contacts and modes
    of the next phase; ``flight`` the phase that ended with the impact): record it, and when the
    impacts form an accumulation whose bounces are below the length tolerance, jump to its limit.
    Returns (t_inf, q_inf, v_inf, tail phase) or None."""
    at = _impacts_at(integ, t)
    seq = integ.bounces
    if not at:
        seq.reset()
        return None
    seq.push(t, at, q, v, (tuple(idx), tuple(modes)))
    if not seq.geometric():
        return None
    if integ.model.kinematic:
        return kinematic_accumulation(integ.notes, t)
    if integ.model.moving:
        # no jump on a moving obstacle (the series is a fixed obstacle's): resolved one by one, as
        # the planar integrator does (lcp.events.integrator.Integrator.watch_bounces)
        if not any("moving contact" in note for note in integ.notes):
            names = ", ".join(repr(integ.sys.contacts[j].name) for j in at)
            integ.notes.append(f"From t = {t:.10g} the impacts on the moving contact(s) {names} accumulate: "
                               "resolved impact by impact (no extrapolation to their limit).")
        return None
    return _sum_up(integ, t, q, v, P, at, idx, modes, flight)


def _flight_acceleration(flight):
    """The flight's acceleration at its end, and whether it was constant over the flight."""
    model, n, nq = flight.model, flight.model.n, flight.model.nq
    qdd = flight.evaluate(flight.t1, flight.y1)[0][nq:nq + n]
    constant = bool(model.constant and model.affine_force and not model.state_force and not flight.slide)
    return qdd, constant


def _sum_up(integ, t, q, v, P, at, idx, modes, flight):
    seq, model = integ.bounces, integ.model
    fr = model.frame(t, q, v)
    at_a = np.array(at, dtype=int)
    uN = fr.H[at_a] @ v
    times = [it[0] for it in seq.items]
    delta_next = (times[-1] - times[-2]) ** 2 / (times[-2] - times[-3])
    if float(np.max(np.abs(uN))) * delta_next / 4 > integ.gap_tol:
        return None  # bounces still visible: resolve them
    qdd, constant = _flight_acceleration(flight)
    closed_form = None
    if constant and at_a.size == 1:
        j = int(at_a[0])
        a = float(fr.H[j] @ qdd)
        if a < 0 < uN[0] and model.e[j] < 1:
            closed_form = (2.0 * float(uN[0]) / -a, float(model.e[j]))
    lim = seq.limit(closed_form)
    if lim is None or not lim[0] < integ.t_end:
        return None
    t_inf, q_inf, v_inf, method = lim
    contacts = sorted(set(at) | set(idx))
    stick = [c for c, md in zip(idx, modes) if md == STICK]
    q_inf, v_inf = integ.project(t_inf, q_inf, v_inf, contacts, contacts, stick)
    if min(model.gaps(q_inf).tolist()) < -integ.gap_tol:
        return None  # the extrapolation moved another body into a contact: no jump
    # the tail's impulse: normal rows of the impacting contacts, then their tangent rows
    trows = [model.trows[j] for j in at]
    rows = np.concatenate([at_a] + trows).astype(int)
    n, nb = model.n, model.nb
    G = (np.array(integ.sys.constraints_fn(t, q)[1], dtype=float).reshape(nb, n) if nb else np.zeros((0, n)))
    Pt = tail_impulse(fr.A, fr.H[rows], G, v_inf - v, qdd, t_inf - t)
    k, off = at_a.size, at_a.size
    PT = []
    for i, j in enumerate(at):
        d = trows[i].size
        pT = Pt[off:off + d]
        off += d
        PT.append(float(pT[0]) if d == 1 else pT.copy())
        integ.impulses.append(Impulse(float(t_inf), int(j), float(Pt[i]), PT[-1], "accumulation",
                                      "limit of an accumulation of impacts"))
    integ.events.append(Event(float(t_inf), "accumulation", int(at[0]) if k == 1 else -1))
    integ.accumulations.append(Accumulation(float(t_inf), tuple(int(j) for j in at), int(seq.count),
                                            float(seq.first), method, tuple(float(x) for x in Pt[:k]),
                                            tuple(PT)))
    tail = TailPhase(t, t_inf, q, q_inf, P, flight.names(), flight.full_modes, (), m=model.m)
    seq.reset()
    return t_inf, q_inf, v_inf, tail
