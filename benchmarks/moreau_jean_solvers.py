"""Time against error of Moreau-Jean on the Jean-Pratt scene, per one-step solver and step size.

Run: ``python benchmarks/moreau_jean_solvers.py [--quick]``. Prints a table and writes
``benchmarks/out/moreau_jean_solvers.csv`` (untracked; pass ``--out`` to write elsewhere). Times are medians of repeats in one run, so the
ratios between solvers are meaningful even on a shared machine.
"""
from __future__ import annotations

import argparse
import csv
import statistics
import time
from pathlib import Path

import numpy as np

import lcp


def measure(scene, h, solver, theta=0.5, repeats=3):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = lcp.simulate(scene, scene.t_end, h=h, theta=theta, solver=solver)
        times.append(time.perf_counter() - t0)
    ex = scene.exact(res.t)
    return dict(solver=solver, theta=theta, h=h, steps=res.stats.steps, time_s=statistics.median(times),
                us_per_step=1e6 * statistics.median(times) / res.stats.steps,
                max_x_error=float(np.max(np.abs(res.q[:, 0] - ex["x"]))),
                bound=scene.B * h * h / 8, max_abs_y=float(np.max(np.abs(res.q[:, 1]))),
                max_residual=res.stats.max_residual, iterations=res.stats.iterations,
                qp_solves=res.stats.qp_solves, success=res.success)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "out")
    args = ap.parse_args(argv)
    scene = lcp.scenes.jean_pratt()
    hs = [1e-2, 1e-3] if args.quick else [1e-2, 1e-3, 1e-4, 1e-5]
    rows = []
    for h in hs:
        for solver in ("enum", "lemke", "osqp"):
            rows.append(measure(scene, h, solver, repeats=1 if args.quick or h < 1e-4 else 3))
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "moreau_jean_solvers.csv"
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    print(f"{'solver':7s} {'h':>7s} {'steps':>7s} {'time (s)':>9s} {'us/step':>8s} {'max|x-ex|':>10s} "
          f"{'Bh^2/8':>9s} {'max|y|':>8s} {'residual':>9s} {'QPs':>6s}")
    for r in rows:
        print(f"{r['solver']:7s} {r['h']:7.0e} {r['steps']:7d} {r['time_s']:9.3f} {r['us_per_step']:8.1f} "
              f"{r['max_x_error']:10.2e} {r['bound']:9.2e} {r['max_abs_y']:8.1e} {r['max_residual']:9.1e} "
              f"{r['qp_solves']:6d}")
    print(f"written to {path}")


if __name__ == "__main__":
    main()
