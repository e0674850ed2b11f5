"""How far LEM (Toma's Linear Equivalence Method) can be trusted: convergence, cost, series, Troesch.

``python -m studies.lem_convergence [--out DIR] [--quick] [--workers N | --scheduler ADDRESS]`` writes,
into DIR (default figures/lem_convergence/) the files below; ``--workers`` (a new local Dask cluster)
or ``--scheduler`` (a running one) computes the degrees of the error sweep and the Troesch cases side
by side, with the same numbers (the cost sweep, a timing, stays in this process):

- ``error_vs_degree.csv``, ``error_vs_degree.png``: y'' = tanh y, y(0) = 0, y'(0) = 1 (the paper's
  (3.9) with z0 = 1). Error of y against solve_ivp (rtol 1e-13) against the truncation degree N at
  x = 0.5, 1, 1.5, 2, for the plain engine (one expansion about the origin, as in the paper) with
  its own error estimate and divergence flag, and for the engine restarted every 0.5;
- ``cost_vs_degree.csv``, ``cost_vs_degree.png``: moment dimension and build/solve time against N,
  for the moments the output needs (odd degrees only, the paper's (3.17)) and for all moments;
- ``coefficients_3_20.csv``, ``series_3_20_curves.csv``, ``series_3_20.png``: the printed (3.20)
  coefficient by coefficient beside the engine's exact series and an independent exact
  recursion, and the three curves (printed series, true series, numerical solution) against x;
- ``smooth_friction_coefficients.csv``, ``smooth_friction_motions.csv``, ``smooth_friction.png``:
  the smooth slide qdd = -B tanh(qd/eps): the engine's Taylor coefficients beside the printed
  (4.1) and the exact Coulomb slide, and the motions for several eps;
- ``troesch.csv``, ``troesch_solutions.csv``, ``troesch.png``: Troesch's problem
  y'' = lambda sinh(lambda y), y(0) = 0, y(1) = 1 by shooting over the restarted engine, against
  20-digit reference slopes.

:func:`run` returns the numbers behind every figure (tests check them).

Example
-------
>>> from studies import lem_convergence
>>> res = lem_convergence.run(out=None, quick=True)          # doctest: +SKIP
>>> res["checks"]["x1_error_N61"] <= 1e-10                   # doctest: +SKIP
True
"""
from __future__ import annotations

import functools
import math
import time
import warnings
from fractions import Fraction

import matplotlib.pyplot as plt
import numpy as np
from scipy.integrate import solve_ivp

from lem import series
from lem.moments import clear_structure_cache, moment_system
from lem.paper_equations import smooth_friction_field, tanh_ode_field
from lem.propagation import solve
from lem.result import LEMWarning
from lem.taylor import taylor_coefficients
from lem.troesch import TROESCH_REFERENCE, solve_troesch, troesch_field
from studies._cluster import add_options, cluster, pieces
from studies._common import out_dir, parse_args, save, write_csv

NAME = "lem_convergence"
XS = (0.5, 1.0, 1.5, 2.0)
Z0 = 1.0
RESTART_H = 0.5
#: the paper's reference slide: v0 = 1, B = 6.54 (R = 0.5)
V0_SLIDE, B_SLIDE = 1.0, 6.54
REF = dict(method="DOP853", rtol=1e-13, atol=1e-15)


def tanh_f(t, y):
    return [y[1], np.tanh(y[0])]


def reference(f, y0, xs):
    """solve_ivp (rtol 1e-13) stopped exactly at each x (its dense output is only good to 1e-12)."""
    out, x, y = [], 0.0, np.asarray(y0, dtype=float)
    for xe in xs:
        if xe != x:
            r = solve_ivp(f, (x, xe), y, **REF)
            x, y = xe, r.y[:, -1]
        out.append(y)
    return np.array(out).T


def reference_mp(y0, xs, dps=25):
    """mpmath's Taylor-series ODE solver at 25 digits: a reference below double rounding, so that
    the plots show LEM's own error floor rather than solve_ivp's (~1e-14). Without mpmath (it is
    not a dependency of the package) this falls back to the solve_ivp reference."""
    try:
        import mpmath
    except ImportError:  # pragma: no cover - depends on the environment
        return reference(tanh_f, y0, xs)
    mpmath.mp.dps = dps
    f = mpmath.odefun(lambda x, y: [y[1], mpmath.tanh(y[0])], 0, [mpmath.mpf(v) for v in y0])
    return np.array([[float(v) for v in f(x)] for x in xs]).T


def _quiet(fn, *args, **kw):
    # divergence is a result here, recorded in the tables; the warning would only repeat it
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LEMWarning)
        return fn(*args, **kw)


# ----------------------------------------------------------------------------- error vs degree
def error_vs_degree(quick: bool, client=None) -> list:
    """Rows per degree N and point x. ``client``: a Dask client to run the degrees on (None: here)."""
    Ns = [1, 5, 11, 21, 31, 41, 51, 61] if quick else list(range(1, 82, 4))
    xs = np.array(XS)
    Y = reference(tanh_f, [0.0, Z0], xs)
    Ymp = reference_mp([0.0, Z0], xs)
    return [r for part in pieces(functools.partial(degree_rows, xs, Y, Ymp), Ns, client, "degrees") for r in part]


def degree_rows(xs, Y, Ymp, N) -> list:
    """The rows of one degree N of :func:`error_vs_degree` (one piece of work)."""
    rows = []
    plain = _quiet(solve, tanh_f, (0.0, xs[-1]), [0.0, Z0], degree=N, t_eval=xs)
    rest = _quiet(solve, tanh_f, (0.0, xs[-1]), [0.0, Z0], degree=N, t_eval=xs, restart=RESTART_H)
    for i, x in enumerate(xs):
        j = int(np.flatnonzero(rest.t == x)[0]) if np.any(rest.t == x) else None
        rows.append(dict(
            x=float(x), N=N,
            plain_error_y=float(abs(plain.y[0, i] - Y[0, i])),
            plain_error_z=float(abs(plain.y[1, i] - Y[1, i])),
            plain_error_y_mp=float(abs(plain.y[0, i] - Ymp[0, i])),
            plain_estimate_y=float(plain.error_estimate[0, i]),
            plain_diverging=bool(plain.diverging_points[i]),
            plain_status=plain.status,
            moment_dimension=plain.moment_dimension,
            restart_error_y=float(abs(rest.y[0, j] - Y[0, i])) if j is not None else math.nan,
            restart_error_y_mp=float(abs(rest.y[0, j] - Ymp[0, i])) if j is not None else math.nan,
            solve_ivp_error_y=float(abs(Y[0, i] - Ymp[0, i])),
            restart_estimate_y=float(rest.error_estimate[0, j]) if j is not None else math.nan,
            restart_status=rest.status))
    return rows


def auto_restart_check() -> dict:
    xs = np.array(XS)
    Y = reference(tanh_f, [0.0, Z0], xs)
    r = solve(tanh_f, (0.0, xs[-1]), [0.0, Z0], degree=20, restart="auto", t_eval=xs)
    return dict(status=r.status, n_restarts=r.n_restarts, max_error=float(np.max(np.abs(r.y - Y))),
                max_estimate=float(np.max(r.error_estimate)))


#: the error plot's range: values below FLOOR are drawn on it and marked, values above CEIL are
#: off the plot and marked at its top edge
FLOOR, CEIL = 1e-17, 1e25


def _clip_markers(ax, N, v, color, name, hollow=False, slot=0):
    """Mark the values of series ``name`` outside [FLOOR, CEIL]: a true 0, below the floor, above
    the ceiling (off scale, annotated with the largest value). ``hollow`` draws the markers open
    (an estimate rather than an error); ``slot`` stacks the annotations of several series."""
    v = np.asarray(v, dtype=float)
    zero = v == 0
    low = (v < FLOOR) & ~zero
    high = v > CEIL
    face = "white" if hollow else color
    if zero.any():
        ax.plot(N[zero], np.full(zero.sum(), FLOOR), "D" if hollow else "o", mfc="white", mec=color,
                ms=6, label=f"{name}: exactly 0 (drawn at {FLOOR:.0e})")
    if low.any():
        ax.plot(N[low], np.full(low.sum(), FLOOR), "v", mfc=face, mec=color, ms=7,
                label=f"{name}: below {FLOOR:.0e}")
    if high.any():
        # open markers larger and below, filled ones on top: both stay visible at the same N
        ax.plot(N[high], np.full(high.sum(), CEIL), "^", mfc=face, mec=color, clip_on=False,
                ms=10 if hollow else 6, zorder=3 if hollow else 4,
                label=f"{name}: above {CEIL:.0e} (off scale)")
        # the text goes where this plot has no data: right of the middle, between the curves
        ax.text(0.98, 0.52 - 0.07 * slot,
                f"{name}, N >= {int(N[high].min())}: above {CEIL:.0e}, up to {v[high].max():.0e}",
                transform=ax.transAxes, ha="right", va="top", fontsize=7, color=color,
                bbox=dict(facecolor="white", edgecolor="none", alpha=0.8, pad=1))


def plot_error_vs_degree(rows, path):
    fig, axes = plt.subplots(2, 2, figsize=(10, 7.8), sharex=True, sharey=True)
    for ax, x in zip(axes.ravel(), XS):
        rs = [r for r in rows if r["x"] == x]
        N = np.array([r["N"] for r in rs])
        pe = np.array([r["plain_error_y_mp"] for r in rs])
        ps = np.array([r["plain_estimate_y"] for r in rs])
        re = np.array([r["restart_error_y_mp"] for r in rs])
        dv = np.array([r["plain_diverging"] for r in rs])
        for slot, (v, style, color, label, name) in enumerate((
                (pe, "o-", "C0", "plain LEM: error", "plain LEM"),
                (ps, ":", "C0", "plain LEM: its error estimate", "plain LEM estimate"),
                (re, "s--", "C2", f"restarted every {RESTART_H}: error", f"restarted every {RESTART_H}"))):
            inside = (v >= FLOOR) & (v <= CEIL)
            # the line joins only points on the plot: clipped ones are marked, not connected
            ax.semilogy(np.where(inside, N, np.nan), np.where(inside, v, np.nan), style,
                        color=color, ms=4 if style.startswith("s") else 6, label=label)
            _clip_markers(ax, N, v, color, name, hollow="estimate" in name, slot=slot)
        if dv.any():
            inside = dv & (pe <= CEIL)
            ax.semilogy(N[inside], pe[inside], "x", color="C3", ms=10, mew=2,
                        label="flagged: diverging")
        ax.axhline(rs[0]["solve_ivp_error_y"], color="C1", lw=1, ls="-.",
                   label="error of solve_ivp (rtol 1e-13) itself")
        ax.axhline(1e-10, color="0.5", lw=0.8)
        ax.set_title(f"x = {x}")
        ax.grid(True, which="major", alpha=0.3)
        ax.set_ylim(FLOOR / 10, CEIL * 10)
    for ax in axes[1]:
        ax.set_xlabel("truncation degree N (dimensionless)")
    for ax in axes[:, 0]:
        ax.set_ylabel("|y_N(x) - y(x)|  (y dimensionless)")
    seen = {}
    for ax in axes.ravel():
        for h, lab in zip(*ax.get_legend_handles_labels()):
            seen.setdefault(lab, h)
    fig.legend(list(seen.values()), list(seen), loc="lower center", ncol=3, fontsize=8)
    fig.suptitle("y'' = tanh y, y(0) = 0, y'(0) = 1: error of the truncated LEM system against degree\n"
                 "(reference: 25-digit Taylor integration (mpmath); grey line: 1e-10; plain = one "
                 "expansion about the origin, as in the paper)", fontsize=10)
    fig.tight_layout(rect=(0, 0.09, 1, 1))
    return save(fig, path)


# ----------------------------------------------------------------------------- cost vs degree
def cost_vs_degree(quick: bool) -> list:
    pruned = [11, 31, 61] if quick else [11, 21, 41, 61, 81, 103]
    full = [10, 30] if quick else [10, 20, 40, 60, 72]
    y1 = reference(tanh_f, [0.0, Z0], [1.0])[:, -1]
    rows = []
    for kind, Ns in (("needed moments (odd degrees)", pruned), ("all moments", full)):
        for N in Ns:
            prune = kind.startswith("needed")
            clear_structure_cache()  # time a build from scratch, not a refill of a cached structure
            t0 = time.perf_counter()
            S = moment_system(tanh_f, N, n=2, prune=prune)
            build = time.perf_counter() - t0
            t0 = time.perf_counter()
            r = _quiet(solve, tanh_f, (0.0, 1.0), [0.0, Z0], degree=N, prune=prune, check=False)
            solve_time = time.perf_counter() - t0
            t0 = time.perf_counter()
            rc = _quiet(solve, tanh_f, (0.0, 1.0), [0.0, Z0], degree=N, prune=prune)
            checked = time.perf_counter() - t0
            rows.append(dict(kind=kind, N=N, dimension=S.dimension, nnz=S.nnz, build_s=build,
                             solve_s=solve_time, checked_solve_s=checked,
                             error_x1=float(abs(r.y[0, -1] - y1[0])), status_checked=rc.status))
    return rows


def plot_cost(rows, path):
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 5.4))
    for k, (kind, c) in enumerate((("needed moments (odd degrees)", "C0"), ("all moments", "C1"))):
        rs = [r for r in rows if r["kind"] == kind]
        N = [r["N"] for r in rs]
        a1.plot(N, [r["dimension"] for r in rs], "o-", color=c, label=kind)
        a2.loglog([r["dimension"] for r in rs], [r["build_s"] for r in rs], "o:", color=c,
                  label=f"{kind}: build")
        a2.loglog([r["dimension"] for r in rs], [r["solve_s"] for r in rs], "s-", color=c,
                  label=f"{kind}: build + solve to x = 1")
        a2.loglog([r["dimension"] for r in rs], [r["checked_solve_s"] for r in rs], "^--", color=c,
                  label=f"{kind}: with the estimate (4 degrees)")
    a1.set_xlabel("truncation degree N (dimensionless)")
    a1.set_ylabel("moment dimension (number of moments)")
    a1.set_title("Size of the truncated system")
    a1.legend(fontsize=8, loc="upper left")
    a1.grid(True, alpha=0.3)
    a2.set_xlabel("moment dimension (number of moments)")
    a2.set_ylabel("wall time [s]")
    a2.set_title("Cost (sparse build + expm_multiply)")
    # below the axes: inside, any corner covers points of one of the six series
    a2.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2)
    a2.grid(True, which="both", alpha=0.3)
    fig.suptitle("y'' = tanh y: cost of the LEM engine against the truncation degree")
    fig.tight_layout()
    return save(fig, path)


# ------------------------------------------------------------------------------ series (3.20)
def coefficient_table(z0s=(Fraction(1, 2), Fraction(1), Fraction(2)), order=9) -> list:
    rows = []
    for z0 in z0s:
        eng = taylor_coefficients(tanh_ode_field(order), [0, z0], order)[0]
        ref = series.tanh_ode_true_coefficients(z0, order)
        printed = series.series_3_20_printed_coefficients(float(z0))
        for k in range(1, order + 1):
            rows.append(dict(z0=float(z0), k=k, engine_exact=str(eng[k]), engine=float(eng[k]),
                             exact_recursion=str(ref[k]), equal=bool(eng[k] == ref[k]),
                             printed_3_20=float(printed[k - 1]) if k <= 5 else math.nan))
    return rows


def series_curves(quick: bool) -> dict:
    x = np.linspace(0.0, 2.0, 41 if quick else 201)
    curves = {}
    for z0 in (1.0, 2.0):
        ref = reference(tanh_f, [0.0, z0], x[1:])
        lem = solve(tanh_f, (0.0, 2.0), [0.0, z0], degree=16, restart="auto", t_eval=x)
        curves[z0] = dict(x=x, printed=series.series_3_20_printed(x, z0),
                          true7=series.tanh_ode_true_series(x, z0, 7),
                          true21=np.polyval(taylor_coefficients(tanh_f, [0.0, z0], 21)[0][::-1], x),
                          lem=lem.y[0], lem_status=lem.status,
                          reference=np.concatenate([[0.0], ref[0]]))
    return curves


def plot_series(rows, curves, path):
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.4))
    for ax, (z0, c) in zip(axes[:2], curves.items()):
        ax.plot(c["x"], c["reference"], "k-", lw=3, alpha=0.35, label="solve_ivp (rtol 1e-13)")
        ax.plot(c["x"], c["lem"], "C2--", label="LEM engine, restarted (N = 16)")
        ax.plot(c["x"], c["true7"], "C0-", label="true series to x^7 (engine, exact)")
        ax.plot(c["x"], c["true21"], "C0:", label="true series to x^21")
        ax.plot(c["x"], c["printed"], "C3-", label="printed (3.20), 5 terms")
        ax.set_xlabel("x (dimensionless)")
        ax.set_ylabel("y(x) (dimensionless)")
        ax.set_title(f"y'' = tanh y, y(0) = 0, y'(0) = z0 = {z0:g}")
        ax.grid(True, alpha=0.3)
        lo, hi = c["reference"].min(), c["reference"].max()
        top = hi + 0.5 * (hi - lo)
        ax.set_ylim(lo - 0.5, top)
        cut = [name for name, key in (("printed (3.20)", "printed"), ("true series to x^7", "true7"),
                                      ("true series to x^21", "true21"))
               if np.nanmax(c[key]) > top]
        if cut:
            ax.text(0.98, 0.03, "clipped at the top (diverging):\n" + "\n".join(cut),
                    transform=ax.transAxes, ha="right", va="bottom", fontsize=7,
                    bbox=dict(facecolor="white", edgecolor="0.7", alpha=0.9))
    axes[0].legend(fontsize=8)
    ax = axes[2]
    for i, z0 in enumerate(sorted({r["z0"] for r in rows})):
        rs = [r for r in rows if r["z0"] == z0 and r["k"] <= 5]
        k = np.array([r["k"] for r in rs])
        ax.plot(k - 0.1 + 0.1 * i, [r["printed_3_20"] for r in rs], "x", color=f"C{i}", ms=8, mew=2,
                label=f"printed (3.20), z0 = {z0:g}")
        ax.plot(k - 0.1 + 0.1 * i, [r["engine"] for r in rs], "o", color=f"C{i}", mfc="none",
                label=f"true (engine), z0 = {z0:g}")
    ax.axhline(0.0, color="0.5", lw=0.8)
    ax.set_yscale("symlog", linthresh=1e-2)
    top = max(abs(r["printed_3_20"]) for r in rows if r["k"] <= 5)
    ax.set_ylim(-3 * top, 3 * top)
    ax.set_xlabel("power k of x (dimensionless)")
    ax.set_ylabel("c_k (dimensionless, symlog)")
    ax.set_title("Coefficients: printed (3.20) vs true")
    ax.set_xticks(range(1, 6))
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, ncol=3, loc="upper center", bbox_to_anchor=(0.5, -0.2))
    fig.suptitle("The printed series (3.20) does not solve (3.9): it has y''(0) = -1 where tanh(0) = 0")
    fig.tight_layout()
    return save(fig, path)


# ------------------------------------------------------------------------- smooth friction (4.1)
def smooth_friction(quick: bool) -> tuple:
    epss = (0.3, 0.1, 0.03) if quick else (0.3, 0.1, 0.03, 0.01)
    B, v0 = B_SLIDE, V0_SLIDE
    tau0 = v0 / B
    printed = [v0, -B / 2, 0.8 * B**2 / v0, -0.6 * B**3 / v0**2, 32.0 / 75.0 * B**4 / v0**3]
    rows = []
    t = np.linspace(0.0, 1.5 * tau0, 31 if quick else 151)
    motions = {}
    for eps in epss:
        f = smooth_friction_field(B, eps)
        c = taylor_coefficients(f, [0.0, v0], 5)[0]
        for k in range(1, 6):
            rows.append(dict(eps=eps, k=k, engine=float(c[k]), printed_4_1=printed[k - 1],
                             coulomb=[v0, -B / 2, 0.0, 0.0, 0.0][k - 1]))
        r = solve(f, (0.0, t[-1]), [0.0, v0], degree=14, restart="auto", t_eval=t)
        ref = reference(lambda tt, y: [y[1], -B * np.tanh(y[1] / eps)], [0.0, v0], t[1:])
        motions[eps] = dict(q=r.y[0], status=r.status, n_restarts=r.n_restarts,
                            max_error=float(np.max(np.abs(r.y[0, 1:] - ref[0]))))
    motions["t"] = t
    motions["coulomb"] = series.coulomb_slide(t, v0, B)
    motions["printed"] = series.series_4_1_printed(t, v0, B)
    return rows, motions


def plot_smooth_friction(motions, path):
    fig, ax = plt.subplots(figsize=(7.5, 4.6))
    t = motions["t"]
    tau0 = V0_SLIDE / B_SLIDE
    ax.plot(t / tau0, motions["coulomb"], "k-", lw=3, alpha=0.35, label="exact Coulomb slide and stick")
    ax.plot(t / tau0, motions["printed"], "C3-", label="printed (4.1), 5 terms")
    for i, eps in enumerate(e for e in motions if isinstance(e, float)):
        # C3 (red) is the printed series'
        ax.plot(t / tau0, motions[eps]["q"], "--", color=("C0", "C1", "C2", "C4", "C5", "C6")[i % 6],
                label=f"LEM, qdd = -B tanh(qd/eps), eps = {eps:g}")
    ax.axvline(1.0, color="0.5", lw=0.8)
    ax.set_xlabel("t / tau0 (dimensionless; tau0 = v0 / B)")
    ax.set_ylabel("q [m]")
    top = 1.6 * V0_SLIDE**2 / (2 * B_SLIDE)
    ax.set_ylim(0.0, top)
    if np.nanmax(motions["printed"]) > top:
        ax.text(0.98, 0.03, f"printed (4.1) clipped at the top (reaches {np.nanmax(motions['printed']):.2g} m)",
                transform=ax.transAxes, ha="right", va="bottom", fontsize=8, color="C3",
                bbox=dict(facecolor="white", edgecolor="0.7", alpha=0.9))
    ax.set_title(f"Smooth slide v0 = {V0_SLIDE:g}, B = {B_SLIDE:g}: the printed (4.1) against the "
                 f"true motions")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return save(fig, path)


# -------------------------------------------------------------------------------------- Troesch
def troesch(quick: bool, client=None) -> list:
    """Rows per lambda. ``client``: a Dask client to run them on (None: here)."""
    lams = (0.5, 1.0, 5.0) if quick else (0.5, 1.0, 5.0, 10.0)
    return [r for part in pieces(troesch_rows, lams, client, "Troesch") for r in part]


def troesch_rows(lam) -> list:
    """The row of one lambda of :func:`troesch` (one piece of work), in a list."""
    rows = []
    t0 = time.perf_counter()
    r = solve_troesch(lam)
    dt = time.perf_counter() - t0
    te = np.linspace(0.0, 1.0, 101)
    traj = solve(troesch_field(lam), (0.0, 1.0), [0.0, r.slope], degree=16, restart="auto",
                 t_eval=te, rtol=1e-12, atol=1e-14)
    rows.append(dict(lam=lam, slope=r.slope, reference=TROESCH_REFERENCE[lam],
                     relative_error=r.relative_error, slope_error_estimate=r.slope_error_estimate,
                     status=r.status, iterations=r.iterations, failed_trials=r.failed_trials,
                     segments=r.n_segments, dyds=r.dyds, time_s=dt,
                     x=te, y=traj.y[0]))
    return rows


def plot_troesch(rows, path):
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.3))
    for i, r in enumerate(rows):
        a1.plot(r["x"], r["y"], color=f"C{i}", label=f"lambda = {r['lam']:g}, y'(0) = {r['slope']:.6g}")
    a1.set_xlabel("x (dimensionless)")
    a1.set_ylabel("y(x) (dimensionless)")
    a1.set_title("Solutions (restarted LEM engine)")
    a1.legend(fontsize=8)
    a1.grid(True, alpha=0.3)
    lam = [f"{r['lam']:g}" for r in rows]
    floor = 1e-17
    err = [max(r["relative_error"], floor) for r in rows]
    a2.bar(lam, err, color=[f"C{i}" for i in range(len(rows))], bottom=floor)
    for i, r in enumerate(rows):
        target = 1e-9 if r["lam"] <= 1 else 1e-6
        a2.plot([i - 0.4, i + 0.4], [target, target], "k--", lw=1,
                label="required accuracy" if i == 0 else None)
        txt = "0 (all 17 digits)" if r["relative_error"] == 0 else f"{r['relative_error']:.1e}"
        a2.text(i, max(r["relative_error"], floor) * 3, txt, ha="center", fontsize=8)
    a2.set_yscale("log")
    a2.set_ylim(floor, 1e-3)
    a2.set_xlabel("lambda (dimensionless)")
    a2.set_ylabel("|y'(0) / reference - 1| (relative)")
    a2.set_title("Relative error of y'(0) against the 20-digit reference")
    a2.legend(fontsize=8, loc="upper left")
    a2.grid(True, axis="y", alpha=0.3)
    fig.suptitle("Troesch's problem y'' = lambda sinh(lambda y), y(0) = 0, y(1) = 1, "
                 "by shooting over the LEM propagator")
    fig.tight_layout()
    return save(fig, path)


# ------------------------------------------------------------------------------------------ run
def run(out=None, quick: bool = False, workers: int | None = None, scheduler: str | None = None) -> dict:
    """Run the study; write figures and CSV into ``out``; return the numbers behind them.

    ``workers`` (a new local Dask cluster) or ``scheduler`` (a running one's address) runs the
    degrees of the error sweep and the Troesch cases side by side; the numbers are the same.
    """
    folder = out_dir(out, NAME)
    files = []
    with cluster(workers, scheduler) as client:
        ev = error_vs_degree(quick, client)
        tr = troesch(quick, client)
    files.append(write_csv(folder / "error_vs_degree.csv", list(ev[0]), [list(r.values()) for r in ev]))
    files.append(plot_error_vs_degree(ev, folder / "error_vs_degree.png"))
    auto = auto_restart_check()

    cost = cost_vs_degree(quick)
    files.append(write_csv(folder / "cost_vs_degree.csv", list(cost[0]), [list(r.values()) for r in cost]))
    files.append(plot_cost(cost, folder / "cost_vs_degree.png"))

    coef = coefficient_table()
    curves = series_curves(quick)
    files.append(write_csv(folder / "coefficients_3_20.csv", list(coef[0]), [list(r.values()) for r in coef]))
    files.append(plot_series(coef, curves, folder / "series_3_20.png"))
    keys = ("x", "reference", "lem", "true7", "true21", "printed")
    files.append(write_csv(folder / "series_3_20_curves.csv", ("z0",) + keys,
                           [[z0] + [float(c[k][i]) for k in keys]
                            for z0, c in curves.items() for i in range(c["x"].size)]))

    fr_rows, motions = smooth_friction(quick)
    files.append(write_csv(folder / "smooth_friction_coefficients.csv", list(fr_rows[0]),
                           [list(r.values()) for r in fr_rows]))
    files.append(plot_smooth_friction(motions, folder / "smooth_friction.png"))
    epss = [e for e in motions if isinstance(e, float)]
    files.append(write_csv(folder / "smooth_friction_motions.csv",
                           ["t_s", "coulomb_q_m", "printed_4_1_q_m"] + [f"lem_q_m_eps_{e:g}" for e in epss],
                           [[float(motions["t"][i]), float(motions["coulomb"][i]),
                             float(motions["printed"][i])] + [float(motions[e]["q"][i]) for e in epss]
                            for i in range(motions["t"].size)]))

    keys = [k for k in tr[0] if k not in ("x", "y")]
    files.append(write_csv(folder / "troesch.csv", keys, [[r[k] for k in keys] for r in tr]))
    files.append(plot_troesch(tr, folder / "troesch.png"))
    files.append(write_csv(folder / "troesch_solutions.csv", ["lam", "x", "y"],
                           [[r["lam"], float(x), float(y)] for r in tr for x, y in zip(r["x"], r["y"])]))

    def pick(x, N, key):
        return next(r[key] for r in ev if r["x"] == x and r["N"] == N)

    checks = dict(
        x1_error_N61=pick(1.0, 61, "plain_error_y"),
        x1_estimate_N61=pick(1.0, 61, "plain_estimate_y"),
        x1_errors=[(r["N"], r["plain_error_y"]) for r in ev if r["x"] == 1.0],
        x2_plain_diverging_N61=pick(2.0, 61, "plain_diverging"),
        x2_plain_status_N61=pick(2.0, 61, "plain_status"),
        x2_restart_error_N61=pick(2.0, 61, "restart_error_y"),
        x2_auto_restart=auto,
        coefficients_equal=all(r["equal"] for r in coef),
        troesch_relative_errors={r["lam"]: r["relative_error"] for r in tr},
        smooth_friction_max_error=max(m["max_error"] for e, m in motions.items() if isinstance(e, float)),
    )
    return dict(error_vs_degree=ev, cost=cost, coefficients=coef, smooth_friction=fr_rows,
                troesch=[{k: v for k, v in r.items() if k not in ("x", "y")} for r in tr],
                checks=checks, files=files)


def main(argv=None):
    args = parse_args(NAME, __doc__.splitlines()[0], argv, extra=add_options)
    t0 = time.perf_counter()
    res = run(out=args.out, quick=args.quick, workers=args.workers, scheduler=args.scheduler)
    c = res["checks"]
    print(f"x = 1, N = 61: error {c['x1_error_N61']:.3g} (estimate {c['x1_estimate_N61']:.3g})")
    print(f"x = 2, N = 61: plain diverging flag {c['x2_plain_diverging_N61']} "
          f"(status {c['x2_plain_status_N61']}); restarted every {RESTART_H}: error "
          f"{c['x2_restart_error_N61']:.3g}; auto restart (N = 20): {c['x2_auto_restart']}")
    print(f"engine coefficients equal the exact recursion: {c['coefficients_equal']}")
    for r in res["troesch"]:
        print(f"Troesch lambda = {r['lam']:g}: y'(0) = {r['slope']:.17g}, relative error "
              f"{r['relative_error']:.2g}, status {r['status']}, {r['segments']} segments, "
              f"{r['time_s']:.2f} s")
    print(f"wrote {len(res['files'])} files into {args.out} in {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
