"""Per-step cost of the compiled Moreau-Jean loop for general systems against the Python loop.

Run: ``python benchmarks/general_compiled.py [--quick] [--no-siconos]``. Prints a table and writes
``benchmarks/recorded/general_compiled.csv``.

Scenes, with the default position projection (``projection="auto"``: on for all four, whose
gaps or constraints are curved): a point in a circular bowl (planar, mu = 0.3, sliding), the slider-crank (q-dependent mass, two nonlinear bilateral
constraints, non-affine forces), Housner's rocking block (two corner contacts, rotating
kinematics), a ball in a spherical bowl (one spatial contact). For each: the Python loop
(``fast=False``) on ``N_py`` steps; the compiled loop warm (library and numba kernel cached, the
run repeated in-process, median of 3, or of 9 for short runs) on ``N_c`` steps (1e5; the rocking
block 1500, its rocking phase: its resting phase, two active contacts each step, is the scene
``rocking_block_rest`` and ``benchmarks/general_multi_contact.py``; the per-step time includes the
call's set-up); cold: a fresh interpreter with empty
compiled-code and numba caches (C generation, gcc, numba compilation, the run) -- its wall time,
not per step; "cold C": the same with numba's cache warm (a new system on a machine that has run
the loop once: C generation, gcc, the run). Results are compared with the Python loop's on the common steps (max relative
difference of q). Newton-Euler kinematics (qdot = T(q) v): the Dzhanibekov body (no contact), the
tumbling box (3000 steps, both loops) and the rocking block's resting phase (2000 steps from its state
at t = 3 s, both loops: two active contacts every step). ``--scenes`` runs some scenes only (the
csv is then named after them), ``--no-cold`` skips the fresh-interpreter runs. ``--controls`` runs
the control schedules instead (:data:`CONTROL_SCENES`: B(t, q) depending on q in the compiled
general loop, controlled constant systems in the constant compiled loop; Python loop 2000 steps,
compiled 1e5, warm, median of 3; ``benchmarks/recorded/general_compiled_controls.csv``).

With Siconos 4.4 in ``/usr/bin/python3`` the point in the bowl is run there too, in a subprocess
(``LagrangianLinearTIDS``, the gap and Jacobian as a C plugin of ``LagrangianScleronomousR``,
``NewtonImpactFrictionNSL`` mu = 0.3, ``MoreauJeanOSI`` theta = 1/2, ``FrictionContact`` 2-D with
its default solver, ``TimeStepping``), same h and steps: its per-step time and end position
(printed beside ours, the compiled loop without projection as Siconos's MoreauJeanOSI, and with).
"""
from __future__ import annotations

import argparse
import csv
import math
import os
from pathlib import Path
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
# this benchmark times the compiled loop: its short runs must not take the Python loop while the
# kernel is not loaded yet (lcp.timestepping.first_compile)
os.environ.setdefault("LCP_COMPILE", "always")

SCENES = ("bowl", "slider_crank", "rocking_block", "spatial_bowl", "dzhanibekov", "tumbling_box",
          "rocking_block_rest")
#: compiled steps per scene where the full count would measure something else: the rocking block
#: comes to rest on both corners after its rocking phase (1.5 s; the resting phase is its own scene)
STEPS = {"rocking_block": 1500, "tumbling_box": 3000, "rocking_block_rest": 2000}
#: Python-loop steps where the scene's interesting part is later than the default count
PY_STEPS = {"tumbling_box": 3000, "rocking_block_rest": 2000}


def scene(name):
    """(system, q0, v0, h) of a benchmark scene."""
    import casadi as ca

    from lcp.model.system import Contact, System
    from lcp.scenes.classical import rocking_block, slider_crank

    if name == "bowl":
        q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
        r = ca.norm_2(q)
        s = System(q, v, ca.SX.eye(2), ca.vertcat(0, -9.81),
                   contacts=[Contact(gap=1.0 - r, tangent_jacobian=ca.horzcat(-q[1], q[0]) / r, mu=0.3)])
        return s, np.array([0.0, -1.0]), np.array([2.0, 0.0]), 1e-3
    if name == "slider_crank":
        sc = slider_crank()
        return sc.system, sc.q0, sc.v0, 1e-4
    if name == "rocking_block":
        sc = rocking_block()
        return sc.system, sc.q0, sc.v0, 1e-3
    if name == "rocking_block_rest":
        # the resting phase: the state at t = 3 s of the rocking block (at rest on both corners)
        sc = rocking_block()
        q, v = _rest_state()
        return sc.system, q, v, 1e-3
    if name == "dzhanibekov":  # Newton-Euler kinematics, unit quaternion, no contact
        from lcp.scenes.rigid_bodies import dzhanibekov

        sc = dzhanibekov()
        return sc.system, sc.q0, sc.v0, 1e-3
    if name == "tumbling_box":  # kinematics, eight spatial corners: falls, tumbles, rests on four corners
        from lcp.scenes.rigid_bodies import tumbling_box

        sc = tumbling_box()
        return sc.system, sc.q0, sc.v0, 1e-3
    if name == "spatial_bowl":
        q, v = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
        r = ca.norm_2(q)
        t1 = ca.vertcat(-q[1], q[0], 0) / ca.norm_2(q[:2])
        t2 = ca.cross(q / r, t1)
        s = System(q, v, ca.SX.eye(3), ca.vertcat(0, 0, -9.81),
                   contacts=[Contact(gap=1.0 - r, tangent_jacobian=ca.horzcat(t1, t2).T, mu=0.3)])
        return s, np.array([0.3, 0.0, -math.sqrt(0.91)]), np.array([0.0, 1.0, 0.0]), 1e-3
    raise KeyError(name)


_REST = []


def _rest_state():
    """(q, v) of the rocking block at t = 3 s (Python loop, h = 1e-3), computed once."""
    if not _REST:
        import lcp
        from lcp.scenes.classical import rocking_block

        sc = rocking_block()
        r = lcp.simulate(sc.system, 3.0, h=1e-3, q0=sc.q0, v0=sc.v0, fast=False)
        _REST.append((r.q[-1].copy(), r.v[-1].copy()))
    return _REST[0]


def run(name, steps, fast, projection="auto"):
    import lcp

    s, q0, v0, h = scene(name)
    t0 = time.perf_counter()
    res = lcp.simulate(s, steps * h, h=h, q0=q0, v0=v0, projection=projection, fast=fast)
    return time.perf_counter() - t0, res


def cold(name, steps, keep_numba=False):
    """Wall time of a fresh interpreter's first compiled run (empty caches), from the run's call;
    with ``keep_numba`` the numba cache is the warm one (only the system's C code is compiled: a
    new system on a machine that has run the loop before)."""
    from lcp.numerics import cache

    with tempfile.TemporaryDirectory() as tmp:
        numba_dir = str(cache.numba_cache_dir())
        env = dict(os.environ, LCP_CACHE_DIR=tmp, NUMBA_CACHE_DIR=numba_dir if keep_numba else os.path.join(tmp, "numba"),
                   PYTHONPATH=str(ROOT), LCP_COMPILE="always")  # the compiled loop's cold cost, short runs too
        code = (f"import sys; sys.path.insert(0, {str(ROOT / 'benchmarks')!r}); import general_compiled as g; "
                f"t, r = g.run({name!r}, {steps}, True); print(t)")
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
        return float(out.stdout.strip().splitlines()[-1])


SICONOS_PLUGIN = r"""
#include <math.h>
/* the bowl's gap and contact Jacobian (normal row, tangent row; column-major 2 x 2) */
void h0(unsigned int nq, double* q, unsigned int ny, double* y, unsigned int nz, double* z)
{ double r = sqrt(q[0] * q[0] + q[1] * q[1]); y[0] = 1.0 - r; y[1] = 0.0; }
void G0(unsigned int nq, double* q, unsigned int ny, double* G, unsigned int nz, double* z)
{ double r = sqrt(q[0] * q[0] + q[1] * q[1]);
  G[0] = -q[0] / r; G[1] = -q[1] / r; G[2] = -q[1] / r; G[3] = q[0] / r; }
"""

SICONOS = r"""
import sys, time, numpy as np
import siconos.kernel as sk
plugin, h, N, mu = sys.argv[1], float(sys.argv[2]), int(sys.argv[3]), 0.3
ball = sk.LagrangianLinearTIDS([0.0, -1.0], [2.0, 0.0], np.eye(2))
ball.setFExtPtr(np.array([0.0, -9.81]))
nsds = sk.NonSmoothDynamicalSystem(0.0, N * h)
nsds.insertDynamicalSystem(ball)
rel = sk.LagrangianScleronomousR(plugin + ":h0", plugin + ":G0")
nsds.link(sk.Interaction(sk.NewtonImpactFrictionNSL(0.0, 0.0, mu, 2), rel), ball)
sim = sk.TimeStepping(nsds, sk.TimeDiscretisation(0.0, h), sk.MoreauJeanOSI(0.5), sk.FrictionContact(2))
k = 0
t0 = time.perf_counter()
while sim.hasNextEvent():
    sim.computeOneStep()
    sim.nextStep()
    k += 1
dt = time.perf_counter() - t0
q = ball.q()
print(dt / k, k, q[0], q[1])
"""


def siconos_bowl(h, steps):
    """Siconos 4.4's C++ kernel on the point in the bowl (the gap and Jacobian as a C plugin):
    (seconds per step, description) or (None, why not)."""
    with tempfile.TemporaryDirectory() as tmp:
        src = os.path.join(tmp, "bowl.c")
        Path(src).write_text(SICONOS_PLUGIN)
        try:
            subprocess.run(["gcc", "-O2", "-shared", "-fPIC", src, "-o", os.path.join(tmp, "libbowl.so"), "-lm"],
                           check=True, capture_output=True)
            out = subprocess.run(["/usr/bin/python3", "-c", SICONOS, os.path.join(tmp, "libbowl"), repr(h),
                                  str(steps)], capture_output=True, text=True, timeout=1200)
        except (OSError, subprocess.SubprocessError) as exc:
            return None, str(exc)
    if out.returncode:
        return None, out.stderr.strip().splitlines()[-1] if out.stderr else "failed"
    per, k, x, y = out.stdout.split()[:4]
    return float(per), f"{k} steps, q(t_end) = ({float(x):.6f}, {float(y):.6f})"


#: control schedules (``--controls``): B(t, q) depending on q (compiled general loop) and controlled
#: constant systems (constant compiled loop); before, all of them ran the Python loop
CONTROL_SCENES = ("pendulum_push", "rod_thrust", "body_thrusters", "jean_pratt_push", "chain_push")


def control_scene(name, t_end):
    """(system, q0, v0, h, schedule) of a control benchmark: the schedule has 1000 intervals over
    [0, t_end] (the affine hold for B(q), the constant and linear holds for the constant systems)."""
    import casadi as ca

    from lcp.model.control import ControlSchedule
    from lcp.model.rigid_body import bodies_system, free_body
    from lcp.model.schedule import AffineSchedule
    from lcp.model.system import Contact, System

    times = np.linspace(0.0, t_end, 1001)
    wave = np.sin(2 * np.pi * times / 1.3)
    if name == "pendulum_push":  # a point on a circle (constraint) pushed along (-y, x), a wall at x = 0.3
        q, v, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 1)
        s = System(q, v, ca.SX.eye(2), ca.vertcat(0, -9.81) + ca.vertcat(-q[1], q[0]) * u[0], control=u,
                   constraints=q[0] ** 2 + q[1] ** 2 - 1.0,
                   contacts=[Contact(gap=0.3 - q[0], tangent=q[1], mu=0.2, e=0.3)])
        vals = np.repeat(6.0 * wave[:-1, None], 2, axis=0)
        return s, np.array([0.0, -1.0]), np.array([2.0, 0.0]), 1e-3, AffineSchedule(times, vals)
    if name == "rod_thrust":  # a planar rod on its tip, thrust along its axis and a torque
        q, v, u = ca.SX.sym("q", 3), ca.SX.sym("v", 3), ca.SX.sym("u", 2)
        B = ca.horzcat(ca.vertcat(ca.cos(q[2]), ca.sin(q[2]), 0), ca.vertcat(0, 0, 1))
        tip = Contact(gap=q[1] - 0.5 * ca.sin(q[2]), tangent=q[0] - 0.5 * ca.cos(q[2]), mu=0.4, e=0.2)
        s = System(q, v, ca.diag(ca.SX([1.0, 1.0, 1.0 / 12])), ca.vertcat(0, -9.81, 0) + ca.mtimes(B, u),
                   control=u, contacts=[tip])
        vals = np.repeat(np.column_stack([15.0 + 15.0 * wave[:-1], -0.2 * wave[:-1]]), 2, axis=0)
        return (s, np.array([0.0, 0.5 * np.sin(1.2), 1.2]), np.zeros(3), 1e-3, AffineSchedule(times, vals))
    if name == "body_thrusters":  # a rigid body (unit quaternion) on a foot, thrusters fixed in the body
        b = free_body(1.0, np.diag([0.1, 0.15, 0.2]), name="b")
        u = ca.SX.sym("u", 2)
        R, ez, ex, r = b.rotation, ca.vertcat(0, 0, 1), ca.vertcat(1, 0, 0), ca.SX([0.0, 0.0, -0.3])
        force = ca.vertcat(ca.mtimes(R, ez) * u[0] + ca.mtimes(R, ex) * u[1],
                           ca.cross(r, ez) * u[0] + ca.cross(r, ex) * u[1])
        P = b.point([0.0, 0.0, -0.3])
        foot = Contact(gap=P[2], tangent=ca.vertcat(P[0], P[1]), mu=0.3)
        s = bodies_system([b], [foot], gravity=9.81, force=force, control=u)
        vals = np.repeat(np.column_stack([9.0 + 4.0 * wave[:-1], 0.05 * wave[:-1]]), 2, axis=0)
        return (s, np.array([0.0, 0.0, 0.3, 1.0, 0.0, 0.0, 0.0]), np.zeros(6), 1e-3, AffineSchedule(times, vals))
    if name == "jean_pratt_push":  # Jean-Pratt's block (dense mass matrix), pushed along its line
        q, v, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 1)
        s = System(q, v, ca.SX(np.array([[2.0, -1.0], [-1.0, 2.0]])), ca.vertcat(u[0], -2 * 9.81), control=u,
                   contacts=[Contact(gap=q[1], tangent=q[0], mu=0.5)])
        return s, np.zeros(2), np.array([1.0, 0.0]), 1e-3, ControlSchedule(times, 15.0 * wave[:-1])
    if name == "chain_push":  # lcp.scenes.block_chain(10), its first block pushed
        import lcp

        sc = lcp.scenes.block_chain(10)
        u = ca.SX.sym("u", 1)
        Bm = np.zeros((sc.system.n, 1))
        Bm[0, 0] = 1.0
        s = System(sc.system.q_sym, sc.system.v_sym, sc.system.mass_expr,
                   sc.system.force_expr + ca.mtimes(ca.SX(Bm), u), contacts=sc.system.contacts, control=u)
        return s, sc.q0, sc.v0, 1e-3, ControlSchedule(times, 40.0 * wave, hold="linear")
    raise KeyError(name)


def run_control(name, steps, fast, horizon):
    import lcp

    s, q0, v0, h, sched = control_scene(name, horizon)
    t0 = time.perf_counter()
    res = lcp.simulate(s, steps * h, h=h, q0=q0, v0=v0, control=sched, fast=fast)
    return time.perf_counter() - t0, res


def controls(quick):
    """The control section: Python loop (2000 steps) against the compiled loops (1e5 steps, warm,
    median of 3), the same schedule (over the longer horizon); table and
    benchmarks/recorded/general_compiled_controls.csv."""
    n_py, n_c = (300, 3000) if quick else (2000, 100_000)
    horizon = n_c * 1e-3
    rows = []
    print(f"{'control scene':16s} {'path':22s} {'python us/step':>15s} {'compiled us/step':>17s} {'speed-up':>9s} "
          f"{'max rel dq':>11s} {'bits':>5s}")
    for name in CONTROL_SCENES:
        t_py, ref = run_control(name, n_py, False, horizon)
        _, got = run_control(name, n_py, True, horizon)  # warm: libraries and kernels cached
        t_c = statistics.median(run_control(name, n_c, True, horizon)[0] for _ in range(3 if n_c > 10_000 else 9))
        dq = float(np.max(np.abs(got.q - ref.q)) / np.max(np.abs(ref.q)))
        same = bool(np.array_equal(got.q, ref.q) and np.array_equal(got.v, ref.v))
        path = "constant loop" if got.solver.endswith("(compiled)") else "general loop"
        py, c = t_py / n_py * 1e6, t_c / n_c * 1e6
        print(f"{name:16s} {path:22s} {py:15.1f} {c:17.2f} {py / c:9.0f} {dq:11.2e} {str(same):>5s}")
        rows.append(dict(scene=name, path=path, python_us_per_step=f"{py:.2f}", compiled_us_per_step=f"{c:.3f}",
                         speedup=f"{py / c:.0f}", max_rel_dq=f"{dq:.2e}", bit_for_bit=same, steps_python=n_py,
                         steps_compiled=n_c))
    out = ROOT / "benchmarks" / "recorded" / "general_compiled_controls.csv"
    with open(out, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    print(f"wrote {out.relative_to(ROOT)}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--no-siconos", action="store_true")
    ap.add_argument("--scenes", nargs="*", default=list(SCENES), help=f"some of {SCENES}")
    ap.add_argument("--no-cold", action="store_true", help="skip the fresh-interpreter runs")
    ap.add_argument("--controls", action="store_true", help=f"the control schedules only: {CONTROL_SCENES}")
    args = ap.parse_args()
    if args.controls:
        return controls(args.quick)
    n_c_all = 3000 if args.quick else 100_000
    rows = []
    print(f"{'scene':14s} {'python us/step':>15s} {'compiled us/step':>17s} {'speed-up':>9s} {'cold s':>7s} "
          f"{'cold C s':>9s} {'max rel dq':>11s}")
    for name in args.scenes:
        n_py = PY_STEPS.get(name, 300 if args.quick else 2000)
        t_py, ref = run(name, n_py, False)
        run(name, 10, True)  # warm: library and kernel cached
        n_c = min(n_c_all, STEPS.get(name, n_c_all))
        t_c = statistics.median(run(name, n_c, True)[0] for _ in range(3 if n_c > 10_000 else 9))
        _, got = run(name, n_py, True)
        dq = float(np.max(np.abs(got.q - ref.q)) / np.max(np.abs(ref.q)))
        t_cold = math.nan if args.no_cold else cold(name, n_py)
        t_cold_c = math.nan if args.no_cold else cold(name, n_py, keep_numba=True)
        py, c = t_py / n_py * 1e6, t_c / n_c * 1e6
        print(f"{name:14s} {py:15.1f} {c:17.2f} {py / c:9.0f} {t_cold:7.2f} {t_cold_c:9.2f} {dq:11.2e}")
        rows.append(dict(scene=name, python_us_per_step=f"{py:.2f}", compiled_us_per_step=f"{c:.3f}",
                         speedup=f"{py / c:.0f}", cold_s=f"{t_cold:.2f}", cold_c_only_s=f"{t_cold_c:.2f}",
                         max_rel_dq=f"{dq:.2e}", steps_python=n_py, steps_compiled=n_c))
    if not args.no_siconos and "bowl" in args.scenes:
        _, _, _, h = scene("bowl")
        n_s = n_c_all // 10
        per, what = siconos_bowl(h, n_s)
        if per is not None:
            t_free = statistics.median(run("bowl", n_s, True, False)[0] for _ in range(3))
            _, ours = run("bowl", n_s, True, False)
            print(f"Siconos 4.4 C++ kernel, point in the bowl: {per * 1e6:.2f} us/step ({what}); ours without "
                  f"projection {t_free / n_s * 1e6:.2f} us/step, q(t_end) = ({ours.q[-1, 0]:.6f}, {ours.q[-1, 1]:.6f})")
            rows.append(dict(scene="bowl, no projection (Siconos 4.4 kernel)", python_us_per_step="",
                             compiled_us_per_step=f"{per * 1e6:.3f}", speedup="", cold_s="", cold_c_only_s="", max_rel_dq="",
                             steps_python="", steps_compiled=n_s))
            rows.append(dict(scene="bowl, no projection (ours)", python_us_per_step="",
                             compiled_us_per_step=f"{t_free / n_s * 1e6:.3f}", speedup="", cold_s="", cold_c_only_s="", max_rel_dq="",
                             steps_python="", steps_compiled=n_s))
        else:
            print(f"Siconos: not run ({what})")
    out = ROOT / "benchmarks" / "recorded" / ("general_compiled.csv" if list(args.scenes) == list(SCENES)
                                              else "general_compiled_" + "_".join(args.scenes) + ".csv")
    with open(out, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    print(f"wrote {out.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
