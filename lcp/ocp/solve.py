"""Solving an optimal control problem: guess, transcription, homotopy or fixed phases, replay check.

:meth:`OptimalControlProblem.solve <lcp.ocp.problem.OptimalControlProblem.solve>` runs
:func:`solve_problem`; the problem object holds the data, this module the procedure. Imports the
other :mod:`lcp.ocp` modules below the problem (complementarity, guesses, replay, results).
"""
from __future__ import annotations

import contextlib
import copy
import time
from collections.abc import Iterator
from dataclasses import replace

import numpy as np

from lcp.ocp.blas import one_blas_thread
from lcp.ocp.heap import kept_heap
from lcp.ocp.collocation import RadauTranscription
from lcp.ocp.complementarity import run_homotopy, run_phases
from lcp.ocp.guess import event_guess, resample, screened_start, x0_from_guess
from lcp.ocp.landing import landable, landed
from lcp.ocp.options import OCP_STATUS_MESSAGES, HomotopyOptions, check_shooting
from lcp.ocp.plans import hybrid_plan
from lcp.ocp.replay import node_objective, piece_nodes, replay_check
from lcp.ocp.results import HomotopyStage, OCPGuess, OCPResult
from lcp.ocp.shooting import CHECK_TOL, MODE_TOL, NotShootable, refuse, solve_shooting
from lcp.ocp.spatial import SpatialTranscription
from lcp.ocp.transcription import Transcription

__all__ = ["bound_steps_note", "default_starts", "first_pass", "guess_from", "piecewise_uniform", "polished",
           "result_of", "same_guess",
           "finished", "solve_problem", "stuck_at_start", "unbounded_note", "uniform_fallback", "unstuck",
           "affine_first_pass", "first_pass_route", "solve_defaults", "solver_settings", "replay_objective_ratio",
           "FAR_REPLAY"]


def solve_problem(problem, guess, options, method, option_kw, shooting: bool = True,
                  first_hold: str = "constant") -> OCPResult:
    """The procedure of :meth:`OptimalControlProblem.solve <lcp.ocp.problem.OptimalControlProblem.solve>`."""
    own_sigma0 = options is not None or "sigma0" in option_kw  # the user's first relaxation: kept by every start
    if options is None:
        if problem.contact_law == "velocity":
            # sigma0 = 1e-4 keeps the gap law's relaxed contacts from pushing while open ("hovering");
            # the velocity law has no open contacts, and its routes were validated from sigma0 = 1
            # (from 1e-4 they land on worse local optima: measured 0.78 above the optimum, against
            # 7e-4, on the minimum-effort block at N = 20)
            option_kw = {"sigma0": 1.0, **option_kw}
        options = HomotopyOptions(**option_kw)
    elif option_kw:
        raise ValueError("give either options or keyword options, not both")
    if not isinstance(options, HomotopyOptions):
        raise ValueError(f"options must be HomotopyOptions, got {type(options).__name__}")
    if method not in ("auto", "homotopy", "phases"):
        raise ValueError(f"method must be 'auto', 'homotopy' or 'phases', got {method!r}")
    if method == "auto":  # free steps: place the first pass's phases exactly (falls back to the homotopy)
        method = "phases" if first_pass_route(problem, guess, method) else "homotopy"
    if problem.transcription is None:
        kind = RadauTranscription if getattr(problem, "integrator", "theta") == "radau" else Transcription
        problem.transcription = (SpatialTranscription if problem.system.is_spatial else kind)(problem)
    t0 = time.perf_counter()
    first_pass, history = [], None
    if method == "phases" and guess is None:
        guess = problem.phase_guess(replace(options, tol=max(options.tol, 1e-4), factor=min(options.factor, 1e-2)),
                                    hold=first_hold)
        first_pass = list(guess.homotopy)
    defaults = guess is None
    starts = default_starts(problem, own_sigma0) if defaults else iter([(None, guess_from(problem, guess), None)])
    run = run_phases if method == "phases" else run_homotopy
    tried, earlier = [], []  # the failed starts' messages and homotopy stages (kept in the history)
    last, message = None, ""
    # default starts whose solve converged but whose result failed (its replay, then the shooting):
    # the next start is tried too (the box tip at N = 10, measured when the mid-range control's
    # start still converged: from it cost 19.54, replay miss 2.1e-2; from the pulse start cost
    # 2.249, replay miss 1.4e-2. Now only the pulse start converges there)
    failed, res, where = [], None, None
    for label, gs, sigma0 in starts:
        if history is not None:  # a start before this one failed
            tried.append(f"from the {last}: {message.rstrip('.')}")
            earlier += history
        P0 = np.concatenate([[0.0], problem.q0, problem.v0])
        x0 = x0_from_guess(problem, problem.transcription, gs)
        opts = options if sigma0 is None else replace(options, sigma0=max(sigma0, options.sigma_min))
        x, cost, diag, status, message, history = run(problem.transcription, x0, P0, opts, problem.nlp_solvers)
        last = label
        if status < 0:
            continue
        if tried or last not in (None, MJ_START):
            message += (f" (Started from the {last}" + (f"; before it, {'; '.join(tried)}" if tried else "")
                        + ".)")
        res = finished(problem, x, cost, diag, status, message, first_pass + earlier + history, t0, method, shooting)
        where = (gs, opts, label)
        if res.success or not defaults:
            break
        failed.append((res, len(tried)))
        miss = f", replay miss {res.replay.final_miss:.2e}" if res.replay is not None else ""
        message = (f"its solution (cost {cost:.10g}{miss}) failed" + (", also after the exact-phase shooting"
                                                                      if shooting else ""))
    if res is None:  # no start converged: the last one's failure, as before
        if tried or last not in (None, MJ_START):
            message += (f" (Started from the {last}" + (f"; before it, {'; '.join(tried)}" if tried else "")
                        + ".)")
        return finished(problem, x, cost, diag, status, message, first_pass + earlier + history, t0, method,
                        shooting)
    if not res.success and failed:
        # the lowest-cost failure, with the starts tried after it
        res, k = min(failed, key=lambda rk: rk[0].cost if np.isfinite(rk[0].cost) else np.inf)
        later = tried[k + 1:] + ([f"from the {last}: {message.rstrip('.')}"] if k < len(tried) else [])
        if later:
            res.message += f" (Default starts tried after it: {'; '.join(later)}.)"
        res.solve_time = time.perf_counter() - t0
        return res
    gs, opts, label = where
    if defaults and not own_sigma0 and method == "homotopy" and res.success and opts.sigma0 < UNSTUCK_SIGMA0 \
            and stuck_at_start(problem, res, gs):
        return unstuck(problem, res, gs, label, opts, shooting, t0)
    return res


def finished(problem, x, cost, diag, status, message, history, t0, method, shooting) -> OCPResult:
    """One start's result: replay-checked, the relaxed tail's solution where the tail's fails its
    replay, and the exact-phase shooting (:func:`polished`) where it still fails."""
    res = _checked(problem, result_of(problem, x, cost, diag, status, message, history, time.perf_counter() - t0),
                   method)
    before = diag.get("before_tail")
    if before is not None and res.status == -3:  # the relaxed tail's solution failed its replay
        alt = _checked(problem, result_of(problem, *before, history, time.perf_counter() - t0), method)
        if alt.success:
            alt.message += (f" (The relaxed tail's solution, cost {cost:.10g}, failed its replay: "
                            f"{res.message})")
            return alt
    if shooting and res.status < 0 and problem.replay_tol is not None and np.all(np.isfinite(res.u)):
        return polished(problem, res, t0)
    return res


#: shooting rounds: each starts from the phase sequence of the event replay of the previous
#: round's control (a slide of the cart-pole that grazed zero velocity inside a phase stuck in
#: the replay: the next round has that stick phase)
SHOOTING_ROUNDS = 3
#: shooting solves on hybrid plans (:func:`~lcp.ocp.plans.hybrid_plan`) after the one from the
#: transcription's states, and how near (in replay tolerances) the replay must stay for its phases
HYBRID_ROUNDS = 2
HYBRID_NEAR = 100.0


def polished(problem, res, t0) -> OCPResult:
    """The exact-phase shooting polish (:mod:`lcp.ocp.shooting`) of a result that failed (its
    replay, or the solve): the phase sequence of the event replay of its control, solved again with
    each phase integrated exactly; repeated from the replay of the new control while that replay
    finds other phases (at most :data:`SHOOTING_ROUNDS` rounds). Returned when it succeeds and its
    replay is within tolerance; else ``res`` with a note saying why not."""
    try:
        refuse(problem)
    except NotShootable as exc:
        res.message += f" (Exact-phase shooting not tried: {exc}.)"
        return res
    notes = []
    # first from the replay's phases (a feasible start), then once from the transcription's own
    # states and modes (multiple shooting: its defects closed by IPOPT), which keeps a trajectory
    # the open-loop replay leaves (the cart-pole's swing-up: the replay of Radau's control misses
    # the upright by 17, the shooting from its states swings up at a cost 555.9)
    queue = [("replay", r) for r in range(SHOOTING_ROUNDS)] + [("result", 0)]
    far = replay_objective_ratio(res)
    if far > FAR_REPLAY:
        # the replay is another trajectory: the transcription's states first (the cart-pole at
        # N = 40: a first round from the replay, whose objective is 143 times the transcription's,
        # ran into IPOPT's iteration limit, 90 s; the whole solve took 112 s, 29 s in this order)
        queue = [("result", 0)] + queue[:-1]
        first = (f" (The objective on the event replay's nodes is {far:.3g} times the transcription's: the "
                 "shooting started from the transcription's states, before the replay's phases.)")
    else:
        first = ""
    start, plan = res, None
    while queue:
        kind, rnd = queue.pop(0)
        if kind == "result" or (kind, rnd) == ("replay", 0):
            start = res
        label = {"replay": f"round {rnd + 1}", "result": "from the transcription's states",
                 "hybrid": f"hybrid {rnd + 1}"}[kind]
        try:
            x, cost, diag, st, dt, tr = solve_shooting(problem, start, start="result" if kind == "hybrid" else kind,
                                                       plan=plan if kind == "hybrid" else None)
        except NotShootable as exc:
            notes.append(f"{label} not tried: {exc}")
            queue = _without_rounds(queue) if kind == "replay" else queue
            continue
        except RuntimeError as exc:  # the replay that gives the phases, or an integrator, failed
            notes.append(f"{label} failed: {exc}")
            # the next rounds would replay the same control
            queue = _without_rounds(queue) if kind == "replay" else queue
            continue
        ok = st["return_status"] in ("Solve_Succeeded", "Solved_To_Acceptable_Level")
        stage = HomotopyStage(0.0, int(st["iter_count"]), diag["residual"], 0.0, cost, st["return_status"], ok, dt)
        segments = sum(len(s) for s in tr.plan)
        if not ok or diag["dynamics"] > MODE_TOL or diag["residual"] > MODE_TOL:
            notes.append(f"{label} ({segments} phases) failed: IPOPT returned {st['return_status']}, "
                         f"defect {diag['dynamics']:.2e}, mode conditions violated by {diag['residual']:.2e}")
            # the next rounds would start from the same replay
            queue = _without_rounds(queue) if kind == "replay" else queue
            continue
        source = {"replay": "the event replay of the " + ("transcription" if rnd == 0 else f"shooting round {rnd}")
                  + "'s control", "result": "the transcription's own modes and states",
                  "hybrid": "the previous shooting's plan, with the phases of its control's event replay where "
                  f"that replay stays within {HYBRID_NEAR:g} replay_tol of it"}[kind]
        cut = (f", without the {st['pruned']} phases that IPOPT's iterate shrank to zero length"
               if st.get("pruned") else "")
        how = (f"exact-phase shooting on the {segments} phases of {source}{cut} (the phases joined as "
               f"CVODES integrates them at rtol {CHECK_TOL['reltol']:.0e})")
        out = result_of(problem, x, cost, diag, 0, f"Solved by {how}: every mode condition holds to "
                        f"{max(diag['residual'], 1e-16):.1e}, the phases join to {max(diag['dynamics'], 1e-16):.1e}.",
                        res.homotopy + [stage], time.perf_counter() - t0, tr=tr)
        out = _checked(problem, out, "shooting")
        if out.success:
            out.message += f" The transcription's result: {res.message}"
            if notes:
                out.message += f" (Exact-phase shooting before this one: {'; '.join(notes)})"
            out.message += first
            return out
        notes.append(f"{label} ({segments} phases, cost {cost:.10g}): {out.message}")
        start = out
        following = 0 if kind == "result" else rnd + 1
        if kind != "replay" and following < HYBRID_ROUNDS and out.replay is not None and out.replay.pieces:
            # its replay follows it for a while, then leaves (hybrid_plan): once more on the replay's
            # phases where it follows
            try:
                plan = hybrid_plan(out, tr.plan, HYBRID_NEAR * problem.replay_tol)
            except NotShootable as exc:
                plan = None
                notes[-1] += f" (no hybrid plan: {exc})"
            if plan is not None:  # next: it follows this shooting, whose plan it amends
                queue.insert(0, ("hybrid", following))
        if kind == "replay" and np.isfinite(res.cost) and cost - res.cost > abs(res.cost):
            # the replay's phases led far from the transcription's solution: the next rounds would
            # follow this control's replay further (the cart-pole at N = 20, from a transcription
            # of cost 644 whose replay misses by 24: rounds at 125889 and 92139, then IPOPT's
            # iteration limit, 80 s; the start from the transcription's own states comes next)
            notes[-1] += f" (more than twice the transcription's cost {res.cost:.10g}: no further replay rounds)"
            queue = _without_rounds(queue)
    res.message += f" (Exact-phase shooting: {'; '.join(notes)}){first}"
    return res


#: the objective on the event replay's nodes, over the transcription's (:func:`replay_objective_ratio`),
#: above which the exact-phase shooting starts from the transcription's states, not from the
#: replay's phases (measured: the cart-pole 240, 143 and 11 at N = 20, 40 and 80; the two discs
#: 2.9 at N = 30, which succeed from the replay's phases; the motor, the chain, the box, the hopper
#: about 1)
FAR_REPLAY = 100.0


def replay_objective_ratio(res) -> float:
    """The objective on the nodes of the event replay of ``res``'s control, over the same on its own
    nodes (:func:`lcp.ocp.replay.node_objective`: one rule for both); nan without an event replay
    or where the objective on its own nodes is not positive."""
    rc = res.replay
    if rc is None or not rc.pieces:
        return float("nan")
    q, v = piece_nodes(rc.pieces)
    own = node_objective(res, res.q, res.v)
    return node_objective(res, q, v) / own if own > 0 else float("nan")


def _without_rounds(queue):
    """The shooting queue of :func:`polished` without its remaining replay rounds."""
    return [a for a in queue if a[0] != "replay"]


def _checked(problem, res, method):
    """The result with its bound-steps note and its replay check (status -3 where it misses)."""
    if method == "phases" and problem.steps == "free":
        res.message += bound_steps_note(problem, res)
    if problem.replay_tol is not None and np.all(np.isfinite(res.q)):
        # the message is written after the replay: what the solve found, then what the replay found
        try:
            res.replay = replay_check(res, problem.replay_tol)
        except RuntimeError as exc:
            solved = res.message
            res.status = -3
            res.message = (f"{OCP_STATUS_MESSAGES[-3]} The replay failed: {exc}{unbounded_note(problem)} "
                           f"Before the replay: {solved}")
            return res
        rc = res.replay
        landing = ""
        if method == "shooting" and res.status >= 0 and not rc.ok and landable(rc, problem.replay_tol):
            out, landing = landed(res, rc, problem.replay_tol)
            if out is not None:
                res, rc = out, out.replay
        if res.status >= 0 and not rc.ok:
            solved = res.message
            res.status = -3
            hint = (" The velocity law keeps every contact closed: if a contact should open, give "
                    "contact_law='gap'." if problem.contact_law == "velocity" else "")
            res.message = (f"{OCP_STATUS_MESSAGES[-3]} Replayed by {rc.method}: final-state miss "
                           f"{rc.final_miss:.2e}, path violation {rc.path_violation:.2e} > {problem.replay_tol:.1e}"
                           f"{'; ' + rc.where if rc.where else ''}.{amplified_note(rc) if not landing else landing}"
                           f"{hint}{unbounded_note(problem)} "
                           f"Before the replay: {solved}")
        elif res.status >= 0:
            err = (f" (the integrator's error estimated {rc.integration_error:.1e})"
                   if np.isfinite(rc.integration_error) else "")
            res.message += (f"{landing} Replayed by {rc.method}: final-state miss {rc.final_miss:.2e}{err}, path "
                            f"violation {rc.path_violation:.2e}, within replay_tol = {problem.replay_tol:.1e}.")
    return res


def amplified_note(rc) -> str:
    """Said when a missing replay amplifies start-state errors so much that the optimizer's
    trajectory would need to be exact below 1e-10 for the replay to land within tolerance."""
    a = rc.amplification
    if not np.isfinite(a) or rc.tol / max(a, 1e-300) > 1e-10:
        return ""
    return (f" The replay amplifies errors: a change of the start state moves its final state {a:.1e} "
            f"times as far, so the optimizer's trajectory would have to be exact to about {rc.tol / a:.0e} "
            f"for its replay to land within {rc.tol:.1e} (an unstable trajectory, open loop).")


def unbounded_note(problem) -> str:
    """Said when the replay fails and a control component has no bound on one side or both."""
    free = np.flatnonzero(~(np.isfinite(problem.u_min) & np.isfinite(problem.u_max)))
    if not free.size:
        return ""
    return (f" The control {'component' if free.size == 1 else 'components'} {free.tolist()} "
            f"{'has' if free.size == 1 else 'have'} no bound (u_min, u_max or the system's control_bounds): "
            "the optimizer may use forces and steps that the replay cannot follow.")


#: first relaxation of the second solve from a start whose control the first solve left unchanged
#: (:func:`unstuck`): the velocity law's default, under which the friction pairs pass a gradient
UNSTUCK_SIGMA0 = 1.0


def stuck_at_start(problem, res, gs, rtol: float = 1e-6) -> bool:
    """Whether a solved control is the start's own control with no control bound active: the solve
    ended where it began, a stationary point of the start. A default start's control is arbitrary
    (the mid-range), and at a contact that sticks an exact friction law passes no gradient to a push
    that stays inside the friction cone: the nosnoc cart-pole (friction 2 N, |u| <= 30 N) started at
    rest with u = 0 ends at u = 0, the pole hanging, cost 6471.76, at N = 20, 40 and 80."""
    u, u0 = np.asarray(res.u, dtype=float), np.asarray(gs.u, dtype=float)
    if u.shape != u0.shape or not u.size:
        return False
    lo, hi = np.broadcast_to(problem.u_min, u.shape), np.broadcast_to(problem.u_max, u.shape)
    span = np.where(np.isfinite(hi - lo), hi - lo, np.maximum(1.0, np.abs(u0)))
    inside = np.all((u - lo > rtol * span) & (hi - u > rtol * span))
    return bool(inside and np.all(np.abs(u - u0) <= rtol * span))


def unstuck(problem, res, gs, label, options, shooting, t0) -> OCPResult:
    """A second solve from the start ``gs`` of a result stuck there (:func:`stuck_at_start`), from
    sigma0 = :data:`UNSTUCK_SIGMA0`: the relaxed friction pairs let a push move a sticking contact.
    Returned when it succeeds at a lower cost, else ``res`` with a note saying what it found.
    Measured on the nosnoc cart-pole at N = 20 (theta transcription, gap law): from sigma0 = 1e-4
    the pole never leaves the bottom (cost 6471.76), from sigma0 = 1 it swings up (cost 644.0).
    The friction's relaxation is what frees it: with only the friction pairs relaxed 1e4 times
    more than the normal ones from sigma0 = 1e-4 (an experiment, not the package's transcription)
    the homotopy lands on the same 644.02."""
    alt = solve_problem(problem, gs, replace(options, sigma0=max(UNSTUCK_SIGMA0, options.sigma0)), "homotopy",
                        {}, shooting)
    head = (f"The solve from the {label} ended on that start's control (no control bound active, "
            f"cost {res.cost:.10g}): a stationary point of the start")
    if alt.success and alt.cost < res.cost:
        alt.message += f" ({head}; solved again from sigma0 = {UNSTUCK_SIGMA0:g}.)"
        alt.solve_time = time.perf_counter() - t0
        alt.homotopy = res.homotopy + alt.homotopy
        alt.iterations = sum(s.iterations for s in alt.homotopy)
        return alt
    res.message += (f" ({head}. From sigma0 = {UNSTUCK_SIGMA0:g} the solve found cost {alt.cost:.10g} but "
                    f"{'not a lower one' if alt.success else 'failed'}: {alt.message})")
    res.solve_time = time.perf_counter() - t0
    return res


#: label of the default start (:func:`default_starts`)
MJ_START = "Moreau-Jean simulation of the mid-range control"
#: label of the second start under the gap law
EVENT_START = "event-method simulation of the mid-range control"


def default_starts(problem, own_sigma0: bool = False):
    """The starts tried in turn when ``solve`` has no guess: yields (label, OCPGuess, sigma0 or None).

    First the simulation of the mid-range control by Moreau-Jean at the problem's step
    (:func:`guess_from`). Under the gap law, when the solve from it fails (IPOPT, or the homotopy's
    residual), the same control simulated by the event method and sampled at the nodes
    (:func:`~lcp.ocp.guess.event_guess`), whose nodes do not penetrate: Moreau-Jean closes a
    contact one step late, the gap law bounds every node's gap below by zero, and from such a guess
    IPOPT can end infeasible in the first relaxation (not tried when it is the first start again,
    :func:`same_guess`: a control that touches no contact, such as two discs left at rest, has the
    same simulation by both methods, and the solve from it would repeat the same failure). Then
    the pulse start of :func:`~lcp.ocp.guess.screened_start` (a fraction of the mid-range push over the first part of
    the horizon, the one whose event simulation meets the terminal constraints at the lowest cost;
    none when the mid-range control is the rest control): a mid-range push can carry the system
    far past its target (the box tip). Then, unless the caller chose sigma0, the
    event guess again from sigma0 = 1: the default 1e-4 keeps resting contacts from hovering, but
    asks a landing to fall on a node almost at once. Measured on a ball (e = 0.5) dropped from 1 m
    to a height 0.2 m at T = 0.6 s after its bounce: N = 12 infeasible from Moreau-Jean's guess,
    solved from the event guess; N = 24 infeasible from both at sigma0 <= 0.1, solved from the
    event guess at sigma0 = 1. Each start is simulated only when the one before it failed (its
    solve, or its result's replay and exact-phase shooting); a problem solved from the first is
    solved as before, except that a solve ending on its start's own control is repeated
    (:func:`stuck_at_start`, :func:`unstuck`)."""
    mj = guess_from(problem, None)
    yield MJ_START, mj, None
    if problem.contact_law != "gap" or not problem.system.n_contacts or problem.system.is_spatial:
        return
    ev = event_guess(problem, mj.u, problem.T)
    if ev is None:
        return
    if not same_guess(mj, ev):  # the same start again would repeat the same failure
        yield EVENT_START, ev, None
    # the pulse start before the larger first relaxation: it keeps the small sigma0 (no hovering),
    # and a problem it solves is spared that solve (on the box tip at N = 20: 1242 IPOPT
    # iterations, ending infeasible)
    screened = screened_start(problem, problem.transcription)
    if screened is not None:
        a, f, gs = screened
        yield (f"event-method simulation of {a:g} of the mid-range control's distance from rest over the "
               f"first {f:g} of the horizon (the pulse start nearest the terminal constraints)"), gs, None
    if not own_sigma0:
        yield EVENT_START + " from sigma0 = 1", ev, 1.0


def same_guess(a: OCPGuess, b: OCPGuess, rtol: float = 1e-12) -> bool:
    """Whether two guesses agree in every node value (states, controls, impulses) to ``rtol`` of
    their largest: Moreau-Jean's and the event method's simulations of a control that touches no
    contact (two discs at rest under the rest control) are the same start, and the solve from it
    is deterministic."""
    pairs = [(a.q, b.q), (a.v, b.v), (a.u, b.u), (a.p_N, b.p_N), (a.p_T, b.p_T)]
    if any(np.shape(x) != np.shape(y) for x, y in pairs):
        return False
    scale = max(1.0, *(float(np.max(np.abs(x), initial=0.0)) for x, _ in pairs))
    return all(np.allclose(x, y, rtol=0.0, atol=rtol * scale) for x, y in pairs)


def guess_from(problem, guess) -> OCPGuess:
    if guess is None:
        # the middle of finite bounds, else 0 clipped to the one finite bound (computed only where both
        # are finite: inf + -inf would warn)
        both = np.isfinite(problem.u_min) & np.isfinite(problem.u_max)
        mid = np.array(np.clip(0.0, problem.u_min, problem.u_max), dtype=float)
        mid[both] = 0.5 * (problem.u_min[both] + problem.u_max[both])
        return problem.guess(u=mid)
    if isinstance(guess, (OCPResult, OCPGuess)):
        rows = problem.control_rows
        if guess.q.shape != (problem.N + 1, problem.system.n) or guess.u.shape != (rows, problem.nu):
            return resample(guess, problem.N, problem.hold)
        return guess
    raise ValueError(f"guess must be None, an OCPGuess or an OCPResult, got {type(guess).__name__}")


def bound_steps_note(problem, res) -> str:
    """A note naming the free steps that end at a length bound: with the phase sequence fixed,
    such a step can hold the solution at a local optimum of that sequence (a slide that needs
    more room than one step's upper bound, a control slope stuck on a shortest step)."""
    # (the bound of the variables: with free time, relative to the largest T of T_bounds)
    T = problem.T_bounds[1] if problem.free_time else res.T
    hi = problem.step_bounds[1] * T / problem.N
    at_hi = np.flatnonzero(res.steps >= hi * (1 - 1e-6))
    if not at_hi.size:
        return ""
    return (f" Steps {at_hi.tolist()} end at their upper length bound (step_bounds): the phase sequence may "
            f"be held at a local optimum; compare with method='homotopy'.")


def result_of(problem, x, cost, diag, status, message, history, solve_time, tr=None) -> OCPResult:
    tr = problem.transcription if tr is None else tr
    T, hs, q, v, u, pN, pT = tr.unpack(x)
    t = np.concatenate([[0.0], np.cumsum(hs)])
    t[-1] = T
    peak = float(x[tr.ix["z"]].ravel()[0]) if problem.max_cost is not None else float("nan")
    return OCPResult(t=t, q=q, v=v, u=u, control=problem.schedule(t, u), hold=problem.hold, steps=hs,
                     p_N=pN, p_T=pT, modes=diag["modes"], T=T, h=T / problem.N, cost=cost, peak=peak,
                     complementarity_residual=diag["residual"], lcp_residual=diag["lcp"],
                     dynamics_residual=diag["dynamics"], inactive_conflicts=diag["conflicts"],
                     status=status, message=message, homotopy=history,
                     iterations=sum(s.iterations for s in history), solve_time=solve_time,
                     build_time=problem.build_time, problem=problem)


def first_pass(problem, options: HomotopyOptions | None = None, hold: str = "constant") -> OCPResult:
    """:meth:`OptimalControlProblem.phase_guess <lcp.ocp.problem.OptimalControlProblem.phase_guess>`:
    the problem's twin on fixed steps, uniform between the nodes pinned by ``node_times``
    (:func:`piecewise_uniform`, stored as the twin's ``step_fractions``), ``hold`` (constant by
    default, or the problem's affine hold: :func:`affine_first_pass`), no replay."""
    twin = copy.copy(problem)
    twin.steps, twin.hold, twin.replay_tol, twin.transcription, twin.nlp_solvers = "uniform", hold, None, None, {}
    # the phases, not the integration, are wanted: a Radau problem's first pass on theta steps
    twin.integrator = "theta"
    # with a free T the pins stay constraints of the uniform twin (its grid scales with T)
    twin.step_fractions = None if problem.free_time else piecewise_uniform(problem.N, problem.T, problem.node_times)
    return twin.solve(options=options or HomotopyOptions(tol=1e-4, factor=1e-2))


def piecewise_uniform(N: int, T: float, node_times: dict):
    """Step lengths / T of the grid uniform between the pinned nodes of ``node_times`` (None when
    the uniform grid already holds them), or ValueError when the pins are not increasing in k."""
    if all(abs(t - k * T / N) <= 1e-12 * T for k, t in node_times.items()):
        return None
    ks = [0] + sorted(node_times) + [N]
    ts = [0.0] + [node_times[k] for k in sorted(node_times)] + [T]
    if np.any(np.diff(ts) <= 0):
        raise ValueError(f"node_times must increase with the node index and lie within (0, T), got {node_times!r}")
    frac = np.concatenate([np.full(k1 - k0, (t1 - t0) / (k1 - k0)) for k0, k1, t0, t1 in
                           zip(ks[:-1], ks[1:], ts[:-1], ts[1:])]) / T
    return frac


def first_pass_route(problem, guess, method) -> bool:
    """Whether ``solve`` runs the fixed-phase solve from its own first pass: free steps, a planar
    contact, no guess, and ``method`` "auto" or "phases"."""
    return (method in ("auto", "phases") and guess is None and problem.steps == "free"
            and bool(problem.system.n_contacts) and not problem.system.is_spatial)


def uniform_fallback(problem, res, guess, options, method, option_kw, shooting) -> OCPResult:
    """The solve of a problem whose free steps ``steps="auto"`` chose, repeated on uniform steps
    (and the constant hold where the hold was "auto" too) after ``res`` failed. Free steps with the
    affine hold make the Jean-Pratt problems exact, but their fixed-phase route is less robust on
    others: measured from the defaults, a two-block chain (replay miss 0.30), a block with a user
    complementarity pair (0.20) and a landing on a curved floor (1.4e-3) fail on free steps and
    succeed on uniform ones, where the exact-phase shooting finishes them. Returned when it
    succeeds, with a note; else ``res`` with a note saying what the uniform solve found. Not tried
    when a pinned node is off the uniform grid: there a step-indexed term would move in time."""
    T, N = problem.T, problem.N
    off = [k for k, t in problem.node_times.items() if abs(t - k * T / N) > 1e-12 * T]
    head = f"The solve on free steps (the default for this problem) failed: {res.message}"
    if off and not problem.free_time:
        res.message += (f" (Not solved again on uniform steps: the pinned nodes {off} are not nodes of the "
                        "uniform grid.)")
        return res
    twin = copy.copy(problem)
    twin.steps, twin.transcription, twin.nlp_solvers = "uniform", None, {}
    if twin.hold == "affine" and problem.hold_auto:
        twin.hold = "constant"
    alt = twin.solve(guess, options, "homotopy" if method == "homotopy" else "auto", shooting, **option_kw)
    if alt.success:
        alt.message += f" (Solved on uniform steps with the {twin.hold} hold. {head})"
        alt.solve_time += res.solve_time
        return alt
    res.message += (f" (Solved again on uniform steps with the {twin.hold} hold: it failed too, cost "
                    f"{alt.cost:.10g}: {alt.message})")
    res.solve_time += alt.solve_time
    return res


def affine_first_pass(problem, res, options, option_kw, shooting) -> OCPResult:
    """The fixed-phase solve of an affine-hold problem repeated from a first pass with the affine
    hold (the default first pass holds the control constant), the result of lower cost kept. With a
    piecewise-constant control, a move that should end at rest on a pinned node can stop a step
    early, and the fixed-phase solve keeps the stick step before the node; with the affine hold it
    ends on the node. Neither first pass is always the better: measured on the move-and-hold at
    N = 40 on [0.38, 0.62] s, T = 1.1 s, 3.5e-3 above the optimum from the constant hold's phases
    and 1.9e-11 from the affine hold's (on [0.42, 0.6] s, T = 1.15 s: 1.7e-3 and 1.0e-5); at N = 10
    on [0.4, 0.6] s, T = 1.2 s, exact from the constant hold's and 2.5e-3 above from the affine's."""
    alt = solve_problem(problem, None, options, "phases", option_kw, shooting, first_hold="affine")
    if alt.success and (not res.success or alt.cost < res.cost - 1e-9 * max(1.0, abs(res.cost))):
        alt.message += (f" (From the phases of a first pass with the affine hold; from the constant hold's, "
                        f"{'cost ' + format(res.cost, '.10g') if res.success else 'the solve failed'}.)")
        alt.solve_time += res.solve_time
        return alt
    res.solve_time += alt.solve_time
    return res


@contextlib.contextmanager
def solver_settings() -> Iterator[None]:
    """The process settings every solve runs under, for IPOPT's linear solver: CasADi's OpenBLAS on
    one thread (:func:`lcp.ocp.blas.one_blas_thread`) and its workspace kept on the C heap
    (:func:`lcp.ocp.heap.kept_heap`); each restored at the last exit."""
    with one_blas_thread(), kept_heap():
        yield


def solve_defaults(problem, guess, options, method, option_kw, shooting) -> OCPResult:
    """:func:`solve_problem`, then what the defaults add. An affine problem on free steps solved by
    fixed phases from its own first pass is solved again from the affine hold's first pass
    (:func:`affine_first_pass`); a problem on the free steps that ``steps="auto"`` chose is solved
    again on uniform steps when it failed (:func:`uniform_fallback`).

    The default grid is free steps with the affine hold for planar contacts: on uniform steps the
    Jean-Pratt problems at N = 40 stop 2.5e-4 (minimum time: the switch falls inside a step, and
    the uniform solution replays to 9e-11, so nothing flags it) and 3.4e-4 (minimum effort: a
    piecewise-constant control on a ramp) above their optima, after the exact-phase shooting too.

    It runs under :func:`solver_settings` (one BLAS thread, the linear solver's workspace kept on
    the C heap)."""
    check_shooting(shooting)
    with solver_settings():
        res = solve_problem(problem, guess, options, method, option_kw, shooting)
        if problem.hold == "affine" and first_pass_route(problem, guess, method):
            res = affine_first_pass(problem, res, options, option_kw, shooting)
        # (steps checked too: a first pass's uniform twin copies the flag)
        if problem.grid_fallback and problem.steps == "free" and not res.success:
            res = uniform_fallback(problem, res, guess, options, method, option_kw, shooting)
    return res
