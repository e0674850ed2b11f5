"""Numerical stability under stress: every method on hard cases, and every failure visible.

``python -m studies.stability [--out DIR] [--quick] [--workers N | --scheduler ADDRESS]`` runs each
method on each hard case (the cases side by side on a Dask cluster with ``--workers`` or
``--scheduler``; the table is the same, only the seconds differ) and classifies the outcome:

- **correct**: the run succeeded and every check holds (finite, Coulomb residual, no lift-off or
  sinking, constraint drift, energy, agreement with the exact solution or a reference);
- **reported failure**: the method said it failed (``success`` False, with status and message), or
  the input was refused with a ``ValueError``;
- **silently wrong**: the run said it succeeded but a check fails. This column must stay empty.

It writes ``stability.csv`` (one row per case and method, with the measured numbers),
``summary.csv`` and ``stability.png`` (the outcome table as a colour map).

Energy: with e = 0 and conservative forces the energy E = T + V never increases for theta = 1
(dE = p.u+ - |v+ - v-|_A^2 / 2 <= 0). With theta = 1/2, dE = p.(u+ + u-)/2 exactly, and the
Coulomb law only guarantees p.u+ <= 0: energy can rise where the impulse works along the
pre-step velocity u- (the block turns round, or is stopped by a load, inside the step; a
separating contact is caught by the gap predictor), by at most p.u-/2 = O(h^2). The check allows
exactly that bound for theta = 1/2, and nothing for theta = 1 (the "theta = 1" cases).
"""
from __future__ import annotations

from dataclasses import dataclass, field
import functools
import math
import time
import tracemalloc
from types import SimpleNamespace
from typing import Callable

import casadi as ca
import numpy as np

import lcp
from lcp.timestepping.compiled_step import applicable as compiled_applicable
from lcp.scenes import block_chain, jean_pratt
from lcp.model.system import Contact, System

from ._cluster import add_options, cluster, pieces
from ._common import out_dir, parse_args, plt, save, write_csv

NAME = "stability"

#: methods: label -> keyword arguments of lcp.simulate
METHODS = {
    "MJ compiled": dict(method="moreau-jean", solver="auto"),
    "MJ enum (Python)": dict(method="moreau-jean", solver="enum", fast=False),
    "MJ lemke": dict(method="moreau-jean", solver="lemke"),
    "MJ osqp": dict(method="moreau-jean", solver="osqp"),
    "event": dict(method="event"),
}
OUTCOMES = ("correct", "reported failure", "silently wrong", "not applicable")


@dataclass
class Case:
    """A hard case: how to build it and what 'correct' means.

    ``build()`` returns (scene, t_end, h, save_every). ``reference`` is "exact" (the scene's exact
    solution), "converged" (Moreau-Jean at h/4 must agree to O(h)), or None (invariants only).
    """

    group: str
    name: str
    build: Callable
    reference: str | None = "exact"
    methods: tuple = tuple(METHODS)
    theta: float = 0.5
    x_tol: Callable | None = None  # extra tolerance on x (scene, h) -> float
    notes: str = ""
    energy: bool = True
    quick: bool = True
    sim_kw: dict = field(default_factory=dict)  # extra keyword arguments of lcp.simulate
    gap_check: bool = True  # False where the contact legitimately opens
    #: (scene, res, h, method) -> (ok, reason, measured): a case's own check instead of the ones below
    check: Callable | None = None


@dataclass
class Row:
    group: str
    case: str
    method: str
    outcome: str
    reason: str = ""
    steps: int = 0
    seconds: float = 0.0
    peak_mb: float = float("nan")
    nan_inf: bool = False
    residual: float = float("nan")
    max_gap: float = float("nan")
    bilateral_drift: float = float("nan")
    energy_rise: float = float("nan")
    x_error: float = float("nan")
    x_tol: float = float("nan")
    status: int = 0
    message: str = ""
    extra: dict = field(default_factory=dict)


# ----------------------------------------------------------------------------- cases
def _jp(h_per_tau=50 + 1 / 7, t_factor=1.5, **kw):
    """A Jean-Pratt scene with h scaled to its stop time (about 50 steps to the stop)."""
    def build():
        sc = jean_pratt(**kw)
        tau = sc.tau0 if np.isfinite(sc.tau0) and sc.tau0 > 0 else 0.1
        h = tau / h_per_tau
        return sc, t_factor * tau + 10 * h, h, 1
    return build


def _kappa_R(kappa, m=1.0, M=1.0, alpha=math.pi / 4):
    t = 1.0 if alpha == math.pi / 4 else math.tan(alpha)
    return kappa * (m + M * t * t) / (M * t)


def _bounce(e=0.5, h=1e-3):
    def build():
        q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
        s = System(q, v, ca.SX.eye(2), ca.vertcat(0, -9.81), contacts=[Contact(gap=q[1], tangent=q[0], mu=0.3, e=e)],
                   names=("x", "y"))
        from lcp.scenes import Scene
        sc = Scene(s, np.array([0.0, 1.0]), np.array([0.5, 0.0]), 2.0, "bouncing_block", dict(e=e), None)
        return sc, 2.0, h, 1
    return build


def _chain(K=6, mass_ratio=1e6, k_spring=1e4, h=1e-3):
    def build():
        masses = np.geomspace(1.0, mass_ratio, K)
        rng = np.random.default_rng(K)
        sc = block_chain(K, m=masses, mu=0.4, k_spring=k_spring * masses.min(), v0=rng.uniform(-1, 1, K), t_end=0.5)
        return sc, 0.5, h, 1
    return build


def _periodic(h=1e-3):
    def build():
        sc = jean_pratt(v0=0.0, load=lambda t: 15.0 * ca.sin(2 * math.pi * t), t_end=3.0)
        return sc, 3.0, h, 1
    return build


def cases(quick: bool) -> list[Case]:
    out = []
    hs = [1e-1, 1e-2, 1e-3, 1e-4] + ([] if quick else [1e-5, 1e-6])
    for h in hs:
        def build(h=h):
            sc = jean_pratt()
            return sc, 0.3 if h < 1e-4 else 0.3, h, 1
        slow_python = h < 1e-4
        out.append(Case("step size", f"h = {h:g}", build,
                        methods=("MJ compiled", "event") + (() if slow_python else ("MJ enum (Python)", "MJ lemke", "MJ osqp")),
                        quick=h >= 1e-3))
    ks = range(1, 16) if not quick else (1, 6, 12, 15)
    for k in ks:
        for sgn in (-1, +1):
            kap = 1 + sgn * 10.0 ** -k
            out.append(Case("kappa near 1", f"kappa = 1 {'+' if sgn > 0 else '-'} 1e-{k}",
                            lambda kap=kap: (jean_pratt(R=2.0 * kap), 0.05, 1e-3, 1)))
    out.append(Case("kappa near 1", "kappa = 1 exactly", lambda: (jean_pratt(R=2.0), 0.05, 1e-3, 1)))
    for ratio in ([1e-6, 1e-3, 1.0, 1e3, 1e6] if not quick else [1e-6, 1e6]):
        out.append(Case("mass ratio m/M", f"m/M = {ratio:g}",
                        _jp(m=ratio, M=1.0, alpha=0.6, R=_kappa_R(0.5, ratio, 1.0, 0.6))))
    for tan in ([1e-3, 1e-2, 1e2, 1e3] if not quick else [1e-3, 1e3]):
        al = math.atan(tan)
        out.append(Case("alpha near 0 or pi/2", f"tan(alpha) = {tan:g}",
                        _jp(alpha=al, R=_kappa_R(0.5, alpha=al))))
    for v0 in ([1e-12, 1e-6, 1e-2, 1e2, 1e3] if not quick else [1e-12, 1e3]):
        for sgn in (1, -1):
            out.append(Case("|v0|", f"v0 = {sgn * v0:g}", _jp(v0=sgn * v0)))
    n_long = 10**6 if not quick else 10**5
    out.append(Case("long horizon", f"{n_long:.0e} steps",
                    lambda n=n_long: (jean_pratt(), 0.3, 0.3 / n, 1000),
                    methods=("MJ compiled", "event"), notes="memory: decimated (save_every = 1000)"))
    out.append(Case("long horizon", "1e5 steps (Python loops)",
                    lambda: (jean_pratt(), 0.3, 0.3e-5, 1000),
                    methods=("MJ enum (Python)", "MJ lemke", "MJ osqp"), quick=False))
    out.append(Case("periodic load", "phi(t) = 15 sin(2 pi t), 3 s", _periodic(2e-3 if quick else 1e-3),
                    reference="converged", methods=("MJ compiled", "MJ enum (Python)", "MJ lemke", "MJ osqp", "event"),
                    energy=False, notes="non-conservative load: energy not checked"))
    out.append(Case("loaded contact", "phi = -12 (reversal)", _jp(phi=-12.0, t_factor=4.0),
                    x_tol=lambda sc, h: 2 * 13.0 * h * 1.0))
    out.append(Case("open and close", "bouncing block, e = 0.5", _bounce(), reference=None,
                    methods=("MJ compiled", "MJ enum (Python)", "MJ lemke", "MJ osqp", "event"), energy=True))
    out.append(Case("open and close", "bouncing block, e = 0", _bounce(e=0.0), reference=None,
                    methods=("MJ compiled", "MJ enum (Python)", "MJ lemke", "MJ osqp", "event"), energy=True))
    out.append(Case("open and close", "kappa = 1.25, load beyond stick from rest: lift-off",
                    lambda: (jean_pratt(R=2.5, v0=0.0, phi=60.0), 0.1, 1e-3, 1), reference="converged",
                    gap_check=False, energy=False, notes="the contact opens; no exact solution"))
    mj = ("MJ compiled", "MJ enum (Python)", "MJ lemke", "MJ osqp")
    out.append(Case("theta = 1 (energy)", "bouncing block, e = 0", _bounce(e=0.0), reference=None, methods=mj,
                    theta=1.0))
    out.append(Case("theta = 1 (energy)", "phi = -12 (reversal)", _jp(phi=-12.0, t_factor=4.0), methods=mj,
                    theta=1.0, x_tol=lambda sc, h: 2 * 13.0 * h * 1.0 + 2 * 13.0 * h))
    out.append(Case("theta = 1 (energy)", "default scene", _jp(), methods=mj, theta=1.0))
    for ratio in ([1e2, 1e6] if quick else [1e2, 1e4, 1e6]):
        out.append(Case("ill-conditioned chain", f"K = 6, mass ratio {ratio:g}", _chain(6, ratio),
                        reference="converged", methods=("MJ lemke", "MJ osqp", "MJ compiled"),
                        notes="MJ compiled = auto (Lemke for several contacts)"))
    # failures that must be reported, never silent
    out.append(Case("must be reported", "alpha = pi/2 (bad input)", lambda: (jean_pratt(alpha=math.pi / 2), 0.1, 1e-3, 1)))
    out.append(Case("must be reported", "OSQP capped at 1 ADMM iteration, no fallback",
                    lambda: (block_chain(3), 0.1, 1e-3, 1), methods=("MJ osqp",), reference=None,
                    sim_kw=dict(solver_options=dict(osqp_max_iter=1, max_iter=1), fallback=False)))
    out.append(Case("must be reported", "enum forced on 3 contacts",
                    lambda: (block_chain(3), 0.1, 1e-3, 1), methods=("MJ enum (Python)",), reference=None))
    out.extend(classical_cases(quick))
    out.extend(example_cases(quick))
    out.extend(moving_and_rigid_cases(quick))
    return [c for c in out if c.quick or not quick]


# ----------------------------------------------------------------------------- classical systems
def _classical_check(quantity, exact_tol, mj_tol=None):
    """A check of a classical system (lcp.classical): ``quantity(scene, res)`` returns (computed,
    reference) arrays; the event method must agree to ``exact_tol``; Moreau-Jean to ``mj_tol(scene,
    h)`` when given, else to its own first-order error estimate, 2.5 |q_h - q_{h/2}| (a run at h/2
    on the same grid), so that a result off its order is caught without a hand-set tolerance."""
    def check(scene, res, h, method):
        m = dict(residual=float(res.stats.max_residual), bilateral_drift=float(res.max_constraint_violation))
        if not (np.all(np.isfinite(res.q)) and np.all(np.isfinite(res.v))):
            m["nan_inf"] = True
            return False, "non-finite state", m
        got, ref = quantity(scene, res)
        err = float(np.max(np.abs(got - ref)))
        if method == "event":
            tol = exact_tol
        elif mj_tol is not None:
            tol = mj_tol(scene, h)
        else:
            half = lcp.simulate(scene, res.t[-1], **dict(METHODS[method], h=h / 2, save_every=2))
            if not half.success:
                return False, f"the h/2 run failed: {half.message}", m
            n = min(len(half.t), len(res.t))
            got_half, _ = quantity(scene, SimpleNamespace(t=half.t[:n], q=half.q[:n], v=half.v[:n]))
            tol = 2.5 * float(np.max(np.abs(got[:n] - got_half))) + 1e-12
        m["x_error"], m["x_tol"] = err, tol
        if not err <= tol:
            return False, f"error {err:.2e} > {tol:.2e}", m
        return True, "", m
    return check


def classical_cases(quick: bool) -> list:
    """The classical systems of lcp.classical, each with its exact solution or reference."""
    from lcp import classical as cl

    def q_of(sc, res):
        return res.q, sc.exact(res.t)["q"]

    one = ("MJ compiled", "MJ enum (Python)", "MJ lemke", "MJ osqp", "event")
    many = ("MJ compiled", "MJ lemke", "MJ osqp", "event")

    def incline_tol(sc, h):
        segs, T = sc.solution.segments, sc.t_end
        a1, a2 = segs[0].a, segs[1].a
        rev = segs[1].mode != "stick"
        return 1e-12 + abs(a1) * h * h / 8 + (abs(a1 - a2) * h * (T - segs[1].t0 + h) + abs(a2) * h * h if rev else 0.0)

    def rod_impulse(sc, res):
        return np.array([res.p_N[0, 0], res.p_T[0, 0]]), sc.solution.tangential_impact()[0]

    def rod_event_impulse(sc, res):
        if res.method != "event":
            return rod_impulse(sc, res)
        imp = [i for i in res.impulses if i.kind == "tangential impact"]
        return (np.array([imp[0].P_N, imp[0].P_T]) if imp else np.zeros(2)), sc.solution.tangential_impact()[0]

    def stack_rest(sc, res):
        dropped = float(np.sum(res.modes == -1)) if res.method != "event" else 0.0
        return np.concatenate([res.q.ravel(), [dropped]]), np.concatenate([np.tile(sc.q0, len(res.t)), [0.0]])

    group = "classical systems"
    out = [
        Case(group, "incline: launch up, stop, slide back", lambda: (cl.incline(0.5, 0.2, 2.0), 1.0, 1e-3, 1),
             methods=one, check=_classical_check(q_of, 1e-10, incline_tol), energy=False),
        Case(group, "incline: launch up, stop, stick", lambda: (cl.incline(0.3, 0.5, 2.0), 1.0, 1e-3, 1),
             methods=one, check=_classical_check(q_of, 1e-10, incline_tol), energy=False),
        Case(group, "bouncing ball e = 0.5 (Zeno, rest)", lambda: (cl.bouncing_ball(0.5), 2.0, 1e-3, 1),
             methods=one, check=_classical_check(lambda sc, r: (r.q[:, 1], sc.exact(r.t)["y"]), 1e-9,
                                                 lambda sc, h: 3 * sc.solution.approach_speeds[0] * h), energy=False),
        Case(group, "pendulum via x^2 + y^2 = L^2, 90 deg, 1.5 periods",
             lambda: (cl.pendulum(periods=1.5), cl.pendulum().solution.period * 1.5, 1e-3, 1),
             methods=("MJ compiled", "event"), check=_classical_check(q_of, 1e-8), energy=False),
        Case(group, "Painleve rod, consistent sliding", lambda: (cl.painleve_rod(mu=0.3, t_end=0.2), 0.2, 1e-3, 1),
             methods=one, check=_classical_check(lambda sc, r: (r.q, sc.solution.reference(r.t)), 1e-8), energy=False),
        Case(group, "Painleve rod, inconsistent: tangential impact",
             lambda: (cl.painleve_rod(mu=3.0, t_end=0.05), 0.05, 1e-3, 1), methods=one, energy=False,
             check=_classical_check(rod_event_impulse, 1e-10,
                                    lambda sc, h: 10 * h * np.max(np.abs(sc.solution.tangential_impact()[0])))),
        Case(group, "Painleve rod, indeterminate", lambda: (cl.painleve_rod(mu=3.0, omega0=8.0, t_end=0.05), 0.05, 1e-3, 1),
             methods=one[:-1], energy=False, notes="Moreau-Jean takes the impulsive solution",
             check=_classical_check(rod_impulse, 1e-10,
                                    lambda sc, h: 10 * h * np.max(np.abs(sc.solution.tangential_impact()[0])))),
        Case(group, "5 stacked blocks at rest, 1e3 steps of 1e-4",
             lambda: (cl.stacked_blocks(5, height=0.1), 0.1, 1e-4, 1), methods=many, energy=False,
             check=_classical_check(stack_rest, 1e-12, lambda sc, h: 8 * np.finfo(float).eps)),
        Case(group, "10 stacked blocks at rest, 1e5 steps of 1e-6",
             lambda: (cl.stacked_blocks(10, height=0.1), 0.1, 1e-6, 100), methods=many, energy=False, quick=False,
             check=_classical_check(stack_rest, 1e-12, lambda sc, h: 8 * np.finfo(float).eps)),
        Case(group, "2 blocks pushed: top slips", lambda: (cl.stacked_blocks(2, mu=[0.5, 0.3], push=20.0), 0.5, 1e-3, 1),
             methods=many, energy=False, check=_classical_check(q_of, 1e-10, lambda sc, h: 1e-12)),
        Case(group, "box on two corners: slides", lambda: (cl.box_on_corners(mu=0.3), 1.6, 1e-3, 1), methods=many,
             energy=False, check=_classical_check(
                 lambda sc, r: (r.q[:, 0], sc.solution(r.t)["x"]), 1e-9,
                 lambda sc, h: sc.params["ramp"] * h * h / (2 * sc.params["m"]) * 1.6 + 1e-12)),
        Case(group, "box on two corners: tips", lambda: (cl.box_on_corners(mu=1.2, push_height=0.45, t_end=2.6), 2.6, 2e-3, 1),
             methods=many, energy=False, quick=False,
             check=_classical_check(lambda sc, r: (r.q[:, 2], sc.solution.tip_angle(r.t)), 1e-8)),
        # impacts fall anywhere in their step, so the error is O(h) but not smooth in h: bounded by
        # the angular speed times a step per impact (and one for the pivots' drift), times 4
        Case(group, "rocking block (Housner)", lambda: (cl.rocking_block(t_end=0.75), 0.75, 5e-4, 1), methods=many,
             energy=False, check=_classical_check(
                 lambda sc, r: (r.q[:, 2], sc.solution(r.t)["theta"]), 1e-9,
                 lambda sc, h: 4 * (sum(t <= sc.t_end for t in sc.solution.impact_times) + 1) * h
                 * max(float(np.max(np.abs(p.y[1]))) for p in sc.solution.pieces))),
    ]
    return out


# ----------------------------------------------------------------------------- example scenes
def _energy_and_limit_check(energy, limit, tol_per_h):
    """A check for a scene without a closed form: the energy ``energy(scene, res)`` never rises
    (to rounding for Moreau-Jean, to its integrator's tolerance for the event method) and, where
    ``limit`` is given, Moreau-Jean's positions lie within ``tol_per_h * h`` of ``limit(scene, t)``
    (the event method's run, or Moreau-Jean's limit; first order, the constant measured)."""
    def check(scene, res, h, method):
        m = dict(residual=float(res.stats.max_residual))
        if not (np.all(np.isfinite(res.q)) and np.all(np.isfinite(res.v))):
            m["nan_inf"] = True
            return False, "non-finite state", m
        E = energy(scene, res)
        rise = float(np.max(np.diff(E))) if E.size > 1 else 0.0
        m["energy_rise"] = rise
        allow = (1e-12 if res.method == "moreau-jean" else 1e-10) * float(np.max(np.abs(E)))
        if rise > allow:
            return False, f"energy rose by {rise:.2e}", m
        if limit is not None and res.method == "moreau-jean":
            err = float(np.max(np.abs(res.q - limit(scene, res.t))))
            m["x_error"], m["x_tol"] = err, tol_per_h * h
            if not err <= tol_per_h * h:
                return False, f"|q - limit| = {err:.2e} > {tol_per_h * h:.2e}", m
        return True, "", m
    return check


def example_cases(quick: bool) -> list:
    """The example scenes: the woodpecker toy, Flores's slider-crank with clearance,
    a point mass in a bowl and a rod falling on two end contacts."""
    from lcp import classical as cl
    from lcp.scenes.slider_crank_clearance import slider_crank_clearance_energy
    from lcp.scenes.woodpecker import woodpecker_energy

    group = "example scenes"
    one = ("MJ compiled", "MJ enum (Python)", "MJ lemke", "MJ osqp", "event")
    many = ("MJ compiled", "MJ lemke", "MJ osqp", "event")

    @functools.lru_cache(maxsize=1)
    def woodpecker_event():
        sc = cl.woodpecker()
        return lcp.simulate(sc, 0.3, method="event", t_eval=np.linspace(0.0, 0.3, 15001))

    def woodpecker_limit(sc, t):
        ev = woodpecker_event()
        return np.array([np.interp(t, ev.t, ev.q[:, j]) for j in range(3)]).T

    def rod_q(sc, res):
        ok = res.t <= sc.solution.t_valid
        return res.q[ok], sc.exact(res.t[ok])["q"]

    return [
        # measured |q - event| = 3.8e-3 at h = 2e-5 (phi_M; 190 h): first order, constant 500 allowed
        Case(group, "woodpecker (Siconos's data, start projected)", lambda: (cl.woodpecker(), 0.3, 2e-5, 1),
             methods=("MJ compiled", "event") + (() if quick else ("MJ lemke",)), energy=False,
             check=_energy_and_limit_check(lambda sc, r: woodpecker_energy(sc.params, r.q, r.v),
                                           woodpecker_limit, 500.0)),
        # measured 5.1e-3 rad at h = 1e-4 over 0.01 s (redundant corner pairs: both closed at c = 0)
        Case(group, "slider-crank, zero clearance = ideal crank",
             lambda: (cl.slider_crank_clearance(c=0.0, omega3=0.0, mu=0.0, t_end=0.01), 0.01, 1e-4, 1),
             methods=("MJ compiled", "event"), energy=False,
             check=_classical_check(lambda sc, r: (r.q[:, :2], sc.exact(np.minimum(r.t, sc.t_end))["q"][:, :2]),
                                    1e-8, lambda sc, h: 150.0 * h)),
        Case(group, "slider-crank, clearance 1 mm (energy)",
             lambda: (cl.slider_crank_clearance(t_end=0.02), 0.02, 1e-4, 1), methods=("MJ compiled", "MJ lemke"),
             energy=False, quick=False,
             check=_energy_and_limit_check(lambda sc, r: slider_crank_clearance_energy(sc.params, r.q, r.v),
                                           None, 0.0)),
        Case(group, "point mass in a bowl, mu = 0.1", lambda: (cl.bowl(mu=0.1, t_end=1.2), 1.2, 2e-3, 1),
             methods=("MJ compiled", "MJ lemke", "event") if quick else one, energy=False,
             check=_classical_check(lambda sc, r: (r.q, sc.exact(r.t)["q"]), 1e-9)),
        Case(group, "rod falling on two ends, e = 0.5, mu = 0.3",
             lambda: (cl.impacting_rod(), cl.impacting_rod().solution.t_valid, 1e-3, 1),
             methods=many, energy=False, check=_classical_check(rod_q, 1e-9)),
    ]


# ----------------------------------------------------------------------------- moving obstacles, rigid bodies
def _against_run(reference, event_tol, mj_per_h):
    """A check against another run: ``reference(scene, t)`` gives the reference positions at the
    saved times; the event method must agree to ``event_tol``, Moreau-Jean to ``mj_per_h * h``
    (first order: impacts fall anywhere in their step; the constant measured, with margin)."""
    def check(scene, res, h, method):
        m = dict(residual=float(res.stats.max_residual))
        if not (np.all(np.isfinite(res.q)) and np.all(np.isfinite(res.v))):
            m["nan_inf"] = True
            return False, "non-finite state", m
        err = float(np.max(np.abs(res.q[:, :2] - reference(scene, res.t))))
        tol = event_tol if method == "event" else mj_per_h * h
        m["x_error"], m["x_tol"] = err, tol
        if not err <= tol:
            return False, f"|q - reference| = {err:.2e} > {tol:.2e}", m
        return True, "", m
    return check


def _rigid_check(scene, res, h, method):
    """Torque-free body: energy and |L| (world frame) conserved -- to 1e-10 by the event method, to
    5 h^2 relative by Moreau-Jean (its drift is 2.4 h^2 on this body) -- and |quaternion| = 1."""
    m = dict(residual=float(res.stats.max_residual))
    E = np.array([scene.energy(q, v) for q, v in zip(res.q, res.v)])
    L = np.array([np.linalg.norm(scene.angular_momentum(q, v)) for q, v in zip(res.q, res.v)])
    drift = max(float(np.max(np.abs(E / E[0] - 1))), float(np.max(np.abs(L / L[0] - 1))))
    norm = float(np.max(np.abs(np.linalg.norm(res.q[:, 3:7], axis=1) - 1)))
    tol = 1e-10 if method == "event" else 5 * h * h
    m["x_error"], m["x_tol"] = drift, tol
    if not drift <= tol:
        return False, f"energy or |L| drifted by {drift:.2e} > {tol:.2e}", m
    if not norm <= 1e-14:
        return False, f"|quaternion| - 1 = {norm:.2e}", m
    return True, "", m


def _box_rest_check(scene, res, h, method):
    """Tumbling cube: energy never rises after the drop, and at the end it rests on a face (centre
    at half the side, one body axis vertical, at rest)."""
    m = dict(residual=float(res.stats.max_residual))
    E = np.array([scene.energy(q, v) for q, v in zip(res.q, res.v)])
    rise = float(np.max(np.diff(E)))
    m["energy_rise"] = rise
    if rise > (1e-12 if method != "event" else 1e-10) * float(np.max(np.abs(E))):
        return False, f"energy rose by {rise:.2e}", m
    half = 0.5 * scene.params["side"]
    q, v = res.q[-1], res.v[-1]
    err = max(abs(float(q[2]) - half), float(np.max(np.abs(v))))
    m["x_error"], m["x_tol"] = err, 1e-6
    if not err <= 1e-6:
        return False, f"not at rest on a face: |z - side/2| or |v| = {err:.2e}", m
    return True, "", m


def _bead_column_check(after: float):
    """Bead column: no gap below -1e-9 (event) or -5 h (Moreau-Jean), the energy never rises (to rounding for
    Moreau-Jean, to the integrator's 1e-10 for the event method), and Moreau-Jean agrees with the
    event method's run to 5 h once the column has settled (t >= ``after``). While the beads bounce
    the difference is not monotone in h: the bounces depend on where the impacts fall on the grid
    (measured on 10 beads, e = 0.5, max over 0.3 <= t < 0.9: 1.8e-2, 3.7e-2, 1.8e-2, 7.0e-2 at
    h = 1e-3, 1e-4, 1e-5, 2e-6, then 4.2e-6 at h = 1e-6; at t >= 0.9: 2.3e-3, 3.1e-4, 2.4e-6)."""
    @functools.lru_cache(maxsize=2)
    def event_run(K, e, t_end):
        from lcp.classical import bead_column

        sc = bead_column(K, e=e, t_end=t_end)
        return lcp.simulate(sc, t_end, method="event", n_eval=int(round(t_end * 1000)) + 1)

    def check(scene, res, h, method):
        m = dict(residual=float(res.stats.max_residual))
        if not (np.all(np.isfinite(res.q)) and np.all(np.isfinite(res.v))):
            m["nan_inf"] = True
            return False, "non-finite state", m
        gaps = min(float(np.min(scene.system.gaps(q))) for q in res.q[:: max(1, len(res.q) // 500)])
        # Moreau-Jean: a contact pushed shut within a step by an impulse from below enters the
        # working set a step late, O(h |v|) deep (measured -1.1e-4 at h = 1e-4)
        if gaps < (-1e-9 if method == "event" else -5 * h):
            return False, f"a gap reached {gaps:.2e}", m
        E = scene.energy(res.q, res.v)
        rise = float(np.max(np.diff(E)))
        m["energy_rise"] = rise
        if method == "event" and rise > 1e-10 * float(np.max(np.abs(E))):
            return False, f"energy rose by {rise:.2e}", m
        if method != "event":
            ev = event_run(scene.params["K"], scene.params["e"], float(res.t[-1]))
            keep = ev.t >= after
            idx = np.round(ev.t[keep] / h).astype(int)
            err = float(np.max(np.abs(res.q[idx] - ev.q[keep])))
            m["x_error"], m["x_tol"] = err, 5 * h
            if not err <= 5 * h:
                return False, f"|q - event| = {err:.2e} > {5 * h:.2e} after the cascades", m
        return True, "", m
    return check


def moving_and_rigid_cases(quick: bool) -> list:
    """Moving obstacles (time-dependent gaps: a cam, a table, a conveyor belt) and free rigid bodies
    in 3D (the Dzhanibekov flip, a cube tumbling onto its corners)."""
    from lcp.scenes import dzhanibekov, tumbling_box
    from lcp.scenes.moving import cam_follower, conveyor, moving_table

    group = "moving obstacles, rigid bodies"
    moving = ("MJ compiled", "MJ lemke", "event")

    def pinned(build):
        @functools.lru_cache(maxsize=4)
        def run(t_key):
            t = np.array(t_key)
            return lcp.simulate(build(), float(t[-1]), method="event", t_eval=t).q[:, :2]
        return lambda sc, t: run(tuple(np.asarray(t, dtype=float)))

    from lcp.classical import bead_column

    return [
        # Moreau-Jean's energy rises by up to 1e-6 in a step at h = 1e-4 (restitution on several
        # contacts closing at once): only the event method's energy is checked
        Case(group, "column of 10 beads falling, e = 0.5", lambda: (bead_column(10, e=0.5, t_end=1.5), 1.5, 1e-4, 1),
             methods=("MJ compiled", "MJ lemke", "event"), energy=False, check=_bead_column_check(0.9)),
        Case(group, "conveyor belt: slip then stick (exact)", lambda: (conveyor(t_end=0.5), 0.5, 1e-3, 1),
             methods=moving, energy=False,
             check=_classical_check(lambda sc, r: (r.q[:, 0], sc.exact(r.t)["x"]), 1e-12,
                                    lambda sc, h: 10 * h * h + 1e-12)),
        # measured against the pinned form: event 1e-11; Moreau-Jean 1.2e-3 at h = 1e-3 (impacts land on the grid)
        Case(group, "cam follower, gap y - c(t), e = 0.8", lambda: (cam_follower(t_end=1.0), 1.0, 1e-3, 1),
             methods=moving, energy=False,
             check=_against_run(pinned(lambda: cam_follower(t_end=1.0, pinned=True)), 1e-8, 5.0)),
        Case(group, "ball on a table moving as A sin(wt)", lambda: (moving_table(t_end=1.0), 1.0, 1e-3, 1),
             methods=moving, energy=False,
             check=_against_run(pinned(lambda: moving_table(t_end=1.0, pinned=True)), 1e-8, 5.0)),
        Case(group, "torque-free body: Dzhanibekov flip", lambda: (dzhanibekov(t_end=10.0 if not quick else 4.0),
                                                                     10.0 if not quick else 4.0, 5e-3, 1),
             methods=("MJ compiled", "event"), energy=False, check=_rigid_check),
        Case(group, "cube tumbling onto its corners, mu = 0.3", lambda: (tumbling_box(t_end=2.0), 2.0, 1e-3, 10),
             methods=("MJ compiled", "event"), energy=False, quick=False, check=_box_rest_check),
    ]


# ----------------------------------------------------------------------------- LEM cases
LEM_METHOD = "LEM engine"


def _tanh_reference(x_end, z0=1.0):
    from scipy.integrate import solve_ivp

    sol = solve_ivp(lambda _, y: [y[1], math.tanh(y[0])], (0.0, x_end), [0.0, z0], rtol=1e-13, atol=1e-15)
    return float(sol.y[0, -1])


def lem_cases(quick: bool):
    """(group, name, run) for the LEM engine; run() -> (status, success, y, estimate, reference)."""
    import warnings

    from lem import solve

    def tanh_ode(x_end, restart=None, degree=61):
        def run():
            f = lambda _, y: [y[1], np.tanh(y[0])]  # noqa: E731
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                kw = dict(degree=degree, rtol=1e-9)  # the accuracy the issue asks of it (1e-10 absolute)
                if restart is not None:
                    kw["restart"] = restart
                res = solve(f, (0.0, x_end), [0.0, 1.0], **kw)
            return res.status, res.success, float(res.y[0, -1]), float(res.error_estimate[0, -1]), \
                _tanh_reference(x_end), res.message
        return run

    def saturated_friction(eps):
        def run():
            from scipy.integrate import solve_ivp

            B = 6.54  # the default scene's deceleration: qdd = -B tanh(qd / eps)
            f = lambda _, y: [y[1], -B * np.tanh(y[1] / eps)]  # noqa: E731
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                res = solve(f, (0.0, 0.3), [0.0, 1.0], degree=12, restart="auto")
            ref = solve_ivp(lambda _, y: [y[1], -B * math.tanh(y[1] / eps)], (0.0, 0.3), [0.0, 1.0],
                            method="Radau", rtol=1e-12, atol=1e-14)
            return res.status, res.success, float(res.y[0, -1]), float(res.error_estimate[0, -1]), \
                float(ref.y[0, -1]), res.message
        return run

    def troesch(lam):
        def run():
            from lem.troesch import TROESCH_REFERENCE, solve_troesch

            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                res = solve_troesch(lam)
            est = getattr(res, "error_estimate", 0.0)
            return res.status, res.success, float(res.slope), float(np.max(est)) if np.size(est) else 0.0, \
                TROESCH_REFERENCE[lam], res.message
        return run

    out = [("LEM (smooth ODEs)", "y'' = tanh y, x = 1, N = 61", tanh_ode(1.0)),
           ("LEM (smooth ODEs)", "y'' = tanh y, x = 2, N = 61, no restart", tanh_ode(2.0)),
           ("LEM (smooth ODEs)", "y'' = tanh y, x = 2, N = 61, restarted", tanh_ode(2.0, "auto")),
           ("LEM (smooth ODEs)", "qdd = -B tanh(qd/eps), eps = 0.01, auto restarts", saturated_friction(0.01)),
           ("LEM (smooth ODEs)", "Troesch, lambda = 1", troesch(1.0))]
    if not quick:
        out.append(("LEM (smooth ODEs)", "Troesch, lambda = 10", troesch(10.0)))
    return out


def run_lem_case(group, name, fn) -> Row:
    row = Row(group, name, LEM_METHOD, "correct")
    t0 = time.perf_counter()
    try:
        status, success, y, est, ref, message = fn()
    except ValueError as exc:
        row.outcome, row.reason = "reported failure", f"ValueError: {exc}"
        return row
    row.seconds = time.perf_counter() - t0
    row.status, row.message = status, message
    row.nan_inf = not math.isfinite(y)
    err = abs(y - ref)
    row.x_error = err
    # trust what the result claims: its own estimate (never below rounding) must cover the error
    row.x_tol = max(10 * est, 1e-12 * max(1.0, abs(ref)))
    if not success or status != 0:
        row.outcome, row.reason = "reported failure", message
    elif not err <= row.x_tol:
        row.outcome, row.reason = "silently wrong", f"error {err:.2e} > claimed {row.x_tol:.2e}"
    return row


# ----------------------------------------------------------------------------- checks
def _energy(scene, res):
    """Total energy along the result for Jean-Pratt (reduced/full) and the bouncing block / chain."""
    s = scene.system
    T = np.array([s.kinetic_energy(q, v) for q, v in zip(res.q, res.v)])
    p = scene.params
    if scene.name == "jean_pratt":
        if p["coordinates"] == "reduced":
            V = (p["m"] + p["M"]) * p["g"] * res.q[:, 1] - p["phi"] * res.q[:, 0]
        else:
            V = p["g"] * (p["m"] * res.q[:, 1] + p["M"] * res.q[:, 2]) + (p["M"] * p["g"] * scene.tan - p["phi"]) * res.q[:, 0]
    elif scene.name == "bouncing_block":
        V = 9.81 * res.q[:, 1]
    else:  # block chain
        x = res.q[:, 0::2]
        V = 0.5 * p["k_spring"] * np.sum((np.diff(x, axis=1) - p["spacing"]) ** 2, axis=1) \
            + p["g"] * res.q[:, 1::2] @ p["m"]
    return T + V


def _energy_rise(scene, res, theta):
    """Largest energy rise per saved step beyond what the scheme allows (see module docstring)."""
    E = _energy(scene, res)
    dE = np.diff(E)
    scale = max(1.0, float(np.max(np.abs(E))))
    allow = 1e-12 * scale * np.ones_like(dE)
    if theta == 0.5 and res.p_T.shape[0] == dE.size and res.method == "moreau-jean":
        # theta = 1/2 with constant forces: dE = p.(u+ + u-)/2 exactly, and Coulomb's law gives
        # p.u+ <= 0; so energy can rise only where the impulse works along the pre-step velocity
        # u- (a separating contact caught by the gap predictor, friction turning inside the
        # step), by at most p.u-/2 = O(h^2). That, and nothing more, is allowed.
        s_ = scene.system
        m = s_.n_contacts
        H = s_.contact_jacobian(res.q[0])
        u_minus = res.v[:-1] @ H.T  # (steps, 2m): exact for constant H (all scenes here)
        work = np.sum(res.p_N * u_minus[:, :m] + res.p_T * u_minus[:, m:], axis=1)
        allow = allow + 0.5 * np.maximum(work, 0.0)
    return float(np.max(dE - allow)) if dE.size else 0.0, scale


def _check(case: Case, scene, res, h, method, ref_cache) -> tuple[bool, str, dict]:
    """Checks of a successful run: returns (ok, reason, measured numbers)."""
    if case.check is not None:
        return case.check(scene, res, h, method)
    m = dict()
    finite = bool(np.all(np.isfinite(res.q)) and np.all(np.isfinite(res.v)))
    m["nan_inf"] = not finite
    if not finite:
        return False, "non-finite state", m
    m["residual"] = float(res.stats.max_residual)
    s = scene.system
    gaps = np.array([s.gaps(q) for q in res.q[:: max(1, len(res.q) // 2000)]])
    m["max_gap"] = float(np.max(np.abs(gaps))) if gaps.size else 0.0
    if s.n_bilateral:
        drift = np.array([s.constraint_residual(q) for q in res.q[:: max(1, len(res.q) // 2000)]])
        m["bilateral_drift"] = float(np.max(np.abs(drift)))
    else:
        m["bilateral_drift"] = 0.0
    reasons = []
    scale_p = 1.0
    if scene.solution is not None:
        scale_p = max(1.0, abs(scene.params["M"] * scene.tan * scene.params["v0"]))
    if method == "event":  # its residual is the acceleration-level one, in force units
        scale_p = max(scale_p, float(np.max(np.abs(res.force_N))))
    if m["residual"] > 1e-9 * scale_p:
        reasons.append(f"Coulomb residual {m['residual']:.2e}")
    xscale = max(1.0, float(np.max(np.abs(res.q[:, 0]))))
    if scene.name in ("jean_pratt", "block_chain") and case.gap_check:
        if m["max_gap"] > 1e-12 * xscale:
            reasons.append(f"gap {m['max_gap']:.2e} (lift-off or sinking)")
    elif scene.name == "bouncing_block":
        # velocity-level contact: sinking at most one step of the impact velocity
        if np.min(gaps) < -h * 10.0:
            reasons.append(f"penetration {np.min(gaps):.2e}")
    if m["bilateral_drift"] > 1e-10 * xscale:
        reasons.append(f"bilateral drift {m['bilateral_drift']:.2e}")
    if case.energy:
        rise, escale = _energy_rise(scene, res, case.theta)
        m["energy_rise"] = rise
        if rise > 1e-10 * escale:
            reasons.append(f"energy rose by {rise:.2e}")
    if case.reference == "exact" and scene.solution is not None:
        ex = scene.exact(res.t)
        err = float(np.max(np.abs(res.q[:, 0] - ex["x"])))
        xs = max(1.0, abs(scene.x_stop) if np.isfinite(scene.x_stop) else 1.0)
        if method == "event":
            tol = 1e-12 * xs
        elif scene.params["phi"] == 0.0 and case.theta == 0.5:
            B = scene.B if np.isfinite(scene.B) else 0.0
            tol = B * h * h / 8 + 1e-12 * xs + (res.q.shape[0] * 2e-16 * xs)
        elif scene.params["phi"] == 0.0:  # theta = 1: first order, |v| h / 2 per unit of motion
            tol = abs(scene.params["v0"]) * h + 1e-12 * xs
        else:
            tol = case.x_tol(scene, h) if case.x_tol else 1e-12
        if scene.kappa >= 1 and method != "event":
            tol = max(tol, abs(scene.params["v0"]) * h * (1 - case.theta) + 1e-12)
        m["x_error"], m["x_tol"] = err, tol
        if not err <= tol:
            reasons.append(f"|x - exact| = {err:.2e} > {tol:.2e}")
    elif case.reference == "converged":
        key = case.name
        if key not in ref_cache:
            fine = lcp.simulate(scene, res.t[-1], h=h / 4, solver="lemke", fast=False)
            ref_cache[key] = fine
        fine = ref_cache[key]
        if not fine.success:
            reasons.append("reference run failed")
        else:
            xf = np.array([np.interp(res.t, fine.t, fine.q[:, j]) for j in range(0, s.n, 2 if s.n > 2 else 1)]).T
            xr = res.q[:, 0:s.n:2 if s.n > 2 else 1]
            err = float(np.max(np.abs(xr - xf)))
            vmax = max(1.0, float(np.max(np.abs(res.v))))
            accel = 50.0  # generous: O(h) error constant of the load and spring scenes
            tol = (vmax + accel) * h * float(res.t[-1]) + 1e-9
            m["x_error"], m["x_tol"] = err, tol
            if not err <= tol:
                reasons.append(f"disagrees with the h/4 reference by {err:.2e} > {tol:.2e}")
    return not reasons, "; ".join(reasons), m


def run_case(case: Case, method: str, ref_cache: dict) -> Row:
    row = Row(case.group, case.name, method, "correct")
    try:
        scene, t_end, h, every = case.build()
    except ValueError as exc:
        row.outcome, row.reason = "reported failure", f"ValueError: {exc}"
        return row
    kw = dict(METHODS[method])
    kw.update(case.sim_kw)
    if kw["method"] == "moreau-jean":
        kw.update(h=h, theta=case.theta, save_every=every)
        if method == "MJ compiled" and not compiled_applicable(scene.system):
            kw["solver"] = "auto"  # several contacts: auto (Lemke) in the Python loop
    else:
        n_eval = min(2001, int(t_end / h) + 1) if every == 1 else 1001
        kw.update(n_eval=max(n_eval, 2))
    trace = case.group == "long horizon"  # tracemalloc slows Python down: only where memory matters
    if trace:
        tracemalloc.start()
    t0 = time.perf_counter()
    try:
        res = lcp.simulate(scene, t_end, **kw)
    except ValueError as exc:
        tracemalloc.stop()
        row.outcome, row.reason = "reported failure", f"ValueError: {exc}"
        return row
    except Exception as exc:  # noqa: BLE001 - a crash is recorded, never hidden
        tracemalloc.stop()
        row.outcome, row.reason = "reported failure", f"exception {type(exc).__name__}: {exc}"
        row.extra["crash"] = True
        return row
    row.seconds = time.perf_counter() - t0
    if trace:
        row.peak_mb = tracemalloc.get_traced_memory()[1] / 2**20
        tracemalloc.stop()
    row.steps, row.status, row.message = res.stats.steps, res.status, res.message
    if not res.success:
        row.outcome, row.reason = "reported failure", res.message
        return row
    ok, reason, meas = _check(case, scene, res, h, method, ref_cache)
    for k, val in meas.items():
        setattr(row, k, val)
    if not ok:
        row.outcome, row.reason = "silently wrong", reason
    return row


def case_rows(quick: bool, index: int) -> list:
    """The rows of case ``index`` of :func:`cases`, every method (one piece of work)."""
    case = cases(quick)[index]
    ref_cache = {}
    rows = []
    for method in METHODS:
        if method not in case.methods:
            rows.append(Row(case.group, case.name, method, "not applicable"))
            continue
        rows.append(run_case(case, method, ref_cache))
    return rows


def lem_case_rows(quick: bool, index: int) -> list:
    """The rows of LEM case ``index`` of :func:`lem_cases` (one piece of work)."""
    group, name, fn = lem_cases(quick)[index]
    return [Row(group, name, method, "not applicable") for method in METHODS] + [run_lem_case(group, name, fn)]


def run(out=None, quick: bool = False, workers: int | None = None, scheduler: str | None = None) -> dict:
    """Run every case with every applicable method; write the table and the figure.

    ``workers`` (a new local Dask cluster) or ``scheduler`` (a running one's address) runs the
    cases side by side; the rows are the same, only ``seconds`` differs.

    Returns
    -------
    dict
        ``rows`` (list of Row), ``counts`` {outcome: n}, ``files``.
    """
    outdir = out_dir(out, NAME)
    rows = []
    with cluster(workers, scheduler) as client:
        for part in pieces(functools.partial(case_rows, quick), range(len(cases(quick))), client, "cases"):
            rows.extend(part)
        for part in pieces(functools.partial(lem_case_rows, quick), range(len(lem_cases(quick))), client,
                           "LEM cases"):
            rows.extend(part)
    for case in cases(quick):  # the simulators have nothing to say about the LEM-only cases
        rows.append(Row(case.group, case.name, LEM_METHOD, "not applicable"))
    fields_ = ["group", "case", "method", "outcome", "reason", "steps", "seconds", "peak_mb", "nan_inf",
               "residual", "max_gap", "bilateral_drift", "energy_rise", "x_error", "x_tol", "status", "message"]
    write_csv(outdir / "stability.csv", fields_, [[getattr(r, f) for f in fields_] for r in rows])
    counts = {o: sum(r.outcome == o for r in rows) for o in OUTCOMES}
    all_methods = list(METHODS) + [LEM_METHOD]
    per_method = {mth: {o: sum(r.outcome == o and r.method == mth for r in rows) for o in OUTCOMES}
                  for mth in all_methods}
    write_csv(outdir / "summary.csv", ["method"] + list(OUTCOMES),
              [[mth] + [per_method[mth][o] for o in OUTCOMES] for mth in all_methods])
    _figure(rows, outdir)
    return dict(rows=rows, counts=counts, per_method=per_method, out=str(outdir),
                files=sorted(p.name for p in outdir.iterdir()))


def _figure(rows, outdir):
    case_names = list(dict.fromkeys((r.group, r.case) for r in rows))
    methods = list(METHODS) + [LEM_METHOD]
    code = {"correct": 0, "reported failure": 1, "silently wrong": 2, "not applicable": 3}
    grid = np.full((len(case_names), len(methods)), 3)
    for r in rows:
        grid[case_names.index((r.group, r.case)), methods.index(r.method)] = code[r.outcome]
    from matplotlib.colors import ListedColormap
    cmap = ListedColormap(["#4daf4a", "#ffbf00", "#e41a1c", "#dddddd"])
    fig, ax = plt.subplots(figsize=(9.5, 0.24 * len(case_names) + 1.8))
    ax.imshow(grid, cmap=cmap, vmin=-0.5, vmax=3.5, aspect="auto")
    ax.set_xticks(range(len(methods)), methods, rotation=20, ha="right", fontsize=8)
    ax.set_yticks(range(len(case_names)), [f"{g}: {c}" for g, c in case_names], fontsize=7)
    ax.set_title("Outcome per hard case and method (green correct, amber reported failure,\n"
                 "red silently wrong, grey not applicable)", fontsize=9)
    for i in range(len(case_names)):
        for j in range(len(methods)):
            if grid[i, j] == 2:
                ax.text(j, i, "WRONG", ha="center", va="center", fontsize=6, color="white")
    fig.tight_layout()
    save(fig, outdir / "stability.png")


def main(argv=None):
    args = parse_args(NAME, "Stress every method on hard cases; no silently wrong result allowed.", argv,
                      extra=add_options)
    res = run(args.out, args.quick, workers=args.workers, scheduler=args.scheduler)
    print(f"Stability table written to {res['out']}/")
    print(f"{'method':18s} " + " ".join(f"{o:>17s}" for o in OUTCOMES))
    for mth, c in res["per_method"].items():
        print(f"{mth:18s} " + " ".join(f"{c[o]:17d}" for o in OUTCOMES))
    for r in res["rows"]:
        if r.outcome in ("silently wrong", "reported failure"):
            print(f"  [{r.outcome}] {r.group} / {r.case} / {r.method}: {r.reason[:160]}")


if __name__ == "__main__":
    main()
