"""Cost of Moreau-Jean's position projection on the pendulum written with a constraint, and what it buys.

Run: ``python benchmarks/projection_cost.py [--quick] [--periods P] [--repeats K] [--out DIR]``.
Prints two tables and writes ``projection_cost.csv`` and ``projection_accuracy.csv`` into
``benchmarks/out/`` (untracked; ``--out`` writes elsewhere).

Scene: :func:`lcp.classical.pendulum` (L = 1, released at 90 degrees from rest, q = (x, y) with
x^2 + y^2 - L^2 = 0), h = 1e-3, theta = 1/2.

1. Cost: the same run (``--periods`` exact periods, 10 by default) with ``projection=True`` and
   ``projection=False``, alternated K times (so a change of load hits both), each timed whole;
   per-step cost = median time / steps, and the ratio projected / unprojected of the medians.
2. Accuracy: 100 periods with and without the projection (relative length error, mean period from
   the downward zero crossings of x, its error against 4 K(sin(theta0/2)) sqrt(L/g)), and the
   first swing's period error at h = 4e-3, 2e-3, 1e-3, 5e-4 with its observed order.
"""
from __future__ import annotations

import argparse
import csv
import os
import statistics
import time
from pathlib import Path

import numpy as np

import lcp
from lcp.classical import pendulum

# this script times the compiled loops: its short runs must not take the Python loop while a
# kernel is not loaded yet (lcp.timestepping.first_compile)
os.environ.setdefault("LCP_COMPILE", "always")



def _crossings(t, x):
    i = np.flatnonzero((x[:-1] > 0) & (x[1:] <= 0))
    return t[i] + x[i] / (x[i] - x[i + 1]) * (t[i + 1] - t[i])


def cost(periods: float, repeats: int, h: float = 1e-3):
    sc = pendulum(periods=periods)
    times = {True: [], False: []}
    steps = 0
    lcp.simulate(sc, h=h, t_end=20 * h)  # warm-up: CasADi functions built once per system
    for _ in range(repeats):
        for proj in (False, True):
            t0 = time.perf_counter()
            res = lcp.simulate(sc, h=h, projection=proj, save_every=10)
            times[proj].append(time.perf_counter() - t0)
            assert res.success, res.message
            steps = res.stats.steps
    med = {k: statistics.median(v) for k, v in times.items()}
    return dict(steps=steps, us_plain=1e6 * med[False] / steps, us_projected=1e6 * med[True] / steps,
                ratio=med[True] / med[False], spread_plain=(min(times[False]), max(times[False])),
                spread_projected=(min(times[True]), max(times[True])))


def accuracy(periods: float, h: float = 1e-3):
    sc = pendulum(periods=periods)
    T = sc.solution.period
    rows = []
    for proj in (True, False):
        res = lcp.simulate(sc, h=h, projection=proj)
        assert res.success, res.message
        tc = _crossings(res.t, res.q[:, 0])
        length = np.hypot(res.q[:, 0], res.q[:, 1])
        rows.append(dict(what=f"{periods:g} periods, h = {h:g}", projection=proj,
                         length_error=float(np.max(np.abs(length - 1.0))), final_length=float(length[-1]),
                         mean_period_error=float((np.mean(np.diff(tc)) - T) / T),
                         max_violation=res.max_constraint_violation,
                         newton_per_step=res.stats.projection_iterations / max(1, res.stats.projections)))
    return rows


def order(hs=(4e-3, 2e-3, 1e-3, 5e-4)):
    sc = pendulum(periods=1.5)
    T = sc.solution.period
    errs = []
    for h in hs:
        res = lcp.simulate(sc, h=h)
        tc = _crossings(res.t, res.q[:, 0])
        errs.append(abs(tc[1] - tc[0] - T) / T)
    slope = float(np.polyfit(np.log(hs), np.log(errs), 1)[0])
    return list(zip(hs, errs)), slope


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="2 periods, 3 repeats, 10 periods for accuracy")
    ap.add_argument("--periods", type=float, default=None, help="periods per timed run (default 10)")
    ap.add_argument("--repeats", type=int, default=None, help="alternated repeats (default 5)")
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "out")
    args = ap.parse_args(argv)
    periods = args.periods or (2 if args.quick else 10)
    repeats = args.repeats or (3 if args.quick else 5)
    load0 = os.getloadavg()
    c = cost(periods, repeats)
    load1 = os.getloadavg()
    print(f"Pendulum, h = 1e-3, {c['steps']} steps per run, median of {repeats} alternated runs "
          f"(load {load0[0]:.2f} -> {load1[0]:.2f}, {os.cpu_count()} cores)")
    print(f"{'path':28s} {'us/step':>9s}")
    print(f"{'unprojected':28s} {c['us_plain']:9.1f}")
    print(f"{'projected':28s} {c['us_projected']:9.1f}")
    print(f"ratio projected / unprojected: {c['ratio']:.3f}")
    acc = accuracy(10 if args.quick else 100)
    print(f"\n{'run':22s} {'proj':>5s} {'max |len - L|/L':>16s} {'final len':>10s} {'mean period err':>16s} "
          f"{'violation':>10s} {'Newton/step':>11s}")
    for r in acc:
        print(f"{r['what']:22s} {str(r['projection']):>5s} {r['length_error']:16.3e} {r['final_length']:10.4f} "
              f"{r['mean_period_error']:16.3e} {r['max_violation']:10.2e} {r['newton_per_step']:11.2f}")
    pts, slope = order()
    print("\nfirst swing's period error (projected): "
          + ", ".join(f"h = {h:g}: {e:.3e}" for h, e in pts) + f"; observed order {slope:.2f}")
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "projection_cost.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["steps", "repeats", "us_per_step_unprojected", "us_per_step_projected", "ratio", "load_before",
                    "load_after"])
        w.writerow([c["steps"], repeats, c["us_plain"], c["us_projected"], c["ratio"], load0[0], load1[0]])
    with open(args.out / "projection_accuracy.csv", "w", newline="") as f:
        w = csv.writer(f)
        keys = list(acc[0])
        w.writerow(keys)
        for r in acc:
            w.writerow([r[k] for k in keys])
        for h, e in pts:
            w.writerow([f"first swing, h = {h:g}", True, "", "", e, "", ""])
    print(f"\nwritten to {args.out}/projection_cost.csv, projection_accuracy.csv")
    return c, acc, (pts, slope)


if __name__ == "__main__":
    main()
