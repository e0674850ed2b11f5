"""Open-loop replay of an optimal control on the same System, and the replay miss of a solution.

The control of a solution is a :class:`lcp.control.ControlSchedule`; the replay simulates the
problem's own controlled System with it (``System.with_control``), so there is no second model:

- ``method="moreau-jean"`` at the optimizer's step (``refine=1``, uniform steps) repeats the
  optimizer's steps, the control's impulse over each step integrated exactly, so the mismatch is
  round-off; at ``refine > 1`` it measures the time-discretization error of the transcription.
- ``method="event"``: the event-driven integrator (:mod:`lcp.events`) restarted at every node of
  the control, the control's breakpoints thus being events; exact (to round-off) wherever the
  phases have closed forms (constant forces, as for the Jean-Pratt block under a piecewise-constant
  control), and it follows the continuous-time response whatever the transcription's steps.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from ..control import ControlSchedule
from .results import OCPResult, ReplayCheck, ReplayResult

__all__ = ["replay", "replay_check"]


def _event_available() -> bool:
    from .. import simulation

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


def _replay_event_pieces(result: OCPResult, **options):
    """Event-driven replay restarted at every node: (q, v) at the nodes, the piece results."""
    from ..simulation import simulate

    pb = result.problem
    sysc, t, sched = pb.system, result.t, result.control
    q, v = [pb.q0.copy()], [pb.v0.copy()]
    pieces = []
    for k in range(len(t) - 1):
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
        Moreau-Jean at a uniform step, or the event-driven integrator restarted at every node.
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
    >>> res = rest_to_rest_problem(10, "time").solve()
    >>> replay(res, refine=1).max_error_q < 1e-12
    True
    """
    from ..simulation import simulate

    if not isinstance(result, OCPResult) or result.problem is None:
        raise ValueError("result must be an OCPResult returned by OptimalControlProblem.solve")
    if not isinstance(refine, (int, np.integer)) or refine < 1:
        raise ValueError(f"refine must be an integer >= 1, got {refine!r}")
    if method not in ("moreau-jean", "event"):
        raise ValueError(f"method must be 'moreau-jean' or 'event', got {method!r}")
    pb = result.problem
    N = len(result.t) - 1
    if method == "event":
        q, v, pieces = _replay_event_pieces(result, **method_options)
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


def replay_check(result: OCPResult, tol: float, refine: int = 50) -> ReplayCheck:
    """The replay miss of a solution: final state and path constraints, replayed open loop.

    The event-driven replay (exact, restarted at the control's nodes) for a piecewise-constant
    or piecewise-affine control when the event integrator is available and the drift does not depend on time;
    otherwise (continuous linear hold) Moreau-Jean at T / (N refine), which reports its method and step.
    Path constraints (the largest value) and path equalities (the largest magnitude) are
    evaluated on the replayed states at the nodes (with the optimizer's impulses and controls).
    """
    pb = result.problem
    # the event replay is exact for the constant and the affine hold (polynomial phases in closed
    # form); for the linear hold the Moreau-Jean replay is kept as before (a pinned, cheaper check)
    if result.hold in ("constant", "affine") and _event_available() and not pb.system.force_depends_on_t:
        rp = replay(result, method="event", n_eval=2)  # the nodes only: no dense output to evaluate
        method = "event"
    else:
        rp = replay(result, refine=refine)
        method = f"moreau-jean h={rp.h:.3g}"
    final = float(max(np.max(np.abs(rp.q[-1] - result.q[-1])), np.max(np.abs(rp.v[-1] - result.v[-1]))))
    nodes = float(max(rp.max_error_q, rp.max_error_v))
    viol = 0.0
    if pb.path_constraints is not None or pb.path_equalities is not None:
        u = result.u
        for k in range(len(result.t) - 1):
            j = 2 * k if result.hold == "affine" else k
            ua, ub = u[j], u[j] if result.hold == "constant" else u[j + 1]
            st = pb.make_step(k, result.t[k], result.steps[k], rp.q[k], rp.q[k + 1], rp.v[k], rp.v[k + 1],
                              ua, ub, result.p_N[k], result.p_T[k])
            for fn, absolute in ((pb.path_constraints, False), (pb.path_equalities, True)):
                if fn is None:
                    continue
                val = fn(st)
                if isinstance(val, ca.SX):  # built with CasADi operations on numbers: constant
                    val = ca.evalf(val)
                val = np.array(val, dtype=float).ravel()
                if val.size:
                    viol = max(viol, float(np.max(np.abs(val) if absolute else val)))
    return ReplayCheck(method=method, final_miss=final, node_miss=nodes, path_violation=viol, tol=tol)
