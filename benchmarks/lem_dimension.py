"""Cost of the LEM engine against the moment dimension, with the error it buys.

Run: ``python benchmarks/lem_dimension.py [--quick] [--repeats K] [--out DIR]``. Prints a table and
writes ``lem_dimension.csv`` into DIR (default ``benchmarks/out/``, untracked).

Problem: y'' = tanh y, y(0) = 0, y'(0) = 1 (the paper's (3.9) with z0 = 1), solved to x = 1 by
one truncated moment system (no restart). Three families of systems:

- ``odd (needed)``: expansion about the origin keeping only the moments the output needs (odd
  degrees: the paper's (3.17)); dimension = sum over odd d <= N of (d + 1);
- ``all moments``: the same expansion with every moment up to degree N (``prune=False``);
  dimension C(N + 2, 2) - 1;
- ``centred at y0``: expansion about the initial state (what each restart does): f(c) != 0, so
  v_0 = 1 couples every degree and every moment is needed; dimension C(N + 2, 2).

Columns: ``build_s`` = Taylor expansion of f (jets) + reachability search + sparse assembly
(``lem.moments.moment_system``); ``solve_s`` = one ``lem.solve(..., check=False)``
(build + ``expm_multiply``) minus the build; ``total_s`` = build + solve; ``checked_s`` = a full
``solve`` with the a-posteriori estimate (four degrees N - 4, N - 2, N, N + 2). Times are medians
of K repeats after a warm-up. ``error`` is |y_N(1) - y(1)| against a 25-digit mpmath reference
(solve_ivp at rtol 1e-13 if mpmath is missing).
Target: build + solve at dimension ~2700 under 2 s.
"""
from __future__ import annotations

import argparse
import csv
import statistics
import time
import warnings
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

from lem.moments import clear_structure_cache, moment_system
from lem.propagation import solve
from lem.result import LEMWarning

TARGET_S = 2.0


def f(t, y):
    return [y[1], np.tanh(y[0])]


def reference():
    try:
        import mpmath
    except ImportError:  # not a package dependency: fall back to solve_ivp (good to ~1e-14)
        return float(solve_ivp(f, (0.0, 1.0), [0.0, 1.0], method="DOP853", rtol=1e-13,
                               atol=1e-15).y[0, -1])
    mpmath.mp.dps = 25
    sol = mpmath.odefun(lambda x, y: [y[1], mpmath.tanh(y[0])], 0, [0, 1])
    return float(sol(1)[0])


def timed(fn, repeats):
    fn()  # warm-up (imports, numba)
    ts = []
    out = None
    for _ in range(repeats):
        # a first build (reachability search, term placement), not a refill of a cached structure
        clear_structure_cache()
        t0 = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts), out


def run_case(kind, N, repeats, y_ref):
    opts = dict(prune=kind != "all moments",
                centre="initial" if kind == "centred at y0" else "origin")
    centre = [0.0, 1.0] if kind == "centred at y0" else None
    build, S = timed(lambda: moment_system(f, N, n=2, centre=centre, prune=opts["prune"]), repeats)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LEMWarning)
        total, r = timed(lambda: solve(f, (0.0, 1.0), [0.0, 1.0], degree=N, check=False, **opts),
                         repeats)
        checked, rc = timed(lambda: solve(f, (0.0, 1.0), [0.0, 1.0], degree=N, **opts),
                            max(1, repeats // 2))
    return dict(kind=kind, N=N, dimension=S.dimension, nnz=S.nnz, build_s=build,
                solve_s=max(total - build, 0.0), total_s=total, checked_s=checked,
                error=abs(float(r.y[0, -1]) - y_ref), estimate=float(rc.error_estimate[0, -1]),
                status=rc.status, under_target=total < TARGET_S)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="small sizes only (smoke test)")
    p.add_argument("--repeats", type=int, default=3, help="timing repeats (median)")
    p.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "out",
                   help="output folder")
    args = p.parse_args(argv)
    if args.quick:
        cases = [("odd (needed)", 21), ("all moments", 20), ("centred at y0", 20)]
    else:
        cases = ([("odd (needed)", N) for N in (21, 41, 61, 81, 103)]
                 + [("all moments", N) for N in (20, 40, 60, 72)]
                 + [("centred at y0", N) for N in (20, 40, 60, 72)])
    y_ref = reference()
    rows = []
    head = (f"{'system':<15} {'N':>4} {'dim':>5} {'nnz':>7} {'build s':>8} {'solve s':>8} "
            f"{'total s':>8} {'checked s':>9} {'error':>9} {'estimate':>9} {'status':>6}")
    print(head)
    print("-" * len(head))
    for kind, N in cases:
        r = run_case(kind, N, args.repeats, y_ref)
        rows.append(r)
        print(f"{kind:<15} {N:>4} {r['dimension']:>5} {r['nnz']:>7} {r['build_s']:>8.3f} "
              f"{r['solve_s']:>8.3f} {r['total_s']:>8.3f} {r['checked_s']:>9.3f} {r['error']:>9.2e} "
              f"{r['estimate']:>9.2e} {r['status']:>6}")
    big = [r for r in rows if r["dimension"] >= 2600]
    for r in big:
        print(f"dimension {r['dimension']} ({r['kind']}, N = {r['N']}): build + solve "
              f"{r['total_s']:.2f} s -> {'under' if r['under_target'] else 'OVER'} the "
              f"{TARGET_S:g} s target")
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "lem_dimension.csv"
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(list(rows[0]))
        for r in rows:
            w.writerow([repr(v) if isinstance(v, float) else v for v in r.values()])
    print(f"wrote {path.relative_to(Path.cwd()) if path.is_relative_to(Path.cwd()) else path.name}")
    return rows


if __name__ == "__main__":
    main()
