"""Run time against error: every method of the package and the usual smooth-friction baseline on one set of axes.

``python -m studies.work_precision [--out DIR] [--quick] [--workers N | --scheduler ADDRESS]`` writes,
into DIR (default figures/work_precision/) the files below (``--workers``, a new local Dask cluster,
or ``--scheduler``, a running one, runs the measurements side by side: the same errors, each time
measured where it ran, alongside the others):

- ``work_precision_<scene>.csv``: one row per method and setting (wall time, e_max, e_final,
  stop-time error, max |y|, the error the method claims, status);
- ``work_precision.png`` (e_max), ``work_precision_final.png`` (e_final),
  ``work_precision_stop.png`` (stop-time error): log-log error against wall time, one panel per
  scene, each method a series;
- ``work_precision_summary.csv``: per scene, the best error of each family and whether the
  package's best method is ahead of the regularized baseline at every accuracy below 1e-6;
- ``creep.csv``, ``creep.png``: the loaded stick over a long horizon, where the regularized law
  creeps and the complementarity methods hold x exactly.

Scenes (``lcp.scenes.jean_pratt``; m = M = 1, alpha = pi/4 with tan = 1 exactly, g = 9.81):

- ``default``: R = 0.5, v0 = 1 (kappa = 0.25), horizon 0.306 s;
- ``reverse``: v0 = -1, horizon 0.510 s;
- ``near_shock``: R = 1.98 (kappa = 0.99; N0 = 1962 N, stop after 0.51 ms), horizon 0.3 s;
- ``loaded_stick``: phi = 5 N, v0 = -1: the block slides back, stops at 0.169 s and then sticks
  under a tangential load 5 N < R (m+M) g = 9.81 N, horizon 1 s (100 s for the creep figure).

Methods:

- Moreau-Jean, theta in {1/2, 1}, h = 1e-2 ... 1e-6: the compiled fast path (``solver="auto"``,
  closed form inside a compiled CasADi ``mapaccum``) and the Python loop with each one-step solver
  (``enum``, ``lemke``, ``osqp``; ``fast=False``), the latter down to ``h_min_python``;
- the event-driven integrator (``method="event"``);
- the paper's printed series (4.1)/(4.2), with the paper's B and tau0, held after tau0;
- the LEM engine (:func:`lem.solve`) on the tanh-regularized model, degree 12, restarted
  every eps/|a| (|a| the exact deceleration) or with ``restart="auto"``;
- the tanh-regularized law f = -R N tanh(xd/eps), N = (m+M) g - M tan(alpha) xdd (linear in xdd,
  so xdd = (phi - R(m+M)g th) / (A - R M tan(alpha) th), th = tanh(xd/eps)), integrated by
  ``solve_ivp`` with RK45, LSODA and Radau (analytic Jacobian for the implicit ones), eps = 1e-1
  ... 1e-6, rtol 1e-12 and 1e-8 (atol = 1e-3 rtol). RK45 is stiff-limited for small eps and gives up
  after ``max_nfev`` right-hand-side evaluations (reported, not hidden);
- MuJoCo (``import mujoco``), when installed: the same scene as a 3-joint model with the slide as a
  tendon equality, soft contact; skipped with a message otherwise.

Errors (x is the block's position, exact solution :class:`lcp.scenes.jean_pratt_exact.JeanPrattExact`):

- ``e_max``: max |x - exact| over the method's output times: every grid point for Moreau-Jean,
  ``n_out`` equally spaced times for the others (the printed series: only those up to its tau0);
- ``e_final``: |x - exact| at the last output time (the printed series: its value held from tau0);
- ``stop_err``: |t_stop - t_s|, with t_stop the first time |xd| <= v_s = 1e-9 |v0| and t_s the
  exact solution's crossing of that level, tau0 - v_s/|a| (tau0 itself for the methods that reach
  xd = 0; they differ by < 2e-10 s here): for Moreau-Jean the first grid time after the step that
  ended in stick (xd is then 0 to rounding), for the event integrator its stop event (xd = 0
  exactly), for the tanh ODE an event function on the dense
  output, for the LEM engine linear interpolation between its output samples. A regularized law
  never reaches xd = 0: its velocity decays exponentially after tau0 (phi = 0), or creeps at
  eps atanh(phi/(R N)) for ever (loaded stick), and then t_stop is NaN (never). The printed series:
  its velocity's first zero, NaN if it has none (the paper sets t_stop = tau0 by fiat);
- ``max_y``: max |gap| (lift-off or sinking). The reduced regularized model, the series and the LEM
  model have one degree of freedom: y = 0 by construction, which they cannot violate, so it is
  reported as 0.

Times are medians of repeats after one warm-up call, in one run (the machine's load is recorded).

Example
-------
>>> from studies import work_precision
>>> res = work_precision.run(out=None, quick=True)          # doctest: +SKIP
>>> res["summary"]["loaded_stick"]["best_package_e_max"] < 1e-12   # doctest: +SKIP
True
"""
from __future__ import annotations

import functools
import math
import os
import statistics
import time
import warnings

import numpy as np
from scipy.integrate import solve_ivp

import lcp
from lem import series
from studies._cluster import add_options, cluster, pieces
from studies._common import floored, legend, out_dir, parse_args, save, write_csv

import matplotlib.pyplot as plt  # noqa: E402  (studies._common selects the Agg backend first)

# this script times the compiled loops: its short runs must not take the Python loop while a
# kernel is not loaded yet (lcp.timestepping.first_compile)
os.environ.setdefault("LCP_COMPILE", "always")


NAME = "work_precision"
#: a method has stopped when |xd| <= V_STOP_REL |v0| (a regularized law never reaches 0 exactly)
V_STOP_REL = 1e-9
#: errors of exactly 0 are drawn here on log axes
FLOOR = 1e-18
#: the accuracy below which the package must beat the regularized baseline
TARGET = 1e-6
LOADED_PHI = 5.0

SCENE_LABELS = {
    "default": "default (R = 0.5, v0 = 1, kappa = 0.25)",
    "reverse": "reverse (v0 = -1)",
    "near_shock": "near shock (R = 1.98, kappa = 0.99)",
    "loaded_stick": f"loaded stick (phi = {LOADED_PHI:g}, v0 = -1)",
}

FIELDS = ["scene", "family", "method", "params", "h", "theta", "solver", "eps", "rtol", "degree", "restart",
          "time_s", "repeats", "e_max", "e_final", "stop_err", "max_y", "claim", "claim_kind", "err_vs_reg",
          "error_estimate", "cost", "status", "success", "note"]


# ----------------------------------------------------------------------------------- settings
def settings(quick: bool) -> dict:
    """What is run, in full and quick mode."""
    if quick:
        return dict(hs=[1e-2, 1e-3, 1e-4], h_min_python={0.5: 1e-2, 1.0: 1e-2}, thetas=[0.5, 1.0],
                    python_solvers=["enum", "lemke", "osqp"], epss=[1e-2, 1e-4, 1e-6], rtols=[1e-10],
                    ivp_methods=["RK45", "LSODA", "Radau"], max_nfev=20_000, n_out=201, n_out_lem=101,
                    lem=[("default", 1e-1, "fixed"), ("default", 1e-2, "auto"), ("loaded_stick", 1e-1, "fixed")],
                    lem_degree=12, max_segments=3000, repeats=3, slow=0.3, creep_T=10.0,
                    creep_epss=[1e-2, 1e-4, 1e-6], creep_h=1e-3, creep_osqp_h=1e-2)
    return dict(hs=[1e-2, 1e-3, 1e-4, 1e-5, 1e-6], h_min_python={0.5: 1e-5, 1.0: 1e-4}, thetas=[0.5, 1.0],
                python_solvers=["enum", "lemke", "osqp"], epss=[1e-1, 1e-2, 1e-3, 1e-4, 1e-5, 1e-6],
                rtols=[1e-8, 1e-12], ivp_methods=["RK45", "LSODA", "Radau"], max_nfev=200_000, n_out=1001,
                n_out_lem=201, lem=[(s, e, r) for s in SCENE_LABELS for e in (1e-1, 1e-2) for r in ("fixed", "auto")],
                lem_degree=12, max_segments=3000, repeats=7, slow=2.0, creep_T=100.0,
                creep_epss=[1e-2, 1e-4, 1e-6], creep_h=1e-3, creep_osqp_h=1e-2)


def make_scenes() -> dict:
    """The four scenes and their horizons: {key: (scene, T)}."""
    out = {}
    for key, sc in (("default", lcp.scenes.jean_pratt()),
                    ("reverse", lcp.scenes.jean_pratt(v0=-1.0)),
                    ("near_shock", lcp.scenes.jean_pratt(R=1.98)),
                    ("loaded_stick", lcp.scenes.jean_pratt(phi=LOADED_PHI, v0=-1.0, t_end=1.0))):
        out[key] = (sc, float(sc.t_end))
    return out


# ----------------------------------------------------------------------------------- helpers
def first_accel(scene) -> float:
    """Acceleration of the first (sliding) segment of the exact motion."""
    return float(scene.solution.segments[0].a)


def exact_crossing(scene, v_s: float) -> float:
    """Time at which the exact |xd| first falls to v_s (first segment: v0 + a t = sign(v0) v_s)."""
    v0, a = float(scene.v0[0]), first_accel(scene)
    return (math.copysign(v_s, v0) - v0) / a


def timed(fn, repeats: int, slow: float):
    """Median wall time of ``fn()`` over ``repeats`` calls after one warm-up call (a second call's
    time when both are slower than ``slow`` seconds): (time, repeats, last output).

    The warm-up's own time is never reported: it includes one-time compilation (numba, CasADi's C
    code), which made a 0.2 ms event run look like 2 s.
    """
    t0 = time.perf_counter()
    out = fn()
    first = time.perf_counter() - t0
    if first > slow:
        t0 = time.perf_counter()
        out = fn()
        first = time.perf_counter() - t0
    if first > slow or repeats <= 1:
        return first, 1, out
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), repeats, out


def _row(**kw) -> dict:
    r = {k: "" for k in FIELDS}
    r.update(kw)
    return r


def _reg_params(scene):
    p = scene.params
    m, M, R, g, phi = p["m"], p["M"], p["R"], p["g"], p["phi"]
    return phi, R * (m + M) * g, scene.A, R * M * scene.tan


def tanh_rhs(scene, eps: float):
    """(rhs, jac) of the tanh-regularized reduced model, state (x, xd)."""
    phi, RW, A, RMt = _reg_params(scene)

    def rhs(_, y):
        th = math.tanh(y[1] / eps)
        return [y[1], (phi - RW * th) / (A - RMt * th)]

    def jac(_, y):
        th = math.tanh(y[1] / eps)
        d = (1.0 - th * th) / eps
        den = A - RMt * th
        return [[0.0, 1.0], [0.0, (-RW * d * den + (phi - RW * th) * RMt * d) / (den * den)]]

    return rhs, jac


class _Budget(Exception):
    pass


def tanh_ivp(scene, T, t_eval, eps, method, rtol, atol, max_nfev=None):
    """Integrate the tanh law with solve_ivp; returns (OdeResult or None when over budget, nfev)."""
    rhs0, jac = tanh_rhs(scene, eps)
    count = [0]

    def rhs(t, y):
        count[0] += 1
        if max_nfev is not None and count[0] > max_nfev:
            raise _Budget
        return rhs0(t, y)

    v0 = float(scene.v0[0])
    v_s = V_STOP_REL * abs(v0)

    def crossing(_, y):
        return v0 * y[1] - abs(v0) * v_s  # |xd| - v_s while xd keeps the sign of v0
    crossing.terminal = False
    crossing.direction = -1.0
    kw = {} if method == "RK45" else {"jac": jac}
    try:
        sol = solve_ivp(rhs, (0.0, T), [0.0, v0], method=method, t_eval=t_eval, rtol=rtol, atol=atol,
                        events=crossing, **kw)
    except _Budget:
        return None, count[0]
    return sol, count[0]


def regularized_reference(scene, T, t_eval, eps):
    """High-accuracy solution of the tanh law (Radau, rtol 1e-13): the reference of the LEM engine."""
    rhs, jac = tanh_rhs(scene, eps)
    sol = solve_ivp(rhs, (0.0, T), [0.0, float(scene.v0[0])], method="Radau", jac=jac, t_eval=t_eval,
                    rtol=1e-13, atol=1e-16)
    return sol.y


def lem_field(scene, eps):
    """The tanh-regularized model written with NumPy ufuncs (LEM's jets expand it exactly)."""
    phi, RW, A, RMt = _reg_params(scene)

    def f(_, y):
        th = np.tanh(y[1] / eps)
        return [y[1], (phi - RW * th) / (A - RMt * th)]

    return f


# ----------------------------------------------------------------------------------- methods
def run_moreau_jean(key, scene, T, h, theta, solver, fast, cfg) -> dict:
    res_holder = {}

    def go():
        res_holder["r"] = lcp.simulate(scene, T, h=h, theta=theta, solver=solver, fast=fast)
        return res_holder["r"]

    t, reps, res = timed(go, cfg["repeats"], cfg["slow"])
    x_ex = scene.exact(res.t)["x"]
    e = np.abs(res.q[:, 0] - x_ex)
    v0 = float(scene.v0[0])
    stopped = np.flatnonzero(np.abs(res.v[1:, 0]) <= V_STOP_REL * abs(v0))
    t_stop = float(res.t[stopped[0] + 1]) if stopped.size else math.nan
    a1 = abs(first_accel(scene))
    if theta == 0.5:
        claim, kind = a1 * h * h / 8, "B h^2/8 (|a| h^2/8, theta = 1/2)"
    else:
        claim, kind = abs(v0) * h / 2 + a1 * h * h / 8, "|v0| h/2 + |a| h^2/8 (theta = 1)"
    label = "MJ compiled" if (fast and solver == "auto") else f"MJ {solver} (Python loop)"
    return _row(scene=key, family="moreau-jean", method=f"{label}, theta={theta:g}",
                params=f"h={h:g}, theta={theta:g}, solver={res.solver}", h=h, theta=theta, solver=res.solver,
                time_s=t, repeats=reps, e_max=float(e.max()), e_final=float(e[-1]),
                stop_err=abs(t_stop - scene.tau0), max_y=float(np.max(np.abs(res.q[:, 1]))), claim=claim, claim_kind=kind, cost=res.stats.steps, status=res.status, success=res.success,
                note=f"{res.stats.steps} steps, {res.stats.qp_solves} QP solves, residual {res.stats.max_residual:.1e}")


def run_event(key, scene, T, cfg) -> dict:
    te = np.linspace(0.0, T, cfg["n_out"])
    t, reps, res = timed(lambda: lcp.simulate(scene, T, method="event", t_eval=te), cfg["repeats"], cfg["slow"])
    e = np.abs(res.q[:, 0] - scene.exact(te)["x"])
    stops = [ev.t for ev in res.events if ev.kind in ("stop", "tangential impact")]
    t_stop = stops[0] if stops else math.nan
    return _row(scene=key, family="event", method="event-driven", params=f"{cfg['n_out']} output times",
                time_s=t, repeats=reps, e_max=float(e.max()), e_final=float(e[-1]),
                stop_err=abs(t_stop - scene.tau0), max_y=float(np.max(np.abs(res.q[:, 1]))), claim=1e-12,
                claim_kind="machine precision (closed-form phases)", cost=len(res.events), status=res.status,
                success=res.success, note=f"{len(res.phases)} phases, {len(res.events)} events")


def run_printed_series(key, scene, T, cfg) -> dict:
    p = scene.params
    v0 = float(p["v0"])
    sgn = 1 if v0 > 0 else -1
    B = series.B_printed(p["m"], p["M"], p["alpha"], p["R"], p["g"], v0_sign=sgn)
    tau_p = abs(series.tau0_printed(v0, B))  # as printed it is negative for v0 < 0 (erratum)
    fn = series.series_4_1_printed if v0 > 0 else series.series_4_2_printed
    # its own output times: n_out on [0, tau0] (where it is meant to hold), n_out on [0, T]
    te = np.unique(np.concatenate([np.linspace(0.0, min(tau_p, T), cfg["n_out"]), np.linspace(0.0, T, cfg["n_out"])]))

    def go():
        return fn(np.minimum(te, tau_p), v0, B)

    t, reps, x = timed(go, cfg["repeats"], cfg["slow"])
    x_ex = scene.exact(te)["x"]
    on = te <= tau_p
    e = np.abs(x - x_ex)
    # the printed q(t) = sum c_k t^k: its velocity's first positive root, if any, is its stop
    c = [v0, -sgn * B / 2, 0.8 * B**2 / v0, -0.6 * B**3 / v0**2, 32.0 / 75.0 * B**4 / v0**3]
    dpoly = np.polynomial.Polynomial([k * ck for k, ck in enumerate([0.0] + c)][1:])
    roots = [r.real for r in dpoly.roots() if abs(r.imag) < 1e-12 and 0 < r.real <= T]
    t_stop = min(roots) if roots else math.nan
    return _row(scene=key, family="lem-series", method="printed series (4.1)/(4.2)",
                params=f"5 terms, paper's B = {B:.6g}, tau0 = {tau_p:.6g}, held after tau0", time_s=t,
                repeats=reps, e_max=float(e[on].max()), e_final=float(e[-1]),
                stop_err=abs(t_stop - scene.tau0), max_y=0.0, claim="", claim_kind="(none: as printed)",
                cost=te.size, status=0, success=True,
                note=("e_max on [0, tau0] only; " + ("no velocity zero in [0, T]: the series never stops"
                                                      if not roots else f"first velocity zero at {t_stop:.6g}")))


def run_lem(key, scene, T, eps, restart_kind, cfg, ref_cache) -> dict:
    from lem import solve

    a1 = abs(first_accel(scene))
    te = np.linspace(0.0, T, cfg["n_out_lem"])
    restart = eps / a1 if restart_kind == "fixed" else "auto"
    base = dict(scene=key, family="lem-engine", method=f"LEM engine ({restart_kind} restart)",
                params=f"tanh law eps={eps:g}, degree {cfg['lem_degree']}, restart="
                       + (f"{restart:.3g}" if restart_kind == "fixed" else "auto"),
                eps=eps, degree=cfg["lem_degree"], restart=restart_kind, max_y=0.0)
    if restart_kind == "fixed" and T / restart > cfg["max_segments"]:
        return _row(**base, status="skipped", success=False,
                    note=f"{T / restart:.0f} restart segments needed (> {cfg['max_segments']})")
    f = lem_field(scene, eps)
    v0 = float(scene.v0[0])

    def go():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return solve(f, (0.0, T), [0.0, v0], t_eval=te, degree=cfg["lem_degree"], restart=restart)

    t, reps, res = timed(go, min(cfg["repeats"], 3), cfg["slow"])
    if (key, eps) not in ref_cache:
        ref_cache[(key, eps)] = regularized_reference(scene, T, te, eps)
    ref = ref_cache[(key, eps)]
    x = res.y[0]
    e = np.abs(x - scene.exact(te)["x"])
    # the crossing of the level v_s, linearly interpolated between output samples
    v_s = V_STOP_REL * abs(v0)
    below = np.flatnonzero(np.abs(res.y[1]) <= v_s)
    if below.size and below[0] > 0:
        i = below[0]
        s0, s1 = abs(res.y[1][i - 1]) - v_s, abs(res.y[1][i]) - v_s
        t_cross = te[i - 1] + (te[i] - te[i - 1]) * s0 / (s0 - s1)
    else:
        t_cross = math.nan
    est = float(np.nanmax(res.error_estimate[0])) if res.error_estimate.size else math.nan
    err_reg = float(np.max(np.abs(x - ref[0])))
    silent = res.status >= 0 and err_reg > 10 * est + 1e-9
    return _row(**base, time_s=t, repeats=reps, e_max=float(e.max()), e_final=float(e[-1]),
                stop_err=abs(t_cross - exact_crossing(scene, v_s)), claim=est,
                claim_kind="its error estimate, against the regularized solution", err_vs_reg=err_reg,
                error_estimate=est, cost=res.n_restarts + 1, status=res.status, success=res.success,
                note=(f"{res.n_restarts} restarts, dimension {res.moment_dimension}; "
                      + ("SILENTLY WRONG: status >= 0 but the error against the regularized solution is "
                         f"{err_reg:.2g} (estimate {est:.2g})" if silent else res.message[:60])))


def run_tanh(key, scene, T, eps, method, rtol, cfg) -> dict:
    te = np.linspace(0.0, T, cfg["n_out"])
    atol = rtol * 1e-3
    t, reps, (sol, nfev) = timed(lambda: tanh_ivp(scene, T, te, eps, method, rtol, atol, cfg["max_nfev"]),
                                 cfg["repeats"], cfg["slow"])
    base = dict(scene=key, family="tanh-ivp", method=f"tanh law + solve_ivp {method}",
                params=f"eps={eps:g}, rtol={rtol:g}, atol={atol:g}", eps=eps, rtol=rtol, time_s=t, repeats=reps,
                max_y=0.0, cost=nfev, claim_kind="(model error: none claimed)")
    if sol is None:
        return _row(**base, e_max=math.nan, e_final=math.nan, stop_err=math.nan, status="budget", success=False,
                    note=f"gave up after {cfg['max_nfev']} rhs evaluations (stiff for small eps)")
    if not sol.success or sol.y.shape[1] != te.size:
        return _row(**base, e_max=math.nan, e_final=math.nan, stop_err=math.nan, status=sol.status, success=False,
                    note=sol.message)
    e = np.abs(sol.y[0] - scene.exact(te)["x"])
    v_s = V_STOP_REL * abs(float(scene.v0[0]))
    t_cross = float(sol.t_events[0][0]) if sol.t_events[0].size else math.nan
    return _row(**base, e_max=float(e.max()), e_final=float(e[-1]), stop_err=abs(t_cross - exact_crossing(scene, v_s)),
                status=sol.status, success=True,
                note=f"{nfev} rhs evaluations; y = 0 by construction (1-DOF reduced model)")


# ----------------------------------------------------------------------------------- MuJoCo (optional peer)
def mujoco_available() -> tuple[bool, str]:
    try:
        import mujoco  # noqa: F401
    except Exception as exc:  # ImportError, or a broken install
        return False, f"MuJoCo skipped: `import mujoco` failed ({type(exc).__name__}: {exc})"
    return True, f"MuJoCo {mujoco.__version__}"


def mujoco_model_xml(scene, h: float, cone: str = "elliptic", solref: str | None = None) -> str:
    """The Jean-Pratt scene for MuJoCo: block m (slide joints x, y), guided body M (slide joint Y),
    the slide Y - y + x tan(alpha) = const as a fixed-tendon equality, the block a box on a plane
    with friction R (condim 3). M's weight reaches x through the slide as + M g tan(alpha); a motor
    on x supplies phi - M g tan(alpha) (the paper's applied force when phi = 0), so that the
    reduced model is that of docs/models.md. MuJoCo's contact and equality are soft
    (default solref/solimp)."""
    p = scene.params
    m, M, R, g = p["m"], p["M"], p["R"], p["g"]
    t = scene.tan
    sref = f'solref="{solref}"' if solref else ""
    return f"""
<mujoco model="jean_pratt">
  <option timestep="{h!r}" gravity="0 0 {-g!r}" cone="{cone}" integrator="Euler">
    <flag gravity="enable"/>
  </option>
  <worldbody>
    <geom name="line" type="plane" size="10 10 0.1" friction="{R!r} 0 0" condim="3" {sref}/>
    <body name="block" pos="0 0 0.05">
      <joint name="x" type="slide" axis="1 0 0"/>
      <joint name="y" type="slide" axis="0 0 1"/>
      <geom name="block" type="box" size="0.05 0.05 0.05" mass="{m!r}" friction="{R!r} 0 0" condim="3" {sref}/>
    </body>
    <body name="guided" pos="0 2 1">
      <joint name="Y" type="slide" axis="0 0 1"/>
      <geom name="guided" type="box" size="0.05 0.05 0.05" mass="{M!r}" contype="0" conaffinity="0"/>
    </body>
  </worldbody>
  <tendon>
    <fixed name="slide">
      <joint joint="y" coef="1"/>
      <joint joint="x" coef="{-t!r}"/>
      <joint joint="Y" coef="-1"/>
    </fixed>
  </tendon>
  <equality>
    <tendon tendon1="slide"/>
  </equality>
  <actuator>
    <motor name="load" joint="x" gear="1"/>
  </actuator>
</mujoco>"""


def run_mujoco(key, scene, T, h, cfg) -> dict:
    import mujoco

    model = mujoco.MjModel.from_xml_string(mujoco_model_xml(scene, h))
    data = mujoco.MjData(model)
    n = int(math.ceil(T / h * (1 - 1e-12)))
    v0 = float(scene.v0[0])
    phi = float(scene.params["phi"])
    jx, jy = model.joint("x").qposadr[0], model.joint("y").qposadr[0]
    dx, dY = model.joint("x").dofadr[0], model.joint("Y").dofadr[0]
    # M's weight acts through the slide on x as + M g tan(alpha): the motor supplies phi - M g tan(alpha)
    load = phi - scene.params["M"] * scene.params["g"] * scene.tan
    # settle the soft contact at rest first (it sinks under load), outside the timing
    mujoco.mj_resetData(model, data)
    data.ctrl[0] = load
    for _ in range(int(round(0.2 / h))):
        mujoco.mj_step(model, data)
        data.qvel[dx] = 0.0
    settled_q = data.qpos.copy()
    x0, y0 = settled_q[jx], settled_q[jy]

    def go():
        mujoco.mj_resetData(model, data)
        data.qpos[:] = settled_q
        data.qvel[:] = 0.0
        data.qvel[dx] = v0
        data.qvel[dY] = -v0 * scene.tan
        data.ctrl[0] = load
        X = np.empty(n + 1)
        Y = np.empty(n + 1)
        V = np.empty(n + 1)
        X[0], Y[0], V[0] = 0.0, 0.0, v0
        for k in range(n):
            mujoco.mj_step(model, data)
            X[k + 1] = data.qpos[jx] - x0
            Y[k + 1] = data.qpos[jy] - y0
            V[k + 1] = data.qvel[model.joint("x").dofadr[0]]
        return X, Y, V

    t, reps, (X, Y, V) = timed(go, cfg["repeats"], cfg["slow"])
    tt = h * np.arange(n + 1)
    e = np.abs(X - scene.exact(tt)["x"])
    v_s = V_STOP_REL * abs(v0)
    below = np.flatnonzero(np.abs(V) <= v_s)
    t_cross = float(tt[below[0]]) if below.size else math.nan
    return _row(scene=key, family="mujoco", method="MuJoCo (soft contact, elliptic cone)",
                params=f"h={h:g}, default solref/solimp", h=h, time_s=t, repeats=reps, e_max=float(e.max()),
                e_final=float(e[-1]), stop_err=abs(t_cross - exact_crossing(scene, v_s)),
                max_y=float(np.max(np.abs(Y))), claim_kind="(soft contact: none claimed)", cost=n, status=0,
                success=True, note="Python loop over mj_step; settled at rest first (untimed); y relative to the settled gap")


# ----------------------------------------------------------------------------------- the sweep
def sweep(quick: bool, log=print, client=None, **overrides) -> tuple[list, list]:
    """Every method on every scene: (rows, messages). ``overrides`` replace entries of :func:`settings`.

    ``client``: a Dask client to run the measurements on, side by side (None: this process, one
    after the other). The errors are the same either way; the times are each measured where it ran,
    alongside the others (on a busy machine they are larger).
    """
    cfg = settings(quick)
    unknown = sorted(set(overrides) - set(cfg))
    if unknown:
        raise ValueError(f"unknown setting(s) {unknown}; known: {sorted(cfg)}")
    cfg.update(overrides)
    messages = []
    have_mj, mj_msg = mujoco_available()
    messages.append(mj_msg)
    log(mj_msg)
    tasks = []
    for key, (_scene, _T) in make_scenes().items():
        for theta in cfg["thetas"]:
            for h in cfg["hs"]:
                tasks.append(("moreau-jean", key, h, theta, "auto", True))
                if h >= cfg["h_min_python"][theta] * (1 - 1e-9):
                    for solver in cfg["python_solvers"]:
                        tasks.append(("moreau-jean", key, h, theta, solver, False))
        tasks += [("event", key), ("printed series", key)]
        tasks += [("lem", key, eps, rk) for sk, eps, rk in cfg["lem"] if sk == key]
        tasks += [("tanh", key, eps, method, rtol)
                  for method in cfg["ivp_methods"] for eps in cfg["epss"] for rtol in cfg["rtols"]]
        if have_mj:
            tasks += [("mujoco", key, h) for h in ([1e-3] if quick else [1e-3, 1e-4])]
    rows = []
    for task_rows, msg in pieces(functools.partial(sweep_piece, cfg), tasks, client, "measurements"):
        rows += task_rows
        if msg:
            messages.append(msg)
            log(msg)
    for key in make_scenes():
        log(f"{key}: {sum(r['scene'] == key for r in rows)} rows")
    return rows, messages


def sweep_piece(cfg, task) -> tuple[list, str]:
    """One measurement of :func:`sweep` (one piece of work): (rows, message)."""
    kind, key, *args = task
    scene, T = make_scenes()[key]
    if kind == "moreau-jean":
        return [run_moreau_jean(key, scene, T, *args, cfg)], ""
    if kind == "event":
        return [run_event(key, scene, T, cfg)], ""
    if kind == "printed series":
        return [run_printed_series(key, scene, T, cfg)], ""
    if kind == "lem":
        return [run_lem(key, scene, T, *args, cfg, {})], ""
    if kind == "tanh":
        return [run_tanh(key, scene, T, *args, cfg)], ""
    if kind == "mujoco":
        try:
            return [run_mujoco(key, scene, T, *args, cfg)], ""
        except Exception as exc:  # a peer's failure must not stop the benchmark
            return [], f"MuJoCo failed on {key}: {type(exc).__name__}: {exc}"
    raise ValueError(f"unknown measurement kind {kind!r}")


def _num(x) -> float:
    try:
        return float(x)
    except (TypeError, ValueError):
        return math.nan


def pareto(points):
    """Lower-left frontier of (time, error) points: sorted by time, strictly decreasing error."""
    pts = sorted((t, e) for t, e in points if np.isfinite(t) and np.isfinite(e))
    front, best = [], math.inf
    for t, e in pts:
        if e < best:
            front.append((t, e))
            best = e
    return front


#: families in the package's frontier (the printed series reproduces the paper: not a method to pick)
PACKAGE = ("moreau-jean", "event", "lem-engine")
BASELINE = ("tanh-ivp",)


def summarize(rows: list) -> dict:
    """Per scene: best error per family and the comparison of the package's frontier with the
    baseline's below TARGET."""
    out = {}
    for key in SCENE_LABELS:
        rs = [r for r in rows if r["scene"] == key]
        fam_best = {}
        for r in rs:
            e = _num(r["e_max"])
            if np.isfinite(e):
                fam_best[r["family"]] = min(fam_best.get(r["family"], math.inf), e)
        pk = pareto([(_num(r["time_s"]), max(_num(r["e_max"]), 0.0)) for r in rs
                     if r["family"] in PACKAGE and r["success"] is True])
        bl = pareto([(_num(r["time_s"]), _num(r["e_max"])) for r in rs if r["family"] in BASELINE and r["success"]])
        # every accuracy E < TARGET that the baseline reaches, in time t_b: does the package reach
        # an error <= E in less time?
        comparisons = []
        for tb, eb in bl:
            if eb < TARGET:
                tp = min((t for t, e in pk if e <= eb), default=math.inf)
                comparisons.append(dict(baseline_error=eb, baseline_time=tb, package_time=tp,
                                        speedup=tb / tp if tp > 0 else math.inf))
        # Moreau-Jean alone (the time stepper a user would pick for many contacts) against the baseline
        mj = pareto([(_num(r["time_s"]), _num(r["e_max"])) for r in rs if r["family"] == "moreau-jean" and r["success"]])
        mj_cmp = [tb / min((t for t, e in mj if e <= eb), default=math.inf) for tb, eb in bl if eb < TARGET]
        best_pk = min((e for _, e in pk), default=math.nan)
        best_bl = min((e for _, e in bl), default=math.nan)
        # accuracies below TARGET that only the package reaches count as wins too
        out[key] = dict(best_package_e_max=best_pk, best_baseline_e_max=best_bl,
                        best_by_family=fam_best, comparisons=comparisons,
                        package_ahead_below_target=all(c["speedup"] > 1 for c in comparisons),
                        min_speedup=min((c["speedup"] for c in comparisons), default=math.inf),
                        package_front=pk, baseline_front=bl,
                        moreau_jean_ahead_below_target=all(x > 1 for x in mj_cmp),
                        moreau_jean_min_speedup=min(mj_cmp, default=math.inf))
    return out


# ----------------------------------------------------------------------------------- creep
def creep(quick: bool, **overrides) -> dict:
    """The loaded stick over a long horizon: |x - exact| and the drift since the stop, per method."""
    cfg = settings(quick)
    cfg.update(overrides)
    T = cfg["creep_T"]
    scene = lcp.scenes.jean_pratt(phi=LOADED_PHI, v0=-1.0, t_end=T)
    tau0 = scene.tau0
    t1 = tau0 + 0.05  # the drift is measured from here
    te = np.unique(np.concatenate([np.geomspace(t1, T, 60), np.linspace(0.0, T, 201), [t1]]))
    p = scene.params
    N = (p["m"] + p["M"]) * p["g"]
    rate_per_eps = math.atanh(LOADED_PHI / (p["R"] * N))  # creep velocity / eps
    series_out = []

    def add(method, eps, t, x, seconds):
        x_at_t1 = float(np.interp(t1, t, x))
        err = np.abs(x - scene.exact(t)["x"])
        after = t >= t1
        series_out.append(dict(method=method, eps=eps, t=t[after], err=err[after],
                               drift=np.abs(x[after] - x_at_t1), seconds=seconds))

    for eps in cfg["creep_epss"]:
        for method in ("LSODA", "Radau"):
            t0 = time.perf_counter()
            sol, _ = tanh_ivp(scene, T, te, eps, method, 1e-12, 1e-15)
            add(f"tanh law + {method}", eps, sol.t, sol.y[0], time.perf_counter() - t0)
    h = cfg["creep_h"]
    every = max(1, int(round(0.05 / h)))
    t0 = time.perf_counter()
    r = lcp.simulate(scene, T, h=h, save_every=every)
    add(f"MJ compiled, h={h:g}", "", r.t, r.q[:, 0], time.perf_counter() - t0)
    h2 = cfg["creep_osqp_h"]
    t0 = time.perf_counter()
    r2 = lcp.simulate(scene, T, h=h2, solver="osqp", fast=False, save_every=max(1, int(round(0.05 / h2))))
    add(f"MJ osqp (Python loop), h={h2:g}", "", r2.t, r2.q[:, 0], time.perf_counter() - t0)
    t0 = time.perf_counter()
    r3 = lcp.simulate(scene, T, method="event", t_eval=te)
    add("event-driven", "", r3.t, r3.q[:, 0], time.perf_counter() - t0)
    return dict(T=T, tau0=tau0, t1=t1, rate_per_eps=rate_per_eps, series=series_out,
                predicted=lambda t, eps: eps * rate_per_eps * (np.asarray(t) - tau0))


# ----------------------------------------------------------------------------------- figures
def _style(r):
    fam, m = r["family"], r["method"]
    th = r["theta"]
    dashed = "--" if th == 1.0 else "-"
    if fam == "moreau-jean":
        col = {"compiled": "C0", "enum": "C1", "lemke": "C2", "osqp": "C3"}
        k = next(k for k in col if k in m)
        return dict(color=col[k], ls=dashed, marker="o" if th == 0.5 else "s", ms=4, lw=1.2,
                    alpha=1.0 if th == 0.5 else 0.7)
    if fam == "event":
        return dict(color="k", ls="", marker="*", ms=13)
    if fam == "lem-series":
        return dict(color="saddlebrown", ls="", marker="X", ms=9)
    if fam == "lem-engine":
        return dict(color="purple", ls="", marker="D" if "fixed" in m else "d", ms=7,
                    mfc="purple" if "fixed" in m else "none")
    if fam == "mujoco":
        return dict(color="teal", ls=":", marker="P", ms=8)
    col = {"RK45": "tab:olive", "LSODA": "tab:cyan", "Radau": "tab:pink"}
    k = next(k for k in col if k in m)
    return dict(color=col[k], ls=":", marker="^", ms=4, lw=1.0)


def _series_key(r):
    if r["family"] == "tanh-ivp":
        return (r["method"] + f" (rtol {r['rtol']:g})") if isinstance(r["rtol"], float) else r["method"]
    return r["method"]


def figure(rows, summary, metric, path, ylabel):
    fig, axes = plt.subplots(2, 2, figsize=(14, 10.5))
    marked = set()
    for ax, key in zip(axes.ravel(), SCENE_LABELS):
        rs = [r for r in rows if r["scene"] == key and np.isfinite(_num(r["time_s"])) and r["time_s"] != ""]
        groups = {}
        for r in rs:
            e = _num(r[metric])
            if not np.isfinite(e):
                continue
            groups.setdefault(_series_key(r), []).append((_num(r["time_s"]), e, r))
        for name, pts in groups.items():
            r0 = pts[0][2]
            st = _style(r0)
            if r0["family"] == "tanh-ivp":
                # one line per integrator and rtol, ordered by eps
                pts = sorted(pts, key=lambda p: -p[2]["eps"])
                if isinstance(r0["rtol"], float) and r0["rtol"] > 1e-10:
                    st = dict(st, alpha=0.45, mfc="none")
            elif r0["family"] == "moreau-jean":
                pts = sorted(pts, key=lambda p: -p[2]["h"])
            tt, ee = np.array([p[0] for p in pts]), np.array([p[1] for p in pts])
            (ln,) = ax.loglog(tt, np.where(ee >= FLOOR, ee, np.nan), label=name, **st)
            # below the floor: marked at the floor, never on a line and never called zero unless it is
            for sel, mk in ((ee == 0, "x"), ((ee > 0) & (ee < FLOOR), "v")):
                if sel.any():
                    ax.plot(tt[sel], np.full(sel.sum(), FLOOR), mk, color=ln.get_color(), mfc="none", ms=7)
                    marked.add(mk)
        if metric == "e_max":
            pk, bl = summary[key]["package_front"], summary[key]["baseline_front"]
            # a frontier holds for every longer time: extend it to the panel's slowest run, so that a
            # frontier of one point (one method fastest and most accurate) is still drawn
            t_max = max((_num(r["time_s"]) for r in rs), default=None)
            if t_max is not None:
                pk = list(pk) + [(t_max, pk[-1][1])] if pk else pk
                bl = list(bl) + [(t_max, bl[-1][1])] if bl else bl
            if pk:
                ax.step(*zip(*[(t, max(e, FLOOR)) for t, e in pk]), where="post", color="k", lw=6, alpha=0.3,
                        zorder=0, label="package: best (frontier; at the floor where below it)")
            if bl:
                ax.step(*zip(*bl), where="post", color="tab:red", lw=6, alpha=0.3, zorder=0,
                        label="tanh baseline: best (frontier)")
        ax.axhline(TARGET, color="gray", lw=0.8, ls="-.")
        never = [r for r in rs if r["success"] is True and not np.isfinite(_num(r[metric]))]
        if metric == "stop_err" and never:
            fams = sorted({r["family"] for r in never})
            ax.text(0.98, 0.02, f"never stopped (not drawn): {len(never)} runs ({', '.join(fams)})",
                    transform=ax.transAxes, ha="right", va="bottom", fontsize=8)
        ax.set_title(SCENE_LABELS[key], fontsize=11)
        ax.set_xlabel("wall time (s)")
        ax.set_ylabel(ylabel)
        ax.grid(True, which="major", alpha=0.3)
    handles = {}
    for ax in axes.ravel():
        for hnd, lab in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(lab, hnd)
    from matplotlib.lines import Line2D

    if "v" in marked:
        handles[f"error below {FLOOR:g} (marked at {FLOOR:g})"] = Line2D([], [], ls="", marker="v", mfc="none", color="k")
    if "x" in marked:
        handles[f"error exactly 0 (marked at {FLOOR:g})"] = Line2D([], [], ls="", marker="x", color="k")
    fig.legend(list(handles.values()), list(handles.keys()), loc="lower center", ncol=4, fontsize=8.5,
               frameon=False, bbox_to_anchor=(0.5, -0.005))
    fig.suptitle(f"Work-precision, Jean-Pratt scenes: {ylabel} against wall time "
                 f"(dash-dot line: {TARGET:g})", fontsize=12)
    fig.tight_layout(rect=(0, 0.1, 1, 0.97))
    return save(fig, path)


def _thinned(t, y, floor, keep=25):
    """Indices to draw: every point at or above the floor, about `keep` of those below it (their markers
    would otherwise merge into a band; the CSV holds every point)."""
    below = np.flatnonzero(y < floor)
    step = max(1, len(below) // keep)
    return np.union1d(np.flatnonzero(y >= floor), below[::step])


PREDICTED = "predicted drift eps atanh(phi/(R N)) (t - t1)"


def _predicted_drift(cr):
    """(eps, t, drift) of the creep law the regularized runs should follow (the figure's dash-dot lines)."""
    t = np.geomspace(cr["t1"], cr["T"], 50)[1:]
    return [(eps, ti, cr["predicted"](ti, eps) - cr["predicted"](cr["t1"], eps))
            for eps in sorted({s["eps"] for s in cr["series"] if s["eps"] != ""}, reverse=True) for ti in t]


def creep_figure(cr, path):
    fig, axes = plt.subplots(1, 2, figsize=(14, 5))
    eps_colors = {}
    for s in cr["series"]:
        if s["method"].startswith("tanh"):
            eps_colors.setdefault(s["eps"], ["tab:orange", "tab:purple", "tab:brown", "tab:olive",
                                             "tab:cyan"][len(eps_colors) % 5])
            st = dict(lw=1.5, color=eps_colors[s["eps"]], ls="-" if "LSODA" in s["method"] else ":")
            label = f"{s['method']}, eps = {s['eps']:g}"
        else:
            color = "k" if "compiled" in s["method"] else ("tab:red" if "osqp" in s["method"] else "tab:green")
            st = dict(lw=2.0, color=color, ls="--")
            label = s["method"]
        fmt = st.pop("ls")
        i = _thinned(s["t"], s["err"], FLOOR)
        floored(axes[0], s["t"][i], s["err"][i], FLOOR, fmt=fmt, label=label, **st)
        later = s["t"] > cr["t1"]
        t_l, d_l = s["t"][later], s["drift"][later]
        i = _thinned(t_l, d_l, FLOOR)
        if np.any(d_l >= FLOOR):
            floored(axes[1], t_l[i], d_l[i], FLOOR, fmt=fmt, label=label, **st)
        else:  # drift exactly 0: crosses at the floor, and a legend entry (no data) for the left panel's line
            floored(axes[1], t_l[i], d_l[i], FLOOR, fmt=fmt, **st)
            axes[1].plot([], [], fmt, label=label, **st)
    pred = _predicted_drift(cr)
    for k, eps in enumerate(sorted({e for e, _, _ in pred}, reverse=True)):
        t, d = np.array([(ti, di) for e, ti, di in pred if e == eps]).T
        axes[1].plot(t, d, color="k", lw=0.8, ls="-.", label="eps atanh(phi/(R N)) (t - t1)" if k == 0 else None)
    axes[0].set_title("|x - exact| on the loaded stick (phi = 5 N < R (m+M) g)", fontsize=10)
    axes[1].set_title("drift since t1 = tau0 + 0.05 s", fontsize=10)
    for ax in axes:
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("t (s)")
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel("error (m)")
    axes[1].set_ylabel("|x(t) - x(t1)| (m)")
    axes[1].text(0.03, 0.16, "MJ (compiled, OSQP) and event-driven: drift exactly 0", transform=axes[1].transAxes,
                 fontsize=9)
    axes[1].set_ylim(bottom=FLOOR / 30)  # room for the floor note below the floor's markers
    legend(axes[1])
    fig.suptitle("The regularized law creeps; the complementarity methods hold the stick", fontsize=12)
    return save(fig, path)


# ----------------------------------------------------------------------------------- entry points
def write_tables(rows, summary, folder, prefix="work_precision"):
    files = []
    for key in SCENE_LABELS:
        files.append(write_csv(folder / f"{prefix}_{key}.csv", FIELDS,
                               [[r[f] for f in FIELDS] for r in rows if r["scene"] == key]))
    hdr = ["scene", "best_package_e_max", "best_baseline_e_max", "package_ahead_below_1e-6", "min_speedup",
           "n_baseline_points_below_1e-6", "moreau_jean_ahead_below_1e-6", "moreau_jean_min_speedup", "best_by_family"]
    files.append(write_csv(folder / f"{prefix}_summary.csv", hdr, [
        [k, s["best_package_e_max"], s["best_baseline_e_max"], s["package_ahead_below_target"], s["min_speedup"],
         len(s["comparisons"]), s["moreau_jean_ahead_below_target"], s["moreau_jean_min_speedup"], "; ".join(f"{f}={e:.3g}" for f, e in s["best_by_family"].items())]
        for k, s in summary.items()]))
    return files


def run(out=None, quick: bool = False, log=None, workers: int | None = None, scheduler: str | None = None) -> dict:
    """Run the sweep and the creep study, write CSV and figures; return the numbers.

    ``workers`` (a new local Dask cluster) or ``scheduler`` (a running one's address) runs the
    sweep's measurements side by side: the same errors; each time measured where it ran.

    Returns
    -------
    dict
        ``rows`` (list of dicts, fields :data:`FIELDS`), ``summary`` (per scene, see
        :func:`summarize`), ``creep`` (the loaded-stick series), ``messages``, ``load``
        (os.getloadavg() before and after), ``files``, ``seconds``.
    """
    log = log or (lambda *a: None)
    t_start = time.perf_counter()
    load0 = os.getloadavg()
    folder = out_dir(out, NAME)
    with cluster(workers, scheduler) as client:
        rows, messages = sweep(quick, log, client)
    summary = summarize(rows)
    cr = creep(quick)
    files = write_tables(rows, summary, folder)
    files.append(write_csv(folder / "creep.csv", ["method", "eps", "t", "error", "drift"],
                           [[s["method"], s["eps"], float(t), float(e), float(d)]
                            for s in cr["series"] for t, e, d in zip(s["t"], s["err"], s["drift"])]
                           + [[PREDICTED, eps, float(t), "", float(d)] for eps, t, d in _predicted_drift(cr)]))
    files.append(figure(rows, summary, "e_max", folder / "work_precision.png", "e_max = max |x - exact|"))
    files.append(figure(rows, summary, "e_final", folder / "work_precision_final.png", "e_final = |x(T) - exact|"))
    files.append(figure(rows, summary, "stop_err", folder / "work_precision_stop.png", "stop-time error (s)"))
    files.append(creep_figure(cr, folder / "creep.png"))
    return dict(rows=rows, summary=summary, creep=cr, messages=messages, load=(load0, os.getloadavg()),
                files=files, seconds=time.perf_counter() - t_start, quick=quick)


def main(argv=None):
    args = parse_args(NAME, __doc__.splitlines()[0], argv, extra=add_options)
    res = run(args.out, args.quick, log=print, workers=args.workers, scheduler=args.scheduler)
    for key, s in res["summary"].items():
        print(f"{key:13s} best package e_max {s['best_package_e_max']:.2e}, best baseline {s['best_baseline_e_max']:.2e}, "
              f"package ahead below {TARGET:g}: {s['package_ahead_below_target']} (min speed-up {s['min_speedup']:.3g})")
    print(f"load average before/after: {res['load'][0]} / {res['load'][1]}")
    print(f"wrote {len(res['files'])} files to {args.out} in {res['seconds']:.1f} s")
    return res


if __name__ == "__main__":
    main()
