"""Event-driven integration against SciPy's LSODA on a tanh-regularized friction law.

Run: ``python benchmarks/event_vs_lsoda.py [--quick]``. Prints a table and writes
``benchmarks/out/event_vs_lsoda.csv`` (untracked; pass ``--out`` to write elsewhere).

Default Jean-Pratt scene (m = M = 1, alpha = pi/4, R = 0.5, v0 = 1, horizon scene.t_end), and for
context a loaded one (phi = 5, v0 = -1: slide, stop, stick under a tangential load). Errors are
max |x(t) - exact| at the same 1000 output times for both methods. The baseline is the smooth law
f = -R N tanh(xd / eps) with N = (m + M) g - M tan(alpha) xdd, which is linear in xdd:

    xdd = (phi - R (m + M) g tanh(xd/eps)) / (A - R M tan(alpha) tanh(xd/eps)),

integrated by ``solve_ivp(method="LSODA")``. eps and rtol (atol = rtol * 1e-3) are tuned over a
grid to LSODA's best error against the exact solution (among the settings that reach it, the
fastest, timed again with repeats); that setting is then timed against the event-driven integrator. The two are timed in alternation (rounds of one LSODA call and a batch
of event-driven calls), and each time is the median over the rounds of the time per call, so a
change of load on a shared machine hits both alike and the speed-up is meaningful. The load
average is printed and written with the results. Target: the event-driven integrator at least
10x faster than LSODA at LSODA's best error on the default scene.
"""
from __future__ import annotations

import argparse
import csv
import itertools
import os
import statistics
import time
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

import lcp


def lsoda_tanh(scene, t_eval, eps, rtol):
    p = scene.params
    m, M, R, g, phi = p["m"], p["M"], p["R"], p["g"], p["phi"]
    t, A = scene.tan, scene.A
    RW, RMt = R * (m + M) * g, R * M * t

    def rhs(_, y):
        th = np.tanh(y[1] / eps)
        return [y[1], (phi - RW * th) / (A - RMt * th)]

    return solve_ivp(rhs, (0.0, t_eval[-1]), [0.0, scene.v0[0]], method="LSODA", t_eval=t_eval,
                     rtol=rtol, atol=rtol * 1e-3)


def compare(name, scene, quick):
    """Both methods on one scene: (rows, LSODA tuning grid)."""
    T = scene.t_end
    t_eval = np.linspace(0.0, T, 1000)
    x_exact = scene.exact(t_eval)["x"]
    # event-driven: warm once (per-system data are built on the first call and kept)
    event = lambda: lcp.simulate(scene, T, method="event", t_eval=t_eval)  # noqa: E731
    res = event()
    err_event = float(np.max(np.abs(res.q[:, 0] - x_exact)))
    # LSODA on tanh friction: tune eps and rtol to the best error (ties: the faster)
    epss = [1e-5, 1e-7, 1e-9] if quick else [1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-12]
    rtols = [1e-10, 1e-12] if quick else [1e-8, 1e-9, 1e-10, 1e-11, 1e-12, 1e-13]
    grid = []
    for eps, rtol in itertools.product(epss, rtols):
        t1, sol = timed(lambda: lsoda_tanh(scene, t_eval, eps, rtol), 1)
        ok = sol.success and sol.y.shape[1] == t_eval.size
        err = float(np.max(np.abs(sol.y[0] - x_exact))) if ok else np.inf
        grid.append(dict(scene=name, eps=eps, rtol=rtol, error=err, time_s=t1, nfev=sol.nfev))
    # the best error; among the settings that reach it, the fastest (timed again: one run each
    # is too noisy to pick the baseline by)
    err_best = min(r["error"] for r in grid)
    tied = [r for r in grid if r["error"] == err_best]
    if len(tied) > 1:
        for r in tied:
            r["time_s"], _ = timed(lambda r=r: lsoda_tanh(scene, t_eval, r["eps"], r["rtol"]), 3 if quick else 7)
    best = min(tied, key=lambda r: r["time_s"])
    lsoda = lambda: lsoda_tanh(scene, t_eval, best["eps"], best["rtol"])  # noqa: E731
    sol = lsoda()
    err_lsoda = float(np.max(np.abs(sol.y[0] - x_exact)))
    t_event, t_lsoda = timed_pair(event, lsoda, rounds=5 if quick else 31, batch=10)
    rows = [
        dict(scene=name, method="event-driven (closed-form phases)", settings="default options, 1000 output times",
             time_s=t_event, max_x_error=err_event, nfev=0, speedup=t_lsoda / t_event),
        dict(scene=name, method="LSODA, tanh-regularized friction",
             settings=f"eps={best['eps']:g}, rtol={best['rtol']:g}, atol={best['rtol'] * 1e-3:g}",
             time_s=t_lsoda, max_x_error=err_lsoda, nfev=sol.nfev, speedup=1.0),
    ]
    return rows, grid


def timed(fn, repeats):
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def timed_pair(fast, slow, rounds, batch):
    """Median times per call of ``fast`` and ``slow``, timed in alternation: each round times
    ``batch`` calls of ``fast`` (too short to time one by one) and one call of ``slow``."""
    t_fast, t_slow = [], []
    for _ in range(rounds):
        t0 = time.perf_counter()
        for _ in range(batch):
            fast()
        t1 = time.perf_counter()
        slow()
        t2 = time.perf_counter()
        t_fast.append((t1 - t0) / batch)
        t_slow.append(t2 - t1)
    return statistics.median(t_fast), statistics.median(t_slow)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="smaller tuning grid and fewer repeats")
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "out")
    args = ap.parse_args(argv)
    load_before = os.getloadavg()
    rows, grid = compare("default (phi = 0)", lcp.scenes.jean_pratt(), args.quick)
    # context: a tangentially loaded stick, where a smoothed law creeps at xd = eps atanh(phi / (R N))
    r2, g2 = compare("loaded (phi = 5, v0 = -1)", lcp.scenes.jean_pratt(phi=5.0, v0=-1.0), args.quick)
    rows, grid = rows + r2, grid + g2
    load = f"load average (1, 5, 15 min) {load_before} before, {os.getloadavg()} after, {os.cpu_count()} CPUs"
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "event_vs_lsoda.csv"
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=["scene", "method", "settings", "time_s", "max_x_error", "nfev", "speedup"])
        w.writeheader()
        for r in rows:
            w.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in r.items()})
        fh.write(f"# {load}\n")
        fh.write("\n# LSODA tuning grid (one run each; the settings tied at the best error: median of repeats)\n")
        w2 = csv.DictWriter(fh, fieldnames=["scene", "eps", "rtol", "error", "time_s", "nfev"])
        w2.writeheader()
        for r in grid:
            w2.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in r.items()})
    print(f"{'scene':26s} {'method':34s} {'settings':36s} {'time (s)':>9s} {'max |x-exact|':>13s} {'speed-up':>8s}")
    for r in rows:
        print(f"{r['scene']:26s} {r['method']:34s} {r['settings']:36s} {r['time_s']:9.3g} {r['max_x_error']:13.3g} "
              f"{r['speedup']:8.2f}")
    print(load)
    target = rows[0]["speedup"] >= 10
    print(f"target (event-driven >= 10x faster than LSODA on the default scene): {'met' if target else 'NOT met'}")
    print(f"wrote {path}")
    return rows, grid


if __name__ == "__main__":
    main()
