"""Optimal control of the Jean-Pratt block through frictional contact.

Problems on the Jean-Pratt scene (m = M = 1, alpha = pi/4, g = 9.81), the control a horizontal
force u on the block, solved with :mod:`lcp.ocp` (Moreau-Jean transcription, Scholtes homotopy,
IPOPT), every solution replayed open loop on the same System:

1. **Rest to rest** (R = 0.5, kappa = 0.25, |u| <= 20 N, from rest at x = 0 to rest at 0.5 m):
   (a) minimum time, against the bang-bang optimum T* = sqrt(2 d (1/a1 + 1/a2)), a1 = (u_max - c)/D,
   a2 = (u_max + c)/D, c = R (m+M) g, D = A (1 - kappa) (forward sliding: D a = u - c);
   (b) minimum effort int u^2 dt over T = 1 s, against J* = (4/3) c^2 L*, L* = (36 D^2 d^2/c^2)^(1/4):
   the block sticks, then slides for L* while u falls linearly from 2c to 0.
2. **Move and hold** (same block): to rest at x = 0.3 m by t = 0.4 s, held there (at rest) until
   0.6 s, back to rest at x = 0 by T = 1.2 s, with minimum effort. Backward sliding has the larger
   inertia D- = A (1 + kappa) (the friction's reaction lifts M), so the way back needs more time
   (with T = 1 s it could not be done: its minimum time is 0.4445 s > 0.4 s). Each move is shorter
   than its free optimum L*, so u is affine in t and clipped at u_max: u = min(u_max, alpha + beta t)
   (:func:`move_effort`, closed form; :func:`hold_bound` = 168.49986 N^2 s).
3. **Shock avoidance** (R = 1.9, kappa = 0.95, v0 = 1 m/s): stop by T = 0.2 s with the smallest
   peak normal force, |u| <= 39 N; bound (m+M) g + M tan(alpha) v0 / T = 24.62 N against the
   uncontrolled N0 = 392 N.

Three transcriptions are compared (``METHODS``): uniform steps with the control linear between
nodes (the former default); uniform steps with a piecewise-constant control (consistent with the
step's impulse: replayed exactly wherever the mode does not change inside a step); and free step
lengths with FESD cross complementarity (the stop and the control's switches placed on nodes, so
that the transcription is exact between them and the objective converges at high order).

Why the linear hold made the minimum-effort control ring before the block moves: while the block
sticks, the dynamics only require |u| <= c, so the cost alone picks u; the linear hold's cost
(u_k^2 + u_k u_{k+1} + u_{k+1}^2)/3 couples neighbouring nodes, and its minimizer given the first
moving value is the geometric sequence of ratio -(2 - sqrt(3)). It is the true discrete optimum of
that parametrization, an artefact of it; the piecewise-constant hold's cost decouples and gives
u = 0 exactly while the block sticks.

Documented initial guesses: the simulation of u = 0 on the problem's grid
(:meth:`~lcp.ocp.OptimalControlProblem.guess`) for uniform steps; for free steps a deterministic
multi-start from that simulation and from the uniform-step, constant-hold solution at the same N
(with sigma0 = 1, 1e-2 and 1e-4): the free-step MPCC has local minima, and ``message`` and the CSV column
``distinct_optima`` say when the starts disagree. The hold problem also runs the deterministic
multi-start (:meth:`~lcp.ocp.OptimalControlProblem.solve_multistart`) and reports whether the
starts agree.

Fixed-phase solves (``PHASE_METHODS``, ``solve(method="phases")``): a first pass on uniform steps
gives the mode of every step; with those modes fixed, one smooth NLP with free steps places the
switches, without the homotopy (tens of IPOPT iterations). It reaches the optimum of that phase
sequence, which here is the continuous optimum to 1e-12 with the affine hold (effort, hold) and to
1e-9 with the constant hold (minimum time), unless a step is pinned at a length bound.

nosnoc (FESD with IPOPT, the optional extra ``ocp-peers``) solves the same problems when installed
(``studies._nosnoc_peer``); its controls are replayed by the same event integrator and its series
join the convergence figure (``nosnoc.csv``); without it the figure says they are skipped.

``python -m studies.optimal_control [--out DIR] [--quick]`` writes the figures and CSV tables.
"""
from __future__ import annotations

import math
from pathlib import Path

import casadi as ca
import numpy as np

from studies._common import out_dir, parse_args, save, write_csv  # noqa: I001 (selects the Agg backend)
import matplotlib.pyplot as plt  # noqa: E402

import lcp  # noqa: E402
from lcp.contact.problem import MODE_NAMES, OPEN, SLIDE_NEG, SLIDE_POS, STICK  # noqa: E402
from lcp.ocp import OptimalControlProblem, add_control, effort, replay, tangential_push  # noqa: E402

NAME = "optimal_control"
DESCRIPTION = "Optimal control through frictional contact: rest to rest, move and hold, shock avoidance."

G = 9.81
BASE = {"m": 1.0, "M": 1.0, "alpha": math.pi / 4, "g": G}
#: problem 1 (rest to rest)
REST = {"R": 0.5, "d": 0.5, "u_max": 20.0, "T_effort": 1.0}
#: problem 2 (move, hold, return)
HOLD = {"d": 0.3, "t_hold": (0.4, 0.6), "T": 1.2}
#: problem 3 (shock avoidance)
SHOCK = {"R": 1.9, "v0": 1.0, "T": 0.2, "u_max": 39.0, "rate_weight": 1e-6}
SHOCK_SWEEP_R = (1.8, 1.9, 1.98)  # kappa = 0.9, 0.95, 0.99
#: transcriptions compared: label -> OptimalControlProblem options
METHODS = {"uniform, linear hold": {"hold": "linear", "steps": "uniform"},
           "uniform, constant hold": {"hold": "constant", "steps": "uniform"},
           "free steps, constant hold": {"hold": "constant", "steps": "free"},
           "free steps, affine hold": {"hold": "affine", "steps": "free"}}
#: the fixed-phase solves (``solve(method="phases")``): a uniform-step, constant-hold first pass
#: gives the phase sequence, one smooth NLP with free steps places its switches (no homotopy)
PHASE_METHODS = {"fixed phases, constant hold": {"hold": "constant", "steps": "free"},
                 "fixed phases, affine hold": {"hold": "affine", "steps": "free"}}
#: every transcription and solve compared, in the order of the tables and figures
ALL_METHODS = {**METHODS, **PHASE_METHODS}
#: label of the optional peer's rows (nosnoc, FESD with IPOPT; the extra ``ocp-peers``)
NOSNOC = "nosnoc (FESD, peer)"
#: the replay tolerance that success requires
REPLAY_TOL = 1e-6
#: output samples per control interval of the event replays kept for figures and the hold check
EVENT_SAMPLES = 100


def AFFINE_STARTS(ocp, uniform_solution):
    """The multi-start of the free-step, affine-hold transcription: from the uniform-step,
    constant-hold solution (sigma0 = 1e-4 and 1e-2) and from the u = 0 simulation (sigma0 = 1e-2);
    sigma falls by 100 per stage. From sigma0 = 1 IPOPT needs more than 500 iterations at N = 40."""
    opts = {"factor": 1e-2, "max_iter": 3000}
    return [("uniform-step solution, sigma0 = 1e-4", uniform_solution, {"sigma0": 1e-4, **opts}),
            ("uniform-step solution, sigma0 = 1e-2", uniform_solution, {"sigma0": 1e-2, **opts}),
            ("u = 0, sigma0 = 1e-2", ocp.guess(u=0.0), {"sigma0": 1e-2, **opts})]


# ---------------------------------------------------------------------------------------- references
def _scene_constants(R):
    sc = lcp.scenes.jean_pratt(R=R, v0=0.0, **BASE)
    m, M, t = BASE["m"], BASE["M"], sc.tan
    # forward sliding: A a = u - R N with N = (m+M) g - M t a, i.e. D a = u - c
    c = R * (m + M) * G
    D = sc.A * (1.0 - sc.kappa)
    return sc, c, D, M * t


def min_time_bound(R=REST["R"], d=REST["d"], u_max=REST["u_max"]) -> float:
    """Bang-bang minimum time from rest to rest over d, forward sliding: sqrt(2 d (1/a1 + 1/a2))."""
    _, c, D, _ = _scene_constants(R)
    a1, a2 = (u_max - c) / D, (u_max + c) / D
    return math.sqrt(2.0 * d * (1.0 / a1 + 1.0 / a2))


def min_effort_bound(R=REST["R"], d=REST["d"], u_max=REST["u_max"], T=REST["T_effort"]) -> float:
    """Minimum of int u^2 dt from rest to rest over d within T (one forward slide, u = c + D a).

    The slide of length L costs c^2 L + 12 D^2 d^2 / L^3 (linear deceleration profile); its
    minimizer L* = (36 D^2 d^2 / c^2)^(1/4) starts at u = 2c and ends at u = 0, so J* = 4/3 c^2 L*.
    Valid when 2c <= u_max and L* <= T (checked).
    """
    _, c, D, _ = _scene_constants(R)
    L = (36.0 * D * D * d * d / (c * c)) ** 0.25
    if 2 * c > u_max or L > T:
        raise ValueError("the closed-form minimum effort needs 2 c <= u_max and L* <= T")
    return 4.0 / 3.0 * c * c * L


def move_effort(L, d, R=REST["R"], u_max=REST["u_max"], backward: bool = False) -> float:
    """Least int u^2 dt for one slide from rest to rest over d in exactly L, |u| <= u_max.

    Forward, u = c + D a with D = A (1 - kappa); backward (mirrored: x -> -x, u -> -u) the same
    with D = A (1 + kappa). The optimality conditions make u affine in t, clipped at the bounds. Unclipped:
    c^2 L + 12 D^2 d^2 / L^3. Clipped at u_max over [0, tau) and then u_max + beta (t - tau) over
    s = L - tau: int u = c L and int (L - t) u = D d + c L^2 / 2 give s = 3 (L/2 - D d/((u_max - c) L))
    and beta = -2 (u_max - c) L / s^2. Raises when the lower bound would also be active, when the
    block would stop early, or when L exceeds the free optimum L*.
    """
    sc, c, D, _ = _scene_constants(R)
    if backward:
        D = sc.A * (1.0 + sc.kappa)
    a0 = 6 * d / L ** 2  # initial acceleration of the unclipped (linear) profile
    if c + D * a0 <= u_max:
        return c * c * L + 12 * D * D * d * d / L ** 3
    U = u_max
    s = 3.0 * (L / 2 - D * d / ((U - c) * L))
    if not 0 < s <= L:
        raise ValueError("no clipped-affine slide of this length")
    beta = -2.0 * (U - c) * L / s ** 2
    if U + beta * s < -U:
        raise ValueError("the lower control bound would be active too")
    tau = L - s
    return U * U * tau + U * U * s + U * beta * s * s + beta * beta * s ** 3 / 3.0


def hold_bound(R=REST["R"], d=HOLD["d"], u_max=REST["u_max"]) -> float:
    """Move-and-hold minimum effort: a forward slide over [0, t_a], a backward one over [t_b, T]."""
    t_a, t_b = HOLD["t_hold"]
    return move_effort(t_a, d, R, u_max) + move_effort(HOLD["T"] - t_b, d, R, u_max, backward=True)


def peak_bound(R=SHOCK["R"], v0=SHOCK["v0"], T=SHOCK["T"]) -> float:
    """Smallest possible peak normal force when stopping by T: (m+M) g + M tan(alpha) v0 / T."""
    _, _, _, Mt = _scene_constants(R)
    return (BASE["m"] + BASE["M"]) * G + Mt * v0 / T


# ---------------------------------------------------------------------------------------- problems
#: the contact law of this study's problems. The block never leaves the floor, so the velocity law is
#: exact for it, and the method comparison below (uniform/free steps, holds, homotopy starts) was
#: designed and measured on it. ``solve()``'s default is the gap law, under which the same routes
#: land on other local optima (free-step homotopy from u = 0: replay -3 at N = 10, 40); the defaults
#: themselves reach the targets on the three problems at N = 40 (tests/test_ocp_gap_default.py).
CONTACT_LAW = "velocity"

def controlled_block(R=REST["R"], u_max=REST["u_max"], v0=0.0):
    """The Jean-Pratt scene and its System with the horizontal push u as control input."""
    sc = lcp.scenes.jean_pratt(R=R, v0=v0, **BASE)
    return sc, add_control(sc.system, tangential_push(sc.system), -u_max, u_max)


def rest_to_rest_problem(N: int, objective: str = "time", hold: str = "auto",
                         steps: str = "auto", contact_law: str | None = None) -> OptimalControlProblem:
    """Problem 1 on N control intervals, ``objective`` "time" (T free) or "effort" (T = 1 s);
    ``contact_law`` None is the package's default (the study passes :data:`CONTACT_LAW`)."""
    sc, system = controlled_block()
    d = REST["d"]
    common = {"q0": sc.q0, "v0": sc.v0, "hold": hold, "steps": steps, "replay_tol": REPLAY_TOL,
              "contact_law": contact_law,
              "terminal_constraints": lambda q, v: ca.vertcat(q[0] - d, v[0])}
    if objective == "time":
        return OptimalControlProblem(system, N, T=0.5, free_time=True, T_bounds=(0.05, 5.0),
                                     terminal_cost=lambda T, q, v: T, **common)
    if objective == "effort":
        return OptimalControlProblem(system, N, T=REST["T_effort"], stage_cost=effort, **common)
    raise ValueError(f"objective must be 'time' or 'effort', got {objective!r}")


def hold_problem(N: int, hold: str = "auto", steps: str = "auto",
                 contact_law: str | None = None) -> OptimalControlProblem:
    """Problem 2 on N intervals: with uniform steps N a multiple of 6 (the hold's ends are nodes of
    the uniform grid); with free steps (and "auto", the package's default, which the pins make free)
    any N >= 6, nodes round(N t_a / T) and round(N t_b / T) pinned at t_a and t_b."""
    if steps == "uniform" and N % 6:
        raise ValueError(f"N must be a multiple of 6 with uniform steps (the hold's ends are nodes), got {N}")
    if not isinstance(N, int) or N < 6:
        raise ValueError(f"N must be an integer >= 6, got {N!r}")
    sc, system = controlled_block()
    d, (t_a, t_b), T = HOLD["d"], HOLD["t_hold"], HOLD["T"]
    k_a, k_b = round(N * t_a / T), round(N * t_b / T)

    def at_rest_on_hold(s):  # steps ending in [t_a, t_b] end at rest at x = d
        if k_a - 1 <= s.k < k_b:
            return ca.vertcat(s.q1[0] - d, s.v1[0])
        return ca.SX.zeros(0, 1)

    return OptimalControlProblem(system, N, q0=sc.q0, v0=sc.v0, T=T, stage_cost=effort, hold=hold, steps=steps,
                                 node_times={k_a: t_a, k_b: t_b} if steps != "uniform" else None,
                                 path_equalities=at_rest_on_hold, replay_tol=REPLAY_TOL, contact_law=contact_law,
                                 terminal_constraints=lambda q, v: ca.vertcat(q[0], v[0]))


def shock_problem(N: int, R: float = SHOCK["R"], contact_law: str | None = None) -> OptimalControlProblem:
    """Problem 3 on N control intervals: stop by T with the smallest peak normal force."""
    sc, system = controlled_block(R, SHOCK["u_max"], SHOCK["v0"])
    return OptimalControlProblem(system, N, q0=sc.q0, v0=sc.v0, T=SHOCK["T"], max_cost=lambda s: s.N[0],
                                 terminal_constraints=lambda q, v: v[0], replay_tol=REPLAY_TOL,
                                 control_rate_weight=SHOCK["rate_weight"], contact_law=contact_law,
                                 hold="constant", steps="uniform")


def hold_violation(res, rp) -> float:
    """max |x - d| and |xdot| over the hold window on a replay (event pieces or Moreau-Jean)."""
    t_a, t_b = HOLD["t_hold"]
    sims = rp.pieces if rp.pieces else [rp.sim]
    offsets = res.t[:-1] if rp.pieces else [0.0]
    worst = 0.0
    for sim, t0 in zip(sims, offsets):
        t = np.asarray(sim.t) + t0
        sel = (t >= t_a - 1e-12) & (t <= t_b + 1e-12)
        if np.any(sel):
            worst = max(worst, float(np.max(np.abs(sim.q[sel, 0] - HOLD["d"]))),
                        float(np.max(np.abs(sim.v[sel, 0]))))
    return worst


def _distinct(res) -> int:
    """Distinct optimal costs (relative 1e-6) among the successful starts of a multi-start (1 without)."""
    costs = sorted(s["cost"] for s in res.starts if s["success"])
    return max(1, sum(1 for i, c in enumerate(costs) if i == 0 or abs(c - costs[i - 1]) > 1e-6 * abs(c)))


def _event_available() -> bool:
    return "event" in lcp.METHODS


def solve(ocp: OptimalControlProblem, multistart: bool = False, guess=None, phases: bool = False):
    """The study's solve of ``ocp`` (its replay check included, no further replays): from ``guess``
    (default: the u = 0 simulation), or the multi-start (free steps: from rest and from the
    uniform-step solution ``guess``; :data:`AFFINE_STARTS` for the affine hold), or with ``phases``
    the fixed-phase solve from its own first pass (:meth:`OptimalControlProblem.phase_guess`).
    Without the exact-phase shooting: each row is its transcription's own result (the shooting
    would finish a row that fails its replay on its replay's phases, a linear hold's included, and
    the row would no longer show its method; ``studies.ocp_examples`` shows the shooting)."""
    if phases:
        return ocp.solve(method="phases", max_iter=3000, shooting=False)
    if multistart and guess is not None and ocp.hold == "affine":
        return ocp.solve_multistart(guesses=AFFINE_STARTS(ocp, guess), shooting=False)
    if multistart and guess is not None:  # free steps: from rest, and from the uniform-step solution
        return ocp.solve_multistart(guesses=[("u = 0", ocp.guess(u=0.0)), ("uniform-step solution", guess),
                                             ("uniform-step solution, sigma0 = 1e-2", guess,
                                              {"sigma0": 1e-2, "max_iter": 3000}),
                                             ("uniform-step solution, sigma0 = 1e-4", guess, {"sigma0": 1e-4})],
                                    shooting=False)
    if multistart:
        return ocp.solve_multistart(shooting=False)
    return ocp.solve(ocp.guess(u=0.0) if guess is None else guess, shooting=False)


def solve_and_verify(ocp: OptimalControlProblem, h_fine: float, multistart: bool = False, guess=None,
                     phases: bool = False) -> dict:
    """:func:`solve`, then replay by Moreau-Jean at the same h (uniform steps), at about h_fine,
    and by the event integrator."""
    res = solve(ocp, multistart, guess, phases)
    out = {"result": res}
    out["same_h"] = replay(res, refine=1) if ocp.steps == "uniform" else None
    refine = max(1, int(math.ceil(res.h / h_fine - 1e-9)))
    out["mj"] = replay(res, refine=refine)
    out["event"] = (replay(res, method="event", n_eval=EVENT_SAMPLES)
                    if _event_available() and res.hold in ("constant", "affine") else None)
    return out


def _row(problem: str, method: str, N: int, v: dict, reference: float, value: float) -> dict:
    res = v["result"]
    rp = res.replay
    return {"problem": problem, "method": method, "N": N, "value": value, "reference": reference,
            "rel_gap": (value - reference) / abs(reference), "T": res.T, "success": res.success,
            "status": res.status, "residual": res.complementarity_residual, "lcp_residual": res.lcp_residual,
            "dynamics_residual": res.dynamics_residual, "iterations": res.iterations,
            "homotopy_steps": res.homotopy_steps, "solve_time": res.solve_time, "build_time": res.build_time,
            "replay_method": rp.method, "final_miss": rp.final_miss, "path_violation": rp.path_violation,
            "err_same_h": v["same_h"].max_error_q if v["same_h"] is not None else float("nan"),
            "err_mj": float(v["mj"].error_q[0]), "h_replay": v["mj"].h,
            "err_event": float(v["event"].error_q[0]) if v["event"] is not None else float("nan"),
            "hold_violation": (hold_violation(res, v["event"] if v["event"] is not None else v["mj"])
                               if problem == "hold" else float("nan")),
            "peak_N_opt": float(res.N.max()), "starts": len(res.starts),
            "distinct_optima": _distinct(res)}


# ---------------------------------------------------------------------------------------- figures
_MODE_COLORS = {OPEN: "0.75", STICK: "tab:blue", SLIDE_POS: "tab:orange", SLIDE_NEG: "tab:green"}


def _mode_bar(ax, t_edges, modes, y, height=0.6):
    """Draw one timeline of contact modes: one colored segment per interval, merged when equal."""
    modes = np.asarray(modes)
    i = 0
    while i < len(modes):
        j = i
        while j + 1 < len(modes) and modes[j + 1] == modes[i]:
            j += 1
        if modes[i] >= 0:
            ax.broken_barh([(t_edges[i], t_edges[j + 1] - t_edges[i])], (y - height / 2, height),
                           color=_MODE_COLORS[int(modes[i])])
        i = j + 1


def _event_modes(sim):
    code = {name: c for c, name in MODE_NAMES.items()}
    edges = [ph.t0 for ph in sim.phases] + [sim.phases[-1].t1]
    return np.array(edges), np.array([code[ph.modes[0]] for ph in sim.phases])


def _modes_panel(ax, rows):
    """rows: list of (label, t_edges, modes)."""
    for i, (label, edges, md) in enumerate(rows):
        _mode_bar(ax, edges, md, len(rows) - 1 - i)
    ax.set_yticks(range(len(rows)))
    ax.set_yticklabels([r[0] for r in rows][::-1], fontsize=8)
    ax.set_ylim(-0.6, len(rows) - 0.4)
    handles = [plt.Rectangle((0, 0), 1, 1, color=_MODE_COLORS[c]) for c in (STICK, SLIDE_POS, SLIDE_NEG, OPEN)]
    ax.legend(handles, [MODE_NAMES[c] for c in (STICK, SLIDE_POS, SLIDE_NEG, OPEN)], ncol=4, fontsize=7,
              loc="lower right", bbox_to_anchor=(1.0, 1.0), frameon=False, borderaxespad=0.1)


def _legend_below(ax, ncol=2, **kw):
    """Legends go below the axes: they never cover data."""
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=ncol, fontsize=7, frameon=False, **kw)


def _step_u(ax, res, **kw):
    """The control as held: stairs for the constant hold, lines between nodes for the linear hold."""
    if res.hold == "constant":
        ax.stairs(res.u[:, 0], res.t, baseline=None, **kw)
    elif res.hold == "affine":  # one segment per step, jumps at the nodes
        ax.plot(np.repeat(res.t, 2)[1:-1], res.u[:, 0], **kw)
    else:
        ax.plot(res.t, res.u[:, 0], **kw)


def _trajectory_panels(axes, v: dict, title: str, u_max: float, lower_visible: bool = True, extra=None):
    res, mj, ev = v["result"], v["mj"], v["event"]
    t = res.t
    ax = axes[0]
    _step_u(ax, res, color="k", lw=1.5, label=f"optimal u ({res.hold} hold)")
    ax.axhline(u_max, ls=":", color="0.5", lw=1, label=r"$+u_{max}$")
    if lower_visible:
        ax.axhline(-u_max, ls="--", color="0.5", lw=1, label=r"$-u_{max}$")
    ax.set_ylabel("force u [N]")
    ax.set_title(title, fontsize=9)
    _legend_below(ax, ncol=3)
    ax = axes[1]
    ax.plot(mj.sim.t, mj.sim.v[:, 0], "-", color="tab:red", lw=1.5, label=f"replay Moreau-Jean h = {mj.h:.1e} s")
    if ev is not None:
        for i, (piece, t0) in enumerate(zip(ev.pieces, t[:-1])):
            ax.plot(np.asarray(piece.t) + t0, piece.v[:, 0], "--", color="tab:purple", lw=1.2,
                    label="replay event-driven" if i == 0 else None)
    ax.plot(t, res.v[:, 0], "o", ms=3, color="k", label=f"optimizer nodes (N = {len(t) - 1})")
    ax.set_ylabel(r"velocity $\dot x$ [m/s]")
    _legend_below(ax, ncol=2)
    ax = axes[2]
    ax.stairs(res.N[:, 0], t, baseline=None, color="k", lw=1.5, label="optimizer p_N / h")
    ax.stairs(mj.sim.N[:, 0], mj.sim.t, baseline=None, color="tab:red", lw=1, label="replay Moreau-Jean")
    if extra is not None:
        extra(ax)
    ax.set_ylabel("normal force N [N]")
    _legend_below(ax, ncol=2)
    _modes_panel(axes[3], [("optimizer", t, res.modes[:, 0]), ("Moreau-Jean", mj.sim.t, mj.sim.modes[:, 0])])
    axes[3].set_xlabel("time t [s]; contact mode per step")


#: widest figure, inches: at the study's 130 dpi about 2000 px, readable at normal size
MAX_WIDTH_IN = 15.0


def _checked_title(title: str, res) -> str:
    """The panel title, with a warning when the replay did not confirm the solution."""
    if res.replay is None:
        return title + "\nUNCHECKED: not replayed"
    if not res.success:
        return title + f"\nREPLAY FAILED (miss {res.replay.final_miss:.1e}): not a solution"
    return title


def _fig_trajectories(cases, path, suptitle):
    """cases: list of (v, title, u_max). One column per case, at most three columns to a row."""
    ncol = min(3, len(cases))
    nrow = -(-len(cases) // ncol)
    fig, axes = plt.subplots(4 * nrow, ncol, figsize=(min(5.0 * ncol, MAX_WIDTH_IN), 11 * nrow), squeeze=False,
                             gridspec_kw={"height_ratios": [1, 1, 1, 0.45] * nrow})
    for j, (v, title, u_max) in enumerate(cases):
        r, c = divmod(j, ncol)
        col = axes[4 * r:4 * r + 4, c]
        _trajectory_panels(col, v, _checked_title(title, v["result"]), u_max)
        if not v["result"].success:
            for ax in col:
                ax.set_facecolor("#fde8e8")
    for j in range(len(cases), nrow * ncol):
        r, c = divmod(j, ncol)
        for ax in axes[4 * r:4 * r + 4, c]:
            ax.axis("off")
    fig.suptitle(suptitle, fontsize=11)
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.6 / (11 * nrow)))  # room for the suptitle above the titles
    return save(fig, path)


def _fig_shock(v, unc, path):
    fig, axes = plt.subplots(4, 1, figsize=(8, 12), sharex=True, gridspec_kw={"height_ratios": [1, 1, 1.2, 0.55]})
    res = v["result"]
    sc = lcp.scenes.jean_pratt(R=SHOCK["R"], v0=SHOCK["v0"], **BASE)

    def extra(ax):
        ax.stairs(unc.N[:, 0], unc.t, baseline=None, color="0.5", lw=1.2,
                  label=f"uncontrolled (u = 0), MJ h = {unc.h:.0e} s")
        ax.axhline(sc.N0, ls=":", color="0.4", lw=1, label=f"uncontrolled peak N0 = (m+M)g/(1-kappa) = {sc.N0:.0f} N")
        ax.axhline(peak_bound(), ls=":", color="tab:blue", lw=1,
                   label=f"lower bound (m+M)g + Mt v0/T = {peak_bound():.2f} N")
        ax.set_yscale("log")
        ax.set_ylim(5, sc.N0 * 3)

    _, c, _, _ = _scene_constants(SHOCK["R"])
    _trajectory_panels(axes, v, f"shock avoidance, kappa = {sc.kappa:.2f}: optimal peak N = {res.peak:.3f} N "
                       f"(N = {len(res.t) - 1}); the lower bound -u_max = -{SHOCK['u_max']:g} N is off-scale",
                       SHOCK["u_max"], lower_visible=False, extra=extra)
    axes[1].plot(unc.t, unc.v[:, 0], color="0.5", lw=1.2, label="uncontrolled (u = 0)")
    _legend_below(axes[1], ncol=2)
    axes[0].axhline(c, color="tab:orange", lw=1, ls="--", label=f"R(m+M)g = {c:.2f} N: sliding without deceleration")
    axes[0].axhline(0.0, color="0.5", lw=1.2, label="uncontrolled (u = 0)")
    axes[0].set_ylim(-3, SHOCK["u_max"] * 1.12)
    _legend_below(axes[0], ncol=2)
    fig.tight_layout()
    return save(fig, path)


_METHOD_STYLE = {"uniform, linear hold": ("tab:red", "o", "-"), "uniform, constant hold": ("tab:blue", "s", "-"),
                 "free steps, constant hold": ("tab:green", "^", "-"),
                 "free steps, affine hold": ("tab:purple", "D", "-"),
                 "fixed phases, constant hold": ("tab:olive", "v", "--"),
                 "fixed phases, affine hold": ("tab:brown", "P", "--"),
                 NOSNOC: ("k", "x", ":")}
_PROBLEMS = {"min_time": "minimum time", "min_effort": "minimum effort", "hold": "move and hold"}
FLOOR = 1e-16


def _floored(values):
    """(plotted values, mask of exact zeros): values at or below FLOOR are drawn at FLOOR, and the
    exact zeros among them are drawn apart (a cross on the floor), so they are not read as
    round-off."""
    a = np.abs(np.asarray(values, dtype=float))
    return np.maximum(a, FLOOR), a == 0


def _fig_convergence(rows, path):
    """Per problem: replay miss (top) and relative gap of the objective (bottom) against N per method.

    Solutions whose replay failed (not solutions of the system) and unchecked ones are ringed in
    red; an objective below the continuous optimum J* (possible only for such a solution, or for
    a transcription that is not exact) is drawn with an open marker; exact zeros sit on the floor
    as crosses."""
    from matplotlib.lines import Line2D

    fig, axes = plt.subplots(2, 3, figsize=(MAX_WIDTH_IN, 8.5))
    any_failed = any_below = any_zero = False
    for j, (prob, label) in enumerate(_PROBLEMS.items()):
        for meth, (col, mk, ls) in _METHOD_STYLE.items():
            rr = sorted((r for r in rows if r["problem"] == prob and r["method"] == meth), key=lambda r: r["N"])
            if not rr:
                continue
            N = np.array([r["N"] for r in rr])
            for ax, key in ((axes[0, j], "final_miss"), (axes[1, j], "rel_gap")):
                y, zero = _floored([r[key] for r in rr])
                ax.loglog(N, y, ls, color=col, lw=1)
                ax.loglog(N[~zero], y[~zero], mk, color=col, ls="none", label=meth)
                if zero.any():
                    any_zero = True
                    ax.loglog(N[zero], y[zero], "x", color=col, ms=8, mew=1.5, ls="none")
                failed = np.array([not r.get("success", True) or r.get("replay_method", "x") in (None, "") for r in rr])
                if failed.any():
                    any_failed = True
                    ax.loglog(N[failed], y[failed], "o", mfc="none", mec="red", mew=1.6, ms=13, ls="none")
            below = np.array([r["rel_gap"] < 0 for r in rr])
            if below.any():
                any_below = True
                yb, _ = _floored([r["rel_gap"] for r in rr])
                axes[1, j].loglog(N[below], yb[below], mk, color="white", ms=4, ls="none")
        axes[0, j].axhline(REPLAY_TOL, color="k", ls=":", lw=1, label=f"replay_tol = {REPLAY_TOL:g} (success)")
        axes[0, j].set_title(f"{label}: replay miss of the final state", fontsize=10)
        axes[0, j].set_ylabel("max |x, xdot (opt) - (replay)| at T [m, m/s]")
        axes[1, j].set_title(f"{label}: objective vs continuous optimum", fontsize=10)
        axes[1, j].set_ylabel("|J_N - J*| / J*")
        for ax in axes[:, j]:
            Ns = sorted({r["N"] for r in rows if r["problem"] == prob})
            ax.set_xticks(Ns)
            ax.set_xticklabels([str(n) for n in Ns])
            ax.minorticks_off()
            ax.set_xlabel("control intervals N")
            ax.axhline(FLOOR, color="0.7", lw=0.8, ls="-")
            _legend_below(ax, ncol=1)
    keys = []
    if any_failed:
        keys.append((Line2D([], [], marker="o", mfc="none", mec="red", mew=1.6, ms=11, ls="none"),
                     "replay failed or not replayed: not a solution of the system"))
    if any_below:
        keys.append((Line2D([], [], marker="s", mfc="white", mec="0.3", ls="none"),
                     "open marker: objective below the optimum J*"))
    if any_zero:
        keys.append((Line2D([], [], marker="x", color="0.3", ls="none"), "exactly zero (drawn on the floor)"))
    keys.append((Line2D([], [], color="0.7", lw=0.8), f"floor {FLOOR:g}: smaller values (round-off) drawn on it"))
    fig.legend(*zip(*keys), loc="lower center", ncol=len(keys), fontsize=8, frameon=False)
    note = "" if any(r["method"] == NOSNOC for r in rows) else \
        "nosnoc (the optional peer, extra 'ocp-peers') is not installed: its series are skipped"
    fig.text(0.5, 0.03, note, ha="center", fontsize=8)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    return save(fig, path)


def nosnoc_rows(Ns, hold_Ns) -> list[dict]:
    """nosnoc's solves of the three problems at the study's N, each control replayed exactly by the
    event integrator; [] when nosnoc is not installed."""
    from studies import _nosnoc_peer as peer

    if not peer.available():
        return []
    return [{**peer.solve_and_replay(prob, N), "method": NOSNOC}
            for prob in ("min_time", "min_effort", "hold") for N in (hold_Ns if prob == "hold" else Ns)]


def _fig_homotopy(histories, N_hist, path):
    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    cols = {"min_time": "tab:red", "min_effort": "tab:green", "hold": "tab:purple", "shock": "tab:blue"}
    for prob, hist in histories.items():
        hs = [s for s in hist if s.sigma > 0]
        sig = np.array([s.sigma for s in hs])
        y, zero = _floored([s.residual for s in hs])
        ax.loglog(sig, y, "-", color=cols[prob], lw=1)
        ax.loglog(sig[~zero], y[~zero], "o", color=cols[prob], ls="none",
                  label=f"{prob} ({sum(s.iterations for s in hist)} IPOPT it.)")
        ax.loglog(sig[zero], y[zero], "x", color=cols[prob], ms=8, mew=1.5, ls="none")
        pol = [s for s in hist if s.sigma == 0]
        if pol:
            yp, zp = _floored([pol[0].residual])
            ax.loglog([hs[-1].sigma * 0.1], yp, "x" if zp[0] else "o", color=cols[prob], mfc="none", ms=9)
    ax.axhline(1e-8, color="k", ls=":", lw=1, label="target 1e-8")
    ax.axhline(FLOOR, color="0.7", lw=0.8, label=f"floor {FLOOR:g}; crosses: exactly zero")
    ax.plot([], [], "o", color="0.3", mfc="none", ms=9, ls="none", label="polishing solve (sigma = 0)")
    ax.invert_xaxis()
    ax.set_xlabel(r"Scholtes relaxation $\sigma$: bound on each product $a\,w$ (force $\times$ velocity) [W]")
    ax.set_ylabel("Coulomb residual (impulse) [N s]")
    ax.set_title(f"homotopy history, free steps, constant hold (N = {N_hist})", fontsize=9)
    _legend_below(ax, ncol=2)
    fig.tight_layout()
    return save(fig, path)


def _fig_sweep(sweep, path):
    fig, ax = plt.subplots(figsize=(6, 4.5))
    k = [r["kappa"] for r in sweep]
    k = np.asarray(k, dtype=float)
    dk = 0.012 * (np.ptp(k) if len(k) > 1 else 1.0)  # side by side: equal values stay visible
    ax.semilogy(k - dk, [r["N0"] for r in sweep], "o", color="0.4", mfc="none", ms=8,
                label="uncontrolled peak N0 = (m+M)g/(1-kappa)")
    ax.semilogy(k - dk, [r["peak_uncontrolled"] for r in sweep], "x", color="k", ms=7, label="uncontrolled, simulated")
    ax.semilogy(k + dk, [r["peak_opt"] for r in sweep], "s", color="tab:blue", mfc="none", ms=8,
                label="optimal control: peak (optimizer)")
    ax.semilogy(k + dk, [r["peak_replay"] for r in sweep], "+", ms=10, color="tab:red",
                label="optimal control: peak (replay)")
    ax.semilogy(k, [r["bound"] for r in sweep], "_", ms=16, mew=2, color="tab:blue", label="bound (m+M)g + Mt v0/T")
    ax.set_xticks(k)
    ax.set_xlabel(r"shock number $\kappa$ = R M tan(alpha) / A [-]")
    ax.set_ylabel("peak normal force [N]")
    ax.set_title(f"stopping from v0 = {SHOCK['v0']} m/s by T = {SHOCK['T']} s", fontsize=10)
    _legend_below(ax, ncol=2)
    fig.tight_layout()
    return save(fig, path)


# ---------------------------------------------------------------------------------------- the study
def _value(prob, res):
    return res.T if prob == "min_time" else (res.peak if prob == "shock" else res.cost)


def run(out=None, quick: bool = False) -> dict:
    """Solve every problem for several N and methods, replay every control, write CSV and figures.

    Returns
    -------
    dict
        ``rows`` (one dict per problem, method and N: value, reference, rel_gap, success,
        final_miss, path_violation, hold_violation, err_same_h, err_mj, err_event, residual,
        iterations, solve_time, ...), ``sweep`` (shock avoidance per kappa), ``references``,
        ``multistart`` (the hold problem's starts), ``event_available``, ``N_figure`` and ``files``.
    """
    path = out_dir(out, NAME)
    Ns = (10, 20, 40) if quick else (10, 20, 40, 80)
    hold_Ns = (12, 24, 48) if quick else (12, 24, 48, 96)  # the hold's ends on the uniform grid
    N_fig = 20 if quick else 40
    N_fig_hold = 24 if quick else 48
    h_fine = 5e-4 if quick else 5e-5
    refs = {"min_time": min_time_bound(), "min_effort": min_effort_bound(), "hold": hold_bound(),
            "shock": peak_bound()}
    make = {"min_time": lambda N, kw: rest_to_rest_problem(N, "time", contact_law=CONTACT_LAW, **kw),
            "min_effort": lambda N, kw: rest_to_rest_problem(N, "effort", contact_law=CONTACT_LAW, **kw),
            "hold": lambda N, kw: hold_problem(N, contact_law=CONTACT_LAW, **kw)}
    rows, keep = [], {}
    for prob, build in make.items():
        for N in (hold_Ns if prob == "hold" else Ns):
            for meth, kw in ALL_METHODS.items():
                # free steps: a multi-start from rest and from the uniform-step solution (the
                # free-step MPCC has local minima; from rest IPOPT fails on the hold problem)
                uni = keep.get((prob, "uniform, constant hold", N))
                phases = meth in PHASE_METHODS
                free = kw["steps"] == "free" and uni is not None and not phases
                v = solve_and_verify(build(N, kw), h_fine, multistart=free, guess=uni["result"] if free else None,
                                     phases=phases)
                keep[(prob, meth, N)] = v
                rows.append(_row(prob, meth, N, v, refs[prob], _value(prob, v["result"])))
                if N == (N_fig_hold if prob == "hold" else N_fig):
                    keep[(prob, meth)] = v
    for N in Ns:
        v = solve_and_verify(shock_problem(N, contact_law=CONTACT_LAW), h_fine)
        rows.append(_row("shock", "uniform, constant hold", N, v, refs["shock"], v["result"].peak))
        if N == N_fig:
            keep[("shock", "uniform, constant hold")] = v
    # multi-start on the hold problem, uniform steps (the default guesses: u held at u_min, 0,
    # mid-range, u_max)
    ms = solve_and_verify(hold_problem(N_fig_hold, "constant", "uniform", contact_law=CONTACT_LAW), h_fine,
                          multistart=True)["result"]
    files = []
    cols = list(rows[0].keys())
    files.append(write_csv(path / "convergence.csv", cols, [[r[c] for c in cols] for r in rows]))
    files.append(write_csv(path / "multistart_hold.csv", ["label", "cost", "status", "success"],
                           [[s["label"], s["cost"], s["status"], s["success"]] for s in ms.starts]))

    # shock avoidance against kappa, with the uncontrolled stop
    sweep = []
    N_sweep = 20 if quick else 40
    for R in SHOCK_SWEEP_R:
        sc = lcp.scenes.jean_pratt(R=R, v0=SHOCK["v0"], **BASE)
        v = solve_and_verify(shock_problem(N_sweep, R, contact_law=CONTACT_LAW), h_fine)
        unc = lcp.simulate(sc, SHOCK["T"], h=h_fine)
        ev = v["event"]
        peak_rep = (max(float(np.max(p.force_N)) for p in ev.pieces) if ev is not None
                    else float(v["mj"].sim.N.max()))
        sweep.append({"R": R, "kappa": sc.kappa, "N": N_sweep, "N0": sc.N0, "peak_uncontrolled": float(unc.N.max()),
                      "peak_opt": v["result"].peak, "bound": peak_bound(R=R), "peak_replay": peak_rep,
                      "residual": v["result"].complementarity_residual, "final_miss": v["result"].replay.final_miss,
                      "solve_time": v["result"].solve_time, "iterations": v["result"].iterations,
                      "u_mean": float(np.mean(v["result"].u[:, 0]))})
    cols = list(sweep[0].keys())
    files.append(write_csv(path / "shock_sweep.csv", cols, [[r[c] for c in cols] for r in sweep]))

    keep = {key: v for key, v in keep.items() if len(key) == 2}
    # every plotted trajectory series, per case
    for (prob, meth), v in keep.items():
        res, mj = v["result"], v["mj"]
        tag = f"{prob}_{meth.replace(', ', '_').replace(' ', '_')}"
        u_nodes = res.control(res.t[:-1])[:, 0]
        files.append(write_csv(path / f"trajectory_{tag}.csv",
                               ["t_start", "t_end", "u_start", "x_end", "xdot_end", "N_step", "mode"],
                               [[float(res.t[k]), float(res.t[k + 1]), float(u_nodes[k]), float(res.q[k + 1, 0]),
                                 float(res.v[k + 1, 0]), float(res.N[k, 0]), MODE_NAMES.get(int(res.modes[k, 0]), "")]
                                for k in range(len(res.t) - 1)]))
        files.append(write_csv(path / f"replay_{tag}.csv", ["t", "x", "xdot", "N_step_start", "mode"],
                               [[float(mj.sim.t[i]), float(mj.sim.q[i, 0]), float(mj.sim.v[i, 0]),
                                 float(mj.sim.N[i, 0]) if i < len(mj.sim.N) else float("nan"),
                                 MODE_NAMES.get(int(mj.sim.modes[i, 0]), "") if i < len(mj.sim.modes) else ""]
                                for i in range(len(mj.sim.t))]))
        if v["event"] is not None:
            ev = v["event"]
            files.append(write_csv(path / f"replay_event_{tag}.csv", ["t", "x", "xdot"],
                                   [[float(t0 + tt), float(p.q[i, 0]), float(p.v[i, 0])]
                                    for p, t0 in zip(ev.pieces, res.t[:-1]) for i, tt in enumerate(p.t)]))
    hist = {p: keep[(p, "free steps, constant hold")]["result"].homotopy for p in _PROBLEMS}
    hist["shock"] = keep[("shock", "uniform, constant hold")]["result"].homotopy
    files.append(write_csv(path / "homotopy.csv", ["problem", "sigma", "iterations", "residual", "max_product",
                                                   "cost", "return_status", "time"],
                           [[p, s.sigma, s.iterations, s.residual, s.max_product, s.cost, s.return_status, s.time]
                            for p, hh in hist.items() for s in hh]))
    umax = REST["u_max"]
    files.append(_fig_trajectories(
        [(keep[("min_time", m)], f"min time, {m}: T = {keep[('min_time', m)]['result'].T:.6f} s "
          f"(T* = {refs['min_time']:.6f})", umax) for m in ALL_METHODS], path / "rest_to_rest_min_time.png",
        f"Jean-Pratt block, R = {REST['R']}: rest to rest over {REST['d']} m in minimum time, |u| <= {umax:g} N"))
    files.append(_fig_trajectories(
        [(keep[("min_effort", m)], f"min effort, {m}: J = {keep[('min_effort', m)]['result'].cost:.4f} N²s "
          f"(J* = {refs['min_effort']:.4f})", umax) for m in ALL_METHODS], path / "rest_to_rest_min_effort.png",
        f"rest to rest over {REST['d']} m within {REST['T_effort']:g} s with minimum effort int u² dt"))
    files.append(_fig_trajectories(
        [(keep[("hold", m)], f"move and hold, {m}: J = {keep[('hold', m)]['result'].cost:.4f} N²s "
          f"(J* = {refs['hold']:.4f})", umax) for m in ALL_METHODS], path / "move_and_hold.png",
        f"to {HOLD['d']} m, held at rest on [{HOLD['t_hold'][0]}, {HOLD['t_hold'][1]}] s, back by {HOLD['T']:g} s"))
    sc = lcp.scenes.jean_pratt(R=SHOCK["R"], v0=SHOCK["v0"], **BASE)
    unc = lcp.simulate(sc, SHOCK["T"], h=keep[("shock", "uniform, constant hold")]["mj"].h)
    files.append(_fig_shock(keep[("shock", "uniform, constant hold")], unc, path / "shock_avoidance.png"))
    nos = nosnoc_rows(Ns, hold_Ns)
    if nos:
        cols = list(nos[0].keys())
        files.append(write_csv(path / "nosnoc.csv", cols, [[r[c] for c in cols] for r in nos]))
    files.append(_fig_convergence(rows + nos, path / "convergence.png"))
    files.append(_fig_homotopy(hist, N_fig, path / "homotopy.png"))
    files.append(_fig_sweep(sweep, path / "shock_sweep.png"))
    return {"rows": rows, "sweep": sweep, "references": refs, "multistart": ms, "event_available": _event_available(),
            "N_figure": N_fig, "nosnoc": nos, "files": [Path(f) for f in files]}


def main(argv=None):
    args = parse_args(NAME, DESCRIPTION, argv)
    out = run(args.out, quick=args.quick)
    r = out["references"]
    print(f"references: T* = {r['min_time']:.9f} s, J* = {r['min_effort']:.6f} N^2 s, hold J* = {r['hold']:.6f} "
          f"N^2 s, peak bound = {r['shock']:.4f} N; event replay: {out['event_available']}")
    print(f"{'problem':>10} {'method':>26} {'N':>4} {'value':>12} {'rel_gap':>9} {'ok':>3} {'final_miss':>10} "
          f"{'path_viol':>9} {'hold_viol':>9} {'iter':>5} {'solve[s]':>8} {'replay':>10}")
    for r in out["rows"]:
        print(f"{r['problem']:>10} {r['method']:>26} {r['N']:>4} {r['value']:>12.9g} {r['rel_gap']:>9.2e} "
              f"{'yes' if r['success'] else 'no':>3} {r['final_miss']:>10.2e} {r['path_violation']:>9.1e} "
              f"{r['hold_violation']:>9.1e} {r['iterations']:>5} {r['solve_time']:>8.3f} {r['replay_method']:>10}")
    for r in out["nosnoc"]:
        print(f"{r['problem']:>10} {r['method']:>26} {r['N']:>4} {r['value']:>12.9g} {r['rel_gap']:>9.2e} "
              f"{r['status']:>3} {r['final_miss']:>10.2e} {'':>9} {r['hold_violation']:>9.1e} "
              f"{r['ipopt_iterations']:>5} {r['solve_s']:>8.3f} {'event':>10}")
    if not out["nosnoc"]:
        print("nosnoc (optional peer, pip install 'lcp-lem[ocp-peers]') is not installed: its rows and series are skipped")
    print(f"hold problem, multi-start: {out['multistart'].message}")
    print("note: IPOPT may try points where a constraint is NaN and backs off from them; CasADi's warning for "
          "each such trial is switched off (lcp.ocp), and a solve that cannot recover is reported above")
    for r in out["sweep"]:
        print(f"kappa = {r['kappa']:.2f}: uncontrolled peak {r['peak_uncontrolled']:.1f} N (N0 = {r['N0']:.1f}), "
              f"optimal peak {r['peak_opt']:.4f} N (replay {r['peak_replay']:.4f}, bound {r['bound']:.4f})")
    print("wrote", ", ".join(str(f) for f in out["files"]))
    return out


if __name__ == "__main__":
    main()
