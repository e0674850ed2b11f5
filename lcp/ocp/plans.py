"""The phase sequences the exact-phase shooting solves on (:mod:`lcp.ocp.shooting`).

A plan lists, for each control interval, its segments ``(modes, duration, impacts)``: the contact
modes of one smooth phase (one code per contact), its length (the segments of an interval sum to
the interval's length), and the impacts at its start as ``(contact, tangential mode, P_N, P_T)``.
Plans come from four places:

- :func:`phase_plan`: the phases the event method finds when it replays a solution's control;
- :func:`plan_of_modes`: a solution's own mode in each interval (a switch at a node may move into
  the interval);
- :func:`hybrid_plan`: the replay's phases where the replay still follows a solution, the
  solution's own plan where the replay has left it;
- :func:`pruned_plan`: a plan without the segments that an NLP's iterate shrank to zero length.
  A phase the optimum does not have can only shrink to zero in the shooting; once it has, its
  check points coincide, its conditions repeat each other, and IPOPT's multipliers grow without
  bound: the NLP is solved again on the plan without it, its impacts moved to the next segment.

:func:`plan_keys` picks the independent rows of each segment's modes along a plan.

Imports NumPy, the contact mode codes, the phase dynamics and the event replay; it must not import
the shooting, the solve or the problem (they call it).
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from lcp.contact.modes import OPEN, SLIDE_NEG, SLIDE_POS, STICK
from lcp.ocp.phase_dynamics import (
    CHECK_TOL,
    NotShootable,
    impact_rows,
    impulse_dv,
    independent_rows,
    mode_dynamics,
    segment_integrator,
)
from lcp.ocp.options import START_RHS
from lcp.ocp.replay import event_pieces, piece_nodes

__all__ = ["MODE_CODES", "PRUNE_TOL", "check_plan", "hybrid_plan", "iterate_of", "phase_plan", "plan_keys",
           "plan_of_modes", "pruned_plan", "pruned_start"]

#: the event method's mode names -> codes
MODE_CODES = {"open": OPEN, "stick": STICK, "slide+": SLIDE_POS, "slide-": SLIDE_NEG}


def phase_plan(result):
    """The phase sequence of the event replay of a solution's control: for each control interval
    a list of segments (modes, duration, impacts), modes a tuple of codes (one per contact),
    durations summing to the interval's length, impacts the impacts at the segment's start as
    (contact, tangential mode, P_N, P_T) (the replay's impulses: the start of the shooting).
    Raises :class:`~lcp.ocp.phase_dynamics.NotShootable` on other impulses (the Painleve fallback,
    accumulations) and on a contact that closes without an impact."""
    rc = getattr(result, "replay", None)
    pieces = rc.pieces if rc is not None and rc.pieces and len(rc.pieces) == len(result.t) - 1 else None
    if pieces is None:  # (the replay check keeps its pieces: they are reused)
        # one integration (not restarted at the nodes, which would integrate a force of t from
        # t = 0 in every interval: the check has no pieces exactly when it replayed such a force
        # by Moreau-Jean)
        pieces = event_pieces(result, n_eval=2, rhs=START_RHS)[2]
    mu = np.asarray(result.problem.system.mu, dtype=float)
    plan, carried = [], []
    for k, sim in enumerate(pieces):
        h = float(result.t[k + 1] - result.t[k])
        hits = carried
        carried = []
        for imp in sim.impulses:
            if imp.kind != "impact":
                raise NotShootable(f"the replay has an impulse ({imp.kind}) on contact {imp.contact} at "
                                   f"t = {result.t[k] + imp.t:.6g}: only impacts are modelled")
            pT, pN, j = float(imp.P_T), float(imp.P_N), int(imp.contact)
            if mu[j] == 0.0:  # frictionless: no tangential impulse, whatever the direction
                tmode = OPEN
            else:
                tmode = STICK if abs(pT) < mu[j] * pN * (1 - 1e-6) else (SLIDE_POS if pT < 0 else SLIDE_NEG)
            if imp.t >= h * (1 - 1e-12):  # at the interval's end: the next interval's start
                carried.append((0.0, (j, tmode, pN, pT)))
            else:
                hits.append((float(imp.t), (j, tmode, pN, pT)))
        segs = []
        for ph in sim.phases:
            dur = float(ph.t1 - ph.t0)
            modes = tuple(MODE_CODES[nm] for nm in ph.modes)
            if dur <= 0.0:
                continue
            at = tuple(hit for t_i, hit in hits if abs(t_i - ph.t0) <= 1e-9 * h)
            if segs and segs[-1][0] == modes and not at:
                segs[-1] = (modes, segs[-1][1] + dur, segs[-1][2])
            else:
                segs.append((modes, dur, at))
        placed = sum(len(sg[2]) for sg in segs)
        if placed != len(hits):
            raise NotShootable(f"an impact in interval {k} (t = {result.t[k]:.6g}) does not start a smooth phase")
        if not segs:
            raise NotShootable(f"the replay of interval {k} has no smooth phase")
        total = sum(sg[1] for sg in segs)
        plan.append([(md, d * h / total, at) for md, d, at in segs])  # round-off in the phase times
    check_plan(plan, result.t)
    return plan


def hybrid_plan(result, own, near: float):
    """The phases of the event replay of ``result``'s control in every interval whose two nodes the
    replay meets within ``near``, ``own`` (the plan ``result`` was solved on) elsewhere; None where
    that is ``own`` again. A trajectory whose replay leaves it late (an unstable one, or a mode
    that the replay takes between the shooting's check points) keeps its own phases where the
    replay has gone elsewhere, and takes the replay's where the replay still follows it: on the
    cart-pole at N = 40 the replay stuck for 14 ms in a step the shooting slid through (its velocity
    touched zero between two check points), then missed by 5.1 at the end; on the hybrid plan the
    shooting swung up at cost 621.81, its joins 3.6e-12."""
    rp = phase_plan(result)
    q, v = piece_nodes(result.replay.pieces)
    err = np.maximum(np.max(np.abs(q - result.q), axis=1), np.max(np.abs(v - result.v), axis=1))
    plan = [rp[k] if max(err[k], err[k + 1]) <= near else list(own[k]) for k in range(len(own))]
    # the same NLP again where every interval has own's modes in the same order and no impacts
    # (the durations are variables: they start elsewhere, but the solve would repeat the last one)
    if all([md for md, _, _ in a] == [md for md, _, _ in b] and not any(at for _, _, at in a + b)
           for a, b in zip(plan, own)):
        return None
    check_plan(plan, result.t)
    return plan


def check_plan(plan, t) -> None:
    """NotShootable where a contact of ``plan`` closes without an impact (t: the node times)."""
    previous = None
    for k, segs in enumerate(plan):
        for md, _, at in segs:
            if previous is not None:
                hit = {i[0] for i in at}
                for j, (a, b) in enumerate(zip(previous, md)):
                    if a == OPEN and b != OPEN and j not in hit:
                        raise NotShootable(f"contact {j} closes without an impact in interval {k} (t = "
                                           f"{t[k]:.6g} to {t[k + 1]:.6g})")
            previous = md


#: a segment shorter than this fraction of its interval, in the last iterate of an NLP that IPOPT
#: could not solve, is a phase the optimum does not have: the NLP is solved again without it
PRUNE_TOL = 1e-6


def pruned_plan(tr, x):
    """The plan of ``tr`` without the segments that the iterate ``x`` shrinks below
    :data:`PRUNE_TOL` of their interval, their impacts moved to the next segment's start, the
    durations and impulses those of ``x``; None where no segment can be removed."""
    _, hs, *_ = tr.unpack(x)
    ds, PN, PT = (np.ravel(tr.ix.get(key, [])).astype(int) for key in ("d", "PN", "PT"))
    plan, carried, i, p, removed = [], (), 0, 0, 0
    for k, segs in enumerate(tr.plan):
        durs = x[ds[i:i + len(segs)]] if len(segs) > 1 else [hs[k]]
        i += len(segs) if len(segs) > 1 else 0
        kept = []
        for (modes, _, impacts), d in zip(segs, durs):
            here = []
            for c, tmode, _, _ in impacts:
                here.append((c, tmode, float(x[PN[p]]), float(x[PT[p]])))
                p += 1
            here = carried + tuple(here)
            if len(segs) > 1 and d <= PRUNE_TOL * hs[k]:
                carried, removed = here, removed + 1
                continue
            if len({c[0] for c in here}) < len(here):  # two impacts of one contact at one instant
                return None
            kept.append((modes, float(d), here))
            carried = ()
        if not kept:  # every segment of the interval shrunk (an iterate far from feasible)
            return None
        total = sum(sg[1] for sg in kept)
        plan.append([(md, d * hs[k] / total, at) for md, d, at in kept])
    if carried or not removed:  # (an impact at the horizon's end stays)
        return None
    try:
        check_plan(plan, np.concatenate([[0.0], np.cumsum(hs)]))
    except NotShootable:
        return None
    return plan, removed


def pruned_start(pb, tr, x):
    """(plan, keys, segments removed, the iterate as a result) to solve again from, where ``x``,
    an iterate of ``tr``'s NLP, shrinks segments to zero (:func:`pruned_plan`); None where none can
    be removed, or where the pruned plan's kept rows cannot be chosen at its new start (a mode
    whose accelerations are not unique there: :func:`plan_keys`)."""
    cut = pruned_plan(tr, x)
    if cut is None:
        return None
    it = iterate_of(tr, x)
    try:
        return cut[0], plan_keys(pb, cut[0], it), cut[1], it
    except NotShootable:
        return None


def iterate_of(tr, x):
    """What :func:`~lcp.ocp.shooting.initial_point` and :func:`plan_keys` read of a result (node
    times, steps, states, controls, impulses), from ``tr``'s variables x."""
    T, hs, q, v, u, pN, pT = tr.unpack(x)
    peak = float(x[tr.ix["z"]].ravel()[0]) if tr.pb.max_cost is not None else float("nan")
    return SimpleNamespace(t=np.concatenate([[0.0], np.cumsum(hs)]), T=T, steps=hs, q=q, v=v, u=u,
                           p_N=pN, p_T=pT, peak=peak)


def plan_of_modes(result):
    """The phase sequence of a solution's own modes: one segment per interval in the interval's
    mode, and where the mode changes at a node a first short segment in the previous mode (the
    switch may move into the interval)."""
    modes = [tuple(int(c) for c in row) for row in np.asarray(result.modes)]
    plan = []
    for k, md in enumerate(modes):
        h = float(result.t[k + 1] - result.t[k])
        if k and modes[k - 1] != md:
            plan.append([(modes[k - 1], 1e-3 * h, ()), (md, (1 - 1e-3) * h, ())])
        else:
            plan.append([(md, h, ())])
    return plan


def plan_keys(pb, plan, result, states: str = "integrated") -> list:
    """The rows each segment of ``plan`` holds, for :class:`~lcp.ocp.shooting.PhaseShooting`'s ``keys``: per
    interval and segment the pair (:func:`~lcp.ocp.phase_dynamics.independent_rows`,
    :func:`~lcp.ocp.phase_dynamics.impact_rows` of its impacts) at the segment's start state (None
    where every row is independent), the states integrated by CVODES through the plan
    at ``result``'s control and steps, from the problem's start or with ``states="result"`` from
    ``result``'s node state at each interval's start (the walk of
    :func:`~lcp.ocp.shooting.initial_point`, whose states the rank is decided on). Raises
    :class:`~lcp.ocp.phase_dynamics.NotShootable` where a mode's accelerations are not unique."""
    sys, n = pb.system, pb.system.n
    t, u = np.asarray(result.t, dtype=float), np.asarray(result.u, dtype=float)
    fns, keys = {}, []
    xs = np.concatenate([pb.q0, pb.v0])
    for k, segs in enumerate(plan):
        h, j0 = t[k + 1] - t[k], {"constant": k, "linear": k}.get(pb.hold, 2 * k)
        ua, ub = u[j0], u[j0] if pb.hold == "constant" else u[j0 + 1]
        if states != "integrated":
            xs = np.concatenate([result.q[k], result.v[k]])
        t_seg, row = t[k], []
        for modes, dur, *rest in segs:
            modes = tuple(int(c) for c in modes)
            impacts = tuple(rest[0]) if rest else ()
            if impacts:
                xs = np.concatenate([xs[:n], xs[n:] + impulse_dv(sys, xs[:n], impacts)])
            keep = independent_rows(pb, modes, t_seg, xs[:n]) if sys.n_contacts else None
            row.append((keep, impact_rows(sys, impacts, xs[:n]) if impacts else None))
            if (modes, keep) not in fns:
                fns[modes, keep] = segment_integrator(pb, mode_dynamics(pb, modes, keep), "seg", CHECK_TOL)
            out = fns[modes, keep](x0=xs, p=np.concatenate([[t_seg, dur, t[k], h], ua, ub]))
            xs, t_seg = np.array(out["xf"])[:, -1], t_seg + dur
        keys.append(row)
    return keys
