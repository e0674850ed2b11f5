"""Regenerate the paper's figure and comparison plots, and its errata table.

``python -m studies.paper_figures [--out DIR] [--quick]`` writes into DIR (default
``figures/paper_figures/``):

- ``fig_2_1_system.png``: the Jean-Pratt system (paper Fig. 2.1) drawn to scale from the scene;
- ``trajectories_forward.png`` / ``trajectories_reverse.png`` (+ CSV): x(t), xdot(t), N(t), f(t)
  from Moreau-Jean, from the exact solution and from the printed series (4.1) / (4.2);
- ``error_vs_h.png`` (+ ``convergence.csv``): Moreau-Jean's error against the exact solution,
  against the bound B h^2/8, with the observed orders for theta = 1/2 and 1;
- ``error_table.csv`` (also printed): the README's results table, Moreau-Jean on the default scene
  over [0, 0.3] s for every solver, at h = 1e-2 ... 1e-5 (``--quick``: 1e-2 and 1e-3 only);
- ``errata.csv`` (also printed): the paper's claims against what the package computes.

Examples
--------
>>> from studies import paper_figures
>>> out = paper_figures.run(out="/tmp/pf_doctest", quick=True)  # doctest: +SKIP
>>> out["errata"][0]["computed"]  # doctest: +SKIP
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

import lcp
from lem import series

from ._common import legend, out_dir, parse_args, plt, save, write_csv

NAME = "paper_figures"


# ----------------------------------------------------------------------------- figure 2.1
def draw_system(scene, x: float = 0.0, ax=None):
    """Draw the Jean-Pratt system to scale: line B, block m at P, slide C at alpha, body M on guide A."""
    p = scene.params
    t = scene.tan
    alpha = math.atan(t)
    if ax is None:
        _, ax = plt.subplots(figsize=(6.4, 4.6))
    w, hb = 0.5, 0.3  # block m: width and height (m)
    # block m with its top-right corner on the slide C
    ax.add_patch(plt.Rectangle((x - w / 2, 0), w, hb, fc="#9ecae1", ec="k", lw=1.2))
    ax.text(x, hb / 2, "m", ha="center", va="center", fontsize=13)
    # slide C passes through the block's top-right corner with slope tan(alpha)
    cx, cy = x + w / 2, hb
    dirc = np.array([math.cos(alpha), math.sin(alpha)])
    c0 = np.array([cx, cy]) - 0.25 * dirc
    c1 = np.array([cx, cy]) + 1.45 * dirc
    # body M: its lower face lies on the slide; it moves between the rails of the vertical guide A
    gx0, gx1 = cx, cx + 1.0
    y_lo0, y_lo1 = cy, cy + (gx1 - gx0) * t
    top = max(y_lo1, cy) + 0.9
    ax.add_patch(plt.Polygon([[gx0, y_lo0], [gx1, y_lo1], [gx1, top], [gx0, top]], fc="#fdd0a2", ec="k", lw=1.2))
    ax.text((gx0 + gx1) / 2, top - 0.3, "M", ha="center", va="center", fontsize=13)
    ax.annotate("Mg", xy=((gx0 + gx1) / 2, top - 0.95), xytext=((gx0 + gx1) / 2, top - 0.5),
                arrowprops=dict(arrowstyle="->"), ha="center", fontsize=9)
    for gx, y0 in ((gx0 - 0.04, y_lo0 + 0.1), (gx1 + 0.04, y_lo1 - 0.3)):
        ax.plot([gx, gx], [y0, top + 0.4], color="0.3", lw=2.5)
    ax.text(gx1 + 0.1, top + 0.3, "A (vertical guide)", fontsize=9, va="center")
    ax.plot(*np.c_[c0, c1], color="tab:red", lw=1.5, ls="--")
    ax.text(*(c1 + [0.05, -0.05]), "C (slide)", color="tab:red", fontsize=9)
    # angle alpha at the corner
    arc = np.linspace(0, alpha, 30)
    ax.plot(cx + 0.35 * np.cos(arc), cy + 0.35 * np.sin(arc), color="tab:red", lw=1)
    ax.plot([cx, cx + 0.45], [cy, cy], color="tab:red", lw=0.8)
    ax.text(cx + 0.42 * math.cos(alpha / 2), cy + 0.42 * math.sin(alpha / 2) - 0.03, r"$\alpha$", color="tab:red")
    # frictional line B and contact point P
    xs = np.array([x - 2.0, x + 2.4])
    ax.plot(xs, [0, 0], color="k", lw=2)
    for hx in np.arange(xs[0], xs[1], 0.15):
        ax.plot([hx, hx - 0.1], [0, -0.1], color="k", lw=0.6)
    ax.text(xs[0] + 0.05, -0.3, "B (line with friction R)", fontsize=9)
    ax.plot([x], [0], "ko", ms=5)
    ax.text(x + 0.05, -0.27, "P", fontsize=11)
    # contact forces on m at P, the initial velocity and the applied horizontal load
    ax.annotate("", xy=(x - 0.08, 0.62), xytext=(x - 0.08, 0.0), arrowprops=dict(arrowstyle="->", color="tab:green"))
    ax.text(x - 0.14, 0.62, "N", color="tab:green", ha="right", va="top")
    ax.annotate("", xy=(x - 0.75, 0.04), xytext=(x, 0.04), arrowprops=dict(arrowstyle="->", color="tab:purple"))
    ax.text(x - 0.8, 0.04, "f", color="tab:purple", va="center", ha="right")
    ax.annotate("", xy=(x + 0.1, hb + 0.45), xytext=(x - 0.4, hb + 0.45),
                arrowprops=dict(arrowstyle="->", color="tab:blue"))
    ax.text(x - 0.4, hb + 0.5, r"$v_0$", color="tab:blue", va="bottom")
    ax.annotate("", xy=(x - w / 2 - 0.45, 0.22), xytext=(x - w / 2, 0.22), arrowprops=dict(arrowstyle="->"))
    ax.text(x - w / 2 - 0.5, 0.22, r"$-Mg\tan\alpha+\varphi$", fontsize=8, va="center", ha="right")
    ax.set_aspect("equal")
    ax.set_xlim(x - 2.1, x + 2.6)
    ax.set_ylim(-0.5, top + 0.6)
    ax.set_xlabel("horizontal position (m)")
    ax.set_ylabel("height (m)")
    ax.set_title("Fig. 2.1, to scale: m = {m:g}, M = {M:g}, alpha = {a:.4g} rad, R = {R:g}, kappa = {k:.3g}".format(
        m=p["m"], M=p["M"], a=p["alpha"], R=p["R"], k=scene.kappa), fontsize=9)
    return ax


# ----------------------------------------------------------------------------- trajectories
def printed_series_forces(scene, t):
    """q, qdot, N, f implied by the printed series (4.1)/(4.2) on [0, tau0] (as printed)."""
    v0, B = scene.params["v0"], scene.B
    fn = series.series_4_1_printed if v0 > 0 else series.series_4_2_printed
    q = fn(t, v0, B)
    c = [v0, (-1 if v0 > 0 else 1) * B / 2, 0.8 * B**2 / v0, -0.6 * B**3 / v0**2, 32 / 75 * B**4 / v0**3]
    qd = sum((k + 1) * ck * t**k for k, ck in enumerate(c))
    qdd = sum((k + 1) * k * ck * t ** (k - 1) for k, ck in enumerate(c) if k >= 1)
    p = scene.params
    N = (p["m"] + p["M"]) * p["g"] - p["M"] * scene.tan * qdd
    f = scene.A * qdd - p["phi"]
    return q, qd, N, f


def trajectories(scene, hs, label: str, outdir: Path, theta: float = 0.5):
    """Moreau-Jean at several h, exact and printed series: figure + CSV. Returns per-h errors."""
    t_end = scene.t_end
    tt = np.linspace(0.0, t_end, 1201)
    ex = scene.exact(tt)
    ts = np.linspace(0.0, scene.tau0, 400)
    sq, sqd, sN, sf = printed_series_forces(scene, ts)
    fig, axs = plt.subplots(2, 2, figsize=(11, 7.2), sharex=True)
    keys = [("x", "x (m)"), ("xdot", r"$\dot x$ (m/s)"), ("N", "N (N)"), ("f", "f (N)")]
    for ax, (k, lab) in zip(axs.flat, keys):
        ax.plot(tt, ex[k], "k-", lw=2, label="exact (Coulomb)")
        ax.set_ylabel(lab)
        ax.grid(alpha=0.3)
    for ax, val in zip(axs.flat, (sq, sqd, sN, sf)):
        ax.plot(ts, val, "--", color="tab:red", lw=1.5, label="printed series (4.%d), as printed" %
                (1 if scene.params["v0"] > 0 else 2))
    rows, errs = [], {}
    markers = ["o", "s", "^", "v"]
    for i, h in enumerate(hs):
        res = lcp.simulate(scene, t_end, h=h, theta=theta)
        if not res.success:
            raise RuntimeError(res.message)
        exg = scene.exact(res.t)
        errs[h] = dict(x=float(np.max(np.abs(res.q[:, 0] - exg["x"]))), bound=scene.B * h * h / 8,
                       y=float(np.max(np.abs(res.q[:, 1]))), residual=res.stats.max_residual)
        tm = 0.5 * (res.t[:-1] + res.t[1:])  # mean forces belong to the middle of their step
        every = max(1, len(res.t) // 60)
        kw = dict(ls="none", marker=markers[i % 4], ms=4, mfc="none", label=f"Moreau-Jean h = {h:g}")
        axs[0, 0].plot(res.t[::every], res.q[::every, 0], **kw)
        axs[0, 1].plot(res.t[::every], res.v[::every, 0], **kw)
        axs[1, 0].plot(tm[::every], res.N[::every, 0], **kw)
        axs[1, 1].plot(tm[::every], res.f[::every, 0], **kw)
        # every run the figure plots, at full resolution, with the mean forces of each step
        Nm = np.append(res.N[:, 0], np.nan)
        fm = np.append(res.f[:, 0], np.nan)
        rows += [(h, float(t), float(q), float(v), float(exg["x"][j]), float(exg["xdot"][j]), float(Nm[j]),
                  float(fm[j])) for j, (t, q, v) in enumerate(zip(res.t, res.q[:, 0], res.v[:, 0]))]
    for ax in axs[1]:
        ax.set_xlabel("t (s)")
    for ax in axs.flat:
        ax.axvline(scene.tau0, color="0.5", ls=":", lw=1)
    axs[0, 0].text(scene.tau0, axs[0, 0].get_ylim()[0], r" $\tau_0$", color="0.4", va="bottom")
    legend(axs[0, 1])  # the same series in every panel: one legend, beside the right column
    p = scene.params
    fig.suptitle(f"Jean-Pratt, v0 = {p['v0']:g}: m = {p['m']:g}, M = {p['M']:g}, alpha = {p['alpha']:.4g}, "
                 f"R = {p['R']:g} (kappa = {scene.kappa:.3g}); N0 = {scene.N0:.5g} N, B = {scene.B:.5g} m/s², "
                 f"tau0 = {scene.tau0:.6g} s", fontsize=10)
    save(fig, outdir / f"trajectories_{label}.png")
    write_csv(outdir / f"trajectories_{label}.csv", ["h", "t", "x_moreau_jean", "xdot_moreau_jean", "x_exact",
                                                     "xdot_exact", "N_mean_step_from_t", "f_mean_step_from_t"], rows)
    ex_rows = [(float(a), float(b), float(c), float(d), float(e_)) for a, b, c, d, e_ in
               zip(tt, ex["x"], ex["xdot"], ex["N"], ex["f"])]
    write_csv(outdir / f"exact_{label}.csv", ["t", "x", "xdot", "N", "f"], ex_rows)
    ser_rows = [(float(a), float(b), float(c), float(d), float(e_)) for a, b, c, d, e_ in zip(ts, sq, sqd, sN, sf)]
    write_csv(outdir / f"printed_series_{label}.csv", ["t", "q", "qdot", "N", "f"], ser_rows)
    return errs


def convergence(scene, hs, outdir: Path):
    """Max |x - exact| against h for theta = 1/2 and 1, with B h^2/8 and the fitted orders."""
    rows, orders = [], {}
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    for theta, mk in ((0.5, "o-"), (1.0, "s-")):
        errs = []
        for h in hs:
            res = lcp.simulate(scene, 1.2 * scene.tau0, h=h, theta=theta)
            e = float(np.max(np.abs(res.q[:, 0] - scene.exact(res.t)["x"])))
            errs.append(e)
            rows.append((theta, h, e, scene.B * h * h / 8, float(np.max(np.abs(res.q[:, 1]))),
                         res.stats.max_residual))
        orders[theta] = float(np.polyfit(np.log(hs), np.log(np.maximum(errs, 1e-300)), 1)[0])
        ax.loglog(hs, errs, mk, label=f"theta = {theta:g} (observed order {orders[theta]:.2f})")
    ax.loglog(hs, scene.B * np.asarray(hs) ** 2 / 8, "k--", label=r"bound $B h^2/8$ (theta = 1/2)")
    ax.set_xlabel("h (s)")
    ax.set_ylabel(r"max$_k$ |x(t_k) - exact|  (m)")
    p = scene.params
    ax.set_title(f"Moreau-Jean error against the exact solution\n(m = {p['m']:g}, M = {p['M']:g}, "
                 f"alpha = {p['alpha']:g}, R = {p['R']:g}, v0 = {p['v0']:g}; grid over [0, 1.2 tau0])", fontsize=9)
    ax.grid(alpha=0.3, which="both")
    legend(ax)
    save(fig, outdir / "error_vs_h.png")
    write_csv(outdir / "convergence.csv", ["theta", "h", "max_x_error", "bound_B_h2_over_8", "max_abs_y",
                                           "max_residual"], rows)
    return orders, rows


#: the solvers of the README's results table (``auto`` is what ``lcp.simulate`` takes by default)
TABLE_SOLVERS = ("auto", "enum", "lemke", "osqp")


def error_table(scene, hs, t_end: float = 0.3, solvers=TABLE_SOLVERS, theta: float = 0.5):
    """Moreau-Jean on ``scene`` over [0, t_end] for every solver at every h: the README's results table.

    Returns
    -------
    list of dict
        One row per (h, solver): ``h``, ``solver``, ``x`` (max |x - exact|), ``bound`` (B h^2/8),
        ``y`` (max |y|, the gap of a contact that stays closed) and ``residual`` (worst Coulomb
        residual, checked apart from the solver).
    """
    rows = []
    for h in hs:
        for solver in solvers:
            res = lcp.simulate(scene, t_end, h=h, theta=theta, solver=solver)
            if not res.success:
                raise RuntimeError(f"h = {h:g}, solver {solver}: {res.message}")
            rows.append(dict(h=float(h), solver=solver,
                             x=float(np.max(np.abs(res.q[:, 0] - scene.exact(res.t)["x"]))),
                             bound=scene.B * h * h / 8, y=float(np.max(np.abs(res.q[:, 1]))),
                             residual=float(res.stats.max_residual)))
    return rows


def table_lines(rows) -> list[str]:
    """The error table as printed: per h, x and B h^2/8 (3 digits), and the largest |y| and residual
    over the solvers (2 digits); x's spread over the solvers is printed beside it."""
    lines = []
    for h in dict.fromkeys(r["h"] for r in rows):
        at = [r for r in rows if r["h"] == h]
        xs = [r["x"] for r in at]
        lines.append(f"  h = {h:<6g} max|x - exact| = {max(xs):.3g} (solvers differ by {max(xs) - min(xs):.1e})  "
                     f"B h^2/8 = {at[0]['bound']:.3g}  max|y| = {max(r['y'] for r in at):.2g}  "
                     f"worst residual = {max(r['residual'] for r in at):.2g}")
    return lines


# ----------------------------------------------------------------------------- errata
def tanh_ode_q_at_tau0(v0: float) -> float:
    """q(tau0) B / v0^2 for the paper's own model (3.9), y'' = tanh y, y(0) = 0, y'(0) = v0 (x = B t)."""
    sol = solve_ivp(lambda _, y: [y[1], math.tanh(y[0])], (0.0, v0), [0.0, v0], rtol=1e-13, atol=1e-14)
    return float(sol.y[0, -1]) / v0**2


def errata(scene_f, scene_r):
    """Rows: claim, as printed, computed, verdict."""
    pf, pr = scene_f.params, scene_r.params
    B, v0 = scene_f.B, pf["v0"]
    q_series = float(series.series_4_1_printed(scene_f.tau0, v0, B)) * B / v0**2
    coef_p = series.series_3_20_printed_coefficients(1.0)
    coef_t = [float(c) for c in series.tanh_ode_true_coefficients(1, 5)]
    after = scene_f.exact(np.array([scene_f.tau0 + 0.1]))
    geo = dict(m=pf["m"], M=pf["M"], alpha=pf["alpha"], R=pf["R"])
    rows = [
        dict(claim="q(tau0) in units of v0^2/B (section 4)", printed="0.42",
             computed=f"{scene_f.x_stop * B / v0**2:.12g} (exact Coulomb); {q_series:.6g} (printed 5-term series "
                      f"(4.1) at tau0, = 169/150); {tanh_ode_q_at_tau0(v0):.6g} (solution of (3.9), v0 = {v0:g})",
             verdict="wrong: any law with |f| <= R N and kappa < 1 gives >= 0.5"),
        dict(claim="for t > tau0: q, f, N (section 4)", printed="q = 0, f = 0, N = 0",
             computed=f"q = {float(after['x'][0]):.9g} m (= v0|v0|/(2B)), f = {float(after['f'][0]) + 0.0:.3g} N, "
                      f"N = {float(after['N'][0]):.6g} N (= (m+M) g)",
             verdict="wrong: the block sticks where it stopped and N carries the weight"),
        dict(claim="tau0 for v0 < 0 (section 4)", printed=f"v0/B = {series.tau0_printed(pr['v0'], scene_r.B):.6g} s",
             computed=f"|v0|/B = {scene_r.tau0:.6g} s", verdict="sign erratum"),
        dict(claim="N0 for v0 > 0 and v0 < 0 (2.7)",
             printed=f"{series.N0_printed(**geo, g=pf['g'], v0_sign=1):.10g} N, "
                     f"{series.N0_printed(**geo, g=pf['g'], v0_sign=-1):.10g} N",
             computed=f"{scene_f.N0:.10g} N, {scene_r.N0:.10g} N", verdict="correct"),
        dict(claim="B = R N0 / A (4.1)", printed=f"{series.B_printed(**geo, g=pf['g']):.10g} m/s^2",
             computed=f"{scene_f.B:.10g} m/s^2", verdict="correct"),
        dict(claim="series (3.20) coefficients of x^1..x^5 at z0 = 1",
             printed=", ".join(f"{c:.6g}" for c in coef_p),
             computed=", ".join(f"{c:.6g}" for c in coef_t[1:6]) + " (true Taylor series of (3.9))",
             verdict="wrong from x^2 on: (3.20) has y''(0) = -1 but tanh(0) = 0"),
        dict(claim="condition (2.2)", printed="RM tan(alpha)/A < 1 holds for v0 > 0; may fail for v0 < 0",
             computed=f"kappa = {scene_f.kappa:.6g}: a sliding solution exists for v0 > 0 iff kappa < 1, "
                      "and always for v0 < 0", verdict="stated backwards"),
        dict(claim="shock limit (section 4)", printed="R > tan(alpha)",
             computed=f"kappa -> 1, i.e. R -> tan(alpha) + m/(M tan(alpha)) = "
                      f"{scene_f.tan + pf['m'] / (pf['M'] * scene_f.tan):.6g}",
             verdict="wrong threshold"),
        dict(claim="sign of L~ (section 2)", printed="+M tan(alpha)/A", computed="-M tan(alpha)/A",
             verdict="sign erratum"),
        dict(claim="friction model (2.8)", printed="q'' = B tanh(B q)",
             computed="Coulomb sliding is q'' = -B sign(q') (constant deceleration)",
             verdict="wrong: position-dependent, wrong sign, never stops"),
    ]
    return rows


# ----------------------------------------------------------------------------- driver
def run(out=None, quick: bool = False) -> dict:
    """Write all figures and CSV files; return the numbers behind them.

    Returns
    -------
    dict
        ``errors_forward`` / ``errors_reverse``: {h: {x, bound, y, residual}};
        ``orders``: {theta: observed order}; ``table``: the README's error table (rows of
        :func:`error_table`); ``errata``: list of rows; ``files``: written paths; ``quick``.
    """
    outdir = out_dir(out, NAME)
    scene_f = lcp.scenes.jean_pratt()
    scene_r = lcp.scenes.jean_pratt(v0=-1.0)
    hs = [1e-2, 1e-3] if quick else [1e-2, 1e-3, 1e-4]

    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    draw_system(scene_f, 0.0, ax)
    save(fig, outdir / "fig_2_1_system.png")

    err_f = trajectories(scene_f, hs[:2], "forward", outdir)
    err_r = trajectories(scene_r, hs[:2], "reverse", outdir)
    # a second parameter set: R = 0.5 would hide a spurious lift-off (docs/models.md)
    scene_o = lcp.scenes.jean_pratt(m=2.0, M=0.7, alpha=0.9, R=0.35, v0=1.7)
    err_o = trajectories(scene_o, hs[:2], "other_parameters", outdir)
    conv_hs = np.array([1e-2, 1e-3, 1e-4] if quick else [1e-2, 1e-3, 1e-4, 1e-5]) * (1 + 1 / 7)
    orders, _ = convergence(scene_o, conv_hs, outdir)
    table = error_table(scene_f, hs[:2] if quick else [1e-2, 1e-3, 1e-4, 1e-5])
    write_csv(outdir / "error_table.csv", list(table[0]), [tuple(r.values()) for r in table])

    rows = errata(scene_f, scene_r)
    write_csv(outdir / "errata.csv", ["claim", "printed", "computed", "verdict"],
              [(r["claim"], r["printed"], r["computed"], r["verdict"]) for r in rows])
    files = sorted(str(p.name) for p in outdir.iterdir())
    return dict(errors_forward=err_f, errors_reverse=err_r, errors_other=err_o, orders=orders, table=table,
                errata=rows, files=files, out=str(outdir), quick=quick)


def main(argv=None):
    args = parse_args(NAME, "Regenerate the paper's Fig. 2.1, the trajectory comparisons and the errata table.",
                      argv)
    res = run(args.out, args.quick)
    print(f"Figures and CSV data written to {res['out']}/")
    for label in ("forward", "reverse", "other"):
        for h, e in res[f"errors_{label}"].items():
            print(f"  {label:8s} h = {h:<7g} max|x - exact| = {e['x']:.3e}  (B h^2/8 = {e['bound']:.3e})"
                  f"  max|y| = {e['y']:.1e}  residual = {e['residual']:.1e}")
    decades = "three decades, --quick" if res["quick"] else "four decades"
    print("  observed order (other parameters, " + decades + "): "
          + ", ".join(f"theta = {k:g}: {v:.2f}" for k, v in res["orders"].items()))
    print(f"\nThe README's results table (default scene, [0, 0.3] s, solvers {', '.join(TABLE_SOLVERS)}"
          + ("; --quick: h = 1e-2 and 1e-3 only" if res["quick"] else "") + "):")
    print("\n".join(table_lines(res["table"])))
    print("\nErrata (the paper's claims against what the package computes):")
    for r in res["errata"]:
        print(f"- {r['claim']}\n    printed : {r['printed']}\n    computed: {r['computed']}\n    verdict : {r['verdict']}")


if __name__ == "__main__":
    main()
