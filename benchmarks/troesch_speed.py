"""Troesch's problem: LEM shooting against SciPy's integrators, time and error in one run.

Run: ``python benchmarks/troesch_speed.py [--lams 5 10] [--repeats K] [--out DIR]``. Prints a
table and writes ``troesch_speed.csv`` into DIR (default ``benchmarks/out/``, untracked).

Problem: y'' = lambda sinh(lambda y), y(0) = 0, y(1) = 1; the unknown is y'(0), whose reference
values (20 digits) are in :data:`lem.troesch.TROESCH_REFERENCE`. Methods:

- ``LEM shooting``: :func:`lem.troesch.solve_troesch` with its defaults (degree 16, auto
  restarts, rtol 1e-12; Newton on the shooting map with the sensitivity the moment system
  carries);
- ``DOP853 shooting``: ``solve_ivp(method="DOP853", rtol=1e-13, atol=1e-15)`` inside
  ``scipy.optimize.brentq`` on [0, 2 s0] (s0 = min(lambda/sinh(lambda), 8 exp(-lambda)));
  a trial whose solution has its pole inside [0, 1] counts as an overshoot;
- ``solve_bvp``: collocation with tol 1e-10 from the boundary-layer approximation
  y = (4/lambda) artanh(tanh(lambda/4) exp(lambda (x - 1))).

Times are medians of K repeats after one warm-up (imports, numba compilation, caches), with the
methods interleaved so that a change of machine load hits all of them. ``ratio`` is the time of a
method over the time of DOP853 shooting.
"""
from __future__ import annotations

import argparse
import csv
import math
import statistics
import time
from pathlib import Path

import numpy as np
from scipy.integrate import solve_bvp, solve_ivp
from scipy.optimize import brentq

from lem.troesch import TROESCH_REFERENCE, solve_troesch

DEFAULT_OUT = Path(__file__).resolve().parent / "out"


def lem_shooting(lam: float) -> float:
    r = solve_troesch(lam)
    if not r.success:
        raise RuntimeError(f"LEM shooting failed at lambda = {lam}: {r.message}")
    return r.slope


def dop853_shooting(lam: float) -> float:
    def F(s):
        r = solve_ivp(lambda x, y: [y[1], lam * math.sinh(lam * y[0])], (0.0, 1.0), [0.0, s],
                      method="DOP853", rtol=1e-13, atol=1e-15)
        if r.status != 0 or not np.all(np.isfinite(r.y[:, -1])):
            return 1e300  # the pole is inside [0, 1]: an overshoot
        return float(r.y[0, -1]) - 1.0

    s0 = min(lam / math.sinh(lam), 8.0 * math.exp(-lam))
    return brentq(F, 0.0, 2.0 * s0, xtol=1e-16 * s0, rtol=4 * np.finfo(float).eps)


def bvp(lam: float) -> float:
    # guess: the boundary-layer approximation y = (4/lam) artanh(tanh(lam/4) exp(lam (x - 1)))
    # (from the straight line y = x the collocation Jacobian turns singular at lambda = 10)
    x = np.linspace(0.0, 1.0, 41)
    q = math.tanh(lam / 4.0) * np.exp(lam * (x - 1.0))
    y = np.vstack([(4.0 / lam) * np.arctanh(q), 4.0 * q / (1.0 - q**2)])
    sol = solve_bvp(lambda x, y: np.vstack([y[1], lam * np.sinh(lam * y[0])]),
                    lambda ya, yb: np.array([ya[0], yb[0] - 1.0]), x, y, tol=1e-10,
                    max_nodes=200_000)
    if not sol.success:
        raise RuntimeError(f"solve_bvp failed at lambda = {lam}: {sol.message}")
    return float(sol.sol(0.0)[1])


METHODS = {"LEM shooting": lem_shooting, "DOP853 shooting": dop853_shooting, "solve_bvp": bvp}


def run(lams, repeats: int) -> list:
    rows = []
    for lam in lams:
        ref = TROESCH_REFERENCE[lam]
        slopes = {name: fn(lam) for name, fn in METHODS.items()}  # warm-up
        times = {name: [] for name in METHODS}
        for _ in range(repeats):
            for name, fn in METHODS.items():
                t0 = time.perf_counter()
                slopes[name] = fn(lam)
                times[name].append(time.perf_counter() - t0)
        base = statistics.median(times["DOP853 shooting"])
        for name in METHODS:
            t = statistics.median(times[name])
            rows.append(dict(lam=lam, method=name, time_s=t, ratio_to_dop853=t / base,
                             slope=slopes[name], relative_error=abs(slopes[name] / ref - 1.0)))
    return rows


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--lams", type=float, nargs="+", default=[5.0, 10.0],
                   help=f"values of lambda, from {sorted(TROESCH_REFERENCE)}")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help="output folder")
    args = p.parse_args(argv)
    for lam in args.lams:
        if lam not in TROESCH_REFERENCE:
            p.error(f"--lams: no reference for lambda = {lam:g}; known: {sorted(TROESCH_REFERENCE)}")
    if args.repeats < 1:
        p.error("--repeats must be >= 1")
    rows = run(args.lams, args.repeats)
    print(f"{'lambda':>6}  {'method':<16} {'time (s)':>9} {'/ DOP853':>9}  {'rel. error':>10}")
    for r in rows:
        print(f"{r['lam']:>6g}  {r['method']:<16} {r['time_s']:>9.4f} {r['ratio_to_dop853']:>9.2f}  "
              f"{r['relative_error']:>10.2e}")
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "troesch_speed.csv"
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
