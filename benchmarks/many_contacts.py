"""Many contacts: cost per contact-step of every one-step solver, against Siconos's fc2d NSGS.

    python benchmarks/many_contacts.py [--quick] [--files DIR] [--no-siconos] [--scenes-only]

1. Scenes (Moreau-Jean, h = 1e-3, theta = 1/2, 1 s): the block chain ``lcp.scenes.block_chain(K)``
   and K independent Jean-Pratt systems as one System, K = 1, 10, 100, 1000 (``--quick``: up to
   100). Each applicable solver runs the whole simulation; the table gives microseconds per
   contact-step of the whole ``lcp.simulate`` call (state checks, assembly, solve, refinement,
   bookkeeping, result) and the largest difference of its trajectory from ``auto``'s; for ``auto``
   also the cost per step without its one-off cost (the time of a one-step run subtracted). Every
   timed call is the first simulation of a fresh scene built by the scene function (the build is
   not timed); what the process keeps by structure (compiled kernels, numba, CasADi functions
   keyed by sparsity pattern) is warmed up on another scene first. ``auto`` and ``nsgs`` run the compiled
   loop (:mod:`lcp.timestepping.compiled_loop`) from two contacts on. Siconos (when its Python module is importable by
   the system Python) solves the same per-step local problems (W once, the free velocity of every
   step from our trajectory), warm-started, tolerance 1e-10, with its fc2d NSGS on sparse-block
   storage; its time is the solver's alone.
2. Synthetic granular problems: random disks in a box (W = H M^-1 H'), about 2000 and 7000
   contacts (``--quick``: 2000), solved by ``auto``/``newton`` and ``nsgs``; time, error,
   nnz(W) and peak memory of the solve.
3. ``--files DIR``: every problem file of DIR through ``studies.fc_benchmark`` (planar files by the
   planar solvers and Siconos's fc2d NSGS/Lemke, spatial ones by the cone solvers and its fc3d
   NSGS; the faceted approximation's rows are named ``faceted (approx.)``); the table goes to
   ``many_contacts_files.csv`` (quoted CSV: the messages hold commas) and, with ``--out DIR``,
   the CSV and performance profiles of ``studies.fc_benchmark`` go to DIR. ``--files-only``
   skips parts 1 and 2.

Writes CSV files into ``benchmarks/out/`` (untracked).
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import casadi as ca
import numpy as np
import scipy.sparse as sp

import lcp
from lcp.timestepping.assembly import StepAssembly
from lcp.contact.problem import ContactProblem
from lcp.fclib import ContactFile, write_dat
from lcp.contact.law import interleave, natural_map_error
from lcp.scenes import Scene
from lcp.contact.solvers import make_solver
from lcp.model.system import Contact, System
from studies import fc_benchmark
from studies._common import write_csv

RESULTS = Path(__file__).resolve().parent / "out"
H_STEP, T_END = 1e-3, 1.0

_SICONOS_STEPS = r'''
import json, sys, time
import numpy as np
import siconos.numerics as sn
path, qs_path, rs_path, tol, max_iter = json.loads(sys.argv[1])
pb = sn.frictionContact_new_from_filename(path)
qs, rs = np.load(qs_path), np.load(rs_path)
so = sn.SolverOptions(sn.SICONOS_FRICTION_2D_NSGS)
so.dparam[sn.SICONOS_DPARAM_TOL] = tol
so.iparam[sn.SICONOS_IPARAM_MAX_ITER] = max_iter
n = qs.shape[1]
r, u = np.zeros(n), np.zeros(n)
total, worst, its, fails, diff = 0.0, 0.0, 0, 0, 0.0
qv = pb.q
for i in range(qs.shape[0]):
    qv[:] = qs[i]
    t0 = time.perf_counter()
    info = sn.fc2d_driver(pb, r, u, so)
    total += time.perf_counter() - t0
    worst = max(worst, so.dparam[sn.SICONOS_DPARAM_RESIDU])
    its += so.iparam[sn.SICONOS_IPARAM_ITER_DONE]
    fails += int(info != 0)
    diff = max(diff, float(np.max(np.abs(r - rs[i]))))
print(json.dumps(dict(time=float(total), worst_error=float(worst), iterations=int(its), failures=int(fails),
                      max_impulse_diff=float(diff))))
'''


def jean_pratt_copies(K: int, R: float = 0.5, alpha: float = np.pi / 4, m: float = 1.0, M: float = 1.0,
                      g: float = 9.81) -> Scene:
    """K independent reduced Jean-Pratt systems in one System (2K coordinates, K contacts);
    copy i starts at v0 = 1 + i/K, so the copies stop at different times."""
    t = float(np.tan(alpha)) if abs(alpha - np.pi / 4) > 1e-15 else 1.0
    n = 2 * K
    q, v = ca.SX.sym("q", n), ca.SX.sym("v", n)
    blk = np.array([[m + M * t * t, -M * t], [-M * t, m + M]])
    # structurally block diagonal: a dense array would carry (2K)^2 structural entries
    mass = ca.SX(ca.DM(sp.csc_matrix(sp.kron(sp.eye(K), blk))))
    force = ca.SX(np.tile([0.0, -(m + M) * g], K))
    contacts = [Contact(gap=q[2 * i + 1], tangent=q[2 * i], mu=R, name=f"P{i}") for i in range(K)]
    system = System(q, v, mass, force, contacts=contacts)
    v0 = np.zeros(n)
    v0[0::2] = 1.0 + np.arange(K) / K
    return Scene(system, np.zeros(n), v0, T_END, f"jean_pratt_copies_{K}", {"K": K, "R": R})


def step_problems(scene, res):
    """The local problems (q per step, interleaved) of a trajectory whose contacts are all active."""
    sysm = scene.system
    asm = StepAssembly(sysm, H_STEP, 0.5)
    m = sysm.n_contacts
    qs, rs = [], []
    W = None
    for k in range(res.p_N.shape[0]):
        dvf, _, W, gap, H = asm.at(k * H_STEP, res.q[k], res.v[k])
        vfree = res.v[k] + dvf
        uN = H[:m] @ res.v[k]
        pred = gap + H_STEP * (0.5 * uN + 0.5 * (H[:m] @ vfree))
        if np.all(pred <= 0):
            qs.append((H @ vfree)[interleave(m)])
            rs.append(np.column_stack([res.p_N[k], res.p_T[k]]).ravel())
    return W, np.array(qs), np.array(rs)


def siconos_steps(scene, res, tmp):
    """Siconos's NSGS on the per-step problems of our trajectory (None when unavailable)."""
    W, qs, rs = step_problems(scene, res)
    if not len(qs):
        return None
    m = scene.system.n_contacts
    perm = interleave(m)
    Wi = sp.csr_matrix(W)[perm][:, perm] if sp.issparse(W) else sp.csr_matrix(np.asarray(W)[np.ix_(perm, perm)])
    path = Path(tmp) / f"{scene.name}.dat"
    write_dat(path, ContactFile(Wi, qs[0], scene.system.mu), storage="sparse-block")
    np.save(Path(tmp) / "qs.npy", qs)
    np.save(Path(tmp) / "rs.npy", rs)
    out = fc_benchmark.run_siconos_script(_SICONOS_STEPS, [str(path), str(Path(tmp) / "qs.npy"),
                                                           str(Path(tmp) / "rs.npy"), 1e-10, 100000])
    out["steps"] = len(qs)
    return out


def ours_steps(scene, res, name):
    """Our solver alone on the same per-step problems as :func:`siconos_steps` (warm-started the
    same way, through the problem key): total solve time, worst error, largest impulse difference."""
    W, qs, rs = step_problems(scene, res)
    if not len(qs):
        return None
    m = scene.system.n_contacts
    back = np.argsort(interleave(m))
    template = ContactProblem(W, qs[0][back], scene.system.mu, key="steps")
    solver = make_solver(name)
    solver.solve(template)  # warm-up (kernels, caches), then from a cold start again
    solver = make_solver(name)
    total, worst, diff = 0.0, 0.0, 0.0
    for qi, ri in zip(qs, rs):
        pb = template.with_q(qi[back])
        t0 = time.perf_counter()
        sol = solver.solve(pb)
        total += time.perf_counter() - t0
        worst = max(worst, natural_map_error(pb.W, pb.q, pb.mu, sol.p))
        diff = max(diff, float(np.max(np.abs(sol.p - ri[back]))))
    return {"time": total, "worst_error": worst, "max_impulse_diff": diff, "steps": len(qs)}


def solvers_for(K):
    names = ["auto", "newton", "nsgs"]
    if K == 1:
        names.append("enum")
    if K <= 100:
        names.append("osqp")
    if K <= 10:
        names.append("lemke")
    return names


def bench_scenes(Ks, use_siconos):
    rows = []
    # load (or compile) the numba kernels once, outside the timings
    make_solver("nsgs").solve(ContactProblem(np.eye(4), np.array([-1.0, -1, 0, 0]), np.array([0.3, 0.3])))
    for family in ("block_chain", "jean_pratt_copies"):
        for K in Ks:
            def fresh():
                return lcp.scenes.block_chain(K) if family == "block_chain" else jean_pratt_copies(K)

            scene = fresh()
            ref, best = None, np.inf
            names = solvers_for(K)
            # warm-up on a scene of its own: what the process keeps by structure (compiled kernels,
            # numba, CasADi functions keyed by sparsity); nothing of a timed scene is ever warm
            for name in names:
                lcp.simulate(scene, 5 * H_STEP, h=H_STEP, solver=name)
            reps = 3 if K <= 100 else 2
            times = {name: [] for name in names}
            one_step = []  # auto's one-off cost: a run of a single step (checks, assembly, packing, dispatch)
            results = {}
            for _ in range(reps):  # interleaved repeats: a change of machine load hits every solver
                for name in names:
                    scene = fresh()  # built outside the timing; its first simulation is timed
                    t0 = time.perf_counter()
                    results[name] = lcp.simulate(scene, T_END, h=H_STEP, solver=name)
                    times[name].append(time.perf_counter() - t0)
                scene = fresh()
                t0 = time.perf_counter()
                lcp.simulate(scene, H_STEP, h=H_STEP, solver="auto")
                one_step.append(time.perf_counter() - t0)
            for name in names:
                r, t = results[name], min(times[name])
                if ref is None:
                    ref = r
                diff = float(np.max(np.abs(r.q - ref.q))) if r.q.shape == ref.q.shape else np.nan
                us = t / (r.stats.steps * K) * 1e6
                best = min(best, us)
                rows.append({"scene": family, "K": K, "solver": name, "status": r.status, "us": us, "diff": diff,
                                 "residual": r.stats.max_residual, "iterations": r.stats.iterations})
                print(f"{family:18s} K={K:5d} {name:8s} status {r.status:2d} {us:10.2f} us/contact-step "
                      f"max|q - q_auto| {diff:.1e} max residual {r.stats.max_residual:.1e}", flush=True)
            auto = next(x for x in rows if x["scene"] == family and x["K"] == K and x["solver"] == "auto")
            print(f"{'':18s} auto / fastest = {auto['us'] / best:.2f} ({results['auto'].solver})", flush=True)
            steps = results["auto"].stats.steps
            per_step = (min(times["auto"]) - min(one_step)) / ((steps - 1) * K) * 1e6
            rows.append({"scene": family, "K": K, "solver": "auto (per step, one-off cost excluded)", "status": 0,
                             "us": per_step, "diff": 0.0, "residual": 0.0, "iterations": 0})
            print(f"{'':18s} auto without its one-off cost ({min(one_step) * 1e3:.2f} ms): {per_step:.3f} "
                  "us/contact-step", flush=True)
            if use_siconos:
                with tempfile.TemporaryDirectory() as tmp:
                    try:
                        s = siconos_steps(scene, ref, tmp)
                    except Exception as exc:  # noqa: BLE001 - the peer's failure is reported
                        print(f"{'':18s} Siconos peer failed: {exc}")
                        s = None
                for name in ("auto", "nsgs"):
                    o = ours_steps(scene, ref, name)
                    if o is not None:
                        us = o["time"] / (o["steps"] * K) * 1e6
                        rows.append({"scene": family, "K": K, "solver": f"{name} (solve only)", "status": 0, "us": us,
                                         "diff": o["max_impulse_diff"], "residual": o["worst_error"], "iterations": 0})
                        print(f"{family:18s} K={K:5d} {name:8s} (solve only) {us:8.2f} us/contact-step "
                              f"max|r - r_auto| {o['max_impulse_diff']:.1e} worst error {o['worst_error']:.1e}",
                              flush=True)
                if s is not None:
                    us = s["time"] / (s["steps"] * K) * 1e6
                    rows.append({"scene": family, "K": K, "solver": "siconos-nsgs (solve only)", "status": -s["failures"],
                                     "us": us, "diff": s["max_impulse_diff"], "residual": s["worst_error"],
                                     "iterations": s["iterations"]})
                    print(f"{family:18s} K={K:5d} siconos  {s['failures']:2d} fails {us:8.2f} us/contact-step "
                          f"(solver only, {s['steps']} steps) max|r - r_auto| {s['max_impulse_diff']:.1e} "
                          f"worst Siconos error {s['worst_error']:.1e}", flush=True)
    return rows


def disk_packing(n_contacts: int, seed: int = 0, mu: float = 0.3, per_disk: float = 1.2):
    """A 2D granular-like problem: disks of random radii on a jittered triangular lattice in a
    box, the bottom row on the floor, and a random subset of lattice neighbours in contact
    (``per_disk`` contacts per disk: 2 rows per contact against 3 velocities per disk, so W is
    nonsingular); W = H M^-1 H', q = H v for a downward velocity plus noise. Returns a
    ContactProblem (normals first)."""
    rng = np.random.default_rng(seed)
    nb_target = int(np.ceil(n_contacts / per_disk))
    nx = max(2, int(np.sqrt(nb_target)))
    ny = int(np.ceil(nb_target / nx))
    nb = nx * ny
    rad = 0.5 * (1 + 0.05 * rng.random(nb))
    pos = np.array([[(i + 0.5 * (j % 2)), j * np.sqrt(3) / 2] for j in range(ny) for i in range(nx)])
    idx = np.arange(nb).reshape(ny, nx)
    pairs = []
    for j in range(ny):
        for i in range(nx):
            a = idx[j, i]
            if i + 1 < nx:
                pairs.append((a, idx[j, i + 1]))
            if j + 1 < ny:
                pairs.append((a, idx[j + 1, i]))
                i2 = i + 1 if j % 2 else i - 1
                if 0 <= i2 < nx:
                    pairs.append((a, idx[j + 1, i2]))
    floor = [(idx[0, i], -1) for i in range(nx)]
    chosen = rng.permutation(len(pairs))[: max(0, n_contacts - len(floor))]
    allc = floor + [pairs[c] for c in sorted(chosen)]
    k = len(allc)
    rows, cols, vals = [], [], []

    def add(row, col, val):
        rows.append(row)
        cols.append(col)
        vals.append(val)

    for c, (a, b) in enumerate(allc):
        nvec = np.array([0.0, 1.0]) if b < 0 else (pos[b] - pos[a]) / np.linalg.norm(pos[b] - pos[a])
        tvec = np.array([-nvec[1], nvec[0]])
        # relative velocity of b against a at the contact (against the fixed floor for b < 0)
        for row, vec in ((c, nvec), (k + c, tvec)):
            sa = -1.0 if b >= 0 else 1.0
            add(row, 3 * a, sa * vec[0])
            add(row, 3 * a + 1, sa * vec[1])
            if b >= 0:
                add(row, 3 * b, vec[0])
                add(row, 3 * b + 1, vec[1])
            if row >= k:  # spins enter the tangential slip
                add(row, 3 * a + 2, -rad[a])
                if b >= 0:
                    add(row, 3 * b + 2, -rad[b])
    H = sp.csr_matrix((vals, (rows, cols)), shape=(2 * k, 3 * nb))
    mass = np.pi * rad ** 2
    minv = np.repeat(1.0 / mass, 3)
    minv[2::3] = 1.0 / (0.5 * mass * rad ** 2)
    W = (H @ sp.diags(minv) @ H.T).tocsr()
    v = np.zeros(3 * nb)
    v[1::3] = -1e-2
    v += 1e-3 * rng.normal(size=3 * nb)
    return ContactProblem(W, H @ v, np.full(k, mu))


def bench_packings(sizes):
    rows = []
    for target in sizes:
        pb = disk_packing(target)
        for name in ("auto", "nsgs"):
            opts = {"max_sweeps": 20000} if name == "nsgs" else {}
            t0 = time.perf_counter()
            sol = make_solver(name, **opts).solve(pb)
            dt = time.perf_counter() - t0
            # memory in a second, traced run (tracing slows the first one down several times)
            tracemalloc.start()
            make_solver(name, **opts).solve(pb)
            peak = tracemalloc.get_traced_memory()[1] / 2 ** 20
            tracemalloc.stop()
            err = natural_map_error(pb.W, pb.q, pb.mu, sol.p)
            rows.append({"contacts": pb.k, "nnz": pb.W.nnz, "solver": name, "status": sol.status, "time": dt,
                             "iterations": sol.iterations, "error": err, "peak_mb": peak})
            print(f"disk packing {pb.k:5d} contacts nnz(W) {pb.W.nnz:7d} {name:6s} status {sol.status:2d} "
                  f"{dt:8.2f} s it {sol.iterations:6d} error {err:.1e} peak memory {peak:.0f} MiB", flush=True)
    return rows


def write_rows(path, rows):
    if not rows:
        return
    import csv

    keys = list(rows[0])
    with open(path, "w", newline="") as fh:  # quoted where needed: solver labels hold commas
        w = csv.writer(fh)
        w.writerow(keys)
        w.writerows([repr(r[k]) if isinstance(r[k], float) else str(r[k]) for k in keys] for r in rows)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--files", type=Path, default=None, help="folder of problem files to solve too")
    ap.add_argument("--no-siconos", action="store_true")
    ap.add_argument("--scenes-only", action="store_true", help="skip the synthetic granular problems")
    ap.add_argument("--files-only", action="store_true", help="only the problem files of --files")
    ap.add_argument("--out", type=Path, default=None, help="with --files: folder for fc_benchmark's CSV and profiles")
    args = ap.parse_args(argv)
    if args.files_only and args.files is None:
        ap.error("--files-only needs --files DIR")
    use_siconos = not args.no_siconos and fc_benchmark.siconos_available()
    if not args.no_siconos and not use_siconos:
        print("note: Siconos's Python module is not importable by the system Python: peer skipped")
    RESULTS.mkdir(exist_ok=True)
    Ks = [1, 10, 100] if args.quick else [1, 10, 100, 1000]
    if not args.files_only:
        write_rows(RESULTS / "many_contacts_scenes.csv", bench_scenes(Ks, use_siconos))
    if not (args.scenes_only or args.files_only):
        write_rows(RESULTS / "many_contacts_packings.csv", bench_packings([2000] if args.quick else [2000, 7000]))
    if args.files is not None:
        print(f"problem files of {args.files} (load {os.getloadavg()[0]:.2f})", flush=True)
        res = fc_benchmark.run(args.files, out=args.out, quick=args.quick, siconos=use_siconos)
        fc_benchmark.print_rows(res["rows"])
        if res["note"]:
            print(res["note"])
        keys = list(res["rows"][0]) if res["rows"] else []
        write_csv(RESULTS / "many_contacts_files.csv", keys, ([r[k] for k in keys] for r in res["rows"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
