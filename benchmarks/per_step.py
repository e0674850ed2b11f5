"""Moreau-Jean per-step cost on the default Jean-Pratt scene, amortized over 1e5 steps, with its error checks.

Run: ``python benchmarks/per_step.py [--quick] [--steps N] [--repeats K] [--no-profile]``. Prints a
table and writes ``benchmarks/out/per_step.csv`` (untracked; pass ``--out`` to write elsewhere).

The scene is the default one (m = M = 1, alpha = pi/4, R = 0.5, v0 = 1), its default horizon
T = 2 tau0 = 0.306 s cut into N = 1e5 steps (h = T / N, theta = 1/2), so that half the steps slide
and half stick. Each path runs the whole simulation through ``lcp.simulate`` (set-up included);
the time is the median of K repeats after one warm-up call, and the cost per step is that time
divided by N. Paths:

- ``compiled``: the fastest exact path (``solver="auto"``, closed form inside compiled CasADi
  ``mapaccum`` chunks), every state kept, and the same with ``save_every=1000``;
- ``enum``, ``lemke``: the Python loop (``fast=False``) with each exact one-step solver;
- ``osqp``: the general path (OSQP set up once per active set, warm-started, branch solved
  exactly);
- ``osqp lean loop (prototype)``: NOT package code: the same OSQP workspace and branch solve in a
  loop stripped to what the single-contact step needs (OSQP's public update/solve, a closed-form
  branch solve, no per-step problem objects). It measures what the
  general OSQP path could cost and is checked like the others.

Every path must keep the contact core's results: max |x - exact| <= B h^2/8 at every grid point (to
rounding, 1e-12) and max |y| <= 1e-12. With ``--profile`` (default on), cProfile splits the OSQP
path's time into the OSQP C solve, the osqp Python wrapper, the contact-problem objects, the
solver logic and the time-stepping loop.
"""
from __future__ import annotations

import argparse
import cProfile
import csv
import math
import os
import pstats
import statistics
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

import lcp
from lcp.contact.problem import PY_OPS, SLIDE_NEG, SLIDE_POS, STICK, OPEN, planar_enum, planar_refine
from lcp.timestepping.assembly import StepAssembly

# this script times the compiled loops: its short runs must not take the Python loop while a
# kernel is not loaded yet (lcp.timestepping.first_compile)
os.environ.setdefault("LCP_COMPILE", "always")


TARGETS = {"compiled": 1.0, "osqp": 60.0}  # microseconds per step


def lean_osqp_loop(scene, T, h, theta=0.5, eps=1e-10):
    """Prototype (not package code): Moreau-Jean with one OSQP QP per step for a constant
    single-contact system, the QP set up once and warm-started, the branch it names solved exactly.

    Returns (t, q, v, qp_solves, fallbacks)."""
    import osqp

    asm = StepAssembly(scene.system, h, theta)
    mu = float(scene.system.mu[0])
    e = float(scene.system.e[0])
    n = asm.n
    S_F = asm.S @ (h * asm.F0)  # constant free-velocity increment
    SHt, W, H = asm.SHt, asm.W, asm.H
    W00, W01, W10, W11 = (float(w) for w in W.ravel())
    P = sp.csc_matrix(np.triu(W))
    solver = osqp.OSQP()
    solver.setup(P, np.zeros(2), sp.identity(2, format="csc"), np.array([0.0, 0.0]), np.array([np.inf, 0.0]),
                 eps_abs=eps, eps_rel=eps, polishing=False, verbose=False, warm_starting=True,
                 eps_prim_inf=1e-12, eps_dual_inf=1e-12, max_iter=20000)
    solved = osqp.SolverStatus.OSQP_SOLVED
    big = solver.constant("OSQP_INFTY")
    n_steps = int(math.ceil(T / h * (1 - 1e-12)))
    Q = np.empty((n_steps + 1, n))
    V = np.empty((n_steps + 1, n))
    q = np.array(scene.q0, dtype=float)
    v = np.array(scene.v0, dtype=float)
    Q[0], V[0] = q, v
    cq, cv = np.zeros(n), np.zeros(n)
    gap0 = float(asm.gap0[0])
    HN, HT = H[0], H[1]
    l = np.array([0.0, 0.0])
    u = np.array([big, 0.0])
    qv = np.zeros(2)
    s = 0.0
    qps = fallbacks = 0
    for k in range(n_steps):
        vfree = v + S_F
        uNm = float(HN @ v)
        qN = float(HN @ vfree) + e * uNm
        qT = float(HT @ vfree)
        gap = gap0 + float(HN @ q)
        if gap + h * ((1 - theta) * uNm + theta * float(HN @ vfree)) > 0:
            pN = pT = 0.0
        else:
            qv[0], qv[1] = qN, qT
            l[1], u[1] = -s, s
            solver.update(q=qv, l=l, u=u)  # OSQP's public API only
            res = solver.solve(raise_error=False)
            qps += 1
            if res.info.status_val != solved:
                raise RuntimeError(f"OSQP status {res.info.status} at step {k}")
            x = res.x
            tol = 1e-7 * max(abs(qN) / W00, abs(qT) / W11, abs(x[0]), abs(x[1]))
            if x[0] <= tol:
                mode = OPEN
            elif s > tol and x[1] >= s - tol:
                mode = SLIDE_NEG
            elif s > tol and x[1] <= -s + tol:
                mode = SLIDE_POS
            else:
                mode = STICK
            # the QP names the branch; the branch's linear system gives its exact fixed point
            pN, pT = planar_refine(W00, W01, W10, W11, qN, qT, mu, mode, ops=PY_OPS)
            uN = W00 * pN + W01 * pT + qN
            uT = W10 * pN + W11 * pT + qT
            ok = (pN >= -tol and (mode == OPEN or abs(uN) <= 1e-9 * (abs(qN) + tol))
                  and abs(pT) <= mu * pN + tol
                  and (mode != STICK or abs(uT) <= 1e-9 * (abs(qT) + abs(qN) + tol))
                  and (mode != SLIDE_POS or uT >= -tol) and (mode != SLIDE_NEG or uT <= tol))
            if not ok:  # the QP's bound s was not yet mu p_N: finish with the closed form
                pN, pT, _, _ = planar_enum(W00, W01, W10, W11, qN, qT, mu, ops=PY_OPS)
                fallbacks += 1
            s = mu * max(pN, 0.0)
        dv = S_F + SHt[:, 0] * pN + SHt[:, 1] * pT
        y = dv - cv
        t_ = v + y
        cv = (t_ - v) - y
        v_new = t_
        y = h * ((1 - theta) * v + theta * v_new) - cq
        t_ = q + y
        cq = (t_ - q) - y
        q, v = t_, v_new
        Q[k + 1], V[k + 1] = q, v
    return h * np.arange(n_steps + 1), Q, V, qps, fallbacks


def measure(name, fn, scene, h, n_steps, repeats):
    fn()  # warm-up: compiled code loaded, solvers built
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    t, Q = out
    x_err = float(np.max(np.abs(Q[:, 0] - scene.exact(t)["x"])))
    bound = scene.B * h * h / 8
    y_max = float(np.max(np.abs(Q[:, 1])))
    med = statistics.median(times)
    return dict(path=name, steps=n_steps, repeats=repeats, time_s=med, min_time_s=min(times),
                us_per_step=1e6 * med / n_steps, max_x_error=x_err, bound=bound, max_abs_y=y_max,
                error_ok=bool(x_err <= bound + 1e-12 and y_max <= 1e-12))


def osqp_profile(scene, h, steps=10_000):
    """cProfile of the general OSQP path, its own time grouped by where it is spent."""
    prof = cProfile.Profile()
    prof.enable()
    lcp.simulate(scene, steps * h, h=h, solver="osqp")
    prof.disable()
    st = pstats.Stats(prof).stats
    groups = {}

    def group(fname, func):
        if "osqp.ext_builtin" in func and ".solve" in func:
            return "OSQP C solve (ext_builtin)"
        if "osqp" in fname.replace("\\", "/").split("/site-packages/")[-1][:5] or "ext_builtin" in func:
            return "osqp Python wrapper (update, solve bookkeeping)"
        if fname.endswith("contact_problem.py"):
            return "lcp.contact.problem (problem objects, residual, branch solve)"
        if fname.endswith("solvers.py"):
            return "lcp.contact.solvers (OsqpSolver: bounds, branch reading)"
        if fname.endswith("timestepping.py"):
            return "lcp.timestepping (loop body, assembly, Kahan sums)"
        if "numpy" in fname or func.startswith("<method") or func.startswith("<built-in method numpy"):
            return "NumPy calls (small-array overhead)"
        return "other"

    total = 0.0
    for (fname, _line, func), (_cc, _nc, tt, _ct, _callers) in st.items():
        g = group(fname, func)
        groups[g] = groups.get(g, 0.0) + tt
        total += tt
    return {g: (t, t / total) for g, t in sorted(groups.items(), key=lambda kv: -kv[1])}, total, steps


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="1e4 steps, one repeat")
    ap.add_argument("--steps", type=int, default=None, help="steps per run (default 1e5)")
    ap.add_argument("--repeats", type=int, default=None, help="repeats of the Python-loop paths (default 3)")
    ap.add_argument("--no-profile", action="store_true")
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "out")
    args = ap.parse_args(argv)
    n_steps = args.steps or (10_000 if args.quick else 100_000)
    rep_py = args.repeats or (1 if args.quick else 3)
    rep_fast = 3 if args.quick else 7
    scene = lcp.scenes.jean_pratt()
    T = scene.t_end
    h = T / n_steps
    load0 = os.getloadavg()

    def sim(**kw):
        def go():
            r = lcp.simulate(scene, T, h=h, **kw)
            assert r.success and r.stats.steps == n_steps, r.message
            return r.t, r.q
        return go

    def sim_decimated():
        r = lcp.simulate(scene, T, h=h, save_every=1000)
        return r.t, r.q

    def lean():
        t, Q, _, _, _ = lean_osqp_loop(scene, T, h)
        return t, Q

    rows = [measure("compiled (auto, fast=True)", sim(), scene, h, n_steps, rep_fast),
            measure("compiled, save_every=1000", sim_decimated, scene, h, n_steps, rep_fast),
            measure("enum, Python loop (fast=False)", sim(solver="enum", fast=False), scene, h, n_steps, rep_py),
            measure("lemke, Python loop (fast=False)", sim(solver="lemke", fast=False), scene, h, n_steps, rep_py),
            measure("osqp (general path)", sim(solver="osqp"), scene, h, n_steps, rep_py),
            measure("osqp lean loop (prototype, not package code)", lean, scene, h, n_steps, rep_py)]
    _, _, _, qps, fb = lean_osqp_loop(scene, T, h)
    rows[-1]["note"] = f"{qps} QP solves, {fb} closed-form completions"
    # the fixed cost of a call (set-up, assembly, chunk binding), to separate it from the per-step cost
    t0 = time.perf_counter()
    for _ in range(20):
        lcp.simulate(scene, 10 * h, h=h)
    fixed = (time.perf_counter() - t0) / 20
    load1 = os.getloadavg()
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "per_step.csv"
    keys = ["path", "steps", "repeats", "time_s", "min_time_s", "us_per_step", "max_x_error", "bound",
            "max_abs_y", "error_ok", "note"]
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: (repr(r[k]) if isinstance(r.get(k), float) else r.get(k, "")) for k in keys})
    print(f"default Jean-Pratt scene, T = {T:.6g} s, {n_steps} steps, h = {h:.4g}, theta = 1/2; "
          f"{os.cpu_count()} cores, load average before {tuple(round(x, 2) for x in load0)}, "
          f"after {tuple(round(x, 2) for x in load1)}")
    print()
    print("| path | steps | repeats | time (s) | µs/step | max \\|x − exact\\| | B h²/8 | max \\|y\\| | checks |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['path']} | {r['steps']} | {r['repeats']} | {r['time_s']:.4g} | {r['us_per_step']:.3g} | "
              f"{r['max_x_error']:.2e} | {r['bound']:.2e} | {r['max_abs_y']:.1e} | "
              f"{'pass' if r['error_ok'] else 'FAIL'} |")
    print(f"\nfixed cost of one simulate() call (10 steps, compiled path): {1e3 * fixed:.3g} ms")
    comp, gen = rows[0]["us_per_step"], rows[4]["us_per_step"]
    print(f"target: fastest exact path <= {TARGETS['compiled']:g} µs/step: {comp:.3g} µs -> "
          f"{'met' if comp <= TARGETS['compiled'] else 'NOT met'}")
    print(f"target: general OSQP path <= {TARGETS['osqp']:g} µs/step: {gen:.3g} µs -> "
          f"{'met' if gen <= TARGETS['osqp'] else 'NOT met'} (lean prototype: {rows[5]['us_per_step']:.3g} µs)")
    if not args.no_profile:
        groups, total, steps = osqp_profile(scene, h, 10_000 if not args.quick else 2_000)
        print(f"\nwhere the OSQP path's time goes (cProfile, {steps} steps, {1e6 * total / steps:.0f} µs/step "
              "under the profiler; shares are indicative):")
        for g, (t, frac) in groups.items():
            print(f"  {g:62s} {1e6 * t / steps:7.1f} µs/step  {100 * frac:5.1f} %")
    print(f"\nwritten to {path}")
    return rows


if __name__ == "__main__":
    main()
