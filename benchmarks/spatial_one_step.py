"""Cost of one spatial (Coulomb disk) one-step solve at 1, 10 and 100 contacts, per solver, next to
the planar cost of the same problems with one tangent.

Run: ``python benchmarks/spatial_one_step.py [--quick] [--out DIR]``. Prints a table and writes
``spatial_one_step.csv`` into ``benchmarks/out/`` (untracked) or ``DIR``.

A companion block times the whole Moreau-Jean loop (``lcp.simulate``, Python loop) per step with one
spatial contact (``plane_slide``, ``jean_pratt_spatial`` launched obliquely) next to one planar
contact (``jean_pratt`` with ``fast=False``); its rows have ``tangent`` = "loop spatial" /
"loop planar", ``solver`` = "scene:solver" and ``median_ms`` the cost per step (best of the
interleaved repeats: the loops alternate, so both see the same load).

Scene: a row of boxes (translational 3-D point masses, m in [0.5, 2]) standing on a horizontal floor
and pressed against their neighbours: every box has a floor contact (normal z, tangents x, y) and
the first ones a contact with the next box (normal x, tangents y, z). W = H M^-1 H' is sparse
(block tridiagonal). The free velocities mix sliding boxes (|v| ~ 1 m/s) with nearly resting ones
(|v| ~ 1 cm/s, which stick), gravity over a step h = 10 ms, and approaching or separating
neighbours. The planar problem keeps the first tangent of every contact (same W rows). Times are
medians of repeated cold solves (no warm start, unkeyed problems) in one run, so the ratios
between solvers are meaningful on a shared machine; residuals are the independent natural-map
residual relative to the impulse scale.
"""
from __future__ import annotations

import argparse
import csv
import os
import statistics
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from lcp.contact.spatial_problem import ConeContactProblem
from lcp.contact.spatial_solvers import make_cone_solver
from lcp.contact.problem import ContactProblem
from lcp.contact.solvers import make_solver

SPATIAL = ["local", "nsgs", "newton", "tresca", "faceted", "auto"]
PLANAR = ["enum", "lemke", "osqp", "nsgs", "newton", "auto"]


def boxes(k: int, seed: int = 0, h: float = 1e-2):
    """(W, q, mu) of k contacts in the box-row scene, spatial layout (dims all 2)."""
    rng = np.random.default_rng(seed)
    nb = k // 2 + 1
    pairs = k - nb
    m = rng.uniform(0.5, 2.0, nb)
    rows, cols, vals = [], [], []
    # blocked rows: normals 0..k-1, then tangents 2 per contact
    for j in range(k):
        t0, t1 = k + 2 * j, k + 2 * j + 1
        if j < nb:  # floor contact of box j
            for r, ax in ((j, 2), (t0, 0), (t1, 1)):
                rows.append(r), cols.append(3 * j + ax), vals.append(1.0)
        else:  # contact between boxes i and i + 1: relative velocity v_{i+1} - v_i
            i = j - nb
            for r, ax in ((j, 0), (t0, 1), (t1, 2)):
                rows += [r, r]
                cols += [3 * (i + 1) + ax, 3 * i + ax]
                vals += [1.0, -1.0]
    H = sp.csr_matrix((vals, (rows, cols)), shape=(3 * k, 3 * nb))
    Minv = sp.diags(np.repeat(1.0 / m, 3))
    W = (H @ Minv @ H.T).tocsr()
    speed = np.where(rng.random(nb) < 0.5, 1.0, 0.01)  # sliding and nearly resting boxes
    v = np.zeros((nb, 3))
    v[:, :2] = rng.normal(size=(nb, 2)) * speed[:, None]
    v[:, 2] = -9.81 * h
    v[:pairs + 1, 0] -= np.linspace(0, 0.2, pairs + 1) * rng.choice([1.0, -1.0])  # neighbours close in or part
    q = H @ v.ravel()
    mu = rng.uniform(0.3, 0.6, k)
    return W, q, mu


def planar_of(W, q, k):
    """The same problem with one tangent (the first of each contact)."""
    keep = np.concatenate([np.arange(k), k + 2 * np.arange(k)])
    return W[keep][:, keep], q[keep]


def measure(solver, pb, budget_s: float, max_repeats: int):
    sol = solver.solve(pb)  # warm-up: compilation, workspaces
    times = []
    t_total = time.perf_counter()
    while len(times) < max_repeats and (not times or time.perf_counter() - t_total < budget_s):
        t0 = time.perf_counter()
        sol = solver.solve(pb)
        times.append(time.perf_counter() - t0)
    scale = max(pb.scale, float(np.max(np.abs(sol.p))) if np.all(np.isfinite(sol.p)) else 0.0)
    return statistics.median(times), len(times), sol, sol.residual / scale


def loop_rows(repeats: int, t_end: float = 1.0, h: float = 1e-3):
    """Per-step cost of the Moreau-Jean loop with one spatial contact vs one planar contact."""
    import lcp
    from lcp.scenes.spatial_systems import jean_pratt_spatial, plane_slide

    cases = [("loop spatial", "plane_slide:local", plane_slide(), {"solver": "local"}),
             ("loop spatial", "plane_slide:auto", plane_slide(), {"solver": "auto"}),
             ("loop spatial", "jean_pratt_spatial:auto", jean_pratt_spatial(v0=(1.0, 0.5)), {"solver": "auto"}),
             ("loop planar", "jean_pratt:auto", lcp.scenes.jean_pratt(), {"fast": False})]
    best = {c[1]: np.inf for c in cases}
    last = {}
    for c in cases:  # warm-up: compilation, CasADi functions
        lcp.simulate(c[2], 0.01, h=h, **c[3])
    for _ in range(repeats):
        for _tangent, name, scene, kw in cases:
            t0 = time.perf_counter()
            res = lcp.simulate(scene, t_end, h=h, **kw)
            best[name] = min(best[name], (time.perf_counter() - t0) / res.stats.steps)
            last[name] = res
    rows = []
    for tangent, name, _scene, _kw in cases:
        res = last[name]
        counts = " ".join(f"{v}{k}" for k, v in res.stats.mode_counts.items() if v)
        rows.append({"k": 1, "tangent": tangent, "solver": name, "median_ms": 1e3 * best[name], "repeats": repeats,
                     "status": res.status, "residual_rel": res.stats.max_residual, "iterations": res.stats.steps,
                     "modes": counts})
    return rows


def mode_counts(pb, sol) -> str:
    """'3OPEN 62SLIDE ...' for a successful solution."""
    if not sol.success:
        return ""
    names, counts = np.unique(pb.modes(sol.p).names, return_counts=True)
    return " ".join(f"{c}{s}" for s, c in zip(names, counts))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer repeats")
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "out")
    args = ap.parse_args(argv)
    budget, max_rep = (0.5, 20) if args.quick else (2.0, 200)
    load0 = os.getloadavg()
    rows = []
    for k in (1, 10, 100):
        W, q, mu = boxes(k)
        pbs = ConeContactProblem(W, q, mu, np.full(k, 2))
        Wp, qp = planar_of(W, q, k)
        pbp = ContactProblem(Wp.toarray() if Wp.shape[0] <= 8 else Wp, qp, mu)
        for name in SPATIAL:
            if name == "local" and k > 1:
                continue
            if name == "faceted" and k > 10 and args.quick:
                continue
            t, n, sol, rel = measure(make_cone_solver(name), pbs, budget, 3 if name == "faceted" and k > 10 else max_rep)
            rows.append({"k": k, "tangent": "spatial", "solver": name, "median_ms": 1e3 * t, "repeats": n,
                         "status": sol.status, "residual_rel": rel, "iterations": sol.iterations,
                         "modes": mode_counts(pbs, sol)})
        for name in PLANAR:
            if name == "enum" and k > 1:
                continue
            t, n, sol, rel = measure(make_solver(name), pbp, budget, max_rep)
            rows.append({"k": k, "tangent": "planar", "solver": name, "median_ms": 1e3 * t, "repeats": n,
                         "status": sol.status, "residual_rel": rel, "iterations": sol.iterations, "modes": ""})
    rows += loop_rows(3 if args.quick else 7)
    load1 = os.getloadavg()
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "spatial_one_step.csv"
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    print(f"{'k':>4s} {'tangent':8s} {'solver':8s} {'ms':>9s} {'reps':>5s} {'status':>6s} {'residual':>9s} "
          f"{'iters':>6s}  modes")
    for r in rows:
        print(f"{r['k']:4d} {r['tangent']:8s} {r['solver']:8s} {r['median_ms']:9.3f} {r['repeats']:5d} "
              f"{r['status']:6d} {r['residual_rel']:9.1e} {r['iterations']:6d}  {r['modes']}")
    loop = {r["solver"]: r["median_ms"] for r in rows if r["tangent"].startswith("loop")}
    for name in ("plane_slide:local", "plane_slide:auto", "jean_pratt_spatial:auto"):
        print(f"loop per step, {name} / planar jean_pratt (Python loop): "
              f"{loop[name] / loop['jean_pratt:auto']:.2f}")
    for k in (1, 10, 100):
        for tangent in ("spatial", "planar"):
            ok = [r for r in rows if r["k"] == k and r["tangent"] == tangent and r["status"] == 0]
            if ok:
                best = min(ok, key=lambda r: r["median_ms"])
                print(f"fastest exact, k = {k}, {tangent}: {best['solver']} ({best['median_ms']:.3f} ms)")
    print(f"load average before / after: {load0[0]:.2f} / {load1[0]:.2f} ({os.cpu_count()} cores)")
    print(f"written to {path}")


if __name__ == "__main__":
    main()
