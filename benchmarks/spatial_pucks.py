"""Spatial pucks: the whole ``lcp.simulate`` call per contact-step against Siconos's fc3d NSGS.

    python benchmarks/spatial_pucks.py [--quick] [--no-siconos] [--out DIR]

Scene: K independent pucks (point masses, coordinates (x, z, y) each) on the floor y = 0, one
Coulomb-disk contact each (mu = 0.3), under gravity; each launched in the plane with its own
velocity (uniform in [0, 1.5 mu g], random direction; puck 0 at 0.5 mu g, so it stops at 0.5 s),
so within the second some
stop and stick and the others still slide. Moreau-Jean, h = 1e-3, theta = 1/2, 1 s, K = 1, 10,
100, 1000 (``--quick``: up to 100).

Ours: the whole ``lcp.simulate`` call on a *fresh* scene (built just before, untimed; its first
simulation is timed, so the checks, the assembly and the packing of the compiled loop count);
what the process keeps by structure (numba's compiled kernels) is warmed up on another scene
first. Minimum over interleaved repeats. Also the one-off cost (a one-step run on a fresh scene).

Siconos 4.4 (its Python module importable by the system Python only, run in a subprocess): its
fc3d NSGS (``SICONOS_FRICTION_3D_NSGS``, tolerance 1e-10) on the same per-step local problems
u = W r + q (W once, in sparse-block storage; q of every step from our trajectory's free
velocities), in a Python loop over the steps with the problem object kept and the impulses
warm-started from the previous step; its time is the solver call's alone. The trajectories are
compared through the impulses (max |r_siconos - r_ours|) and the velocity each implies
(max |S H' (r_siconos - r_ours)|, the difference of the post-step velocities).

Also (K <= ``--kernel-max-k``, 100 by default) Siconos's own simulation of the same scene: one
LagrangianLinearTIDS and LagrangianLinearTIR per puck, NewtonImpactFrictionNSL, MoreauJeanOSI,
FrictionContact(3) by fc3d NSGS, TimeStepping; its whole run (construction included) per
contact-step, and the largest difference of its velocities from ours over the steps.

Prints a table and writes ``spatial_pucks.csv`` to ``benchmarks/recorded/`` (or ``--out``).
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import casadi as ca
import numpy as np
import scipy.sparse as sp

import lcp
from lcp.fclib import ContactFile, write_dat
from lcp.model.system import Contact, System
from lcp.scenes import Scene
from lcp.timestepping.assembly import StepAssembly
from studies import fc_benchmark
from studies._common import write_csv

RECORDED = Path(__file__).resolve().parent / "recorded"
H_STEP, T_END, MU, G = 1e-3, 1.0, 0.3, 9.81

_SICONOS_STEPS = r'''
import json, sys, time
import numpy as np
import siconos.numerics as sn
path, qs_path, tol, max_iter = json.loads(sys.argv[1])
pb = sn.frictionContact_new_from_filename(path)
qs = np.load(qs_path)
so = sn.SolverOptions(sn.SICONOS_FRICTION_3D_NSGS)
so.dparam[sn.SICONOS_DPARAM_TOL] = tol
so.iparam[sn.SICONOS_IPARAM_MAX_ITER] = max_iter
n = qs.shape[1]
r, u = np.zeros(n), np.zeros(n)
R = np.empty_like(qs)
total, cpu, worst, its, fails = 0.0, 0.0, 0.0, 0, 0
qv = pb.q
for i in range(qs.shape[0]):
    qv[:] = qs[i]
    c0 = time.process_time()
    t0 = time.perf_counter()
    info = sn.fc3d_driver(pb, r, u, so)
    total += time.perf_counter() - t0
    cpu += time.process_time() - c0
    worst = max(worst, so.dparam[sn.SICONOS_DPARAM_RESIDU])
    its += so.iparam[sn.SICONOS_IPARAM_ITER_DONE]
    fails += int(info != 0)
    R[i] = r
np.save(qs_path.replace("qs.npy", "rs_siconos.npy"), R)
print(json.dumps(dict(time=float(total), cpu=float(cpu), worst_error=float(worst), iterations=int(its),
                      failures=int(fails))))
'''

#: Siconos's own Moreau-Jean simulation of the pucks: one LagrangianLinearTIDS per puck (M = I, the
#: weight as external force), a LagrangianLinearTIR (rows: normal y, tangents x, z) with a
#: NewtonImpactFrictionNSL (e = 0, mu, dimension 3), MoreauJeanOSI(1/2), FrictionContact(3) by
#: fc3d NSGS (tolerance 1e-10), TimeStepping; timed from the system's construction to the last
#: step, the velocities recorded every step (as our saved states)
_SICONOS_KERNEL = r'''import json, sys, time
import numpy as np
import siconos.kernel as sk
import siconos.numerics as sn
v0_path, K, h, T, mu, g, tol = json.loads(sys.argv[1])
V0 = np.load(v0_path).reshape(K, 3)
t0 = time.perf_counter()
nsds = sk.NonSmoothDynamicalSystem(0.0, T)
dss = []
for i in range(K):
    ds = sk.LagrangianLinearTIDS(np.zeros(3), V0[i].copy(), np.eye(3))
    ds.setFExtPtr(np.array([0.0, 0.0, -g]))
    nsds.insertDynamicalSystem(ds)
    H = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    inter = sk.Interaction(sk.NewtonImpactFrictionNSL(0.0, 0.0, mu, 3), sk.LagrangianLinearTIR(H))
    nsds.link(inter, ds)
    dss.append(ds)
osi = sk.MoreauJeanOSI(0.5)
osnspb = sk.FrictionContact(3, sn.SICONOS_FRICTION_3D_NSGS)
osnspb.numericsSolverOptions().dparam[sn.SICONOS_DPARAM_TOL] = tol
osnspb.numericsSolverOptions().iparam[sn.SICONOS_IPARAM_MAX_ITER] = 100000
td = sk.TimeDiscretisation(0.0, h)
s = sk.TimeStepping(nsds, td, osi, osnspb)
n = int(round(T / h))
V = np.empty((n + 1, 3 * K))
V[0] = V0.ravel()
k = 0
while s.hasNextEvent() and k < n:
    s.computeOneStep()
    k += 1
    for i, ds in enumerate(dss):
        V[k, 3 * i:3 * i + 3] = ds.velocity()
    s.nextStep()
total = time.perf_counter() - t0
np.save(v0_path.replace("v0.npy", "V_kernel.npy"), V[:k + 1])
print(json.dumps(dict(time=total, steps=k)))
'''


def pucks(K: int, mu: float = MU, m: float = 1.0, seed: int = 0) -> Scene:
    """K pucks on the floor, one disk contact each, launched in the plane (module docstring)."""
    n = 3 * K
    q, v = ca.SX.sym("q", n), ca.SX.sym("v", n)
    mass = ca.SX(ca.DM(sp.csc_matrix(sp.eye(n) * m)))  # structurally diagonal
    f = np.zeros(n)
    f[2::3] = -m * G
    contacts = [Contact(gap=q[3 * i + 2], tangent=ca.vertcat(q[3 * i], q[3 * i + 1]), mu=mu, name=f"P{i}")
                for i in range(K)]
    system = System(q, v, mass, ca.SX(f), contacts=contacts)
    rng = np.random.default_rng(seed)
    speed = rng.uniform(0.0, 1.5 * mu * G, K)
    speed[0] = 0.5 * mu * G  # puck 0 (the only one at K = 1) slides, stops at t = 0.5 s, sticks
    ang = rng.uniform(0.0, 2 * np.pi, K)
    v0 = np.zeros(n)
    v0[0::3], v0[1::3] = speed * np.cos(ang), speed * np.sin(ang)
    return Scene(system, np.zeros(n), v0, T_END, f"pucks_{K}", {"K": K, "mu": mu})


def step_problems(scene, res):
    """(W interleaved, q of every step interleaved, our impulses interleaved, S H' blocked, perm):
    every contact of the pucks is active in every step (all on the floor)."""
    sysm = scene.system
    m = sysm.n_contacts
    asm = StepAssembly(sysm, H_STEP, 0.5)
    dvf, SHt, W, _, H = asm.at(0.0, res.q[0], res.v[0])
    H = sp.csr_matrix(H)
    qs = (res.v[:-1] + dvf) @ H.T.toarray() if m <= 100 else (H @ (res.v[:-1] + dvf).T).T
    perm = np.empty(3 * m, dtype=np.int64)  # interleaved row i <- blocked row perm[i]
    perm[0::3] = np.arange(m)
    perm[1::3] = m + 2 * np.arange(m)
    perm[2::3] = m + 2 * np.arange(m) + 1
    ours = np.concatenate([res.p_N, res.p_T], axis=1)  # blocked: normals, then tangents contact by contact
    Wi = sp.csr_matrix(W)[perm][:, perm]
    return Wi, np.ascontiguousarray(qs[:, perm]), ours[:, perm], sp.csr_matrix(SHt), perm


def siconos_steps(scene, res, tmp):
    Wi, qs, ours, SHt, perm = step_problems(scene, res)
    m = scene.system.n_contacts
    path = Path(tmp) / f"{scene.name}.dat"
    write_dat(path, ContactFile(Wi, qs[0], np.full(m, MU), dim=3), storage="sparse-block")
    np.save(Path(tmp) / "qs.npy", qs)
    out = fc_benchmark.run_siconos_script(_SICONOS_STEPS, [str(path), str(Path(tmp) / "qs.npy"), 1e-10, 100000])
    R = np.load(Path(tmp) / "rs_siconos.npy")
    diff = R - ours
    back = np.empty_like(perm)
    back[perm] = np.arange(perm.size)
    dv = (SHt @ diff[:, back].T).T  # the post-step velocities' difference
    out.update(steps=qs.shape[0], max_impulse_diff=float(np.max(np.abs(diff))),
               max_velocity_diff=float(np.max(np.abs(dv))), impulse_scale=float(np.max(np.abs(ours))))
    return out


def siconos_kernel(scene, res, tmp, timeout):
    """Siconos's own simulation of the scene (:data:`_SICONOS_KERNEL`): time, max |v_S - v| over the steps."""
    K = scene.system.n_contacts
    np.save(Path(tmp) / "v0.npy", scene.v0)
    out = fc_benchmark.run_siconos_script(_SICONOS_KERNEL, [str(Path(tmp) / "v0.npy"), K, H_STEP, T_END, MU, G, 1e-10],
                                          timeout=timeout)
    V = np.load(Path(tmp) / "V_kernel.npy")
    out["max_velocity_diff"] = float(np.max(np.abs(V - res.v[:V.shape[0]])))
    return out


def bench(Ks, use_siconos, kernel_max_k=100):
    rows = []
    warm = pucks(3)
    lcp.simulate(warm, 5 * H_STEP, h=H_STEP)  # numba's kernels loaded (or compiled) outside the timings
    for K in Ks:
        lcp.simulate(pucks(K), 5 * H_STEP, h=H_STEP)
        reps = 3 if K <= 100 else 2
        whole, one, cpu = [], [], []
        res = None
        for _ in range(reps):
            scene = pucks(K)
            c0 = time.process_time()
            t0 = time.perf_counter()
            res = lcp.simulate(scene, T_END, h=H_STEP)
            whole.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
            fresh = pucks(K)
            t0 = time.perf_counter()
            lcp.simulate(fresh, H_STEP, h=H_STEP)
            one.append(time.perf_counter() - t0)
        steps = res.stats.steps
        us = min(whole) / (steps * K) * 1e6
        per_step = (min(whole) - min(one)) / ((steps - 1) * K) * 1e6
        mc = res.stats.mode_counts
        cpu_us = min(cpu) / (steps * K) * 1e6
        row = {"K": K, "solver": res.solver, "status": res.status, "whole_call_us": us, "whole_call_cpu_us": cpu_us,
               "per_step_us": per_step,
               "one_off_ms": min(one) * 1e3, "stick": mc["stick"], "slide": mc["slide"], "siconos_nsgs_us": np.nan,
               "ratio": np.nan, "siconos_nsgs_cpu_us": np.nan, "cpu_ratio": np.nan, "siconos_iterations": 0,
               "siconos_failures": 0, "max_impulse_diff": np.nan,
               "max_velocity_diff": np.nan, "siconos_worst_error": np.nan, "siconos_kernel_us": np.nan,
               "kernel_ratio": np.nan, "kernel_max_velocity_diff": np.nan}
        print(f"K={K:5d} {res.solver:16s} status {res.status} whole call {us:8.3f} us/contact-step "
              f"(CPU time {cpu_us:.3f}) "
              f"(per step {per_step:.3f}, one-off {min(one) * 1e3:.2f} ms; stick {mc['stick']}, slide {mc['slide']})",
              flush=True)
        if use_siconos:
            with tempfile.TemporaryDirectory() as tmp:
                try:
                    s = siconos_steps(scene, res, tmp)
                except Exception as exc:  # noqa: BLE001 - the peer's failure is reported
                    print(f"      Siconos peer failed: {exc}", flush=True)
                    s = None
            if s is not None:
                sus = s["time"] / (s["steps"] * K) * 1e6
                scpu = s["cpu"] / (s["steps"] * K) * 1e6
                row.update(siconos_nsgs_us=sus, ratio=us / sus, siconos_nsgs_cpu_us=scpu, cpu_ratio=cpu_us / scpu,
                           siconos_iterations=s["iterations"],
                           siconos_failures=s["failures"], max_impulse_diff=s["max_impulse_diff"],
                           max_velocity_diff=s["max_velocity_diff"], siconos_worst_error=s["worst_error"])
                print(f"      Siconos fc3d NSGS {sus:8.3f} us/contact-step ({s['steps']} steps, {s['iterations']} "
                      f"iterations, {s['failures']} failures; CPU time {scpu:.3f}); ours / Siconos = {us / sus:.2f} "
                      f"(CPU time: {cpu_us / scpu:.2f}); "
                      f"max |r_S - r| {s['max_impulse_diff']:.1e} (impulses up to {s['impulse_scale']:.2g}), "
                      f"max |dv_S - dv| {s['max_velocity_diff']:.1e}", flush=True)
        if use_siconos and K <= kernel_max_k:
            with tempfile.TemporaryDirectory() as tmp:
                try:
                    kr = siconos_kernel(scene, res, tmp, timeout=600)
                except Exception as exc:  # noqa: BLE001 - the peer's failure (or time-out) is reported
                    print(f"      Siconos kernel failed: {str(exc)[:200]}", flush=True)
                    kr = None
            if kr is not None:
                kus = kr["time"] / (kr["steps"] * K) * 1e6
                row.update(siconos_kernel_us=kus, kernel_ratio=us / kus,
                           kernel_max_velocity_diff=kr["max_velocity_diff"])
                print(f"      Siconos kernel (TimeStepping, MoreauJeanOSI, fc3d NSGS) {kus:8.2f} us/contact-step; "
                      f"ours / kernel = {us / kus:.3f}; max |v_S - v| {kr['max_velocity_diff']:.1e}", flush=True)
        rows.append(row)
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--no-siconos", action="store_true")
    ap.add_argument("--out", type=Path, default=RECORDED)
    ap.add_argument("--kernel-max-k", type=int, default=100,
                    help="largest K simulated by Siconos's own kernel (its Python-level set-up grows with K)")
    args = ap.parse_args(argv)
    use_siconos = not args.no_siconos and fc_benchmark.siconos_available()
    if not args.no_siconos and not use_siconos:
        print("Siconos is not importable by the system Python: its column stays empty")
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores", flush=True)
    rows = bench([1, 10, 100] if args.quick else [1, 10, 100, 1000], use_siconos, args.kernel_max_k)
    print(f"load average {os.getloadavg()[0]:.1f}", flush=True)
    print("\n| K | ours: whole call (µs/contact-step) | per step | one-off (ms) | Siconos fc3d NSGS | ours / Siconos "
          "| CPU time: ours / Siconos | Siconos kernel | ours / kernel |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['K']} | {r['whole_call_us']:.3g} | {r['per_step_us']:.3g} | {r['one_off_ms']:.3g} | "
              f"{r['siconos_nsgs_us']:.3g} | {r['ratio']:.2f} | {r['whole_call_cpu_us']:.3g} / "
              f"{r['siconos_nsgs_cpu_us']:.3g} = {r['cpu_ratio']:.2f} | {r['siconos_kernel_us']:.3g} | "
              f"{r['kernel_ratio']:.3f} |")
    args.out.mkdir(parents=True, exist_ok=True)
    header = list(rows[0])
    write_csv(args.out / "spatial_pucks.csv", header, [[r[h] for h in header] for r in rows])
    print(f"wrote {args.out / 'spatial_pucks.csv'}")


if __name__ == "__main__":
    main()
