"""nosnoc (FESD optimal control, IPOPT) as an optional peer of :mod:`lcp.ocp` on the Jean-Pratt problems.

The problems are those of :mod:`studies.optimal_control` (block m = M = 1, alpha = pi/4, R = 0.5,
pushed by a horizontal force |u| <= 20 N): ``"min_time"`` (rest to rest over 0.5 m), ``"min_effort"``
(int u^2 dt, T = 1 s) and ``"hold"`` (to rest at 0.3 m by 0.4 s, held until 0.6 s, back to rest at 0
by 1.2 s). With the block on the line, the contact reduces them to a Filippov system in (x, v)
with the switching function v:

    v > 0:  D+ a = u - c,   v < 0:  D- a = u + c,   c = R (m+M) g,  D+- = A (1 -+ kappa),

and sticking (the sliding mode on v = 0) while |u| <= c. nosnoc solves it in Stewart's form (two
regions) with FESD: N control stages of equal length, u constant on each, each stage cut into finite
elements whose lengths are free (so a stop or a start lands on an element boundary), a Scholtes
homotopy and IPOPT. The minimum time is posed as nosnoc_py does it: the horizon is a global variable
T (``v_global``) scaling the dynamics on the unit interval, with the cost T. The hold is a stage-wise
path constraint: a time-varying parameter is 1 on the stages ending in [t_a, t_b] and multiplies
(x - d, v), which nosnoc requires to vanish at each stage's end (so N must be a multiple of 6, the
hold's ends being stage boundaries, as for the study's uniform grid).

Every control is replayed open loop by the package's event-driven integrator (:func:`lcp.simulate`,
``method="event"``) on the study's controlled System over the whole horizon in one call, the
control's nodes being events: :func:`replay_nosnoc` reports the final-state miss (replay against
nosnoc's own final state, as the study's ``final_miss``) and, for the hold, the study's
:func:`~studies.optimal_control.hold_violation` measure (max |x - d|, |v| on [t_a, t_b]).

nosnoc is optional (``pip install "lcp-lem[ocp-peers]"``); :func:`available` says whether it imports.

Examples
--------
>>> from studies._nosnoc_peer import available, solve_nosnoc, replay_nosnoc
>>> if available():
...     res = solve_nosnoc("min_time", 10)
...     rp = replay_nosnoc(res)
...     ok = res.success and abs(res.objective - 0.44736274) < 1e-6 and rp.final_miss < 1e-8
... else:
...     ok = True
>>> ok
True
"""
from __future__ import annotations

import contextlib
import copy
import importlib.util
import io
import time
from dataclasses import dataclass, field

import numpy as np

import lcp
from lcp.model.control import ControlSchedule
from studies.optimal_control import (
    EVENT_SAMPLES,
    HOLD,
    REST,
    _scene_constants,
    controlled_block,
    hold_bound,
    min_effort_bound,
    min_time_bound,
)

__all__ = ["PROBLEMS", "NosnocReplay", "NosnocResult", "available", "reference", "replay_nosnoc", "scene_dynamics",
           "solve_and_replay", "solve_nosnoc"]

#: the problems and their continuous optima (closed form)
PROBLEMS = {"min_time": min_time_bound, "min_effort": min_effort_bound, "hold": hold_bound}
#: the horizon's bounds of the minimum-time problem (as the study's T_bounds)
T_BOUNDS = (0.05, 5.0)


def available() -> bool:
    """Whether nosnoc can be imported (the optional ``ocp-peers`` extra)."""
    return importlib.util.find_spec("nosnoc") is not None


def reference(problem: str) -> float:
    """The continuous optimum of ``problem`` (minimum time [s] or effort [N^2 s])."""
    _check_problem(problem)
    return PROBLEMS[problem]()


def scene_dynamics(R: float = REST["R"]) -> dict:
    """The Filippov constants of the block: c = R (m+M) g, D+ = A (1 - kappa), D- = A (1 + kappa)."""
    sc, c, D_plus, _ = _scene_constants(R)
    return {"c": c, "D_plus": D_plus, "D_minus": sc.A * (1.0 + sc.kappa), "u_max": REST["u_max"]}


@dataclass
class NosnocResult:
    """One nosnoc solve.

    ``objective`` is T (minimum time) or int u^2 dt recomputed from the control (nosnoc's own cost adds
    its step-equilibration penalty); ``control`` the piecewise-constant u on nosnoc's stage grid;
    ``status`` nosnoc's (``"SUCCESS"`` when the last IPOPT solve of the homotopy returned one of
    Solve_Succeeded, Solved_To_Acceptable_Level, Feasible_Point_Found, Search_Direction_Becomes_Too_Small,
    whatever the complementarity residual), ``ipopt_status`` that last IPOPT return status;
    ``complementarity_residual`` nosnoc's (the largest cross-complementarity product);
    ``x_final`` nosnoc's final (x, v); ``build_time`` (model, NLP and IPOPT set-up) and ``solve_time``
    (the homotopy) are wall-clock seconds.
    """

    problem: str
    N: int
    objective: float
    T: float
    control: ControlSchedule
    status: str
    ipopt_status: str
    complementarity_residual: float
    x_final: np.ndarray
    nlp_iterations: int
    homotopy_steps: int
    build_time: float
    solve_time: float
    fe_times: np.ndarray
    options: dict = field(default_factory=dict)
    log: str = ""

    @property
    def success(self) -> bool:
        return self.status == "SUCCESS"

    @property
    def rel_gap(self) -> float:
        ref = reference(self.problem)
        return (self.objective - ref) / abs(ref)


@dataclass
class NosnocReplay:
    """The event-driven replay of a nosnoc control: ``final_miss`` = max |(x, v)(T) replayed - nosnoc's|,
    ``target_miss`` the replay's distance to the problem's terminal target, ``hold_violation`` (hold
    problem; NaN otherwise) max |x - d|, |v| on [t_a, t_b], ``time`` the replay's wall-clock seconds."""

    sim: object
    final_miss: float
    target_miss: float
    hold_violation: float
    time: float


def _check_problem(problem):
    if problem not in PROBLEMS:
        raise ValueError(f"problem must be one of {sorted(PROBLEMS)}, got {problem!r}")


def _hold_stages(N: int) -> tuple[int, int]:
    t_a, t_b = HOLD["t_hold"]
    return round(N * t_a / HOLD["T"]), round(N * t_b / HOLD["T"])


def _build(problem, N, n_s, finite_elements, comp_tol, u_guess, T_guess, max_iter, sigma0, slope):
    import casadi as ca
    import nosnoc as ns

    k = scene_dynamics()
    x, v, u = ca.SX.sym("x"), ca.SX.sym("v"), ca.SX.sym("u")
    model_kw, ocp_kw = {}, {}
    scale = 1.0
    if problem == "min_time":
        # nosnoc_py 0.2.0 has no time-optimal switch: the horizon is a global variable scaling the
        # dynamics on the unit interval
        T_var = ca.SX.sym("T")
        scale, horizon, d = T_var, 1.0, REST["d"]
        model_kw["v_global"] = T_var
        ocp_kw.update(f_terminal=T_var, g_terminal=ca.vertcat(x - d, v), lbv_global=np.array([T_BOUNDS[0]]),
                      ubv_global=np.array([T_BOUNDS[1]]), v_global_guess=np.array([T_guess]))
    elif problem == "min_effort":
        horizon, d = REST["T_effort"], REST["d"]
        ocp_kw.update(f_q=u ** 2, g_terminal=ca.vertcat(x - d, v))
    else:
        if N % 6:
            raise ValueError(f"N must be a multiple of 6 for the hold problem (its ends are stage boundaries), got {N}")
        horizon, d = HOLD["T"], HOLD["d"]
        k_a, k_b = _hold_stages(N)
        on = ca.SX.sym("on_hold")
        # 1 on the stages ending in [t_a, t_b]: their end states are at rest at x = d
        model_kw.update(p_time_var=on, p_time_var_val=np.array([[1.0 if k_a - 1 <= j < k_b else 0.0]
                                                                 for j in range(N)]))
        ocp_kw.update(f_q=u ** 2, g_terminal=ca.vertcat(x, v), g_path=ca.vertcat(on * (x - d), on * v))
    f_pos = scale * ca.vertcat(v, (u - k["c"]) / k["D_plus"])
    f_neg = scale * ca.vertcat(v, (u + k["c"]) / k["D_minus"])
    model = ns.NosnocModel(x=ca.vertcat(x, v), F=[ca.horzcat(f_pos, f_neg)], c=[v], S=[np.array([[1], [-1]])],
                           x0=np.zeros(2), u=u, name=f"jean_pratt_{problem}", **model_kw)
    ocp = ns.NosnocOcp(lbu=np.array([-k["u_max"]]), ubu=np.array([k["u_max"]]), u_guess=np.array([u_guess]),
                       **ocp_kw)
    opts = ns.NosnocOpts()
    # NosnocOpts keeps its IPOPT options in a class-level dict shared by every instance (and its
    # tolerance, once set, is never reset): give each solve its own copy
    opts.opts_casadi_nlp = copy.deepcopy(ns.NosnocOpts.opts_casadi_nlp)
    opts.opts_casadi_nlp["ipopt"]["max_iter"] = max_iter
    opts.irk_scheme = ns.IrkSchemes.RADAU_IIA
    opts.n_s = n_s
    opts.N_finite_elements = finite_elements
    opts.N_stages = N
    opts.terminal_time = horizon
    opts.comp_tol = comp_tol
    opts.tol_ipopt = comp_tol * 1e-2
    opts.sigma_0 = sigma0
    opts.homotopy_update_slope = slope
    opts.mpcc_mode = ns.MpccMode.SCHOLTES_INEQ
    opts.cross_comp_mode = ns.CrossComplementarityMode.SUM_LAMBDAS_COMPLEMENT_WITH_EVERY_THETA
    opts.step_equilibration = ns.StepEquilibrationMode.HEURISTIC_MEAN
    opts.print_level = 0
    return ns.NosnocSolver(opts, model, ocp)


def solve_nosnoc(problem: str, N: int, *, n_s: int = 2, finite_elements: int = 2, comp_tol: float = 1e-10,
                 u_guess: float = 0.0, T_guess: float = 0.5, max_iter: int = 500, sigma0: float = 1.0,
                 slope: float = 0.1) -> NosnocResult:
    """Solve ``problem`` with nosnoc on N control stages.

    Parameters
    ----------
    problem : {"min_time", "min_effort", "hold"}
    N : int
        Control stages (>= 2; a multiple of 6 for the hold).
    n_s : int
        RADAU IIA stages per finite element.
    finite_elements : int
        Finite elements per control stage (free lengths, summing to the stage's).
    comp_tol : float
        Complementarity tolerance ending the homotopy; IPOPT's tolerance is comp_tol / 100.
    u_guess, T_guess : float
        Initial guess of every control value and of the horizon (minimum time).
    max_iter : int
        IPOPT iterations per homotopy step.
    sigma0, slope : float
        Initial Scholtes relaxation and its factor per homotopy step.

    Returns
    -------
    NosnocResult
    """
    _check_problem(problem)
    if not isinstance(N, (int, np.integer)) or N < 2:
        raise ValueError(f"N must be an integer >= 2, got {N!r}")
    for name, val in (("n_s", n_s), ("finite_elements", finite_elements), ("max_iter", max_iter)):
        if not isinstance(val, (int, np.integer)) or val < 1:
            raise ValueError(f"{name} must be an integer >= 1, got {val!r}")
    if not comp_tol > 0:
        raise ValueError(f"comp_tol must be > 0, got {comp_tol!r}")
    if not available():
        raise ImportError("nosnoc is not installed (pip install 'lcp-lem[ocp-peers]')")
    options = {"n_s": n_s, "finite_elements": finite_elements, "comp_tol": comp_tol, "u_guess": u_guess,
               "T_guess": T_guess, "max_iter": max_iter, "sigma0": sigma0, "slope": slope}
    log = io.StringIO()
    with contextlib.redirect_stdout(log):  # nosnoc prints IPOPT warnings; kept in ``log``
        t0 = time.perf_counter()
        solver = _build(problem, int(N), **options)
        build_time = time.perf_counter() - t0
        t0 = time.perf_counter()
        r = solver.solve()
        solve_time = time.perf_counter() - t0
    w = r["w_sol"]
    comp = float(solver.problem.comp_res(w, solver.p_val).full()[0, 0])
    iters = [i for i in r["nlp_iter"] if i is not None]
    u = np.asarray(r["u_list"], dtype=float).reshape(-1)
    scale = float(np.ravel(r["v_global"])[0]) if problem == "min_time" else 1.0
    t_u = np.asarray(r["t_grid_u"], dtype=float) * scale
    objective = scale if problem == "min_time" else float(np.sum(u ** 2 * np.diff(t_u)))
    return NosnocResult(problem=problem, N=int(N), objective=objective, T=float(t_u[-1]),
                        control=ControlSchedule(t_u, u), status=r["status"].name,
                        ipopt_status=str(solver.solver.stats()["return_status"]), complementarity_residual=comp,
                        x_final=np.asarray(r["x_out"], dtype=float).reshape(-1), nlp_iterations=int(sum(iters)),
                        homotopy_steps=len(iters), build_time=build_time, solve_time=solve_time,
                        fe_times=np.asarray(r["t_grid"], dtype=float) * scale, options=options, log=log.getvalue())


def replay_nosnoc(result: NosnocResult, samples: int = EVENT_SAMPLES) -> NosnocReplay:
    """Replay ``result.control`` open loop with the event-driven integrator on the study's System.

    One call of :func:`lcp.simulate` over [0, T] from rest, output at ``samples`` points per
    control stage (the hold is checked on them). Raises RuntimeError with the integrator's message
    if it fails.
    """
    if not isinstance(result, NosnocResult):
        raise ValueError("result must be a NosnocResult returned by solve_nosnoc")  # noqa: TRY004 (the project's convention)
    if not isinstance(samples, (int, np.integer)) or samples < 1:
        raise ValueError(f"samples must be an integer >= 1, got {samples!r}")
    sc, system = controlled_block()
    t_u = result.control.times
    t_eval = np.unique(np.concatenate([np.linspace(t_u[k], t_u[k + 1], samples + 1) for k in range(len(t_u) - 1)]))
    t_eval[-1] = t_u[-1]
    t0 = time.perf_counter()
    sim = lcp.simulate(system, float(t_u[-1]), method="event", control=result.control, q0=sc.q0, v0=sc.v0,
                       t_eval=t_eval)
    elapsed = time.perf_counter() - t0
    if not sim.success:
        raise RuntimeError(f"event replay of the nosnoc control failed: {sim.message}")
    end = np.array([sim.q[-1, 0], sim.v[-1, 0]])
    final_miss = float(np.max(np.abs(end - result.x_final)))
    target = {"min_time": (REST["d"], 0.0), "min_effort": (REST["d"], 0.0), "hold": (0.0, 0.0)}[result.problem]
    target_miss = float(np.max(np.abs(end - np.array(target))))
    viol = float("nan")
    if result.problem == "hold":
        t_a, t_b = HOLD["t_hold"]
        sel = (sim.t >= t_a - 1e-12) & (sim.t <= t_b + 1e-12)
        viol = float(max(np.max(np.abs(sim.q[sel, 0] - HOLD["d"])), np.max(np.abs(sim.v[sel, 0]))))
    return NosnocReplay(sim=sim, final_miss=final_miss, target_miss=target_miss, hold_violation=viol, time=elapsed)


def solve_and_replay(problem: str, N: int, u_guess: float = 0.0) -> dict:
    """One table row: :func:`solve_nosnoc`, then :func:`replay_nosnoc` (value, gap to the closed form,
    status, iterations, times; final miss, distance to the target and hold violation of the replay).
    A failed replay is reported in ``replay_error``, its misses left NaN, not hidden."""
    res = solve_nosnoc(problem, N, u_guess=u_guess)
    row = {"problem": problem, "N": N, "u_guess": u_guess, "value": res.objective, "reference": reference(problem),
           "rel_gap": res.rel_gap, "final_miss": float("nan"), "target_miss": float("nan"),
           "hold_violation": float("nan"), "success": res.success, "status": res.status,
           "ipopt_status": res.ipopt_status, "complementarity": res.complementarity_residual,
           "ipopt_iterations": res.nlp_iterations, "homotopy_steps": res.homotopy_steps, "build_s": res.build_time,
           "solve_s": res.solve_time, "total_s": res.build_time + res.solve_time, "replay_s": float("nan"),
           "replay_error": ""}
    try:
        rp = replay_nosnoc(res)
    except RuntimeError as err:
        row["replay_error"] = str(err)
        return row
    row.update(final_miss=rp.final_miss, target_miss=rp.target_miss, hold_violation=rp.hold_violation,
               replay_s=rp.time)
    return row
