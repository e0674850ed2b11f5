"""Open-loop replay of an optimal control on the same System, and the replay miss of a solution.

The control of a solution is a :class:`lcp.model.control.ControlSchedule`; the replay simulates the
problem's own controlled System with it (``System.with_control``), so there is no second model:

- ``method="moreau-jean"`` at the optimizer's step (``refine=1``, uniform steps) repeats the
  optimizer's steps, the control's impulse over each step integrated exactly, so the mismatch is
  round-off; at ``refine > 1`` it measures the time-discretization error of the transcription.
- ``method="event"``: the event-driven integrator (:mod:`lcp.events`), the control's nodes being
  ends of phases; exact (to round-off) wherever the phases have closed forms: a constant system
  (the Jean-Pratt block) under a piecewise-constant, -linear or -affine control, whose phases are
  polynomial in t (:mod:`lcp.events.cubic_phase`). It follows the continuous-time response
  whatever the transcription's steps. A planar system is replayed by one integration over the
  whole schedule (the breakpoints end phases within it), its results then cut at the nodes into
  the per-interval ``pieces``; a spatial one is restarted at every node with a one-interval
  schedule (the spatial event integrator).
"""
from __future__ import annotations

import copy
import dataclasses

import casadi as ca
import numpy as np

from lcp.model.control import ControlSchedule
from lcp.ocp.options import START_RHS
from lcp.ocp.pairs import pair_violation
from lcp.ocp.results import OCPResult, ReplayCheck, ReplayResult

__all__ = ["AMPLIFICATION_EVENTS", "PERTURBATION", "amplification", "event_pieces", "node_objective", "piece_nodes",
           "replay", "replay_check"]

#: the start-state change (relative to the start state's size, at least 1) by which an event replay
#: that misses measures how much it amplifies errors (:func:`amplification`)
PERTURBATION = 1e-8
#: the most events that replay may take, per event of the replay it is compared with (and 100 more)
AMPLIFICATION_EVENTS = 10


def _event_available() -> bool:
    from lcp import simulation

    return "event" in simulation.METHODS


def _lift(system, q, tol=1e-12):
    """Undo a round-off penetration (|gap| < tol) of a piece's end state along the contact normals,
    which the next piece would otherwise reject as an initial penetration."""
    m = system.n_contacts
    if not m:
        return q
    gap = system.gaps(q)
    neg = (gap < 0) & (gap > -tol)
    if not np.any(neg):
        return q
    HN = system.contact_jacobian(q)[:m][neg]
    return q - HN.T @ np.linalg.solve(HN @ HN.T, gap[neg])


def _whole_schedule_system(result: OCPResult, options: dict):
    """The problem's System under the solution's whole control schedule, for one event integration
    over [0, T], when only ``n_eval`` (and ``max_events``, ``rtol``, ``rhs``) are asked for and the contacts are planar;
    else None.

    Restarting at every node built a System and an event model per interval, and cost the motor
    (N = 30) 0.10 s per replay against 0.05 s in one integration, at the same replay misses. The
    force's time dependence excludes nothing here: the replay check sends such a system to
    Moreau-Jean, and the optimal control refuses contacts that move with t."""
    if set(options) - {"n_eval", "max_events", "rtol", "rhs"} or result.control is None or result.problem.system.is_spatial:
        return None  # (spatial contacts: the spatial event integrator, restarted at the nodes)
    return result.problem.system.with_control(result.control)


def _shifted(records, t0: float, t1: float, last: bool, *names):
    """The records (frozen dataclasses) with time fields ``names`` in [t0, t1) ([t0, t1] for the
    last interval), clipped and shifted to start at 0."""
    out = []
    for r in records:
        first = getattr(r, names[0])
        end = getattr(r, names[-1])
        if end < t0 or first > t1 or (first == t1 and not last) or (end == t0 and first < t0):
            continue
        out.append(dataclasses.replace(r, **{nm: min(max(getattr(r, nm), t0), t1) - t0 for nm in names}))
    return out


def _cut(sim, nodes, counts):
    """The per-interval views of one event integration whose output times hold the nodes: interval
    k has ``counts[k]`` output times from node k to node k + 1, its times shifted to start at 0."""
    from lcp.events.records import new_event_result

    pieces, i = [], 0
    K = len(nodes) - 1
    for k in range(K):
        a, b = i, i + counts[k]
        t0, t1 = float(nodes[k]), float(nodes[k + 1])
        last = k == K - 1
        ev = _shifted(sim.events, t0, t1, last, "t")
        pieces.append(new_event_result(
            t=sim.t[a:b] - t0, q=sim.q[a:b], v=sim.v[a:b], p_N=sim.p_N[a:b - 1], p_T=sim.p_T[a:b - 1],
            modes=sim.modes[a:b - 1], status=sim.status, message=sim.message, stats=sim.stats, method=sim.method,
            solver=sim.solver, t_events=[e.t for e in ev], force_N=sim.force_N[a:b], force_T=sim.force_T[a:b],
            events=ev, impulses=_shifted(sim.impulses, t0, t1, last, "t"),
            phases=[p for p in _shifted(sim.phases, t0, t1, last, "t0", "t1") if p.t1 > p.t0 or p.t0 == 0.0],
            impacts=_shifted(sim.impacts, t0, t1, last, "t"),
            accumulations=_shifted(sim.accumulations, t0, t1, last, "t"), nonunique_forces=sim.nonunique_forces))
        i = b - 1  # the node is the last time of this interval and the first of the next
    return pieces


def _replay_event_whole(result: OCPResult, sysw, n_eval: int = 1000, **sim_options):
    """Event-driven replay of the whole schedule in one integration: (q, v) at
    the nodes and the per-interval views (``n_eval`` output times per interval, as the restarted
    replay gives)."""
    from lcp.simulation import simulate

    if not isinstance(n_eval, (int, np.integer)) or isinstance(n_eval, bool) or n_eval < 2:
        raise ValueError(f"n_eval must be an integer >= 2, got {n_eval!r}")
    pb = result.problem
    t = np.asarray(result.t, dtype=float)
    grid = [t[:1]]
    for k in range(len(t) - 1):
        g = t[k] + np.linspace(0.0, t[k + 1] - t[k], int(n_eval))
        g[-1] = t[k + 1]
        grid.append(g[1:])
    t_eval = np.concatenate(grid)
    sim = simulate(sysw, float(t[-1]), method="event", q0=pb.q0, v0=pb.v0, t_eval=t_eval, **sim_options)
    if not sim.success:
        raise RuntimeError(f"replay failed: {sim.message}")
    idx = np.arange(len(t)) * (int(n_eval) - 1)
    return sim.q[idx], sim.v[idx], _cut(sim, t, [int(n_eval)] * (len(t) - 1))


def event_pieces(result: OCPResult, restart: bool = False, first: int = 0, start=None, **options):
    """Event-driven replay: (q, v) at the nodes, the piece results. One integration over the whole
    schedule for planar contacts unless ``restart``; else restarted at every node with that
    interval's schedule, from node ``first`` (0: the problem's start; else ``start`` = (q, v)
    there, and the nodes from ``first`` on are returned)."""
    from lcp.simulation import simulate

    if first and (not restart or start is None):
        raise ValueError("a replay from node first > 0 is restarted at every node and needs start = (q, v)")
    sysw = None if restart else _whole_schedule_system(result, options)
    if sysw is not None:
        return _replay_event_whole(result, sysw, **options)
    pb = result.problem
    sysc, t, sched = pb.system, result.t, result.control
    if sysc.force_depends_on_t:
        # each piece is simulated from t = 0: a force of t would be evaluated at the wrong times
        # (a block pushed by u + 4 sin(6 t): 0.28 m off the one integration, which agrees with a
        # fine Moreau-Jean replay to 1.5e-5)
        raise ValueError("the event replay restarted at every node needs a force that does not depend on t "
                         "explicitly; replay with method='moreau-jean', or the event method with n_eval only")
    q0, v0 = (pb.q0, pb.v0) if start is None else start
    q, v = [np.array(q0, dtype=float)], [np.array(v0, dtype=float)]
    pieces = []
    for k in range(int(first), len(t) - 1):
        h = t[k + 1] - t[k]
        if sched.hold == "constant":
            piece = ControlSchedule([0.0, h], sched.values[k:k + 1])
        elif sched.hold == "affine":
            piece = ControlSchedule([0.0, h], sched.values[2 * k:2 * k + 2], hold="linear")
        else:
            piece = ControlSchedule([0.0, h], sched.values[k:k + 2], hold="linear")
        sim = simulate(sysc, h, method="event", control=piece, q0=q[-1], v0=v[-1], **options)
        if not sim.success:
            raise RuntimeError(f"replay failed in interval {k} (t = {t[k]:.6g}): {sim.message}")
        pieces.append(sim)
        q.append(_lift(sysc, sim.q[-1]))
        v.append(sim.v[-1])
    return np.array(q), np.array(v), pieces


def replay(result: OCPResult, refine: int = 10, method: str = "moreau-jean", solver: str = "auto",
           theta: float | None = None, **method_options) -> ReplayResult:
    """Replay an optimal control open loop through :func:`lcp.simulate` and measure the mismatch.

    Parameters
    ----------
    result : OCPResult
    refine : int
        Moreau-Jean steps per optimizer step (>= 1; the replay step is T / (N refine)).
    method : {"moreau-jean", "event"}
        Moreau-Jean at a uniform step, or the event-driven integrator (one integration over the
        whole schedule for planar contacts, else restarted at every node).
    solver : str
        One-step contact solver (Moreau-Jean).
    theta : float, optional
        Theta of the replay (the problem's by default).
    **method_options
        Options of the event integrator.

    Returns
    -------
    ReplayResult
        The replay at the optimizer's nodes and the largest mismatch per coordinate.

    Examples
    --------
    >>> import lcp
    >>> from studies.optimal_control import rest_to_rest_problem
    >>> res = rest_to_rest_problem(10, "time", "constant", "uniform").solve()
    >>> replay(res, refine=1).max_error_q < 1e-10  # IPOPT's tolerance: the same steps
    True
    """
    from lcp.simulation import simulate

    if not isinstance(result, OCPResult) or result.problem is None:
        raise ValueError("result must be an OCPResult returned by OptimalControlProblem.solve")
    if not isinstance(refine, (int, np.integer)) or refine < 1:
        raise ValueError(f"refine must be an integer >= 1, got {refine!r}")
    if method not in ("moreau-jean", "event"):
        raise ValueError(f"method must be 'moreau-jean' or 'event', got {method!r}")
    pb = result.problem
    N = len(result.t) - 1
    if method == "event":
        q, v, pieces = event_pieces(result, **method_options)
        sim, h = pieces[-1], float("nan")
    else:
        pieces = []
        uniform = np.allclose(result.steps, result.T / N, rtol=1e-12, atol=0)
        h = result.T / (N * refine)
        sim = simulate(pb.system, result.T, h=h, theta=pb.theta if theta is None else theta, solver=solver,
                       q0=pb.q0, v0=pb.v0, control=result.control)
        if not sim.success:
            raise RuntimeError(f"replay failed: {sim.message}")
        if uniform:
            q, v = sim.q[::refine][: N + 1], sim.v[::refine][: N + 1]
        else:  # free steps: the replay's grid misses the nodes; interpolate
            q = np.stack([np.interp(result.t, sim.t, sim.q[:, j]) for j in range(sim.q.shape[1])], axis=1)
            v = np.stack([np.interp(result.t, sim.t, sim.v[:, j]) for j in range(sim.v.shape[1])], axis=1)
    return ReplayResult(sim=sim, method=method, h=h, t=result.t, q=q, v=v,
                        error_q=np.max(np.abs(q - result.q), axis=0),
                        error_v=np.max(np.abs(v - result.v), axis=0), pieces=pieces)


def replay_check(result: OCPResult, tol: float, refine: int = 50, rtol: float | None = None,
                 estimate_rtol: float | None = None, restart: bool = False) -> ReplayCheck:
    """The replay miss of a solution: final state and path constraints, replayed open loop.

    The event-driven replay (exact: closed-form phases, the control's nodes ending phases) for a piecewise-constant
    or piecewise-affine control when the event integrator is available and the drift does not depend on time;
    otherwise (continuous linear hold) Moreau-Jean at T / (N refine), which reports its method and step.
    Path constraints (the largest value) and path equalities (the largest magnitude) are
    evaluated on the replayed states at the nodes (with the optimizer's impulses and controls).
    ``rtol``: the event integrator's tolerance for phases without closed forms (its own default
    otherwise); ``restart``: the event replay restarted at every node (every interval integrated on
    its own); with ``estimate_rtol`` the final state is replayed once more at that tolerance,
    restarted at every node, and the two replays' difference is the check's ``integration_error``
    (counted in ``ok``).
    """
    pb = result.problem
    # the event replay is exact for the constant and the affine hold (polynomial phases in closed
    # form); for the linear hold the Moreau-Jean replay is kept as before (a pinned, cheaper check)
    tight = ({} if rtol is None else {"rtol": float(rtol)}) | ({"restart": True} if restart else {})
    err = float("nan")
    if result.hold in ("constant", "affine") and _event_available() and not pb.system.force_depends_on_t:
        rp = replay(result, method="event", n_eval=2, rhs=START_RHS, **tight)  # (the nodes only: no dense output)
        method = ("event" + ("" if rtol is None else f" rtol={rtol:.0e}")
                  + (", restarted at every node" if restart else ""))
        if estimate_rtol is not None:
            # restarted at every node: another sequence of steps as well as another tolerance (on the
            # cart-pole's landed swing-ups the restarted replays converged as rtol fell, and agreed
            # with Radau's; the one integration moved by 2e-6 between rtol 1e-13 and 3e-14)
            q2, v2, _ = event_pieces(result, restart=True, n_eval=2, rtol=float(estimate_rtol))
            err = float(max(np.max(np.abs(q2[-1] - rp.q[-1])), np.max(np.abs(v2[-1] - rp.v[-1]))))
    else:
        rp = replay(result, refine=refine)
        method = f"moreau-jean h={rp.h:.3g}"
    final = float(max(np.max(np.abs(rp.q[-1] - result.q[-1])), np.max(np.abs(rp.v[-1] - result.v[-1]))))
    nodes = float(max(rp.max_error_q, rp.max_error_v))
    viol = 0.0
    pairs = getattr(pb, "complementarity", [])
    if pb.path_constraints is not None or pb.path_equalities is not None or pairs:
        for st in _steps(result, rp.q, rp.v):
            for fn, absolute in ((pb.path_constraints, False), (pb.path_equalities, True)):
                if fn is None:
                    continue
                val = _numbers(fn(st))
                if val.size:
                    viol = max(viol, float(np.max(np.abs(val) if absolute else val)))
            if pairs:  # the user's complementarity pairs on the replayed states (lcp.ocp.pairs)
                viol = max(viol, pair_violation(pairs, st))
    event = method.startswith("event")
    amp = amplification(result, rp, **tight) if event and final > tol else float("nan")
    return ReplayCheck(method=method, final_miss=final, node_miss=nodes, path_violation=viol, tol=tol,
                       where=_where(result, rp, tol), pieces=rp.pieces if event else None,
                       amplification=amp, integration_error=err)


def _steps(result: OCPResult, q, v, wrap=None):
    """The Steps of ``result``'s intervals on the node states (q, v), with its controls and impulses
    (each array passed through ``wrap`` where given)."""
    pb, u = result.problem, result.u
    w = (lambda x: x) if wrap is None else wrap
    for k in range(len(result.t) - 1):
        j = 2 * k if result.hold == "affine" else k
        ua, ub = u[j], u[j] if result.hold == "constant" else u[j + 1]
        yield pb.make_step(k, result.t[k], result.steps[k], w(q[k]), w(q[k + 1]), w(v[k]), w(v[k + 1]),
                           w(ua), w(ub), w(result.p_N[k]), w(result.p_T[k]))


def _numbers(val) -> np.ndarray:
    """A callable's value as a flat float array (an SX built from numbers is constant)."""
    if isinstance(val, ca.SX):
        val = ca.evalf(val)
    return np.array(val, dtype=float).ravel()


def piece_nodes(pieces) -> tuple[np.ndarray, np.ndarray]:
    """(q, v) at the nodes of an event replay from its per-interval pieces (each piece's start, and
    the last piece's end)."""
    q = np.array([p.q[0] for p in pieces] + [pieces[-1].q[-1]])
    v = np.array([p.v[0] for p in pieces] + [pieces[-1].v[-1]])
    return q, v


def node_objective(result: OCPResult, q, v) -> float:
    """The problem's objective on the node states (q, v) with ``result``'s controls and impulses:
    terminal cost, the stage costs summed as sum_k h_k stage_cost(step_k) on the nodes, and
    max_cost's largest value. Not the transcription's own quadrature: for comparing two sets of
    node states (the optimizer's and its replay's) by one rule.

    Examples
    --------
    On the theta transcription's own nodes the rule is its cost:

    >>> from studies.optimal_control import rest_to_rest_problem
    >>> res = rest_to_rest_problem(10, "effort", "constant", "uniform").solve()
    >>> abs(node_objective(res, res.q, res.v) - res.cost) <= 1e-12 * res.cost
    True
    """
    pb = result.problem
    J, top = 0.0, -np.inf
    # as CasADi matrices: a cost written with CasADi's functions (ca.sumsqr, ca.dot) takes them
    for st in _steps(result, q, v, wrap=ca.DM):
        if pb.stage_cost is not None:
            J += float(st.h) * float(_numbers(pb.stage_cost(st))[0])
        if pb.max_cost is not None:
            top = max(top, float(_numbers(pb.max_cost(st))[0]))
    if pb.terminal_cost is not None:
        J += float(_numbers(pb.terminal_cost(result.T, ca.DM(q[-1]), ca.DM(v[-1])))[0])
    return J + (top if pb.max_cost is not None else 0.0)


def amplification(result: OCPResult, rp, **options) -> float:
    """How far the event replay ``rp`` of ``result``'s control moves its final state per unit change
    of the start state: one more event replay, from the start moved by :data:`PERTURBATION` (times
    its size) along a fixed pseudo-random direction that keeps the closed contacts' gaps and the
    bilateral constraints (to first order): the positions, or under Newton-Euler kinematics the
    velocities (a velocity change at rest sets sticking contacts sliding: a box on two stuck corners
    then chattered through 9784 events, 88 s, against 21). A swing-up to an unstable upright
    amplifies millions of times: no open-loop replay can then certify a small miss. nan where that
    replay fails or takes more than :data:`AMPLIFICATION_EVENTS` times the events of ``rp`` (and 100).

    Examples
    --------
    >>> from studies.optimal_control import rest_to_rest_problem
    >>> from lcp.ocp.replay import replay
    >>> res = rest_to_rest_problem(10, "time", "constant", "uniform").solve()
    >>> a = amplification(res, replay(res, method="event", n_eval=2))
    >>> 0.0 < a < 100.0  # a block that stops by friction: start errors are not amplified much
    True
    """
    pb = result.problem
    sys = pb.system
    n = sys.n
    q0, v0 = np.asarray(pb.q0, dtype=float), np.asarray(pb.v0, dtype=float)
    d = np.random.default_rng(20261127).standard_normal(q0.size + n)
    rows = [sys.contact_jacobian(q0)[:sys.n_contacts][sys.gaps(q0) <= 1e-9]] if sys.n_contacts else []
    if sys.n_bilateral:
        rows.append(np.array(sys.constraints_fn(0.0, q0)[1], dtype=float))
    A = np.vstack(rows) if rows else np.zeros((0, n))
    P = np.eye(n) - np.linalg.pinv(A) @ A if A.shape[0] else np.eye(n)
    dq = np.zeros(q0.size) if sys.has_kinematics else P @ d[:n]
    dv = P @ d[q0.size:] if sys.has_kinematics else np.zeros(n)
    size = max(np.max(np.abs(dq), initial=0.0), np.max(np.abs(dv), initial=0.0))
    if size == 0.0:
        return float("nan")
    eps = PERTURBATION * max(1.0, float(np.max(np.abs(np.concatenate([q0, v0])))))
    moved = copy.copy(pb)
    moved.q0, moved.v0 = _lift(sys, q0 + eps / size * dq), v0 + eps / size * dv
    events = sum(len(p.t_events) for p in rp.pieces) if rp.pieces else len(rp.sim.t_events)
    try:
        q, v, _ = event_pieces(dataclasses.replace(result, problem=moved), n_eval=2,
                               max_events=AMPLIFICATION_EVENTS * events + 100, **options)
    except RuntimeError:  # (the replay failed, or took too many events)
        return float("nan")
    return float(max(np.max(np.abs(q[-1] - rp.q[-1])), np.max(np.abs(v[-1] - rp.v[-1])))) / eps


def _replay_modes(rp, k):
    """The replay's contact modes at the start of interval k (None where the replay has no row
    for it: an interval without a piece, or a piece or simulation without output points)."""
    if rp.pieces:
        modes = rp.pieces[k].modes if k < len(rp.pieces) else ()
        return np.asarray(modes[0]) if len(modes) else None
    sim = rp.sim
    if not len(sim.modes):
        return None
    j = int(np.searchsorted(sim.t, rp.t[k] + 1e-12 * max(1.0, float(rp.t[-1])))) - 1
    return np.asarray(sim.modes[min(max(j, 0), len(sim.modes) - 1)])


def _where(result, rp, tol) -> str:
    """Where the replay leaves the optimizer (see :attr:`ReplayCheck.where`). Positions only: at a
    node with an impulse the optimizer's velocity is the one before it."""
    from lcp.contact.problem import MODE_NAMES

    miss = np.max(np.abs(rp.q - result.q), axis=1)
    bad = np.flatnonzero(miss > tol)
    if not bad.size:
        return ""
    first, worst = int(bad[0]), int(np.argmax(miss))
    text = (f"the replay's position first misses by more than {tol:.1e} at node {first} (t = {result.t[first]:.6g}), "
            f"by {miss[first]:.2e}; the largest miss {miss[worst]:.2e} is at node {worst} (t = {result.t[worst]:.6g})")
    k = first - 1
    names = [c.name for c in result.problem.system.contacts]
    modes = _replay_modes(rp, k) if k >= 0 else None
    if modes is not None and result.modes.shape[1]:
        diff = [j for j in range(result.modes.shape[1]) if int(modes[j]) != int(result.modes[k, j])]
        if diff:
            parts = [f"contact {names[j] if names else j!r}: {MODE_NAMES.get(int(result.modes[k, j]), '?')} in "
                     f"the optimizer, {MODE_NAMES.get(int(modes[j]), '?')} in the replay" for j in diff]
            text += f"; in step {k} " + ", ".join(parts)
        else:
            text += f"; in step {k} every contact has the same mode in both"
            hits = _replay_impacts(rp, k, result.t[k])
            if hits:  # an open contact that the optimizer's trajectory crosses between its points
                text += (" at its start, and inside it the replay resolves " +
                         ", ".join(f"an impact of contact {nm!r} at t = {t:.6g}" for t, nm in hits))
    return text


def _replay_impacts(rp, k, t0) -> list:
    """The event replay's impacts inside interval k: (time, contact name) ([] without pieces: a
    Moreau-Jean replay)."""
    if k >= len(rp.pieces):
        return []
    return [(t0 + float(imp.t), imp.name) for imp in rp.pieces[k].impacts]
