"""The shock limit kappa -> 1 of the Jean-Pratt system: exact, event-driven and Moreau-Jean side by side.

``python -m studies.shock_limit [--out DIR] [--quick] [--workers N | --scheduler ADDRESS]`` writes,
into DIR (default figures/shock_limit/) the files below; ``--workers`` (a new local Dask cluster) or
``--scheduler`` (a running one) computes the kappa sweep and the regime map side by side, with the
same numbers:

- ``sweep.csv``, ``sweep_v0_pos.png``, ``sweep_v0_neg.png``: kappa = 1 - 10^-k (k = 1..12) and
  kappa in [1, 1.5]; tau0, N0, the stop distance and the stop impulses, exact against the
  event-driven integrator against Moreau-Jean at several h;
- ``convergence.csv``, ``convergence.png``: the smooth solution tends to the shock as kappa -> 1-;
- ``iterations.csv``, ``iterations.png``: iterations of each one-step solver against kappa, and of
  the plain friction-bound (Tresca) fixed point, which contracts by exactly kappa (docs/numerical_methods.md);
- ``series.csv``, ``series.png``: where the printed LEM series (4.1)/(4.2) stops making sense;
- ``regimes.csv``, ``regimes.png``: regime map over (R, alpha) for a few m/M, with the kappa = 1
  curve, checked against the event-driven integrator on a coarser grid.

The scene is m = M = 1, alpha = pi/4 (tan = 1 exactly, A = 2), g = 9.81, |v0| = 1, so that
kappa = R/2 and kappa = 1 is R = 2 exactly. :func:`run` returns the numbers behind every figure.

Example
-------
>>> from studies import shock_limit
>>> res = shock_limit.run(out=None, quick=True)            # doctest: +SKIP
>>> res["checks"]["event_max_x_error"] <= 1e-13            # doctest: +SKIP
True
"""
from __future__ import annotations

import functools
import math
import time

import numpy as np

import lcp
from lcp.scenes.jean_pratt_exact import JeanPrattExact
from lem import series
from studies._cluster import add_options, cluster, pieces
from studies._common import floored, legend, out_dir, parse_args, save, write_csv

import matplotlib.pyplot as plt  # noqa: E402  (studies._common selects the Agg backend first)

NAME = "shock_limit"
G = 9.81
M_, m_, TAN, A_ = 1.0, 1.0, 1.0, 2.0  # alpha = pi/4
N_STICK = (m_ + M_) * G
T_END = 0.3


def kappas(quick: bool):
    ks = [1, 3, 6, 9, 12] if quick else list(range(1, 13))
    below = [(1.0 - 10.0 ** -k, f"1-1e-{k}") for k in ks]
    above = [(1.0, "1"), (1.5, "1.5")] if quick else [(1.0, "1"), (1.1, "1.1"), (1.25, "1.25"), (1.5, "1.5")]
    return below + above


def _scene(kappa, v0, **kw):
    # R = kappa A / (M tan) = 2 kappa: multiplication by 2 is exact, so kappa = 1 is R = 2 exactly
    return lcp.scenes.jean_pratt(R=2.0 * kappa, v0=v0, t_end=T_END, **kw)


# ----------------------------------------------------------------------------------- sweep
def sweep(quick: bool, client=None) -> list:
    """Rows per (kappa, v0): (rows, hs). ``client``: a Dask client to run them on (None: here)."""
    hs = [1e-2, 1e-3] if quick else [1e-2, 1e-3, 1e-4]
    sets = [(kappa, label, v0) for kappa, label in kappas(quick) for v0 in (1.0, -1.0)]
    return pieces(functools.partial(sweep_row, hs), sets, client, "kappa sweep"), hs


def sweep_row(hs, kappa_label_v0) -> dict:
    """One row of :func:`sweep`: exact, event-driven and Moreau-Jean at each h (one piece of work)."""
    kappa, label, v0 = kappa_label_v0
    sc = _scene(kappa, v0)
    ex = sc.solution
    shock = bool(ex.shocks)
    # stop impulses: beyond the static (m + M) g t, over the whole horizon (shocks included)
    PN, PT = ex.impulse(0.0, T_END)
    ex_excess_N, ex_PT = float(PN[0]) - N_STICK * T_END, float(PT[0])
    ev = lcp.simulate(sc, T_END, method="event")
    tex = sc.exact(ev.t)
    ev_stop = ev.t_events[0] if ev.t_events else math.inf
    ev_N0 = math.inf if ev.impulses else float(ev.force_N[0, 0])
    ev_excess_N = float(np.sum(ev.p_N)) - N_STICK * (ev.t[-1] - ev.t[0])
    row = dict(kappa=kappa, label=label, v0=v0, shock=shock,
               tau0_exact=ex.tau0, N0_exact=ex.N0, x_stop_exact=ex.x_stop,
               excess_PN_exact=ex_excess_N, PT_exact=ex_PT,
               shock_PN_exact=ex.shocks[0][1] if shock else 0.0,
               shock_PT_exact=ex.shocks[0][2] if shock else 0.0,
               tau0_event=ev_stop, N0_event=ev_N0, x_stop_event=float(ev.q[-1, 0]),
               excess_PN_event=ev_excess_N, PT_event=float(np.sum(ev.p_T)),
               shock_PN_event=ev.impulses[0].P_N if ev.impulses else 0.0,
               shock_PT_event=ev.impulses[0].P_T if ev.impulses else 0.0,
               event_x_error=float(np.max(np.abs(ev.q[:, 0] - tex["x"]))),
               event_success=ev.success)
    for h in hs:
        mj = lcp.simulate(sc, T_END, h=h)
        stopped = np.flatnonzero(mj.v[:, 0] * np.sign(v0) <= 0.0)
        T = mj.t[-1]
        row[f"x_stop_mj_{h:g}"] = float(mj.q[-1, 0])
        row[f"tau0_mj_{h:g}"] = float(mj.t[stopped[0]]) if stopped.size else math.inf
        row[f"N0_mj_{h:g}"] = float(mj.p_N[0, 0] / h)
        row[f"excess_PN_mj_{h:g}"] = float(np.sum(mj.p_N)) - N_STICK * T
        row[f"PT_mj_{h:g}"] = float(np.sum(mj.p_T))
    return row


def _log_only_over_a_decade(ax):
    """A log y axis only where the plotted data span more than a decade (else linear)."""
    if ax.get_yscale() != "log":
        return
    ys = np.concatenate([np.asarray(ln.get_ydata(), dtype=float) for ln in ax.get_lines()] or [np.zeros(0)])
    ys = ys[np.isfinite(ys) & (ys > 0)]
    if ys.size and ys.max() < 10 * ys.min():
        ax.set_yscale("linear")


def plot_sweep(rows, hs, v0, path):
    sel = [r for r in rows if r["v0"] == v0]
    x = np.arange(len(sel))
    labels = [r["label"] for r in sel]
    fig, ax = plt.subplots(2, 2, figsize=(17, 9), sharex=True)
    colors = plt.cm.viridis(np.linspace(0.15, 0.8, len(hs)))
    shock = np.array([r["shock"] for r in sel])
    floor = 1e-17

    def pos(vals):
        vals = np.asarray(vals, dtype=float)
        return np.where(vals > 0, vals, np.nan)

    a = ax[0, 0]
    a.semilogy(x, pos([r["tau0_exact"] for r in sel]), "k-", lw=2, label="exact $\\tau_0$")
    a.semilogy(x, pos([r["tau0_event"] for r in sel]), "o", mfc="none", ms=9, color="C3", label="event-driven")
    a.semilogy(x, pos(np.abs([r["x_stop_exact"] for r in sel])), "k--", lw=1.5, label="exact stop distance $|x^*|$ (m)")
    a.semilogy(x, pos(np.abs([r["x_stop_event"] for r in sel])), "s", mfc="none", ms=7, color="C3")
    if shock.any():
        # true zeros, drawn as crosses at the bottom of the log axis (never as "below a floor")
        a.plot(x[shock], np.full(shock.sum(), 3e-16), "kx", ms=9, label="× exactly 0 (shock at t = 0: $\\tau_0 = x^* = 0$)")
    a.set_ylabel("stop time $\\tau_0$ (s), stop distance $x^*$ (m)")
    a.set_title("(a) stop time and stop distance")
    _log_only_over_a_decade(a)
    legend(a)

    a = ax[0, 1]
    a.semilogy(x, pos([r["N0_exact"] if np.isfinite(r["N0_exact"]) else np.nan for r in sel]), "k-", lw=2,
               label="exact sliding $N_0 = (m+M)g/(1 \\mp \\kappa)$")
    a.semilogy(x, pos([r["N0_event"] if np.isfinite(r["N0_event"]) else np.nan for r in sel]), "o", mfc="none",
               ms=9, color="C3", label="event-driven")
    for h, c in zip(hs, colors):
        a.semilogy(x, pos([r[f"N0_mj_{h:g}"] for r in sel]), "x-", color=c, lw=1,
                   label=f"Moreau-Jean, mean over first step, h = {h:g}")
    a.set_ylabel("normal force at t = 0+ (N)")
    a.set_title("(b) normal force while sliding ($N_0 = \\infty$ at the shock)")
    _log_only_over_a_decade(a)
    legend(a)

    a = ax[1, 0]
    a.set_yscale("log")
    floored(a, x, [r["event_x_error"] for r in sel], floor, "o-", color="C3",
            label="event-driven: max$_t$ |x(t) - exact| (1000 times)")
    for h, c in zip(hs, colors):
        floored(a, x, np.abs([r[f"x_stop_mj_{h:g}"] - r["x_stop_exact"] for r in sel]), floor, "x-", color=c,
                label=f"Moreau-Jean |x(T) - x*|, h = {h:g}")
    a.set_ylabel("position error (m)")
    a.set_title("(c) error of the stop position")
    _log_only_over_a_decade(a)
    legend(a)

    a = ax[1, 1]
    a.plot(x, [r["excess_PN_exact"] for r in sel], "k-", lw=2, label="exact $\\int (N - (m+M)g)\\,dt$ + shock")
    a.plot(x, [r["PT_exact"] for r in sel], "k--", lw=2, label="exact $\\int f\\,dt$ + shock")
    a.plot(x, [r["excess_PN_event"] for r in sel], "o", mfc="none", ms=9, color="C3", label="event-driven")
    a.plot(x, [r["PT_event"] for r in sel], "o", mfc="none", ms=9, color="C3")
    for h, c in zip(hs, colors):
        a.plot(x, [r[f"excess_PN_mj_{h:g}"] for r in sel], "x", color=c, label=f"Moreau-Jean, h = {h:g}")
        a.plot(x, [r[f"PT_mj_{h:g}"] for r in sel], "x", color=c)
    a.axhline(M_ * TAN * v0, color="0.5", lw=0.8)
    a.axhline(-A_ * v0, color="0.5", lw=0.8)
    a.set_ylabel("impulse (N s)")
    a.set_title(f"(d) stop impulses: normal $M\\tan\\alpha\\, v_0$ = {M_ * TAN * v0:g}, "
                f"tangential $-A v_0$ = {-A_ * v0:g}, for every $\\kappa$")
    _log_only_over_a_decade(a)
    legend(a)
    for a in ax[1]:
        a.set_xticks(x)
        a.set_xticklabels(labels, rotation=45)
        a.set_xlabel("shock number $\\kappa = R M \\tan\\alpha / A$")
    fig.suptitle(f"Jean-Pratt, m = M = 1, $\\alpha = \\pi/4$, $v_0$ = {v0:g}: "
                 "approaching the shock limit $\\kappa \\to 1$" + ("" if v0 > 0 else
                                                                  " (no shock for $v_0 < 0$: $N_0 = (m+M)g/(1+\\kappa)$)"))
    return save(fig, path)


# ----------------------------------------------------------------------------- convergence
def convergence(quick: bool) -> dict:
    ks = [1, 2, 3, 4, 6, 9, 12] if not quick else [1, 2, 3, 6, 12]
    tt = np.logspace(-16, math.log10(T_END), 400)
    rows, curves = [], {}
    for k in ks:
        kappa = 1.0 - 10.0 ** -k
        sc = _scene(kappa, 1.0)
        ex = sc.solution
        ev = lcp.simulate(sc, T_END, method="event", t_eval=np.concatenate([[0.0], tt]))
        curves[k] = (tt, ev.q[1:, 0], sc.exact(tt)["x"])
        PN, PT = ex.impulse(0.0, ex.tau0)
        rows.append(dict(k=k, kappa=kappa, one_minus_kappa=1.0 - kappa, tau0=ex.tau0, x_stop=ex.x_stop,
                         sup_dist_to_shock=float(np.max(np.abs(ev.q[:, 0]))),
                         slide_PN=float(PN[0]), slide_PT=float(PT[0]),
                         slide_PN_minus_shock=float(PN[0]) - N_STICK * ex.tau0 - M_ * TAN,
                         slide_PT_minus_shock=float(PT[0]) + A_,
                         event_x_error=float(np.max(np.abs(ev.q[1:, 0] - curves[k][2]))),
                         event_tau0_rel_error=abs(ev.t_events[0] - ex.tau0) / ex.tau0))
    return dict(rows=rows, curves=curves)


def plot_convergence(conv, path):
    fig, ax = plt.subplots(1, 2, figsize=(13, 5))
    cols = plt.cm.plasma(np.linspace(0.05, 0.85, len(conv["curves"])))
    for (k, (tt, xe, xx)), c in zip(conv["curves"].items(), cols):
        ax[0].loglog(tt, xx, "-", color=c, lw=1.5, label=f"$\\kappa = 1 - 10^{{-{k}}}$ exact")
        ax[0].loglog(tt[::25], xe[::25], "o", color=c, mfc="none", ms=5)
    ax[0].loglog([], [], "ko", mfc="none", label="event-driven")
    ax[0].set_xlabel("t (s)")
    ax[0].set_ylabel("x(t) (m)")
    ax[0].set_title("(a) x(t) = $v_0 t - B t^2/2$ up to $\\tau_0$, then stick; the shock is x = 0")
    legend(ax[0])
    r = conv["rows"]
    omk = np.array([x["one_minus_kappa"] for x in r])
    ax[1].loglog(omk, [x["tau0"] for x in r], "o-", label="$\\tau_0$ (s)")
    ax[1].loglog(omk, [x["sup_dist_to_shock"] for x in r], "s-", label="$\\sup_t |x_\\kappa(t) - x_{shock}(t)| = x^*$ (m)")
    ax[1].loglog(omk, omk * r[0]["tau0"] / omk[0], "k:", lw=1, label="slope 1")
    dpn = np.abs([x["slide_PN_minus_shock"] for x in r])
    dpt = np.abs([x["slide_PT_minus_shock"] for x in r])
    floored(ax[1], omk, dpn, 1e-17, "^-", label="|$\\int_0^{\\tau_0}(N-(m+M)g)dt - M\\tan\\alpha\\,v_0$| (N s)")
    floored(ax[1], omk, dpt, 1e-17, "v-", label="|$\\int_0^{\\tau_0} f\\,dt + A v_0$| (N s)")
    ax[1].invert_xaxis()
    ax[1].set_xlabel("$1 - \\kappa$ (the shock limit is to the right)")
    ax[1].set_title("(b) distance to the shock: time and distance vanish like $1-\\kappa$,\n"
                    "the impulses equal the shock's (to rounding) for every $\\kappa < 1$")
    legend(ax[1])
    fig.suptitle("Convergence of the smooth solution to the tangential shock as $\\kappa \\to 1^-$ "
                 "(m = M = 1, $\\alpha = \\pi/4$, $v_0 = 1$)")
    return save(fig, path)


# ------------------------------------------------------------------------------ iterations
def tresca_qp(W, q, s):
    """Closed-form minimizer of 1/2 p'W p + q'p with p_N >= 0, |p_T| <= s (one contact, W SPD).

    Tresca's law with bound s: the QP of one friction-bound iteration (docs/numerical_methods.md)."""
    det = W[0, 0] * W[1, 1] - W[0, 1] ** 2
    cands = [np.array([(-q[0] * W[1, 1] + q[1] * W[0, 1]) / det, (-q[1] * W[0, 0] + q[0] * W[0, 1]) / det])]
    for pT in (s, -s):
        cands.append(np.array([-(q[0] + W[0, 1] * pT) / W[0, 0], pT]))
    cands.append(np.array([0.0, min(max(-q[1] / W[1, 1], -s), s)]))
    cands.append(np.array([0.0, s]))
    cands.append(np.array([0.0, -s]))
    best, val = None, math.inf
    for p in cands:
        if p[0] < -1e-15 * max(1.0, abs(p[0])) or abs(p[1]) > s * (1 + 1e-15) + 1e-300:
            continue
        f = 0.5 * p @ W @ p + q @ p
        if f < val:
            best, val = p, f
    return best


def plain_fixed_point(kappa, h, cap, tol=1e-14):
    """Iterate s <- mu p_N(s) on the first Moreau-Jean step problem; (iterations, contraction, converged)."""
    sc = _scene(kappa, 1.0)
    A = sc.system.mass(sc.q0)
    H = sc.system.contact_jacobian(sc.q0)
    F = sc.system.force(sc.q0, sc.v0)
    vfree = sc.v0 + h * np.linalg.solve(A, F)
    W = H @ np.linalg.solve(A, H.T)
    q = H @ vfree
    mu = 2.0 * kappa
    s, ds_prev, ratios = 0.0, None, []
    for it in range(1, cap + 1):
        s_new = mu * max(tresca_qp(W, q, s)[0], 0.0)
        ds = s_new - s
        if ds_prev not in (None, 0.0) and ds != 0.0:
            ratios.append(ds / ds_prev)
        s, ds_prev = s_new, ds
        if abs(ds) <= tol * max(abs(s), 1e-300):
            break
    # early ratios: later differences approach rounding and stop measuring the map
    contraction = float(np.median(ratios[1:20])) if len(ratios) > 1 else math.nan
    return it, contraction, abs(ds) <= tol * max(abs(s), 1e-300)


def iterations(quick: bool) -> list:
    t_end = 0.05 if quick else T_END
    cap = 20_000 if quick else 200_000
    rows = []
    for kappa, label in kappas(quick):
        row = dict(kappa=kappa, label=label)
        sc = _scene(kappa, 1.0)
        for solver in ("enum", "lemke", "osqp"):
            r = lcp.simulate(sc, t_end, h=1e-3, solver=solver)
            row[f"{solver}_max_iterations"] = r.stats.max_iterations
            row[f"{solver}_mean_iterations"] = r.stats.iterations / max(r.stats.solver_calls, 1)
            row[f"{solver}_qp_solves"] = r.stats.qp_solves
            row[f"{solver}_success"] = r.success
        # a step that slides throughout (h << tau0) shows the sliding branch's contraction by kappa
        h = min(1e-3, sc.tau0 / 10) if kappa < 1 else 1e-3
        it, ratio, conv = plain_fixed_point(kappa, h, cap)
        row.update(plain_h=h, plain_iterations=it, plain_converged=conv, plain_contraction=ratio,
                   plain_predicted=(math.log(1e-14) / math.log(kappa)) if kappa < 1 else math.nan)
        rows.append(row)
    return rows


def plot_iterations(rows, path):
    x = np.arange(len(rows))
    fig, ax = plt.subplots(1, 2, figsize=(13, 5))
    a = ax[0]
    # hollow markers of decreasing size: solvers that need the same count stay visible on top of each other
    for solver, mk, ms in (("enum", "o", 11), ("lemke", "s", 7), ("osqp", "^", 5)):
        a.semilogy(x, [max(r[f"{solver}_max_iterations"], 0.8) for r in rows], mk + "-", mfc="none", ms=ms,
                   label=f"'{solver}': most iterations in one step")
    a.semilogy(x, [r["osqp_qp_solves"] for r in rows], "^:", color="C2", alpha=0.6,
               label="'osqp': QP solves in total")
    conv = np.array([r["plain_converged"] for r in rows])
    it = np.array([r["plain_iterations"] for r in rows], dtype=float)
    # no line across the points where the iteration stopped at its cap: NaN breaks the line there
    a.semilogy(x, np.where(conv, it, np.nan), "kD-", label="plain Tresca fixed point $s \\leftarrow \\mu p_N(s)$ to 1e-14")
    if (~conv).any():
        a.semilogy(x[~conv], it[~conv], "kD", mfc="none", ms=9, label="plain fixed point: stopped at the cap")
    pred = np.array([r["plain_predicted"] for r in rows])
    a.semilogy(x, pred, "k:", label="predicted $\\log(10^{-14})/\\log\\kappa$")
    a.set_xticks(x)
    a.set_xticklabels([r["label"] for r in rows], rotation=45)
    a.set_xlabel("$\\kappa$")
    a.set_ylabel("iterations (count)")
    a.set_title("(a) one-step solvers (Moreau-Jean, h = 1e-3) and the plain fixed point")
    legend(a)
    a = ax[1]
    below = [r for r in rows if r["kappa"] < 1]
    omk = np.array([1 - r["kappa"] for r in below])
    a.set_xscale("log")
    a.set_yscale("log")
    floored(a, omk, np.abs([r["plain_contraction"] - r["kappa"] for r in below]), 1e-17, "o-",
            label="|observed contraction factor - $\\kappa$|")
    a.loglog(omk, omk, "k:", label="$1 - \\kappa$ (for scale)")
    a.invert_xaxis()
    a.set_xlabel("$1 - \\kappa$")
    a.set_title("(b) the plain fixed point contracts by exactly $\\kappa$ per iteration")
    legend(a)
    fig.suptitle("Iterations of the one-step contact solvers against the shock number")
    return save(fig, path)


# --------------------------------------------------------------------------------- series
def printed_series(quick: bool) -> dict:
    """Where the printed (4.1)/(4.2) stops making sense. In u = B t / |v0| and units v0^2/B the
    printed series and the exact Coulomb slide do not depend on kappa, so the validity window is a
    fixed fraction of tau0, and it shrinks to nothing with tau0 as kappa -> 1-."""
    u = np.linspace(0.0, 2.0, 20001)
    out = {}
    for v0, fn in ((1.0, series.series_4_1_printed), (-1.0, series.series_4_2_printed)):
        B = 1.0  # scaled units
        qp = fn(u, v0, B) / v0 ** 2
        qe = series.coulomb_slide(u, v0, B) / v0 ** 2
        vp = np.gradient(qp, u)
        err = np.abs(qp - qe)
        x_star = 0.5  # exact stop distance in units v0^2/B
        u_1pct = float(u[np.argmax(err > 0.01 * x_star)])
        # the printed velocity stops decreasing in magnitude: the friction would push the block on
        dv = np.gradient(np.abs(vp), u)
        u_turn = float(u[np.argmax(dv > 0)])
        out[v0] = dict(u=u, q_printed=qp, q_exact=qe, u_1pct=u_1pct, u_turn=u_turn,
                       q_at_tau0_printed=float(fn(1.0, v0, 1.0) / v0 ** 2), q_at_tau0_exact=0.5 * np.sign(v0),
                       min_speed_printed=float(np.min(np.abs(vp[u <= 2.0]))))
    rows = []
    for kappa, label in kappas(quick):
        for v0 in (1.0, -1.0):
            sc = JeanPrattExact(R=2.0 * kappa, v0=v0)
            defined = np.isfinite(sc.B) and sc.B > 0
            tau0 = sc.tau0 if defined else 0.0
            rows.append(dict(kappa=kappa, label=label, v0=v0, B=sc.B if defined else math.inf, tau0=tau0,
                             printed_defined=defined,
                             t_1pct=out[v0]["u_1pct"] * tau0 if defined else 0.0,
                             t_turn=out[v0]["u_turn"] * tau0 if defined else 0.0,
                             q_tau0_printed=out[v0]["q_at_tau0_printed"] * v0 ** 2 / sc.B if defined else math.nan,
                             x_stop_exact=sc.x_stop))
    return dict(scaled=out, rows=rows)


def plot_series(ser, path):
    fig, ax = plt.subplots(1, 2, figsize=(13, 5))
    a = ax[0]
    for v0, c in ((1.0, "C0"), (-1.0, "C1")):
        d = ser["scaled"][v0]
        name = "(4.1), $v_0 > 0$" if v0 > 0 else "(4.2), $v_0 < 0$"
        a.plot(d["u"], d["q_printed"], "-", color=c, label=f"printed {name}")
        a.plot(d["u"], d["q_exact"], "--", color=c, label="exact Coulomb slide, then stick")
        a.axvline(d["u_1pct"], color=c, ls=":", lw=1)
        a.plot(d["u_turn"], np.interp(d["u_turn"], d["u"], d["q_printed"]), "o", color=c, mfc="none", ms=9)
    a.axvline(1.0, color="k", lw=0.8)
    a.text(1.01, 0.1, "$t = \\tau_0$", transform=a.get_xaxis_transform())
    a.plot([], [], "ko", mfc="none", label="printed speed stops decreasing (friction would push)")
    a.plot([], [], "k:", label="printed error reaches 1% of the stop distance")
    a.set_xlabel("$u = B t / |v_0| = t / \\tau_0$ (dimensionless)")
    a.set_ylabel("$q B / v_0^2$ (dimensionless)")
    a.set_ylim(-2.5, 2.5)
    a.text(0.99, 0.98, "clipped at |q B / v0²| = 2.5: the printed curves leave the window", ha="right", va="top",
           fontsize=7, color="0.35", transform=a.transAxes)
    a.set_title("(a) printed series vs exact, scaled: the same for every $\\kappa < 1$")
    legend(a)
    a = ax[1]
    for v0, mk in ((1.0, "o"), (-1.0, "s")):
        rr = [r for r in ser["rows"] if r["v0"] == v0 and r["printed_defined"]]
        omk = np.array([1 - r["kappa"] for r in rr])
        a.loglog(omk, [r["tau0"] for r in rr], mk + "-", color="k", mfc="none", label=f"$\\tau_0$, $v_0$ = {v0:g}")
        a.loglog(omk, [r["t_1pct"] for r in rr], mk + "--", color="C3",
                 label=f"printed series within 1% up to t = {ser['scaled'][v0]['u_1pct']:.3f} $\\tau_0$, $v_0$ = {v0:g}")
    a.invert_xaxis()
    a.set_xlabel("$1 - \\kappa$")
    a.set_ylabel("time (s)")
    a.set_title("(b) the window where (4.1) makes sense closes as $\\kappa \\to 1^-$;\n"
                "for $\\kappa \\geq 1$, $v_0 > 0$ it is undefined ($N_0 \\leq 0$ or $\\infty$)")
    legend(a)
    fig.suptitle("The paper's printed LEM series (4.1)/(4.2) against the exact Coulomb motion")
    return save(fig, path)


# --------------------------------------------------------------------------------- regimes
REGIMES = ["slide, then stick", "stick at once", "slide for ever", "shock, then stick",
           "no consistent mode", "lift-off"]
REGIME_COLORS = ["#9ecae1", "#a1d99b", "#fdd0a2", "#e6550d", "#636363", "#bcbddc"]
CASES = [("$v_0 = +1$, $\\varphi = 0$ (paper)", 1.0, 0.0), ("$v_0 = +1$, $\\varphi = 0.5\\,(m+M)g$", 1.0, 0.5),
         ("$v_0 = 0$, $\\varphi = 0.5\\,(m+M)g$", 0.0, 0.5)]


def classify_exact(m, M, alpha, R, v0, phi) -> str:
    try:
        ex = JeanPrattExact(m=m, M=M, alpha=alpha, R=R, v0=v0, phi=phi, g=G)
    except ValueError:
        return "lift-off"
    if not ex.consistent:
        return "no consistent mode"
    if ex.shocks:
        return "shock, then stick" if ex.segments and ex.segments[-1].mode == "stick" else "no consistent mode"
    if ex.segments[0].mode == "stick":
        return "stick at once"
    return "slide, then stick" if ex.segments[-1].mode == "stick" else "slide for ever"


def classify_event(m, M, alpha, R, v0, phi) -> str:
    try:
        sc = lcp.scenes.jean_pratt(m=m, M=M, alpha=alpha, R=R, v0=v0, phi=phi, g=G)
    except ValueError:
        return "lift-off"
    sw = sc.switch_times()
    t_end = 1.5 * sw[-1] + 0.1 if sw.size else 1.0  # past the exact solution's last switch
    r = lcp.simulate(sc, t_end, method="event", n_eval=2)
    if r.status == -3:
        return "no consistent mode"
    seq = [md[0] for md in r.mode_sequence]
    if "open" in seq:
        return "lift-off"
    if r.impulses and r.impulses[0].t == 0.0:
        return "shock, then stick" if seq[-1] == "stick" else "no consistent mode"
    if seq == ["stick"]:
        return "stick at once"
    return "slide, then stick" if seq[-1] == "stick" else "slide for ever"


def exact_regime_row(Rs, m_M_a_v0_phi) -> list:
    """Regime indices along R at one alpha, from the exact solution (one piece of work)."""
    m, M, a, v0, phi = m_M_a_v0_phi
    return [REGIMES.index(classify_exact(m, M, a, R, v0, phi)) for R in Rs]


def checked_point(m_M_a_R_v0_phi) -> tuple:
    """(exact regime, event-driven regime) at one point (one piece of work)."""
    return classify_exact(*m_M_a_R_v0_phi), classify_event(*m_M_a_R_v0_phi)


def regimes(quick: bool, client=None) -> dict:
    """Regime maps over (R, alpha), checked by the event integrator on a coarse sub-grid.

    ``client``: a Dask client to run the pieces on (None: this process)."""
    ratios = [0.5, 1.0, 2.0]
    nR, na = (50, 50) if quick else (160, 160)
    nc = 5 if quick else 12
    Rs = np.linspace(0.02, 5.0, nR)
    alphas = np.linspace(0.03, 1.45, na)
    panels = [(ratio, 1.0, ci, v0, load * (ratio + 1.0) * G)
              for ratio in ratios for ci, (_title, v0, load) in enumerate(CASES)]
    map_rows = pieces(functools.partial(exact_regime_row, Rs),
                      [(m, M, a, v0, phi) for m, M, _ci, v0, phi in panels for a in alphas], client, "regime map")
    maps = {(m, ci): np.array(map_rows[k * na:(k + 1) * na]) for k, (m, _M, ci, _v0, _phi) in enumerate(panels)}
    # the event integrator on a coarse sub-grid
    points = [(m, M, ci, v0, phi, a, R) for m, M, ci, v0, phi in panels
              for a in np.linspace(alphas[2], alphas[-3], nc) for R in np.linspace(Rs[2], Rs[-3], nc)]
    classes = pieces(checked_point, [(m, M, a, R, v0, phi) for m, M, _ci, v0, phi, a, R in points], client,
                     "regime checks")
    rows, mismatches = [], []
    for (m, M, ci, v0, phi, a, R), (ce, cv) in zip(points, classes):
        rows.append(dict(m_over_M=m, case=ci, v0=v0, phi=phi, alpha=a, R=R,
                         kappa=R * M * math.tan(a) / (m + M * math.tan(a) ** 2), exact=ce, event=cv))
        if ce != cv:
            mismatches.append(rows[-1])
    return dict(ratios=ratios, Rs=Rs, alphas=alphas, maps=maps, rows=rows, mismatches=mismatches)


def plot_regimes(reg, path):
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch

    cmap = ListedColormap(REGIME_COLORS)
    ratios = reg["ratios"]
    fig, ax = plt.subplots(len(ratios), len(CASES), figsize=(15, 4.2 * len(ratios)), sharex=True, sharey=True)
    Rs, alphas = reg["Rs"], reg["alphas"]
    dR, da = Rs[1] - Rs[0], alphas[1] - alphas[0]
    R_lo, R_hi, a_lo, a_hi = Rs[0] - dR / 2, Rs[-1] + dR / 2, alphas[0] - da / 2, alphas[-1] + da / 2
    any_bad = False
    for i, ratio in enumerate(ratios):
        for ci, (title, v0, load) in enumerate(CASES):
            a = ax[i, ci]
            a.pcolormesh(Rs, alphas, reg["maps"][(ratio, ci)], cmap=cmap, vmin=-0.5, vmax=len(REGIMES) - 0.5,
                         shading="nearest")
            # the kappa = 1 curve on a fine grid over the whole shaded extent (cells are centred on the grid)
            af = np.linspace(a_lo, a_hi, 400)
            t = np.tan(af)
            Rk = t + ratio / t  # kappa = 1: R = tan(alpha) + m / (M tan(alpha))
            a.plot(np.where((Rk >= R_lo) & (Rk <= R_hi), Rk, np.nan), af, "k-", lw=2)
            a.set_xlim(R_lo, R_hi)
            a.set_ylim(a_lo, a_hi)
            ok = Rk < R_hi
            if ok.any():
                j = np.flatnonzero(ok)[len(np.flatnonzero(ok)) // 2]
                a.text(Rk[j] + 0.05, af[j], "$\\kappa = 1$", fontsize=9)
            if load:
                a.axvline(load, color="k", ls="--", lw=1)
                a.text(load + 0.03, 1.38, "$|\\varphi| = R(m+M)g$", fontsize=8)
            sub = [r for r in reg["rows"] if r["m_over_M"] == ratio and r["case"] == ci]
            agree = [r for r in sub if r["exact"] == r["event"]]
            a.plot([r["R"] for r in agree], [r["alpha"] for r in agree], "k.", ms=2.5)
            bad = [r for r in sub if r["exact"] != r["event"]]
            if bad:
                any_bad = True
                a.plot([r["R"] for r in bad], [r["alpha"] for r in bad], "rx", ms=6)
            a.set_title(f"m/M = {ratio:g}, {title}", fontsize=10)
            if i == len(ratios) - 1:
                a.set_xlabel("friction coefficient R (dimensionless)")
            if ci == 0:
                a.set_ylabel("slide angle $\\alpha$ (rad)")
    # the legend lists only the outcomes that occur somewhere in the maps
    seen = np.unique(np.concatenate([np.ravel(m) for m in reg["maps"].values()]))
    handles = [Patch(color=c, label=lab) for i, (c, lab) in enumerate(zip(REGIME_COLORS, REGIMES)) if i in seen]
    handles.append(plt.Line2D([], [], color="k", marker=".", ls="", label="event-driven agrees with exact"))
    if any_bad:
        handles.append(plt.Line2D([], [], color="r", marker="x", ls="", label="event-driven differs (see CSV)"))
    fig.legend(handles=handles, loc="lower center", ncol=4, fontsize=9, bbox_to_anchor=(0.5, -0.01))
    fig.suptitle("Regimes of the Jean-Pratt block (exact solution), M = 1, g = 9.81; "
                 "shock = tangential impact at t = 0")
    fig.tight_layout(rect=(0, 0.05, 1, 0.98))
    return save(fig, path)


# ------------------------------------------------------------------------------------ run
def run(out=None, quick: bool = False, workers: int | None = None, scheduler: str | None = None) -> dict:
    """Run the study; write CSV and PNG into ``out`` (a folder; None: figures/shock_limit).

    ``workers`` (a new local Dask cluster) or ``scheduler`` (a running one's address) runs the
    kappa sweep and the regime map side by side; the numbers are the same.

    Returns
    -------
    dict
        ``sweep`` (rows per kappa and v0), ``hs`` (Moreau-Jean steps), ``convergence`` (rows),
        ``iterations`` (rows), ``series`` (scaled curves and rows), ``regimes`` (maps, checked
        rows, mismatches), ``checks`` (the headline numbers), ``files`` and ``seconds``.
    """
    t0 = time.perf_counter()
    path = out_dir(out, NAME)
    files = []
    with cluster(workers, scheduler) as client:
        rows, hs = sweep(quick, client)
        reg = regimes(quick, client)
    keys = list(rows[0].keys())
    files.append(write_csv(path / "sweep.csv", keys, [[r[k] for k in keys] for r in rows]))
    files.append(plot_sweep(rows, hs, 1.0, path / "sweep_v0_pos.png"))
    files.append(plot_sweep(rows, hs, -1.0, path / "sweep_v0_neg.png"))

    conv = convergence(quick)
    keys = list(conv["rows"][0].keys())
    files.append(write_csv(path / "convergence.csv", keys, [[r[k] for k in keys] for r in conv["rows"]]))
    files.append(plot_convergence(conv, path / "convergence.png"))

    its = iterations(quick)
    keys = list(its[0].keys())
    files.append(write_csv(path / "iterations.csv", keys, [[r[k] for k in keys] for r in its]))
    files.append(plot_iterations(its, path / "iterations.png"))

    ser = printed_series(quick)
    keys = list(ser["rows"][0].keys())
    files.append(write_csv(path / "series.csv", keys, [[r[k] for k in keys] for r in ser["rows"]]))
    files.append(plot_series(ser, path / "series.png"))

    keys = list(reg["rows"][0].keys())
    files.append(write_csv(path / "regimes.csv", keys, [[r[k] for k in keys] for r in reg["rows"]]))
    files.append(plot_regimes(reg, path / "regimes.png"))

    below = [r for r in rows if r["kappa"] < 1]
    checks = dict(
        event_max_x_error=max(r["event_x_error"] for r in rows),
        event_all_success=all(r["event_success"] for r in rows),
        shock_impulse_rel_error=max(max(abs(r["shock_PN_event"] - M_ * TAN * r["v0"]), abs(r["shock_PT_event"] + A_ * r["v0"]))
                                    / A_ for r in rows if r["shock"]),
        event_tau0_rel_error_k_le_6=max(abs(r["tau0_event"] - r["tau0_exact"]) / r["tau0_exact"]
                                        for r in below if r["kappa"] <= 1 - 1e-6),
        stop_impulse_spread=max(max(abs(r["excess_PN_event"] - M_ * TAN * r["v0"]), abs(r["PT_event"] + A_ * r["v0"]))
                                for r in rows),
        plain_contraction_error=max(abs(r["plain_contraction"] - r["kappa"]) for r in its
                                    if r["kappa"] < 1 and np.isfinite(r["plain_contraction"])),
        regime_points_checked=len(reg["rows"]), regime_mismatches=len(reg["mismatches"]),
        printed_q_tau0_over_exact=ser["scaled"][1.0]["q_at_tau0_printed"] / 0.5,
    )
    return dict(sweep=rows, hs=hs, convergence=conv["rows"], iterations=its, series=ser, regimes=reg,
                checks=checks, files=files, seconds=time.perf_counter() - t0)


def main(argv=None):
    args = parse_args(NAME, __doc__.splitlines()[0], argv, extra=add_options)
    res = run(args.out, args.quick, workers=args.workers, scheduler=args.scheduler)
    for k, v in res["checks"].items():
        print(f"{k:32s} {v}")
    print(f"wrote {len(res['files'])} files to {args.out} in {res['seconds']:.1f} s")
    return res


if __name__ == "__main__":
    main()
