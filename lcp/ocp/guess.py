"""Initial guesses: resampling a solution onto another grid, and filling every NLP variable."""
from __future__ import annotations

import numpy as np

from lcp.ocp.options import START_RHS, HomotopyOptions, check_shooting
from lcp.ocp.results import OCPGuess

__all__ = ["control_values", "event_guess", "multistart", "pulse_controls", "resample", "screened_start", "simulate_guess",
           "x0_from_guess"]


def _interp(a, told, tnew):
    if not a.shape[1]:
        return np.zeros((len(tnew), 0))
    return np.stack([np.interp(tnew, told, a[:, j]) for j in range(a.shape[1])], axis=1)


def _old_schedule(res, t_old, M):
    """The control of a solution or guess as a schedule on its own grid (its hold from its rows)."""
    from lcp.model.control import ControlSchedule
    from lcp.model.schedule import AffineSchedule

    u = np.asarray(res.u, dtype=float)
    hold = getattr(res, "hold", None)
    if hold is None:
        hold = {M: "constant", M + 1: "linear", 2 * M: "affine"}.get(len(u), "constant")
    return AffineSchedule(t_old, u) if hold == "affine" else ControlSchedule(t_old, u, hold=hold)


def resample(res, N: int, hold: str) -> OCPGuess:
    """Interpolate a solution or guess onto N uniform steps (impulses as forces, rescaled by h).

    The control is sampled, from its own hold on the old grid, at interval midpoints (constant
    hold), at nodes (linear hold), or at both ends of each interval (affine hold).
    """
    T = float(res.T)
    M = res.q.shape[0] - 1
    t_old = getattr(res, "t", None)
    if t_old is None or len(t_old) != M + 1:
        t_old = np.linspace(0.0, T, M + 1) if getattr(res, "steps", None) is None else \
            np.concatenate([[0.0], np.cumsum(res.steps)])
    t_new = np.linspace(0.0, T, N + 1)
    h_old = np.diff(t_old)[:, None]
    tm_old, tm_new = 0.5 * (t_old[1:] + t_old[:-1]), 0.5 * (t_new[1:] + t_new[:-1])
    sched = _old_schedule(res, t_old, M)
    if hold == "constant":
        u_new = sched(tm_new)
    elif hold == "linear":
        u_new = sched(t_new)
    elif getattr(sched, "hold", None) == "constant":
        # a staircase guess for an affine hold: both ends of each step from the line through the
        # old steps' midpoint values. A guess with no slopes at all is a stationary point of the
        # slopes in the fixed-phase solve (the affine effort is flat in the slope at zero slope).
        um = np.asarray(res.u, dtype=float).reshape(M, -1)
        lo_u = getattr(getattr(res, "problem", None), "u_min", None)
        hi_u = getattr(getattr(res, "problem", None), "u_max", None)
        ends = _interp(um, tm_old, t_new)  # (one old step: its value throughout)
        if lo_u is not None:
            ends = np.clip(ends, lo_u, hi_u)
        u_new = np.stack([ends[:-1], ends[1:]], axis=1).reshape(2 * N, -1)
    else:
        u_new = np.stack([sched(t_new[:-1]), sched.left(t_new[1:])], axis=1).reshape(2 * N, -1)
    return OCPGuess(T=T, q=_interp(res.q, t_old, t_new), v=_interp(res.v, t_old, t_new), u=u_new,
                    p_N=_interp(res.p_N / h_old, tm_old, tm_new) * (T / N),
                    p_T=_interp(res.p_T / h_old, tm_old, tm_new) * (T / N), source="resampled")


def x0_from_guess(pb, tr, gs: OCPGuess) -> np.ndarray:
    """Every NLP variable from a guess, the Coulomb multipliers and slacks from the impulses."""
    ix, N = tr.ix, pb.N
    x0 = np.zeros(len(tr.lbx))
    if pb.free_time:
        x0[ix["T"]] = np.clip(gs.T, *pb.T_bounds)
    steps = np.full(N, gs.T / N) if gs.steps is None else np.asarray(gs.steps, dtype=float)
    if pb.steps == "free":
        x0[ix["h"].ravel()] = steps
    for k in range(len(ix["u"])):
        x0[ix["u"][k]] = gs.u[k]
    for k in range(1, N + 1):
        x0[ix["q"][k - 1]] = gs.q[k]
        x0[ix["v"][k - 1]] = gs.v[k]
    m = pb.system.n_contacts
    if hasattr(tr, "stages"):  # Radau collocation (lcp.ocp.collocation): its stage states, and contacts
        tr.x0_law(x0, gs, steps)
    elif m and hasattr(tr, "x0_law"):  # a transcription with its own contact variables (lcp.ocp.spatial)
        tr.x0_law(x0, gs, steps)
    elif m:  # the guess's impulses as forces over the steps; no impulses at the nodes
        mu, e = pb.system.mu, pb.system.e
        for k in range(N):
            H = pb.system.contact_jacobian(gs.q[k])
            uN, uT = H[:m] @ gs.v[k + 1], H[m:] @ gs.v[k + 1]
            uN0, uT0 = H[:m] @ gs.v[k], H[m:] @ gs.v[k]
            pN, pT = np.maximum(gs.p_N[k], 0.0) / steps[k], gs.p_T[k] / steps[k]  # forces
            bp, bm = np.maximum(pT, 0.0), np.maximum(-pT, 0.0)
            lam = np.abs(uT)
            if tr.gap_law:  # the node's impulse by Newton's law where the guess lands (a solution's
                # nodes carry the velocity before it); the step then starts from the velocity after it
                PN, vk = _landing_impulse(pb.system, gs.q[k], gs.v[k], H, m, e)
                uN0, uT0 = H[:m] @ vk, H[m:] @ vk
                vals_i = {"PN": PN, "sI": uN0 + e * np.minimum(H[:m] @ gs.v[k], 0.0)}
            else:
                vals_i = {"sI": uN0 + e * np.minimum(uN0, 0.0)}
            vals = {"pN": pN, "bp": bp, "bm": bm, "lam": lam,
                    "wN": (np.maximum(pb.system.gaps(gs.q[k + 1]) / tr.gap_scale, 0.0) if tr.gap_law else
                           np.maximum(uN + e * np.minimum(H[:m] @ gs.v[k], 0.0), 0.0)),
                    "wp": np.maximum(lam + uT, 0.0), "wm": np.maximum(lam - uT, 0.0),
                    "wl": np.maximum(mu * pN - bp - bm, 0.0),
                    "sU": uN0, **vals_i,
                    "Plam": np.abs(uT0), "Pwp": np.abs(uT0) + uT0, "Pwm": np.abs(uT0) - uT0}
            for nm, val in vals.items():
                if nm not in ix:  # the velocity law has no impulses at the nodes
                    continue
                x0[ix[nm][k]] = val
    if pb.max_cost is not None:
        x0[ix["z"]] = 0.0
    return np.clip(x0, tr.lbx, tr.ubx)


def _landing_impulse(system, q, v, H, m, e):
    """(P_N, v+): the normal impulses of the contacts closed at q and approaching at v that give
    u_N+ = -e u_N- (Newton's law, frictionless), and the velocity after them; zeros elsewhere."""
    PN = np.zeros(m)
    scale = max(1.0, float(np.max(np.abs(q), initial=0.0)))
    # approaching by more than rounding: a resting contact's u_N of 1e-17 is no landing (an impulse
    # of that size would flip the phase guess's choice between the impulse and the gap)
    hit = (system.gaps(q) <= 1e-9 * scale) & (H[:m] @ v < -1e-8 * max(1.0, float(np.max(np.abs(v), initial=0.0))))
    if not np.any(hit) or system.n_bilateral:
        return PN, v
    HN = H[:m][hit]
    MinvHt = np.linalg.solve(system.mass(q), HN.T)
    PN[hit] = np.maximum(np.linalg.solve(HN @ MinvHt, -(1.0 + e[hit]) * (HN @ v)), 0.0)
    return PN, v + MinvHt @ PN[hit]


def simulate_guess(pb, u, T: float, solver: str = "auto") -> OCPGuess:
    """The simulation of the control ``u`` (constant, per interval/node, or a function of t) on pb's grid."""
    from lcp.simulation import simulate

    t = np.linspace(0.0, T, pb.N + 1)
    un = control_values(pb, u, T)
    sim = simulate(pb.system, T, h=T / pb.N, theta=pb.theta, solver=solver, q0=pb.q0, v0=pb.v0,
                   control=pb.schedule(t, un))
    if not sim.success or len(sim.t) != pb.N + 1:
        raise ValueError(f"the guess simulation failed: {sim.message}")
    return OCPGuess(T=T, q=sim.q, v=sim.v, u=un, p_N=sim.p_N, p_T=sim.p_T, source="simulation")


def control_values(pb, u, T: float) -> np.ndarray:
    """The rows of control values of ``u`` (constant, per interval/node, or a function of t) on
    pb's uniform grid over T, clipped to the control bounds."""
    t = np.linspace(0.0, T, pb.N + 1)
    rows = pb.control_rows
    if callable(u):
        ts = np.repeat(t, 2)[1:-1] if pb.hold == "affine" else t[:rows]  # affine: both ends of each step
        un = np.array([np.broadcast_to(np.asarray(u(tk), dtype=float), (pb.nu,)) for tk in ts])
    else:
        ua = np.asarray(u, dtype=float)
        un = (np.repeat(np.broadcast_to(ua, (pb.nu,))[None, :], rows, 0) if ua.size == pb.nu
              else ua.reshape(rows, pb.nu))
    return np.clip(un, pb.u_min, pb.u_max)


def event_guess(pb, u, T: float) -> OCPGuess | None:
    """The control's response by the event method sampled at the nodes (None where the event
    method does not apply or fails).

    Moreau-Jean at h = T / N closes a contact one step late and lets the node after it penetrate
    (the ball dropped on its floor: its gap at the node after the landing is below zero), which the
    gap law's bounds g(q_k) >= 0 refuse at the start; the event method's nodes never penetrate.
    Its impacts fall between nodes, where the transcription has none: the guess is not a
    solution of the NLP, only a start without penetrations."""
    from lcp.simulation import simulate

    un = control_values(pb, u, T)
    t = np.linspace(0.0, T, pb.N + 1)
    try:
        sim = simulate(pb.system, T, method="event", control=pb.schedule(t, un), q0=pb.q0, v0=pb.v0, t_eval=t,
                       rhs=START_RHS)
    except (ValueError, RuntimeError, NotImplementedError, np.linalg.LinAlgError):
        return None
    if not sim.success or len(sim.t) != pb.N + 1 or not np.all(np.isfinite(sim.q)):
        return None
    return OCPGuess(T=T, q=sim.q, v=sim.v, u=un, p_N=sim.p_N, p_T=sim.p_T, source="event simulation")


#: levels a (of the mid-range control's distance from the rest control) and fractions f of the
#: horizon of the pulse starts (:func:`pulse_controls`)
PULSE_LEVELS = (1.0, 0.5, 0.25, 0.125)
PULSE_FRACTIONS = (1.0, 0.5, 0.25)


def pulse_controls(pb) -> list:
    """Candidate start controls: the rest control r (zero clipped to the bounds) plus a fraction a of
    the mid-range control's distance from it, held over the first fraction f of the horizon, r after
    (a in :data:`PULSE_LEVELS`, f in :data:`PULSE_FRACTIONS`; the mid-range control itself, a = f = 1,
    excluded). Returns [(a, f, rows of control values)]; empty when r is the mid-range control."""
    lo, hi = np.asarray(pb.u_min, dtype=float), np.asarray(pb.u_max, dtype=float)
    rest = np.array(np.clip(0.0, lo, hi), dtype=float)
    both = np.isfinite(lo) & np.isfinite(hi)
    mid = rest.copy()
    mid[both] = 0.5 * (lo[both] + hi[both])
    if np.allclose(mid, rest):
        return []
    t = np.linspace(0.0, pb.T, pb.N + 1)
    ts = np.repeat(t, 2)[1:-1] if pb.hold == "affine" else (t[:-1] + 0.5 * np.diff(t) if pb.hold == "constant" else t)
    out = []
    for a in PULSE_LEVELS:
        for f in PULSE_FRACTIONS:
            if a == 1.0 and f == 1.0:
                continue
            on = (ts < f * pb.T)[:, None]
            out.append((a, f, np.clip(np.where(on, rest + a * (mid - rest), rest), lo, hi)))
    return out


def screened_start(pb, tr=None):
    """The pulse start (:func:`pulse_controls`) whose event-method simulation (:func:`event_guess`)
    comes nearest to the terminal constraints, the lowest transcription cost among those that meet
    them (to 1e-6); (a, f, guess) or None. A mid-range control can carry a system far past
    its target (a box pushed at 15 N tumbles instead of tipping onto its side): measured on the
    box (N = 20), every start from it fails, while from the event simulation of 3.75 N held over
    the first quarter of the horizon (it tips the box onto its side) the transcription reaches cost 4.09."""
    import casadi as ca

    # without a transcription (not built yet) the smaller push (a f) stands in for the cost
    cost = None if tr is None else ca.Function("start_cost", [tr.nlp["x"], tr.nlp["p"]], [tr.nlp["f"]])
    P = np.concatenate([[0.0], pb.q0, pb.v0])
    best, key = None, None
    for a, f, u in pulse_controls(pb):
        gs = event_guess(pb, u, pb.T)
        if gs is None:
            continue
        viol = 0.0
        if pb.terminal_constraints is not None:
            viol = float(np.linalg.norm(np.array(ca.DM(pb.terminal_constraints(ca.DM(gs.q[-1]), ca.DM(gs.v[-1]))),
                                                 dtype=float)))
        c = a * f if cost is None else float(cost(x0_from_guess(pb, tr, gs), P))
        if not np.isfinite(viol) or not np.isfinite(c):
            continue
        k = (viol > 1e-6, viol if viol > 1e-6 else 0.0, c)
        if key is None or k < key:
            best, key = (a, f, gs), k
    return best


def multistart(pb, guesses, options, rtol: float, shooting: bool = True, **option_kw):
    """:meth:`OptimalControlProblem.solve_multistart` (see there)."""
    check_shooting(shooting)
    if guesses is None:
        cands = [("u_min", pb.u_min), ("zero", np.clip(0.0, pb.u_min, pb.u_max)),
                 ("mid", 0.5 * (pb.u_min + pb.u_max)), ("u_max", pb.u_max)]
        guesses = [(lab, pb.guess(u=np.where(np.isfinite(u), u, 0.0))) for lab, u in cands]
    results = []
    for entry in guesses:
        lab, gs, extra = (tuple(entry) + ({},))[:3]
        opts = options if options is not None else HomotopyOptions(**{**option_kw, **extra})
        results.append((lab, pb.solve(gs, opts, shooting=shooting)))
    ok = [(lab, r) for lab, r in results if r.success]
    pool = ok if ok else results
    best_lab, best = min(pool, key=lambda lr: lr[1].cost if np.isfinite(lr[1].cost) else np.inf)
    costs = sorted(r.cost for _, r in ok)
    distinct = [c for i, c in enumerate(costs) if i == 0 or abs(c - costs[i - 1]) > rtol * max(1.0, abs(c))]
    best.starts = [{"label": lab, "cost": r.cost, "status": r.status, "success": r.success} for lab, r in results]
    note = (f" {len(ok)}/{len(results)} starts succeeded, reaching {len(distinct)} distinct "
            f"optim{'um' if len(distinct) == 1 else 'a'} (costs {', '.join(f'{c:.8g}' for c in distinct)}); "
            f"best from start '{best_lab}'" + ("; a local solution, the starts disagree." if len(distinct) > 1
                                                else "."))
    best.message += note
    return best

