"""Optimal control of the Jean-Pratt block through frictional contact (issue 6).

Two problems on the Jean-Pratt scene (m = M = 1, alpha = pi/4, g = 9.81), with a horizontal force
u on the block (the scene's ``phi`` slot) as the control, solved with :mod:`lcp.ocp` (Moreau-Jean
transcription, Scholtes homotopy, IPOPT) and verified by open-loop replay through
:func:`lcp.simulate` (Moreau-Jean at a finer step, and the event-driven integrator):

1. **Rest to rest.** R = 0.5 (kappa = 0.25), |u| <= 20 N, from rest at x = 0 to rest at x = 0.5 m
   (a) in minimum time, against the bang-bang bound T* = sqrt(2 d (1/a1 + 1/a2)), with
   a1 = (u_max - c)/D, a2 = (u_max + c)/D, c = R (m+M) g, D = A (1 - kappa); (b) with minimum effort
   int u^2 dt over T = 1 s, against J* = (4/3) c^2 L*, L* = (36 D^2 d^2 / c^2)^(1/4): the block
   sticks, then slides for L* while u falls linearly from 2c to 0.
2. **Shock avoidance.** A block launched at v0 = 1 m/s with kappa close to 1 (R = 1.9: kappa = 0.95)
   stops with the uncontrolled peak normal force N0 = (m+M) g / (1 - kappa) = 392 N. Stopping it by
   T = 0.2 s with the smallest peak normal force, |u| <= 39 N (below the 39.24 N that would lift it
   off), gives the bound (m+M) g + M tan(alpha) v0 / T = 24.62 N: a constant deceleration held by a
   forward push just below the friction force.

Documented initial guess for every solve: the simulation of u = 0 (the block at rest for problem 1,
the uncontrolled stop for problem 2), on the problem's grid.

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
from lcp.contact_problem import MODE_NAMES, OPEN, SLIDE_NEG, SLIDE_POS, STICK  # noqa: E402
from lcp.ocp import OptimalControlProblem, effort, replay, tangential_push  # noqa: E402

NAME = "optimal_control"
DESCRIPTION = "Optimal control through frictional contact: rest-to-rest and shock avoidance (Jean-Pratt)."

G = 9.81
BASE = dict(m=1.0, M=1.0, alpha=math.pi / 4, g=G)
#: problem 1 (rest to rest)
REST = dict(R=0.5, d=0.5, u_max=20.0, T_effort=1.0)
#: problem 2 (shock avoidance)
SHOCK = dict(R=1.9, v0=1.0, T=0.2, u_max=39.0, rate_weight=1e-6)
SHOCK_SWEEP_R = (1.8, 1.9, 1.98)  # kappa = 0.9, 0.95, 0.99


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


def peak_bound(R=SHOCK["R"], v0=SHOCK["v0"], T=SHOCK["T"]) -> float:
    """Smallest possible peak normal force when stopping by T: (m+M) g + M tan(alpha) v0 / T."""
    _, _, _, Mt = _scene_constants(R)
    return (BASE["m"] + BASE["M"]) * G + Mt * v0 / T


# ---------------------------------------------------------------------------------------- problems
def rest_to_rest_problem(N: int, objective: str = "time") -> OptimalControlProblem:
    """Problem 1 on N control intervals, ``objective`` "time" (T free) or "effort" (T = 1 s)."""
    sc = lcp.scenes.jean_pratt(R=REST["R"], v0=0.0, **BASE)
    d, umax = REST["d"], REST["u_max"]
    common = dict(control_matrix=tangential_push(sc.system), u_min=-umax, u_max=umax,
                  terminal_constraints=lambda q, v: ca.vertcat(q[0] - d, v[0]))
    if objective == "time":
        return OptimalControlProblem(sc, N, T=1.0, free_time=True, T_bounds=(0.05, 5.0),
                                     terminal_cost=lambda T, q, v: T, **common)
    if objective == "effort":
        return OptimalControlProblem(sc, N, T=REST["T_effort"], stage_cost=effort, **common)
    raise ValueError(f"objective must be 'time' or 'effort', got {objective!r}")


def shock_problem(N: int, R: float = SHOCK["R"]) -> OptimalControlProblem:
    """Problem 2 on N control intervals: stop by T with the smallest peak normal force."""
    sc = lcp.scenes.jean_pratt(R=R, v0=SHOCK["v0"], **BASE)
    return OptimalControlProblem(sc, N, control_matrix=tangential_push(sc.system), u_min=-SHOCK["u_max"],
                                 u_max=SHOCK["u_max"], T=SHOCK["T"], max_cost=lambda s: s.N[0],
                                 terminal_constraints=lambda q, v: v[0],
                                 control_rate_weight=SHOCK["rate_weight"])


def _event_available() -> bool:
    try:
        import lcp.events  # noqa: F401
    except ImportError:
        return False
    return "event" in lcp.METHODS


def solve_and_verify(ocp: OptimalControlProblem, h_fine: float, event: bool = True) -> dict:
    """Solve from the u = 0 simulation guess; replay at the same h, at about h_fine, and by events."""
    res = ocp.solve(ocp.guess(u=0.0))
    out = {"result": res}
    out["same_h"] = replay(res, refine=1)
    refine = max(1, int(math.ceil(res.h / h_fine - 1e-9)))
    out["mj"] = replay(res, refine=refine)
    out["event"] = replay(res, method="event") if event else None
    return out


def _row(problem: str, N: int, v: dict, reference: float, value: float) -> dict:
    res = v["result"]
    return {"problem": problem, "N": N, "value": value, "reference": reference,
            "rel_gap": (value - reference) / abs(reference), "T": res.T, "success": res.success,
            "residual": res.complementarity_residual, "lcp_residual": res.lcp_residual,
            "dynamics_residual": res.dynamics_residual, "iterations": res.iterations,
            "homotopy_steps": res.homotopy_steps, "solve_time": res.solve_time, "build_time": res.build_time,
            "err_same_h": v["same_h"].max_error_q, "err_mj": float(v["mj"].error_q[0]),
            "h_replay": v["mj"].h,
            "err_event": float(v["event"].error_q[0]) if v["event"] is not None else float("nan"),
            "peak_N_opt": float(res.N.max()),
            "peak_N_event": (float(v["event"].sim.force_N.max()) if v["event"] is not None else float("nan"))}


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


def _trajectory_panels(axes, v: dict, title: str, u_max: float, extra=None):
    res, mj, ev = v["result"], v["mj"], v["event"]
    t = res.t
    ax = axes[0]
    ax.plot(t, res.u[:, 0], "o-", ms=3, color="k", label="optimal u (nodes, linear between)")
    ax.axhline(u_max, ls=":", color="0.5", lw=1)
    ax.axhline(-u_max, ls=":", color="0.5", lw=1, label=r"$\pm u_{max}$")
    ax.set_ylabel("force u [N]")
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=7, loc="best")
    ax = axes[1]
    ax.plot(mj.sim.t, mj.sim.v[:, 0], "-", color="tab:red", lw=1.5, label=f"replay Moreau-Jean h = {mj.h:.1e}")
    if ev is not None:
        ax.plot(ev.sim.t, ev.sim.v[:, 0], "--", color="tab:purple", lw=1.2, label="replay event-driven")
    ax.plot(t, res.v[:, 0], "o", ms=3, color="k", label=f"optimizer (N = {len(t) - 1})")
    ax.set_ylabel(r"velocity $\dot x$ [m/s]")
    ax.legend(fontsize=7, loc="best")
    ax = axes[2]
    ax.stairs(res.N[:, 0], t, baseline=None, color="k", lw=1.5, label="optimizer p_N / h")
    ax.stairs(mj.sim.N[:, 0], mj.sim.t, baseline=None, color="tab:red", lw=1, label="replay Moreau-Jean")
    if ev is not None:
        ax.plot(ev.sim.t, ev.sim.force_N[:, 0], "--", color="tab:purple", lw=1, label="replay event-driven")
    if extra is not None:
        extra(ax)
    ax.set_ylabel("normal force N [N]")
    ax.legend(fontsize=7, loc="best")
    rows = [("optimizer", t, res.modes[:, 0]), ("Moreau-Jean", mj.sim.t, mj.sim.modes[:, 0])]
    if ev is not None:
        rows.append(("event",) + _event_modes(ev.sim))
    _modes_panel(axes[3], rows)
    axes[3].set_xlabel("time t [s]")
    axes[3].set_title("contact mode", fontsize=9, loc="left")


def _fig_rest_to_rest(vt, ve, path):
    fig, axes = plt.subplots(4, 2, figsize=(11, 10), sharex="col",
                             gridspec_kw={"height_ratios": [1, 1, 1, 0.45]})
    _trajectory_panels(axes[:, 0], vt, f"minimum time: T = {vt['result'].T:.4f} s "
                       f"(bang-bang bound {min_time_bound():.4f} s)", REST["u_max"])
    _trajectory_panels(axes[:, 1], ve, f"minimum effort over T = {REST['T_effort']:g} s: "
                       f"J = {ve['result'].cost:.2f} (continuous optimum {min_effort_bound():.2f}) N²s",
                       REST["u_max"])
    for ax in axes[2]:
        ax.axhline((BASE["m"] + BASE["M"]) * G, ls=":", color="0.5", lw=1, label="(m+M) g (no acceleration)")
        ax.legend(fontsize=7, loc="best")
    fig.suptitle(f"Jean-Pratt block, R = {REST['R']}: rest at x = 0 to rest at x = {REST['d']} m, "
                 f"|u| <= {REST['u_max']:g} N", fontsize=11)
    fig.tight_layout()
    return save(fig, path)


def _fig_shock(v, unc, path):
    fig, axes = plt.subplots(4, 1, figsize=(8, 10), sharex=True,
                             gridspec_kw={"height_ratios": [1, 1, 1.2, 0.55]})
    res = v["result"]
    sc = lcp.scenes.jean_pratt(R=SHOCK["R"], v0=SHOCK["v0"], **BASE)

    def extra(ax):
        ax.stairs(unc.N[:, 0], unc.t, baseline=None, color="0.5", lw=1.2,
                  label=f"uncontrolled (u = 0), MJ h = {unc.h:.0e}")
        ax.axhline(sc.N0, ls=":", color="0.4", lw=1)
        ax.text(SHOCK["T"] * 0.3, sc.N0 * 1.15, f"uncontrolled peak N0 = (m+M)g/(1-kappa) = {sc.N0:.0f} N",
                fontsize=8, color="0.3")
        ax.axhline(peak_bound(), ls=":", color="tab:blue", lw=1)
        ax.text(SHOCK["T"] * 0.3, peak_bound() * 1.12, f"lower bound (m+M)g + Mt v0/T = {peak_bound():.2f} N",
                fontsize=8, color="tab:blue")
        ax.set_yscale("log")
        ax.set_ylim(5, sc.N0 * 3)

    _trajectory_panels(axes, v, f"shock avoidance, kappa = {sc.kappa:.2f}: optimal peak N = {res.peak:.3f} N "
                       f"(N = {len(res.t) - 1})", SHOCK["u_max"], extra=extra)
    axes[1].plot(unc.t, unc.v[:, 0], color="0.5", lw=1.2, label="uncontrolled (u = 0)")
    axes[1].legend(fontsize=7, loc="best")
    _, c, D, _ = _scene_constants(SHOCK["R"])
    axes[0].axhline(c, color="tab:orange", lw=1, ls="--",
                    label=f"R(m+M)g = {c:.2f} N: sliding without deceleration")
    axes[0].axhline(0.0, color="0.5", lw=1.2, label="uncontrolled (u = 0)")
    axes[0].set_ylim(-3, SHOCK["u_max"] * 1.12)
    axes[0].legend(fontsize=7, loc="center right")
    fig.tight_layout()
    return save(fig, path)


def _fig_convergence(rows, histories, N_hist, path):
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.4))
    ax = axes[0]
    styles = {"min_time": ("tab:red", "o"), "min_effort": ("tab:green", "s"), "shock": ("tab:blue", "^")}
    Ns = np.array(sorted({r["N"] for r in rows}), dtype=float)
    for prob, (col, mk) in styles.items():
        rr = [r for r in rows if r["problem"] == prob]
        N = np.array([r["N"] for r in rr])
        ax.loglog(N, [r["err_mj"] for r in rr], mk + "-", color=col, label=prob)
        ev = np.array([r["err_event"] for r in rr])
        if np.any(np.isfinite(ev)):
            ax.loglog(N[np.isfinite(ev)], ev[np.isfinite(ev)], mk, color=col, mfc="none", ms=10)
        ax.loglog(N, np.maximum([r["err_same_h"] for r in rr], 1e-17), mk + ":", color=col, ms=3, alpha=0.6)
    ax.loglog(Ns, 1.2e-2 * (Ns / Ns[0]) ** -2, "k--", lw=1, label=r"$\propto N^{-2}$")
    ax.plot([], [], "k-", label="replay, Moreau-Jean at fine h")
    ax.plot([], [], "ko", mfc="none", ms=10, label="replay, event-driven")
    ax.plot([], [], "k:", label="replay, Moreau-Jean at the same h")
    ax.set_xticks(Ns)
    ax.set_xticklabels([f"{int(n)}" for n in Ns])
    ax.minorticks_off()
    ax.set_xlabel("control intervals N")
    ax.set_ylabel(r"max$_k$ |x_opt(t_k) - x_replay(t_k)| [m]")
    ax.set_title("replay mismatch (open loop)", fontsize=10)
    ax.legend(fontsize=7, loc="center right")
    ax = axes[1]
    for prob, lab in (("min_time", "min time: (T_N - T*)/T*"), ("min_effort", "min effort: (J_N - J*)/J*"),
                      ("shock", "shock: (peak_N - bound)/bound (at IPOPT tolerance)")):
        rr = [r for r in rows if r["problem"] == prob]
        col, mk = styles[prob]
        ax.loglog([r["N"] for r in rr], np.maximum(np.abs([r["rel_gap"] for r in rr]), 1e-16), mk + "-",
                  color=col, label=lab)
    ax.set_xticks(Ns)
    ax.set_xticklabels([f"{int(n)}" for n in Ns])
    ax.minorticks_off()
    ax.set_xlabel("control intervals N")
    ax.set_ylabel("relative gap to the continuous optimum")
    ax.set_title("optimal value vs analytic reference", fontsize=10)
    ax.legend(fontsize=7)
    ax = axes[2]
    for prob, hist in histories.items():
        col, mk = styles[prob]
        hs = [s for s in hist if s.sigma > 0]
        ax.loglog([s.sigma for s in hs], [max(s.residual, 1e-17) for s in hs], mk + "-", color=col,
                  label=f"{prob} ({sum(s.iterations for s in hist)} IPOPT it.)")
        pol = [s for s in hist if s.sigma == 0]
        if pol:
            ax.loglog([hs[-1].sigma * 0.1], [max(pol[0].residual, 1e-17)], mk, color=col, mfc="none", ms=9)
    ax.axhline(1e-8, color="k", ls=":", lw=1, label="target 1e-8")
    ax.invert_xaxis()
    ax.set_xlabel(r"Scholtes relaxation $\sigma$ (open markers: polishing solve)")
    ax.set_ylabel("Coulomb residual (impulse) [N s]")
    ax.set_title(f"homotopy history (N = {N_hist})", fontsize=10)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return save(fig, path)


def _fig_sweep(sweep, path):
    fig, ax = plt.subplots(figsize=(6, 4))
    k = [r["kappa"] for r in sweep]
    ax.semilogy(k, [r["N0"] for r in sweep], "o-", color="0.4", label="uncontrolled peak N0 = (m+M)g/(1-kappa)")
    ax.semilogy(k, [r["peak_uncontrolled"] for r in sweep], "x", color="k", label="uncontrolled, simulated")
    ax.semilogy(k, [r["peak_opt"] for r in sweep], "s-", color="tab:blue", label="optimal control: peak (optimizer)")
    ax.semilogy(k, [r["peak_replay"] for r in sweep], "+", ms=10, color="tab:red",
                label="optimal control: peak (replay)")
    ax.semilogy(k, [r["bound"] for r in sweep], ":", color="tab:blue", label="bound (m+M)g + Mt v0/T")
    ax.set_xlabel(r"shock number $\kappa$ = R M tan(alpha) / A")
    ax.set_ylabel("peak normal force [N]")
    ax.set_title(f"stopping from v0 = {SHOCK['v0']} m/s by T = {SHOCK['T']} s", fontsize=10)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return save(fig, path)


# ---------------------------------------------------------------------------------------- the study
def run(out=None, quick: bool = False) -> dict:
    """Solve both problems for several N, replay every control, write CSV tables and figures.

    Returns
    -------
    dict
        ``rows`` (one dict per problem and N: value, reference, rel_gap, residual, iterations,
        homotopy_steps, solve_time, err_same_h, err_mj, err_event, ...), ``sweep`` (shock avoidance
        per kappa: N0, peak_opt, peak_replay, bound, peak_uncontrolled), ``references`` (T*, J*,
        peak bound), ``event_available`` and ``files``.
    """
    path = out_dir(out, NAME)
    Ns = (10, 20, 40) if quick else (10, 20, 40, 80, 160)
    N_fig = 40
    h_fine = 5e-4 if quick else 5e-5
    event = _event_available()
    refs = {"T_star": min_time_bound(), "J_star": min_effort_bound(), "peak_bound": peak_bound()}
    rows, keep = [], {}
    for N in Ns:
        for prob in ("min_time", "min_effort", "shock"):
            if prob == "shock":
                ocp, ref = shock_problem(N), refs["peak_bound"]
            else:
                ocp = rest_to_rest_problem(N, "time" if prob == "min_time" else "effort")
                ref = refs["T_star"] if prob == "min_time" else refs["J_star"]
            # the event replay is the slow part (DOP853 through every kink of the control): in quick
            # mode only for the figures
            v = solve_and_verify(ocp, h_fine, event=event and (not quick or N == N_fig))
            res = v["result"]
            value = res.T if prob == "min_time" else (res.cost if prob == "min_effort" else res.peak)
            rows.append(_row(prob, N, v, ref, value))
            if N == N_fig:
                keep[prob] = v
    files = []
    cols = list(rows[0].keys())
    files.append(write_csv(path / "convergence.csv", cols, [[r[c] for c in cols] for r in rows]))

    # shock avoidance against kappa, with the uncontrolled stop
    sweep = []
    N_sweep = 20 if quick else 40
    for R in SHOCK_SWEEP_R:
        sc = lcp.scenes.jean_pratt(R=R, v0=SHOCK["v0"], **BASE)
        v = solve_and_verify(shock_problem(N_sweep, R), h_fine, event=event and not quick)
        if event:
            unc = lcp.simulate(sc, SHOCK["T"], method="event")
            peak_unc = float(unc.force_N.max())
        else:
            unc = lcp.simulate(sc, SHOCK["T"], h=h_fine)
            peak_unc = float(unc.N.max())
        ev = v["event"]
        sweep.append({"R": R, "kappa": sc.kappa, "N": N_sweep, "N0": sc.N0, "peak_uncontrolled": peak_unc,
                      "peak_opt": v["result"].peak, "bound": peak_bound(R=R),
                      "peak_replay": float(ev.sim.force_N.max()) if ev is not None else float(v["mj"].sim.N.max()),
                      "residual": v["result"].complementarity_residual, "err_mj": float(v["mj"].error_q[0]),
                      "solve_time": v["result"].solve_time, "iterations": v["result"].iterations,
                      "u_mean": float(np.mean(v["result"].u[:, 0]))})
    cols = list(sweep[0].keys())
    files.append(write_csv(path / "shock_sweep.csv", cols, [[r[c] for c in cols] for r in sweep]))

    # trajectories behind the figures
    for prob, v in keep.items():
        res = v["result"]
        modes = np.append(res.modes[:, 0], -1)
        Nf = np.append(res.N[:, 0], np.nan)
        files.append(write_csv(path / f"trajectory_{prob}.csv", ["t", "u", "x", "xdot", "N_step", "mode"],
                               [[float(a), float(b), float(c), float(d), float(e), MODE_NAMES.get(int(f), "")]
                                for a, b, c, d, e, f in zip(res.t, res.u[:, 0], res.q[:, 0], res.v[:, 0], Nf,
                                                            modes)]))
        files.append(write_csv(path / f"homotopy_{prob}.csv",
                               ["sigma", "iterations", "residual", "max_product", "cost", "return_status", "time"],
                               [[s.sigma, s.iterations, s.residual, s.max_product, s.cost, s.return_status, s.time]
                                for s in res.homotopy]))
    sc = lcp.scenes.jean_pratt(R=SHOCK["R"], v0=SHOCK["v0"], **BASE)
    unc = lcp.simulate(sc, SHOCK["T"], h=keep["shock"]["mj"].h)
    files.append(_fig_rest_to_rest(keep["min_time"], keep["min_effort"], path / "rest_to_rest.png"))
    files.append(_fig_shock(keep["shock"], unc, path / "shock_avoidance.png"))
    hist = {p: keep[p]["result"].homotopy for p in keep}
    files.append(_fig_convergence(rows, hist, N_fig, path / "convergence.png"))
    files.append(_fig_sweep(sweep, path / "shock_sweep.png"))
    return {"rows": rows, "sweep": sweep, "references": refs, "event_available": event, "N_figure": N_fig,
            "files": [Path(f) for f in files]}


def main(argv=None):
    args = parse_args(NAME, DESCRIPTION, argv)
    out = run(args.out, quick=args.quick)
    print(f"references: T* = {out['references']['T_star']:.6f} s, J* = {out['references']['J_star']:.4f} N^2 s, "
          f"peak bound = {out['references']['peak_bound']:.4f} N; event replay: {out['event_available']}")
    print(f"{'problem':>10} {'N':>4} {'value':>10} {'rel_gap':>9} {'residual':>9} {'iter':>5} {'hom':>4} "
          f"{'solve[s]':>8} {'err_same_h':>10} {'err_mj':>9} {'err_event':>9}")
    for r in out["rows"]:
        print(f"{r['problem']:>10} {r['N']:>4} {r['value']:>10.6g} {r['rel_gap']:>9.2e} {r['residual']:>9.1e} "
              f"{r['iterations']:>5} {r['homotopy_steps']:>4} {r['solve_time']:>8.3f} {r['err_same_h']:>10.1e} "
              f"{r['err_mj']:>9.2e} {r['err_event']:>9.2e}")
    for r in out["sweep"]:
        print(f"kappa = {r['kappa']:.2f}: uncontrolled peak {r['peak_uncontrolled']:.1f} N (N0 = {r['N0']:.1f}), "
              f"optimal peak {r['peak_opt']:.4f} N (replay {r['peak_replay']:.4f}, bound {r['bound']:.4f})")
    print("wrote", ", ".join(str(f) for f in out["files"]))
    return out


if __name__ == "__main__":
    main()
