"""Per-step cost of the Moreau-Jean routes the constant compiled loop took over from Python.

Run: ``python benchmarks/compiled_routes.py [--repeats N]``. Prints a table and writes
``benchmarks/recorded/compiled_routes.csv``.

Rows: controlled constant systems without a contact (a pushed point; two masses with springs and
dampers, a dense mass matrix; h = 1e-4, 1 s, an affine schedule on three pieces), the springs
without control, and schedules on
constant matrices with a drift F(t), a B(t) or a spatial contact (0.6 s, h = 1e-3: now the compiled
general loop), which ran in the Python loop with ``fast=True`` before; the rocking block and a
tipping rod under the solver ``"nsgs"`` by name (one active contact: the Python contact step
before, the general loop's kernel now; their "before" column is the Python loop's, see
benchmarks/README.md for the compiled run before); Jean-Pratt's block under ``"nsgs"`` (one
contact of a constant system: the Python loop before, the constant compiled loop now); and the bead column (``lcp.scenes.bead_column``, 3 s,
h = 1e-3), whose steps where the kernel's NSGS stops were handed to the Python solver and
are now finished by the compiled Newton (``planar_multi_kernels.solve_planar``). For each: the
Python loop (``fast=False``), the compiled loop as before (for the column: ``newton_params``
returning None, every stopped step to the Python solver; for block chains pushed by a force of t,
constant matrices: ``general_loop._planar_multi`` off there, every contact step to the Python
contact step) and now, warm (kernels cached), the
median of ``--repeats`` runs; the counts of steps handed to Python and finished by the compiled
Newton; the largest difference of q from the Python loop's and from the run before, relative to
max |q| (0: the same bits).
"""
from __future__ import annotations

import argparse
import csv
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def cases():
    """name -> (run(fast) -> result, needs the Python finish switch)."""
    import casadi as ca

    import lcp
    from lcp.model.schedule import AffineSchedule
    from lcp.model.system import Contact, System
    from lcp.scenes.bead_column import bead_column

    out = {}
    q, v, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 2)
    point = System(q, v, ca.SX.eye(2), ca.vertcat(u[0], -9.81 + u[1]), control=u, control_bounds=(-50, 50))
    M = ca.SX(np.array([[2.0, -1.0], [-1.0, 2.0]]))
    F = ca.vertcat(-30 * q[0] + 5 * q[1] - 0.3 * v[0] + u[0], 5 * q[0] - 20 * q[1] - 0.1 * v[1] - 9.81 + u[1])
    springs = System(q, v, M, F, control=u, control_bounds=(-50, 50))
    sched = AffineSchedule([0.0, 0.3, 0.7, 1.0], np.linspace(-7.0, 11.0, 12).reshape(6, 2))
    for name, s, q0 in (("pushed point, no contact", point, [0.0, 0.0]), ("springs, no contact", springs, [0.1, -0.2])):
        out[name] = (lambda fast, s=s, q0=q0: lcp.simulate(s, 1.0, h=1e-4, q0=q0, v0=[0.0, 1.0], control=sched,
                                                           fast=fast), False)
    free = System(q, v, M, ca.vertcat(-30 * q[0] + 5 * q[1] - 0.3 * v[0], 5 * q[0] - 20 * q[1] - 0.1 * v[1] - 9.81))
    out["springs, no contact, no control"] = (lambda fast: lcp.simulate(free, 1.0, h=1e-4, q0=[0.1, -0.2],
                                                                       v0=[0.0, 1.0], fast=fast), False)
    # control schedules on constant matrices that are not a constant planar drift with a constant B:
    # the Python loop before, the compiled general loop now (0.6 s, h = 1e-3, one contact)
    t = ca.SX.sym("t")
    w = ca.SX.sym("u", 1)
    floor = [Contact(gap=q[1], tangent=q[0], mu=0.3)]
    t_drift = System(q, v, M, ca.vertcat(w[0] + ca.sin(5 * t), -9.81 + 2 * ca.cos(3 * t)), t=t, control=w,
                     control_bounds=(-50, 50), contacts=floor)
    t_matrix = System(q, v, M, ca.vertcat(w[0] * ca.cos(2 * t), -9.81 + w[0] * ca.sin(2 * t)), t=t, control=w,
                      control_bounds=(-50, 50), contacts=floor)
    q3, v3 = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
    puck = System(q3, v3, ca.SX.eye(3), ca.vertcat(w[0], 0, -9.81), control=w, control_bounds=(-50, 50),
                  contacts=[Contact(gap=q3[2], tangent=ca.vertcat(q3[0], q3[1]), mu=0.3)])
    one = AffineSchedule([0.0, 0.2, 0.45, 0.6], np.array([[3.0], [-2.0], [-8.0], [5.0], [30.0], [0.0]]))
    for name, s, q0, v0 in (("drift F(t), constant M", t_drift, [0.0, 0.0], [0.5, 0.0]),
                            ("B(t), constant M", t_matrix, [0.0, 0.0], [0.5, 0.0]),
                            ("spatial puck, pushed", puck, [0.0, 0.0, 0.0], [1.0, 0.0, 0.0])):
        out[name] = (lambda fast, s=s, q0=q0, v0=v0: lcp.simulate(s, 0.6, h=1e-3, q0=q0, v0=v0, control=one,
                                                                  fast=fast), False)
    # one active planar contact under "nsgs" by name in the general loop (before: the Python contact step)
    from lcp.scenes.classical import rocking_block

    tip = Contact(gap=q3[1] - 0.5 * ca.sin(q3[2]), tangent=q3[0] - 0.5 * ca.cos(q3[2]), mu=0.4, e=0.2)
    rod = System(q3, v3, ca.diag(ca.SX([1.0, 1.0, 1.0 / 12])), ca.vertcat(0, -9.81, 0), contacts=[tip])
    out["rocking block, nsgs, 3.2 s"] = (lambda fast: lcp.simulate(rocking_block(), 3.2, h=1e-3, solver="nsgs",
                                                                    fast=fast), False)
    out["tipping rod, nsgs, 1 s"] = (lambda fast: lcp.simulate(rod, 1.0, h=1e-3, q0=[0.0, 0.5 * np.sin(0.5) + 0.2, 0.5],
                                                               v0=[0.5, 0.0, 0.0], solver="nsgs", fast=fast), False)
    # several active contacts on constant matrices with a force of t: the general loop handed every
    # such step to the Python contact step before (switch "chain"), its kernel solves them now
    for K in (3, 10, 30):
        sc = lcp.scenes.block_chain(K)
        base = sc.system
        pushed = System(base.q_sym, base.v_sym, base.mass_expr,
                        base.force_expr + ca.vertcat(*([3.0 * ca.sin(3 * t), 0] * K)), t=t, contacts=base.contacts,
                        names=base.names)
        out[f"chain K={K} pushed by sin 3t, 1 s"] = (
            lambda fast, s=pushed, sc=sc: lcp.simulate(s, 1.0, h=1e-3, q0=sc.q0, v0=sc.v0, fast=fast), "chain")
    jp = lcp.scenes.jean_pratt(R=0.5)  # one contact, constant: "nsgs" by name (no closed form)
    out["Jean-Pratt, nsgs, 5 s"] = (lambda fast: lcp.simulate(jp, 5.0, h=1e-3, solver="nsgs", fast=fast), False)
    # coupled spatial contacts of a constant system (two pucks joined by a bar): the Python loop
    # before (compiled_spatial takes independent contacts only), the compiled general loop now
    qp, vp = ca.SX.sym("q", 6), ca.SX.sym("v", 6)
    bar = System(qp, vp, ca.SX.eye(6), ca.vertcat(2.0, 0, -9.81, 0, 0, -9.81), constraints=qp[3] - qp[0] - 1.0,
                 contacts=[Contact(gap=qp[2], tangent=ca.vertcat(qp[0], qp[1]), mu=0.3),
                           Contact(gap=qp[5], tangent=ca.vertcat(qp[3], qp[4]), mu=0.5)])
    out["pucks joined by a bar, 1 s"] = (
        lambda fast: lcp.simulate(bar, 1.0, h=1e-3, q0=[0, 0, 0, 1.0, 0, 0], v0=[1.0, 0.3, 0, 1.0, 0.3, 0], fast=fast),
        False)
    for K, e in ((10, 0.5), (10, 0.9), (20, 0.5), (20, 0.9)):
        sc = bead_column(K, e=e)
        out[f"bead column K={K} e={e}"] = (lambda fast, sc=sc: lcp.simulate(sc, sc.t_end, h=1e-3, fast=fast), True)
    return out


def timed(run, fast, repeats):
    run(fast)  # warm: kernels compiled or loaded from numba's cache
    times, res = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = run(fast)
        times.append(time.perf_counter() - t0)
    return statistics.median(times) / res.stats.steps * 1e6, res


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    from lcp.timestepping import compiled_loop, general_loop

    real, real_multi = compiled_loop.newton_params, general_loop._planar_multi
    rows = []
    for name, (run, column) in cases().items():
        py_us, py = timed(run, False, args.repeats)
        before_us, before = None, None
        if column:
            if column == "chain":  # the kernel off on constant matrices, as before
                general_loop._planar_multi = (lambda solver, asm: np.zeros(4, dtype=np.int64) if asm.matrices_constant
                                              else real_multi(solver, asm))
            else:
                compiled_loop.newton_params = lambda solver: None
            try:
                before_us, before = timed(run, True, args.repeats)
            finally:
                compiled_loop.newton_params, general_loop._planar_multi = real, real_multi
        now_us, now = timed(run, True, args.repeats)
        sq = max(1.0, float(np.max(np.abs(py.q))))
        row = {"case": name, "python_us": py_us, "before_us": before_us if column else py_us, "now_us": now_us,
               "handed_before": before.stats.fallbacks + before.stats.python_steps if column else 0, "handed_now": now.stats.fallbacks + now.stats.python_steps,
               "newton_now": now.stats.kernel_multi_steps,
               "dq_python": float(np.max(np.abs(now.q - py.q))) / sq,
               "dq_before": float(np.max(np.abs(now.q - before.q))) / sq if column else float("nan")}
        rows.append(row)
        print(f"{name:30s} python {py_us:8.1f}  before {row['before_us']:8.1f}  now {now_us:7.2f} us/step  "
              f"handed {row['handed_before']}->{row['handed_now']}  newton {row['newton_now']}  "
              f"dq(python) {row['dq_python']:.1e}  dq(before) {row['dq_before']:.1e}", flush=True)
    out = ROOT / "benchmarks" / "recorded" / "compiled_routes.csv"
    with open(out, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    print(f"written {out.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
