"""Work against precision of the two time-stepping schemes on smooth constrained motion.

Run: ``python benchmarks/second_order.py [--quick] [--repeats K] [--out DIR]``. Prints one table
and writes ``second_order.csv`` into ``benchmarks/out/`` (untracked; ``--out`` writes elsewhere).

Scenes: the pendulum written with the constraint x^2 + y^2 - L^2 = 0 (:func:`lcp.classical.pendulum`,
L = 1, released at 90 degrees from rest; error of q at t = 1 s against ``solve_ivp`` DOP853, rtol
1e-12, on theta'' = -g/L sin(theta)) and the slider-crank (:func:`lcp.classical.slider_crank`,
q-dependent mass matrix, two nonlinear loop-closure constraints, omega0 = 30 rad/s; error of q at
t = 0.5 s against its reduced equation by DOP853). For each scheme (``"moreau-jean"``, theta = 1/2
with the position projection, and ``"order2"``) and h = 4e-3 ... 2.5e-4: the wall time of the run
(best of K, CasADi functions built beforehand), the error, and the observed order between
successive h.

Contact cases (``scheme="order2"`` holds closed contacts as constraints): a point mass inside a
frictionless circular bowl of radius 1 released at rest at 60 degrees (a pendulum held by a
unilateral contact; error of q at t = 1 s against the exact elliptic-function solution), and a
point mass released at rest 0.3 rad from the top of a circle of radius 1 (it leaves the surface at
cos(theta) = 2/3 cos(0.3), t = 0.563 s; error of q at t = 0.8 s against DOP853 rtol 1e-13 up to
the lift-off and the parabola after it).
"""
from __future__ import annotations

import argparse
import csv
import math
import os
import time
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

import casadi as ca

import lcp
from lcp.classical import pendulum, slider_crank
from lcp.model.system import Contact, System
from lcp.scenes.classical import PendulumExact

# this script times the compiled loops: its short runs must not take the Python loop while a
# kernel is not loaded yet (lcp.timestepping.first_compile)
os.environ.setdefault("LCP_COMPILE", "always")


SCHEMES = ("moreau-jean", "order2")


def _pendulum_case():
    sc = pendulum(theta0=math.pi / 2)
    sol = solve_ivp(lambda _t, y: [y[1], -9.81 * math.sin(y[0])], (0.0, 1.0), [math.pi / 2, 0.0],
                    method="DOP853", rtol=1e-12, atol=1e-14)
    th = sol.y[0, -1]
    return "pendulum 90 deg, t = 1 s", sc, 1.0, np.array([math.sin(th), -math.cos(th)]), {}


def _crank_case():
    sc = slider_crank(t_end=0.5)
    return "slider-crank, t = 0.5 s", sc, 0.5, sc.exact(0.5)["q"][0], {}


def _point_on_circle(sign):
    """A point mass under gravity with one frictionless contact on the unit circle: inside it
    (sign = -1, a bowl: gap 1 - |q|) or outside it (sign = 1: gap |q| - 1)."""
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    c = Contact(gap=sign * (ca.norm_2(q) - 1), tangent=ca.atan2(q[0], -sign * q[1]), name="circle")
    return System(q, v, ca.SX.eye(2), ca.vertcat(0, -9.81), contacts=[c])


def _bowl_case():
    th0 = math.pi / 3
    q_ref = PendulumExact(1.0, th0, 9.81)(1.0)["q"][0]
    start = dict(q0=[math.sin(th0), -math.cos(th0)], v0=[0.0, 0.0])
    return "bowl 60 deg, t = 1 s", _point_on_circle(-1), 1.0, q_ref, start


def _lift_off_case():
    g, th0, t_end = 9.81, 0.3, 0.8

    def leave(_t, y):
        return g * math.cos(y[0]) - y[1] ** 2

    leave.terminal, leave.direction = True, -1
    sol = solve_ivp(lambda _t, y: [y[1], g * math.sin(y[0])], (0.0, 5.0), [th0, 0.0], method="DOP853",
                    rtol=1e-13, atol=1e-15, events=leave)
    ts = float(sol.t_events[0][0])
    th, w = sol.y_events[0][0]
    d = t_end - ts
    q_ref = (np.array([math.sin(th), math.cos(th)]) + w * np.array([math.cos(th), -math.sin(th)]) * d
             + 0.5 * np.array([0.0, -g]) * d * d)
    start = dict(q0=[math.sin(th0), math.cos(th0)], v0=[0.0, 0.0])
    return "sphere lift-off, t = 0.8 s", _point_on_circle(1), t_end, q_ref, start


def run(hs, repeats):
    rows = []
    for name, sc, t_end, q_ref, start in (_pendulum_case(), _crank_case(), _bowl_case(), _lift_off_case()):
        for scheme in SCHEMES:
            # warm-up: CasADi functions once per system (the lift-off's past its switch)
            lcp.simulate(sc, t_end, h=hs[0], scheme=scheme, **start)
            prev = None
            for h in hs:
                best = math.inf
                for _ in range(repeats):
                    t0 = time.perf_counter()
                    res = lcp.simulate(sc, t_end, h=h, scheme=scheme, **start)
                    best = min(best, time.perf_counter() - t0)
                assert res.success, res.message
                err = float(np.max(np.abs(res.q[-1] - q_ref)))
                order = math.log2(prev / err) if prev else float("nan")
                rows.append(dict(scene=name, scheme=scheme, h=h, steps=res.stats.steps, seconds=best,
                                 us_per_step=1e6 * best / res.stats.steps, error=err, order=order))
                prev = err
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="h = 4e-3 ... 1e-3, one repeat")
    ap.add_argument("--repeats", type=int, default=None, help="runs per point, best kept (default 3)")
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "out")
    args = ap.parse_args(argv)
    hs = (4e-3, 2e-3, 1e-3) if args.quick else (4e-3, 2e-3, 1e-3, 5e-4, 2.5e-4)
    repeats = args.repeats or (1 if args.quick else 3)
    load0 = os.getloadavg()
    rows = run(hs, repeats)
    load1 = os.getloadavg()
    print(f"best of {repeats} (load {load0[0]:.2f} -> {load1[0]:.2f}, {os.cpu_count()} cores)")
    print(f"{'scene':26s} {'scheme':12s} {'h':>8s} {'steps':>6s} {'time s':>8s} {'us/step':>8s} {'error':>10s} "
          f"{'order':>6s}")
    for r in rows:
        print(f"{r['scene']:26s} {r['scheme']:12s} {r['h']:8.1e} {r['steps']:6d} {r['seconds']:8.3f} "
              f"{r['us_per_step']:8.1f} {r['error']:10.3e} {r['order']:6.2f}")
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "second_order.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(list(rows[0]))
        for r in rows:
            w.writerow(list(r.values()))
    print(f"\nwritten to {args.out}/second_order.csv")
    return rows


if __name__ == "__main__":
    main()
