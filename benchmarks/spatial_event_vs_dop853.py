"""The spatial event method against DOP853 on the reduced ODE of a constant-load slide.

Run: ``python benchmarks/spatial_event_vs_dop853.py [--quick]``. Prints a table and writes
``benchmarks/out/spatial_event_vs_dop853.csv`` (untracked; ``--out`` to write elsewhere).

Scenes: ``plane_slide`` (launched at beta = 0.6: straight), ``incline_slide`` launched up the line
of steepest descent (phi0 = pi: straight; it stops and sticks, mu = tan theta) and, with
mu = tan(theta) / 2, stops and slides back down from rest; ``lateral_force_slide`` with the force
along the launch (straight) and the default one (the force across the launch: a curved slide,
numerical, for context). Every run writes 1001 output times over the scene's horizon.

The baseline is SciPy's ``solve_ivp(method="DOP853")`` on the reduced ODE of the in-plane motion,
X' = U, U' = b - a U / |U| (b the in-plane applied acceleration, a = mu N / m), with a terminal
event at the stop U . U0 = 0 (a straight slide), after which the block sticks (the output holds the stop state) or, where |b| > a, a second DOP853 call slides it
from rest along b. A curved slide's baseline is
:func:`lcp.scenes.spatial_exact.reduced_reference` with DOP853 (the same ODE in the rescaled time
d tau = dt / |U|, smooth up to the stop, which U / |U| is not). Its rtol is the loosest of 1e-6 ... 1e-13 (atol = rtol * 1e-3 of the launch
speed and of its path) that reaches the event method's error against the exact solution, or,
where none does, the one with the best error (marked). The two are timed in alternation (rounds of
one call of each) and each time is the median over the rounds, so the ratio is taken within one
run under the same load.
"""
from __future__ import annotations

import argparse
import csv
import math
import os
import statistics
import time
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

import lcp
from lcp import scenes
from lcp.scenes.spatial_exact import reduced_reference


def reduced_dop853(sol, t_eval, rtol, straight):
    """X, U at t_eval from the reduced ODE by DOP853 (2-vectors; stick or slip after a stop)."""
    if not straight:
        ref = reduced_reference(t_eval, sol.v0, sol.accel, sol.decel, rtol=rtol, method="DOP853")
        return np.array([ref["x"], ref["y"], ref["vx"], ref["vy"]])
    b, a, U0 = sol.accel, sol.decel, sol.v0
    s0 = math.hypot(*U0)
    T = float(t_eval[-1])
    atol = rtol * 1e-3 * np.array([max(s0 * T, 1e-300)] * 2 + [max(s0, 1e-300)] * 2)

    def rhs(_, y):
        u0, u1 = y[2], y[3]
        s = math.hypot(u0, u1)
        return [u0, u1, b[0] - a * u0 / s, b[1] - a * u1 / s]

    def stop(_, y):
        return y[2] * U0[0] + y[3] * U0[1]
    stop.terminal, stop.direction = True, -1
    y0 = np.array([0.0, 0.0, U0[0], U0[1]])
    r = solve_ivp(rhs, (0.0, T), y0, method="DOP853", rtol=rtol, atol=atol, events=stop, dense_output=True)
    Y = np.empty((4, t_eval.size))
    ts = r.t_events[0][0] if r.status == 1 else math.inf
    before = t_eval <= ts
    Y[:, before] = r.sol(t_eval[before])
    if np.any(~before):
        ys = r.y_events[0][0].copy()
        ys[2:] = 0.0
        fb = math.hypot(*b)
        if fb <= a:
            Y[:, ~before] = ys[:, None]
        else:
            # slides from rest along b with the constant acceleration (fb - a) b / fb
            d = b / fb

            def rhs2(_, y):
                return [y[2], y[3], (fb - a) * d[0], (fb - a) * d[1]]
            r2 = solve_ivp(rhs2, (ts, T), ys, method="DOP853", rtol=rtol, atol=atol, dense_output=True)
            Y[:, ~before] = r2.sol(t_eval[~before])
    return Y


def cases():
    th = 0.3
    return [
        ("plane_slide", scenes.plane_slide(), True),
        ("incline_slide up", scenes.incline_slide(phi0=math.pi, t_end=0.5), True),
        ("incline_slide up, slips back", scenes.incline_slide(theta=th, mu=0.5 * math.tan(th), phi0=math.pi,
                                                              t_end=0.5), True),
        ("lateral_force_slide aligned", scenes.lateral_force_slide(F=(2.0, 1.0), v0=(1.0, 0.5)), True),
        ("lateral_force_slide (curved)", scenes.lateral_force_slide(), False),
    ]


def err_of(ex, X, U):
    return float(max(np.max(np.abs(X[0] - ex["x"])), np.max(np.abs(X[1] - ex["y"])))), \
        float(max(np.max(np.abs(U[0] - ex["vx"])), np.max(np.abs(U[1] - ex["vy"]))))


def compare(name, sc, straight, rounds):
    T = sc.t_end
    t_eval = np.linspace(0.0, T, 1001)
    ex = sc.solution.state(t_eval)
    event = lambda: lcp.simulate(sc, T, method="event", t_eval=t_eval)  # noqa: E731
    res = event()
    eq_ev, ev_ev = err_of(ex, res.q[:, :2].T, res.v[:, :2].T)
    integrators = "+".join(p.integrator for p in res.phases)
    # DOP853: the loosest rtol reaching the event method's position error, else the best
    grid = []
    for rtol in (1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11, 1e-12, 1e-13):
        Y = reduced_dop853(sc.solution, t_eval, rtol, straight)
        grid.append((rtol, *err_of(ex, Y[:2], Y[2:])))
    reach = [g for g in grid if g[1] <= max(eq_ev, 1e-300) * 1.0000001]
    matched = bool(reach)
    rtol, eq_d, ev_d = reach[0] if reach else min(grid, key=lambda g: g[1])
    dop = lambda: reduced_dop853(sc.solution, t_eval, rtol, straight)  # noqa: E731
    t_e, t_d = [], []
    for _ in range(rounds):
        t0 = time.perf_counter()
        event()
        t1 = time.perf_counter()
        dop()
        t2 = time.perf_counter()
        t_e.append(t1 - t0)
        t_d.append(t2 - t1)
    te, td = statistics.median(t_e), statistics.median(t_d)
    return dict(scene=name, phases=integrators, event_ms=1e3 * te, dop853_ms=1e3 * td, ratio=te / td,
                event_err_q=eq_ev, event_err_v=ev_ev, dop853_rtol=rtol, dop853_err_q=eq_d, dop853_err_v=ev_d,
                dop853_matched=matched)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer rounds")
    ap.add_argument("--out", default=str(Path(__file__).parent / "out" / "spatial_event_vs_dop853.csv"))
    args = ap.parse_args(argv)
    rounds = 5 if args.quick else 31
    load = os.getloadavg()[0]
    rows = [compare(name, sc, straight, rounds) for name, sc, straight in cases()]
    print(f"load average {load:.2f}; {rounds} alternating rounds per scene, 1001 output times")
    print(f"{'scene':32s} {'phases':26s} {'event ms':>9s} {'DOP853 ms':>9s} {'ratio':>6s} "
          f"{'err q event':>11s} {'err q DOP':>10s} {'rtol':>6s}")
    for r in rows:
        print(f"{r['scene']:32s} {r['phases']:26s} {r['event_ms']:9.3f} {r['dop853_ms']:9.3f} {r['ratio']:6.2f} "
              f"{r['event_err_q']:11.2e} {r['dop853_err_q']:10.2e} {r['dop853_rtol']:6.0e}"
              f"{'' if r['dop853_matched'] else ' (best)'}")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with out.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]) + ["load"])
        w.writeheader()
        for r in rows:
            w.writerow({**r, "load": load})
    return rows


if __name__ == "__main__":
    main()
