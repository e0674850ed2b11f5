"""Batch-mode throughput: 1e5 Jean-Pratt scenes with different parameters stepped together.

Run: ``python benchmarks/batch_throughput.py [--quick] [--scenes N] [--steps K]``. Prints a table
and writes ``benchmarks/out/batch_throughput.csv`` (untracked; pass ``--out`` to write elsewhere).

Scenes: m, M uniform in [0.5, 2], alpha in [0.2, 1.2], R such that kappa is uniform in [0.05, 0.95],
v0 uniform in [-2, 2]; 30 % of them carry a tangential load phi = f R (m+M) g with f uniform in
[-0.9, 0.9] (a loaded stick after the stop). h = 1e-3, theta = 1/2.

Measured in one run (medians of repeats), scene-steps per second = scenes x steps / run time:

- ``compiled``: :func:`lcp.batch.simulate_batch` with ``path="compiled"`` (the CasADi step compiled
  to C with an OpenMP driver, cached per machine), all threads, and in a subprocess with
  ``OMP_NUM_THREADS=1`` (the cost per scene-step of one core);
- ``numpy``: the same closed form on arrays of scenes (``path="numpy"``), a plain NumPy loop over
  steps;
- compile time, separately: a cold build in a subprocess with an empty cache
  (``LCP_LEM_CACHE``), and the warm load of the cached library;
- ``SoA prototype`` (NOT package code, ``--no-prototype`` to skip): the same step hand-written in C
  for n = 2 with constant forces, scenes in blocks of 512 stored as structure-of-arrays so that the
  loop over scenes vectorizes (AVX), divisions by per-scene constants hoisted out of the step loop,
  ``-O3 -march=native``, OpenMP over blocks. It measures what restructuring the batch driver would
  give, and is checked against the package's compiled path.

Checks: the compiled and NumPy paths agree on every final state; scenes without load stop where
the exact solution stops (|x - x*| <= B h^2/8, stop time within h); no lift-off (max |gap| <= 1e-12).
"""
from __future__ import annotations

import argparse
import csv
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from lcp.timestepping import compiled_step as compiled
from lcp.batch import jean_pratt_constants, simulate_batch

TARGET = 3e7  # scene-steps per second

#: prototype kernel (see the module docstring): state rows q0 q1 v0 v1 cq0 cq1 cv0 cv1 nslide maxgap,
#: constants rows as lcp.batch.jean_pratt_constants (a, SHt, W, H row-major, gap0, mu, e, h, theta)
SOA_SOURCE = r"""#include <math.h>
#include <stdlib.h>
#define BLK 512
/* Z: state, row per scene (10 doubles: q0 q1 v0 v1 cq0 cq1 cv0 cv1 nslide maxgap)
   C: constants, row per scene (19): a0 a1 SHt00 SHt01 SHt10 SHt11 W00 W01 W10 W11 H00 H01 H10 H11 gap0 mu e h th */
int soa_run(double* Z, const double* C, long nscenes, long steps) {
  #pragma omp parallel for schedule(dynamic, 1)
  for (long b0 = 0; b0 < nscenes; b0 += BLK) {
    long nb = nscenes - b0 < BLK ? nscenes - b0 : BLK;
    double q0[BLK], q1[BLK], v0[BLK], v1[BLK], cq0[BLK], cq1[BLK], cv0[BLK], cv1[BLK], ns[BLK], mg[BLK];
    double a0[BLK], a1[BLK], s00[BLK], s01[BLK], s10[BLK], s11[BLK], W00[BLK], W01[BLK], W10[BLK], W11[BLK];
    double H00[BLK], H01[BLK], H10[BLK], H11[BLK], g0[BLK], mu[BLK], e[BLK], h[BLK], th[BLK];
    double iW00[BLK], iW11[BLK], idet[BLK], detok[BLK], iap[BLK], okp[BLK], iam[BLK], okm[BLK];
    for (long j = 0; j < nb; ++j) {
      const double* z = Z + (b0 + j) * 10; const double* c = C + (b0 + j) * 19;
      q0[j]=z[0]; q1[j]=z[1]; v0[j]=z[2]; v1[j]=z[3]; cq0[j]=z[4]; cq1[j]=z[5]; cv0[j]=z[6]; cv1[j]=z[7]; ns[j]=z[8]; mg[j]=z[9];
      a0[j]=c[0]; a1[j]=c[1]; s00[j]=c[2]; s01[j]=c[3]; s10[j]=c[4]; s11[j]=c[5];
      W00[j]=c[6]; W01[j]=c[7]; W10[j]=c[8]; W11[j]=c[9]; H00[j]=c[10]; H01[j]=c[11]; H10[j]=c[12]; H11[j]=c[13];
      g0[j]=c[14]; mu[j]=c[15]; e[j]=c[16]; h[j]=c[17]; th[j]=c[18];
      iW00[j] = 1.0 / W00[j]; iW11[j] = 1.0 / W11[j];
      double det = W00[j]*W11[j] - W01[j]*W10[j]; detok[j] = det > 0; idet[j] = 1.0 / (det > 0 ? det : 1.0);
      double ap = W00[j] - mu[j]*W01[j]; okp[j] = ap > 0; iap[j] = 1.0 / (ap > 0 ? ap : 1.0);
      double am = W00[j] + mu[j]*W01[j]; okm[j] = am > 0; iam[j] = 1.0 / (am > 0 ? am : 1.0);
    }
    for (long k = 0; k < steps; ++k) {
      #pragma omp simd
      for (long j = 0; j < nb; ++j) {
        double vf0 = v0[j] + a0[j], vf1 = v1[j] + a1[j];
        double uNm = H00[j]*v0[j] + H01[j]*v1[j];
        double uNf = H00[j]*vf0 + H01[j]*vf1;
        double uTf = H10[j]*vf0 + H11[j]*vf1;
        double gap = g0[j] + H00[j]*q0[j] + H01[j]*q1[j];
        long active = gap + h[j]*((1 - th[j])*uNm + th[j]*uNf) <= 0;
        double qN = uNf + e[j]*uNm, qT = uTf;
        double sa = fabs(qN)*iW00[j], sb = fabs(qT)*iW11[j]; double sc = sa > sb ? sa : sb; sc = sc > 1e-300 ? sc : 1e-300;
        double tol = 1e-12 * sc;
        long open_ok = qN*iW00[j] >= -tol;
        double pNs = (-qN*W11[j] + qT*W01[j]) * idet[j];
        double pTs = (-qT*W00[j] + qN*W10[j]) * idet[j];
        long st_ok = detok[j] != 0 & pNs >= -tol & fabs(pTs) <= mu[j]*pNs + tol;
        double pNp = -qN * iap[j];
        double uTp = (W10[j] - mu[j]*W11[j])*pNp + qT;
        long sp_ok = okp[j] != 0 & pNp >= -tol & uTp*iW11[j] > -tol;
        double pNm = -qN * iam[j];
        double uTm = (W10[j] + mu[j]*W11[j])*pNm + qT;
        long sm_ok = okm[j] != 0 & pNm >= -tol & uTm*iW11[j] < tol;
        double pN = open_ok ? 0.0 : (st_ok ? pNs : (sp_ok ? pNp : (sm_ok ? pNm : NAN)));
        double pT = open_ok ? 0.0 : (st_ok ? pTs : (sp_ok ? -mu[j]*pNp : (sm_ok ? mu[j]*pNm : NAN)));
        long sliding = (!open_ok) & (!st_ok) & (sp_ok | sm_ok);
        pN = active ? pN : 0.0; pT = active ? pT : 0.0;
        double i0 = a0[j] + s00[j]*pN + s01[j]*pT, i1 = a1[j] + s10[j]*pN + s11[j]*pT;
        double y0 = i0 - cv0[j], y1 = i1 - cv1[j];
        double t0 = v0[j] + y0, t1 = v1[j] + y1;
        cv0[j] = (t0 - v0[j]) - y0; cv1[j] = (t1 - v1[j]) - y1;
        double w0 = h[j]*((1 - th[j])*v0[j] + th[j]*t0) - cq0[j];
        double w1 = h[j]*((1 - th[j])*v1[j] + th[j]*t1) - cq1[j];
        v0[j] = t0; v1[j] = t1;
        double r0 = q0[j] + w0, r1 = q1[j] + w1;
        cq0[j] = (r0 - q0[j]) - w0; cq1[j] = (r1 - q1[j]) - w1;
        q0[j] = r0; q1[j] = r1;
        ns[j] += (active & sliding) ? 1.0 : 0.0;
        double ag = fabs(gap); mg[j] = mg[j] > ag ? mg[j] : ag;
      }
    }
    for (long j = 0; j < nb; ++j) {
      double* z = Z + (b0 + j) * 10;
      z[0]=q0[j]; z[1]=q1[j]; z[2]=v0[j]; z[3]=v1[j]; z[4]=cq0[j]; z[5]=cq1[j]; z[6]=cv0[j]; z[7]=cv1[j]; z[8]=ns[j]; z[9]=mg[j];
    }
  }
  return 0;
}
"""
G = 9.81


def parameters(n, seed=0):
    rng = np.random.default_rng(seed)
    m, M = rng.uniform(0.5, 2.0, n), rng.uniform(0.5, 2.0, n)
    alpha = rng.uniform(0.2, 1.2, n)
    t = np.tan(alpha)
    A = m + M * t * t
    kappa = rng.uniform(0.05, 0.95, n)
    R = kappa * A / (M * t)
    v0 = rng.uniform(-2.0, 2.0, n)
    loaded = rng.uniform(size=n) < 0.3
    phi = np.where(loaded, rng.uniform(-0.9, 0.9, n) * R * (m + M) * G, 0.0)
    return dict(m=m, M=M, alpha=alpha, R=R, v0=v0, phi=phi, kappa=kappa, A=A, t=t)


def exact_stops(p):
    """Stop distance and time of the unloaded scenes (phi = 0): slide against friction, then stick."""
    s = np.sign(p["v0"])
    B = p["R"] * (p["m"] + p["M"]) * G / (p["A"] * (1.0 - s * p["kappa"]))
    return p["v0"] * np.abs(p["v0"]) / (2 * B), np.abs(p["v0"]) / B, B


def run(c, steps, h, path, repeats):
    times, res = [], None
    for _ in range(repeats):
        res = simulate_batch(c, steps * h, h=h, path=path)
        times.append(res.run_time)
    return statistics.median(times), res


_CHILD = r"""
import json, sys, time
import numpy as np
sys.path.insert(0, {here!r})
from batch_throughput import parameters
from lcp.batch import jean_pratt_constants, simulate_batch
p = parameters({n})
c = jean_pratt_constants(p["m"], p["M"], p["alpha"], p["R"], p["v0"], phi=p["phi"], h={h!r})
t0 = time.perf_counter()
r = simulate_batch(c, {steps} * {h!r}, h={h!r}, path="compiled")
print(json.dumps(dict(compile_time=r.compile_time, run_time=r.run_time, total=time.perf_counter() - t0,
                      rate=r.scene_steps_per_second, openmp=r.stats["openmp"])))
"""


def child(n, steps, h, env_extra):
    env = dict(os.environ, **env_extra)
    code = _CHILD.format(here=str(Path(__file__).parent), n=n, steps=steps, h=h)
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=1800)
    if out.returncode:
        raise RuntimeError(out.stderr[-2000:])
    return json.loads(out.stdout.strip().splitlines()[-1])


def soa_prototype():
    """Compile the prototype kernel into a temporary folder; a ctypes function or None."""
    import ctypes

    cc = compiled.c_compiler()
    if cc is None:
        return None
    tmp = tempfile.mkdtemp(prefix="lcp_soa_")
    src, lib = Path(tmp) / "soa.c", Path(tmp) / "soa.so"
    src.write_text(SOA_SOURCE)
    flags = ["-O3", "-march=native", "-fPIC", "-shared"] + (["-fopenmp"] if compiled.openmp_available() else [])
    try:
        subprocess.run([cc, *flags, str(src), "-o", str(lib), "-lm"], check=True, capture_output=True, timeout=300)
    except (subprocess.SubprocessError, OSError):
        return None
    fn = ctypes.CDLL(str(lib)).soa_run
    dp = ctypes.POINTER(ctypes.c_double)
    fn.argtypes = [dp, dp, ctypes.c_long, ctypes.c_long]
    fn.restype = ctypes.c_int
    return fn


def run_soa(fn, c, x0, steps, repeats):
    import ctypes

    dp = ctypes.POINTER(ctypes.c_double)
    times, Z = [], None
    Cr = np.ascontiguousarray(c.T)
    for _ in range(repeats):
        Z = np.ascontiguousarray(np.vstack([x0, np.zeros((2, x0.shape[1]))]).T)
        t0 = time.perf_counter()
        fn(Z.ctypes.data_as(dp), Cr.ctypes.data_as(dp), Z.shape[0], steps)
        times.append(time.perf_counter() - t0)
    return statistics.median(times), Z


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="1e4 scenes, fewer steps")
    ap.add_argument("--scenes", type=int, default=None)
    ap.add_argument("--steps", type=int, default=None, help="steps of the compiled runs (default 1000)")
    ap.add_argument("--no-prototype", action="store_true", help="skip the SoA prototype kernel")
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "out")
    args = ap.parse_args(argv)
    n = args.scenes or (10_000 if args.quick else 100_000)
    steps = args.steps or (200 if args.quick else 1000)
    steps_np = max(10, steps // 10)
    h = 1e-3
    reps = 3
    load0 = os.getloadavg()
    p = parameters(n)
    t0 = time.perf_counter()
    c = jean_pratt_constants(p["m"], p["M"], p["alpha"], p["R"], p["v0"], phi=p["phi"], h=h)
    t_pack = time.perf_counter() - t0

    # compile time: a cold build with an empty cache, in a fresh process
    with tempfile.TemporaryDirectory() as tmp:
        cold = child(1000, 10, h, {"LCP_LEM_CACHE": tmp})
    # warm: the cached library, loaded once in this process
    t0 = time.perf_counter()
    compiled.batch_library(2)
    t_load = time.perf_counter() - t0

    t_comp, r_comp = run(c, steps, h, "compiled", reps)
    t_np, r_np = run(c, steps_np, h, "numpy", reps)
    _, r_c_short = run(c, steps_np, h, "compiled", 1)
    single = child(n, max(10, steps // 5), h, {"OMP_NUM_THREADS": "1"})
    soa = None if args.no_prototype else soa_prototype()
    if soa is not None:
        t_soa, _ = run_soa(soa, c[0], c[1], steps, reps)
        _, Z_short = run_soa(soa, c[0], c[1], steps_np, 1)
        soa_agree = float(max(np.max(np.abs(Z_short[:, :2] - r_c_short.q)), np.max(np.abs(Z_short[:, 2:4] - r_c_short.v))))
        soa_slides = bool(np.array_equal(Z_short[:, 8].astype(np.int64), r_c_short.slide_steps))
    load1 = os.getloadavg()

    rate_comp = n * steps / t_comp
    rate_np = n * steps_np / t_np
    # checks
    agree = float(max(np.max(np.abs(r_c_short.q - r_np.q)), np.max(np.abs(r_c_short.v - r_np.v))))
    x_star, tau0, B = exact_stops(p)
    T = steps * h
    free = (p["phi"] == 0.0) & (tau0 < T - 2 * h)
    x_err = np.abs(r_comp.q[free, 0] - x_star[free])
    stop_err = np.abs(r_comp.slide_steps[free] * h - tau0[free])
    ok_x = bool(np.all(x_err <= B[free] * h * h / 8 + 1e-12))
    ok_stop = bool(np.all(stop_err <= h * (1 + 1e-9)))
    gap = float(np.max(r_comp.max_abs_gap))
    step = compiled.step_function(2, False, True)
    rows = [
        dict(path="compiled (C + OpenMP, all threads)", scenes=n, steps=steps, run_time_s=t_comp,
             scene_steps_per_s=rate_comp, ns_per_scene_step=1e9 / rate_comp, note=f"openmp={r_comp.stats['openmp']}"),
        dict(path="compiled, OMP_NUM_THREADS=1 (subprocess)", scenes=n, steps=max(10, steps // 5),
             run_time_s=single["run_time"], scene_steps_per_s=single["rate"], ns_per_scene_step=1e9 / single["rate"],
             note="one core"),
        dict(path="numpy (plain loop over steps, arrays of scenes)", scenes=n, steps=steps_np, run_time_s=t_np,
             scene_steps_per_s=rate_np, ns_per_scene_step=1e9 / rate_np, note="single thread"),
    ]
    if soa is not None:
        rows.append(dict(path="SoA prototype (not package code; AVX, OpenMP)", scenes=n, steps=steps, run_time_s=t_soa,
                         scene_steps_per_s=n * steps / t_soa, ns_per_scene_step=1e9 * t_soa / (n * steps),
                         note=f"agrees with compiled to {soa_agree:.1e}, slide counts equal: {soa_slides}"))
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "batch_throughput.csv"
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        for r in rows:
            w.writerow({k: repr(v) if isinstance(v, float) else v for k, v in r.items()})
        fh.write(f"# compile_cold_s={cold['compile_time']!r}, load_warm_s={t_load!r}, pack_s={t_pack!r}, "
                 f"load_before={load0}, load_after={load1}, cores={os.cpu_count()}\n")
    print(f"{n} Jean-Pratt scenes (random m, M, alpha, kappa in [0.05, 0.95], v0, 30 % loaded), h = {h:g}, "
          f"theta = 1/2; {os.cpu_count()} cores, load average before {tuple(round(x, 2) for x in load0)}, "
          f"after {tuple(round(x, 2) for x in load1)}")
    print()
    print("| path | scenes | steps | run time (s) | scene-steps/s | ns per scene-step |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['path']} | {r['scenes']} | {r['steps']} | {r['run_time_s']:.3g} | {r['scene_steps_per_s']:.3g} | "
              f"{r['ns_per_scene_step']:.3g} |")
    print()
    print(f"compile time (cold, empty cache, fresh process): {cold['compile_time']:.3g} s; "
          f"load of the cached library: {t_load:.3g} s; packing the constants: {t_pack:.3g} s")
    print(f"compiled / numpy: {rate_comp / rate_np:.2f}x; target >= {TARGET:.0e} scene-steps/s: "
          f"{'met' if rate_comp >= TARGET else 'NOT met'} ({rate_comp:.3g})")
    print(f"step: {step.n_instructions()} CasADi instructions per scene-step ({generated_divisions(step)} "
          f"divisions, {generated_branches(step)} selects in the generated C)")
    print(f"checks: compiled == numpy to {agree:.1e}; unloaded scenes that stopped ({int(free.sum())}): "
          f"max |x - x*| / (B h^2/8) = {np.max(x_err / (B[free] * h * h / 8)):.3f} -> {'pass' if ok_x else 'FAIL'}; "
          f"stop time within h: {'pass' if ok_stop else 'FAIL'}; max |gap| = {gap:.1e} -> "
          f"{'pass' if gap <= 1e-12 else 'FAIL'}; all finite: {bool(r_comp.success.all())}")
    if soa is not None:
        print(f"SoA prototype: {n * steps / t_soa:.3g} scene-steps/s ({n * steps / t_soa / rate_comp:.2f}x the package's "
              f"compiled path); agrees with it to {soa_agree:.1e}, slide counts equal: {soa_slides}")
    print(f"written to {path}")
    return rows


def _c_body(step):
    code = compiled.generate_c(step).decode()
    return code[code.find("static int casadi_f0"):]


def generated_divisions(step):
    return sum(line.count("/") for line in _c_body(step).splitlines() if "=" in line and "//" not in line)


def generated_branches(step):
    return sum(line.count("?") for line in _c_body(step).splitlines())


if __name__ == "__main__":
    main()
