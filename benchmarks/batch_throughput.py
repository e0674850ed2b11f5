"""Batch-mode throughput: Jean-Pratt scenes with different parameters stepped together.

Run: ``python benchmarks/batch_throughput.py [--quick] [--sizes 1000,10000,100000] [--rounds R]``.
Prints tables and writes ``benchmarks/out/batch_throughput.csv`` (untracked; ``--out`` elsewhere).

Scenes: m, M uniform in [0.5, 2], alpha in [0.2, 1.2], R such that kappa is uniform in [0.05, 0.95],
v0 uniform in [-2, 2]; 30 % of them carry a tangential load phi = f R (m+M) g with f uniform in
[-0.9, 0.9] (a loaded stick after the stop). h = 1e-3, theta = 1/2.

Measured in one run, rounds alternating the paths (the machine is shared: ratios within a round
are what counts; the median of the rounds' ratios is reported), scene-steps per second = scenes x
steps / run time:

- ``compiled``: :func:`lcp.batch.simulate_batch` with ``path="compiled"`` (the numba kernel of
  :mod:`lcp.sweeps.batch_kernel`), all cores, and with ``threads=1``;
- ``numpy``: the same closed-form step on arrays of scenes (``path="numpy"``), a NumPy-vectorised
  loop over steps;
- the arithmetic limit: operations per scene-step counted on the step's SX instructions, and the
  machine's peak for them measured by simple numba kernels (vectorised multiply-add chains,
  vectorised division chains) on all cores;
- compile time: a cold build in a fresh process with an empty cache (``LCP_CACHE_DIR``), and the
  warm load of the cached kernel in a fresh process.

Checks: the compiled and NumPy paths agree on every final state; scenes without load stop where
the exact solution stops (|x - x*| <= B h^2/8, stop time within h); no lift-off (max |gap| <= 1e-12).
"""
from __future__ import annotations

import argparse
from collections import Counter
import csv
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import casadi as ca
import numpy as np

from lcp.batch import jean_pratt_constants, simulate_batch
from lcp.numerics.jit import njit
from lcp.timestepping import compiled_step as compiled

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


_CHILD = r"""
import json, time
t0 = time.perf_counter()
import numpy as np
from lcp.batch import jean_pratt_constants, simulate_batch
t1 = time.perf_counter()
r = simulate_batch(jean_pratt_constants(1.0, 1.0, 0.7, np.linspace(0.1, 0.9, 1000), h=1e-3), 0.01, h=1e-3)
print(json.dumps(dict(import_s=t1 - t0, compile_s=r.compile_time, total_s=time.perf_counter() - t0)))
"""


def child(env_extra, drop=()):
    env = {k: v for k, v in os.environ.items() if k not in drop}
    env.update(env_extra)
    out = subprocess.run([sys.executable, "-c", _CHILD], env=env, capture_output=True, text=True, timeout=1800)
    if out.returncode:
        raise RuntimeError(out.stderr[-2000:])
    return json.loads(out.stdout.strip().splitlines()[-1])


#: the SX operations of the step, by what they cost: floating-point arithmetic (add, sub, mul, neg,
#: sq, twice), divisions, and the rest (comparisons, selects, abs, min/max: one vector op each)
_FLOPS = {"OP_ADD", "OP_SUB", "OP_MUL", "OP_NEG", "OP_SQ", "OP_TWICE"}
_FREE = {"OP_INPUT", "OP_OUTPUT", "OP_CONST"}


def op_counts():
    step = compiled.step_function(2, False, True)
    names = {getattr(ca, k): k for k in dir(ca) if k.startswith("OP_")}
    ops = Counter(names[step.instruction_id(k)] for k in range(step.n_instructions()))
    flops = sum(v for k, v in ops.items() if k in _FLOPS)
    div = ops.get("OP_DIV", 0)
    other = sum(v for k, v in ops.items() if k not in _FLOPS and k not in _FREE and k != "OP_DIV")
    return flops, div, other, ops


@njit(nogil=True, cache=True)
def _peak_madd(x, reps):
    """32 flops per element and repetition in 16 independent multiply-add chains (no FMA: numba
    compiles without fastmath, as the batch kernel); the loop over elements vectorises."""
    for _ in range(reps):
        for j in range(x.shape[0]):
            y = x[j]
            a0 = y; a1 = y + 1.0; a2 = y + 2.0; a3 = y + 3.0; a4 = y + 4.0; a5 = y + 5.0; a6 = y + 6.0; a7 = y + 7.0
            for _r in range(2):
                a0 = a0 * 0.999 + 0.001; a1 = a1 * 0.999 + 0.001; a2 = a2 * 0.999 + 0.001; a3 = a3 * 0.999 + 0.001
                a4 = a4 * 0.999 + 0.001; a5 = a5 * 0.999 + 0.001; a6 = a6 * 0.999 + 0.001; a7 = a7 * 0.999 + 0.001
            x[j] = ((a0 + a1) + (a2 + a3)) + ((a4 + a5) + (a6 + a7)) - 28.0 * 0.125
    return x


@njit(nogil=True, cache=True, error_model="numpy")
def _peak_div(x, reps):
    """8 divisions per element and repetition, in 8 independent chains; vectorised over elements."""
    for _ in range(reps):
        for j in range(x.shape[0]):
            y = x[j]
            a0 = 1.0 / y; a1 = 2.0 / y; a2 = 3.0 / y; a3 = 4.0 / y; a4 = 5.0 / y; a5 = 6.0 / y; a6 = 7.0 / y; a7 = 8.0 / y
            x[j] = 1.0 + 1e-9 * (((a0 + a1) + (a2 + a3)) + ((a4 + a5) + (a6 + a7)))
    return x


def peak(kernel, per_element, threads, reps=100_000, width=256):
    """Operations per second of ``kernel`` on all threads (L1-resident arrays, one per thread)."""
    from concurrent.futures import ThreadPoolExecutor

    xs = [np.full(width, 1.0) for _ in range(threads)]
    kernel(xs[0], 1)
    t0 = time.perf_counter()
    with ThreadPoolExecutor(threads) as pool:
        list(pool.map(lambda x: kernel(x, reps), xs))
    return threads * width * reps * per_element / (time.perf_counter() - t0)


def limits(p_madd, p_div):
    """The step's arithmetic limit in scene-steps/s, (low, high): every non-division operation on
    the multiply/add pipes at ``p_madd`` per second, divisions at ``p_div``; the two in series
    (low) or overlapped (high)."""
    flops, div, other, _ = op_counts()
    t_flop, t_div = (flops + other) / p_madd, div / p_div
    return 1 / (t_flop + t_div), 1 / max(t_flop, t_div)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="sizes 1e3, 1e4 and fewer rounds")
    ap.add_argument("--sizes", type=str, default=None, help="comma-separated scene counts (default 1e3,1e4,1e5)")
    ap.add_argument("--rounds", type=int, default=None, help="alternating rounds per size (default 5)")
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "out")
    args = ap.parse_args(argv)
    sizes = [int(float(s)) for s in args.sizes.split(",")] if args.sizes else (
        [1000, 10_000] if args.quick else [1000, 10_000, 100_000])
    rounds = args.rounds or (3 if args.quick else 5)
    h = 1e-3
    threads = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    load0 = os.getloadavg()

    with tempfile.TemporaryDirectory() as tmp:
        cold = child({"LCP_CACHE_DIR": tmp}, drop=("NUMBA_CACHE_DIR",))
        warm = child({"LCP_CACHE_DIR": tmp}, drop=("NUMBA_CACHE_DIR",))

    rows, checks = [], []
    for n in sizes:
        p = parameters(n)
        c = jean_pratt_constants(p["m"], p["M"], p["alpha"], p["R"], p["v0"], phi=p["phi"], h=h)
        # about 2e7 scene-steps per compiled run, 2e6 per NumPy run; at least 10 steps
        steps = max(10, int(2e7 // n))
        steps_np = max(10, int(2e6 // n))
        simulate_batch(c, 10 * h, h=h, path="compiled")  # compiled or loaded before timing
        rates = {"compiled": [], "compiled1": [], "numpy": []}
        ratio, ratio1, frac_lo, frac_hi = [], [], [], []
        for _ in range(rounds):
            # the machine's peak measured in the same round: the fraction of the limit is a ratio too
            lim_lo, lim_hi = limits(peak(_peak_madd, 34, threads), peak(_peak_div, 8, threads))
            r_c = simulate_batch(c, steps * h, h=h, path="compiled")
            r_1 = simulate_batch(c, steps * h, h=h, path="compiled", threads=1)
            r_n = simulate_batch(c, steps_np * h, h=h, path="numpy")
            rates["compiled"].append(r_c.scene_steps_per_second)
            rates["compiled1"].append(r_1.scene_steps_per_second)
            rates["numpy"].append(r_n.scene_steps_per_second)
            ratio.append(rates["compiled"][-1] / rates["numpy"][-1])
            ratio1.append(rates["compiled1"][-1] / rates["numpy"][-1])
            frac_lo.append(rates["compiled"][-1] / lim_lo)
            frac_hi.append(rates["compiled"][-1] / lim_hi)
        rows.append(dict(scenes=n, steps=steps, steps_numpy=steps_np, threads=r_c.stats["threads"],
                         compiled=statistics.median(rates["compiled"]), compiled_1thread=statistics.median(rates["compiled1"]),
                         numpy=statistics.median(rates["numpy"]), ratio=statistics.median(ratio),
                         ratio_1thread=statistics.median(ratio1), ratio_min=min(ratio),
                         of_limit_overlapped=statistics.median(frac_hi), of_limit_in_series=statistics.median(frac_lo)))
        # checks on the last compiled run, and the two paths on the same steps
        r_cs = simulate_batch(c, steps_np * h, h=h, path="compiled")
        agree = float(max(np.max(np.abs(r_cs.q - r_n.q)), np.max(np.abs(r_cs.v - r_n.v))))
        x_star, tau0, B = exact_stops(p)
        T = steps * h
        free = (p["phi"] == 0.0) & (tau0 < T - 2 * h)
        ok_x = bool(np.all(np.abs(r_c.q[free, 0] - x_star[free]) <= B[free] * h * h / 8 + 1e-12))
        ok_stop = bool(np.all(np.abs(r_c.slide_steps[free] * h - tau0[free]) <= h * (1 + 1e-9)))
        gap = float(np.max(r_c.max_abs_gap))
        checks.append(f"{n} scenes: compiled = numpy to {agree:.1e}; {int(free.sum())} unloaded scenes stopped: "
                      f"stop distance within B h^2/8 {'pass' if ok_x else 'FAIL'}, stop time within h "
                      f"{'pass' if ok_stop else 'FAIL'}; max |gap| = {gap:.1e} {'pass' if gap <= 1e-12 else 'FAIL'}; "
                      f"all finite: {bool(r_c.success.all())}")

    flops, div, other, ops = op_counts()
    p_madd = statistics.median(peak(_peak_madd, 34, threads) for _ in range(3))
    p_div = statistics.median(peak(_peak_div, 8, threads) for _ in range(3))
    lim_lo, lim_hi = limits(p_madd, p_div)
    load1 = os.getloadavg()

    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "batch_throughput.csv"
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        for r in rows:
            w.writerow({k: repr(v) if isinstance(v, float) else v for k, v in r.items()})
        fh.write(f"# cold={cold}, warm={warm}, flops={flops}, div={div}, other={other}, peak_madd={p_madd!r}, "
                 f"peak_div={p_div!r}, load_before={load0}, load_after={load1}, threads={threads}\n")
    print(f"Jean-Pratt scenes (random m, M, alpha, kappa in [0.05, 0.95], v0, 30 % loaded), h = {h:g}, theta = 1/2; "
          f"{threads} threads, load average before {tuple(round(x, 2) for x in load0)}, after "
          f"{tuple(round(x, 2) for x in load1)}; {rounds} alternating rounds, medians")
    print()
    print("| scenes | compiled (scene-steps/s) | compiled, 1 thread | numpy | compiled / numpy (min) | 1 thread / numpy "
          "| of the arithmetic limit |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['scenes']} | {r['compiled']:.3g} | {r['compiled_1thread']:.3g} | {r['numpy']:.3g} | "
              f"{r['ratio']:.1f}x ({r['ratio_min']:.1f}x) | {r['ratio_1thread']:.1f}x | "
              f"{r['of_limit_overlapped']:.0%} to {r['of_limit_in_series']:.0%} |")
    print()
    print(f"per scene-step: {flops} flops (add/sub/mul/neg), {div} divisions, {other} other vector ops "
          f"(comparisons, selects, abs, min/max); {dict(ops)}")
    print(f"measured peak at the end, {threads} threads: {p_madd:.3g} multiply/add flops/s, {p_div:.3g} divisions/s: "
          f"arithmetic limit of the step {lim_lo:.3g} (pipes in series) to {lim_hi:.3g} (overlapped) scene-steps/s "
          f"(the table's fractions use the peaks measured in each round)")
    print(f"compile (fresh process, empty cache): {cold['compile_s']:.3g} s; load of the cached kernel "
          f"(fresh process): {warm['compile_s']:.3g} s; import of lcp.batch: {warm['import_s']:.3g} s")
    for line in checks:
        print("checks:", line)
    print(f"written to {path}")
    return rows


if __name__ == "__main__":
    main()
