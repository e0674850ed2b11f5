"""The systems and optimal control problems of :mod:`studies.ocp_examples`.

Each builder returns an :class:`Example`: the controlled System, its start, the problem factory
``make(N)`` and the continuous-time cost (``integrand(t, q, v, u)`` and ``terminal(q, v)``) with
which any control, ours or nosnoc's, is scored on its replay. Where nosnoc has the example
(``studies/_nosnoc_examples.py``), the data are nosnoc_py's (examples/cart_pole_with_friction,
examples/motor_with_friction, examples/hopper_robot, examples/discs_exercise); a friction force of
constant magnitude F (nosnoc's Filippov form) is a Coulomb contact with a decoupled vertical
coordinate of unit mass pressed by F / mu, so that mu N = F exactly.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

import lcp
from lcp.model.system import Contact, System
from lcp.ocp import OptimalControlProblem, add_control, effort
from lcp.ocp.options import START_RHS

__all__ = ["CHAIN7", "EXAMPLES", "Example", "ball_bounce", "block_chain", "block_chain7", "box_tip", "cart_pole",
           "hopper", "motor", "point_on_plane", "point_stick_slide", "two_discs"]

G = 9.81


@dataclass
class Example:
    """One example: ``make(N)`` builds the problem; ``integrand``/``terminal`` score a replay."""

    name: str
    title: str
    system: System
    q0: np.ndarray
    v0: np.ndarray
    T: float
    make: Callable
    integrand: Callable  # (t, q, v, u) arrays over samples -> (samples,)
    terminal: Callable  # (q, v) -> float
    N_quick: int
    N_full: tuple
    reference: float = float("nan")
    reference_note: str = ""
    solve_kw: dict = field(default_factory=dict)
    #: problem -> the start of its solve (an OCPGuess), or None for the defaults
    start: Callable = None
    #: (q, v) -> the coordinates shared with nosnoc's model (its replay miss is measured on them)
    common: Callable = None

    def common_state(self, q, v) -> np.ndarray:
        return np.concatenate([q, v]) if self.common is None else np.asarray(self.common(q, v), dtype=float)


#: the examples' grid: N uniform stages with the control held constant over each, as nosnoc poses its
#: examples (and as the recorded comparisons ran); the package's own default for planar contacts
#: would make the steps free and the hold affine, a larger control space than nosnoc's
NOSNOC_GRID = {"hold": "constant", "steps": "uniform"}


def _effort(t, q, v, u):
    return np.sum(u * u, axis=1)


def _zero(q, v):
    return 0.0


# ----------------------------------------------------------------------------- point on a plane
def point_on_plane(mu: float = 0.3, T: float = 1.0, target=(1.0, 0.5)) -> Example:
    """A unit point mass on the plane z = 0 (a spatial contact, the Coulomb disk) pushed by a horizontal
    force u in R^2 from rest at (0, 0) to rest at ``target`` in T with minimum int |u|^2 dt.

    Closed form: the straight slide, u = a + mu g along the line with a linear in t and
    int a = 0, costs 12 d^2 / T^3 + (mu g)^2 T while the optimal slide time sqrt(6 d / (mu g))
    exceeds T (no stick phase)."""
    q, v, u = ca.SX.sym("q", 3), ca.SX.sym("v", 3), ca.SX.sym("u", 2)
    sys = System(q, v, ca.SX.eye(3), ca.vertcat(u[0], u[1], -G),
                 contacts=[Contact(gap=q[2], tangent=ca.vertcat(q[0], q[1]), mu=mu, name="point")],
                 control=u, control_bounds=(-20 * np.ones(2), 20 * np.ones(2)), names=["x", "y", "z"])
    d = float(np.hypot(*target))
    assert np.sqrt(6 * d / (mu * G)) > T
    ref = 12 * d ** 2 / T ** 3 + (mu * G) ** 2 * T

    def make(N):
        return OptimalControlProblem(sys, N, T=T, q0=np.zeros(3), v0=np.zeros(3), stage_cost=effort,
                                     terminal_constraints=lambda q, v: ca.vertcat(q[0] - target[0], q[1] - target[1],
                                                                                  v[0], v[1]))

    return Example("point_on_plane", "point steered on a plane (spatial contact)", sys, np.zeros(3), np.zeros(3), T,
                   make, _effort, _zero, 20, (10, 20, 40), ref,
                   "12 d^2/T^3 + (mu g)^2 T (straight slide); the constant hold's discrete optimum is "
                   "12 d^2 N^2/(T^3 (N^2-1)) + (mu g)^2 T")


def point_stick_slide(mu: float = 0.3, T: float = 2.0, target=(1.0, 0.5)) -> Example:
    """:func:`point_on_plane` over T = 2 s, longer than the optimal slide time sqrt(6 d / (mu g)) = 1.51 s:
    the point sticks, slides and sticks, and free steps (the disk law's cross complementarity) put the
    stop on a node. Continuous optimum 4/3 (mu g)^2 tau* with tau* = (36 d^2 / (mu g)^2)^(1/4); over
    n equal sliding steps of the constant hold 4/3 (mu g)^2 tau_n, tau_n = (36 d^2 n^2 / ((n^2 - 1)
    (mu g)^2))^(1/4)."""
    ex = point_on_plane(mu, T=1.0, target=target)
    d, c = float(np.hypot(*target)), mu * G
    tau = (36 * d ** 2 / c ** 2) ** 0.25
    assert tau < T

    def make(N):
        return OptimalControlProblem(ex.system, N, T=T, q0=np.zeros(3), v0=np.zeros(3), stage_cost=effort,
                                     steps="free",
                                     terminal_constraints=lambda q, v: ca.vertcat(q[0] - target[0], q[1] - target[1],
                                                                                  v[0], v[1]))

    return Example("point_stick_slide", "point on a plane: stick, slide, stick (free steps)", ex.system, ex.q0,
                   ex.v0, T, make, _effort, _zero, 10, (6, 10, 20), 4 / 3 * c * c * tau,
                   "4/3 (mu g)^2 tau*; over n sliding steps 4/3 (mu g)^2 tau_n")


# ----------------------------------------------------------------------------- block chain
def block_chain(K: int = 2, d: float = 0.3, T: float = 1.0, u_max: float = 30.0) -> Example:
    """lcp.scenes.block_chain(K) from rest, the first block pushed horizontally: every block moved by d
    and at rest at T, minimum int u^2 dt."""
    sc = lcp.scenes.block_chain(K, v0=[0.0] * K)
    B = np.zeros((2 * K, 1))
    B[0, 0] = 1.0
    sys = add_control(sc.system, B, -u_max, u_max)

    def term(q, v):
        return ca.vertcat(*[q[2 * i] - (sc.q0[2 * i] + d) for i in range(K)], *[v[2 * i] for i in range(K)])

    def make(N):
        return OptimalControlProblem(sys, N, T=T, q0=sc.q0, v0=sc.v0, stage_cost=effort, terminal_constraints=term,
                                     **NOSNOC_GRID)

    return Example(f"block_chain{K}", f"block chain (K = {K}) moved {d} m", sys, sc.q0, sc.v0, T, make, _effort,
                   _zero, 20, (20, 40, 80), common=lambda q, v: np.concatenate([q[0::2], v[0::2]]))


#: the seven friction blocks of nosnoc (one of its MATLAB examples): unit masses, friction force mu_fric,
#: springs k (the first to a wall at 0) at rest spacing, viscous damping d on every velocity, the first
#: block pushed by |u| <= u_max, from the equilibrium shifted by ``shift`` back to it over T in N stages
CHAIN7 = {"K": 7, "mu_fric": 0.4, "k": 5.0, "d": 0.1, "spacing": 0.2, "shift": 0.2, "u_max": 20.0, "T": 5.0,
          "N": 50, "q_box": 2.0, "v_max": 10.0, "Q_q": 10.0, "Q_v": 0.1, "R": 0.01, "P": 10.0}


def block_chain7() -> Example:
    """nosnoc's seven friction blocks: K = 7 unit blocks in a line, block 1 tied to a wall at x = 0 and
    each block to the next by springs k = 5 N/m (rest spacing 0.2 m), viscous damping 0.1 N s/m on
    every velocity, Coulomb friction of magnitude 0.4 N on every block, the first block pushed by
    |u| <= 20 N. From rest with every block 0.2 m beyond its equilibrium x_i = 0.2 (i - 1), the
    tracking cost int (x - x_eq)' Q (x - x_eq) + 0.01 u^2 dt + (x - x_eq)' 10 Q (x - x_eq) at T = 5 s,
    Q = diag(10 on positions, 0.1 on velocities), positions within [-2, 3.2] m, speeds within 10 m/s;
    no terminal constraint. N = 50 (nosnoc's dt = 0.1 s). The contacts stay closed (Radau IIA
    collocation, the velocity law)."""
    p = CHAIN7
    K = p["K"]
    n = 2 * K
    q, v, u = ca.SX.sym("q", n), ca.SX.sym("v", n), ca.SX.sym("u", 1)
    x, vx = q[0::2], v[0::2]
    x_eq = p["spacing"] * np.arange(K)
    mu = p["mu_fric"]  # pressed by a unit load: mu N = mu_fric
    F = [ca.SX(0)] * n
    for i in range(K):
        F[2 * i] = -p["d"] * vx[i]
        F[2 * i + 1] = -p["mu_fric"] / mu
    F[0] = F[0] - p["k"] * x[0] + u[0]
    for i in range(K - 1):
        tension = p["k"] * (x[i + 1] - x[i] - p["spacing"])
        F[2 * i] = F[2 * i] + tension
        F[2 * i + 2] = F[2 * i + 2] - tension
    sys = System(q, v, ca.diag(ca.SX(np.ones(n))), ca.vertcat(*F),
                 contacts=[Contact(gap=q[2 * i + 1], tangent=x[i], mu=mu, name=f"block{i}") for i in range(K)],
                 control=u, control_bounds=(np.array([-p["u_max"]]), np.array([p["u_max"]])),
                 names=[nm for i in range(K) for nm in (f"x{i}", f"y{i}")])
    q0 = np.zeros(n)
    q0[0::2] = x_eq + p["shift"]
    w = np.concatenate([p["Q_q"] * np.ones(K), p["Q_v"] * np.ones(K)])

    def err(qq, vv):
        return ca.vertcat(qq[0::2] - x_eq, vv[0::2])

    def stage(s):  # the trapezoidal rule on the tracking term; the control is held over the step
        e0, e1 = err(s.q0, s.v0), err(s.q1, s.v1)
        return 0.5 * ca.sum1(w * (e0 * e0 + e1 * e1)) + p["R"] * effort(s)

    def terminal_cost(Tv, qq, vv):
        e = err(qq, vv)
        return p["P"] * ca.sum1(w * e * e)

    lo, hi = -p["q_box"], x_eq[-1] + p["q_box"]

    def box(s):
        return ca.vertcat(s.q1[0::2] - hi, lo - s.q1[0::2], s.v1[0::2] - p["v_max"], -p["v_max"] - s.v1[0::2])

    def make(N):
        # Radau IIA (s = 2) rather than the theta step: the shooting that finishes both lands, from the
        # theta step's control, on a phase sequence whose optimum is 0.2 % above nosnoc's (measured at
        # N = 50: J_replay 10.957 against nosnoc's 10.934; from Radau's, 10.757)
        return OptimalControlProblem(sys, N, T=p["T"], q0=q0, v0=np.zeros(n), stage_cost=stage,
                                     terminal_cost=terminal_cost, path_constraints=box, integrator="radau",
                                     stages=2, **NOSNOC_GRID)

    def integrand(t, qq, vv, uu):
        e = np.column_stack([qq[:, 0::2] - x_eq, vv[:, 0::2]])
        return e * e @ w + p["R"] * uu[:, 0] ** 2

    def terminal(qq, vv):
        e = np.concatenate([qq[0::2] - x_eq, vv[0::2]])
        return float(p["P"] * (e * e @ w))

    return Example("block_chain7", "nosnoc's seven friction blocks", sys, q0, np.zeros(n), p["T"], make, integrand,
                   terminal, p["N"], (p["N"],), common=lambda q, v: np.concatenate([q[0::2], v[0::2]]))


# ----------------------------------------------------------------------------- cart-pole with friction
def cart_pole(F_friction: float = 2.0, mu: float = 0.2, T: float = 5.0) -> Example:
    """nosnoc_py's cart-pole with friction (examples/cart_pole_with_friction): cart m1 = 1, pole m2 = 0.1
    of length 1, the cart's friction of constant magnitude F = 2 N, |u| <= 30 N, swing-up from
    (px, theta) = (1, 0) at rest towards (0, pi) with the quadratic tracking cost
    Q = diag(10, 100, 1, 1), R = 1, Q_T = diag(500, 100, 10, 10), |px| <= 5, T = 5 s."""
    m1, m2, ell = 1.0, 0.1, 1.0
    q, v, u = ca.SX.sym("q", 3), ca.SX.sym("v", 3), ca.SX.sym("u", 1)
    th, om = q[1], v[1]
    M = ca.SX(3, 3)
    M[0, 0], M[0, 1], M[1, 0], M[1, 1], M[2, 2] = m1 + m2, m2 * ell * ca.cos(th), m2 * ell * ca.cos(th), m2 * ell ** 2, 1
    Fn = F_friction / mu
    F = ca.vertcat(u[0] + m2 * ell * om ** 2 * ca.sin(th), -m2 * G * ell * ca.sin(th), -Fn)
    sys = System(q, v, M, F, contacts=[Contact(gap=q[2], tangent=q[0], mu=mu, name="cart")], control=u,
                 control_bounds=(np.array([-30.0]), np.array([30.0])), names=["px", "theta", "y"])
    x_ref = np.array([0.0, np.pi, 0.0, 0.0])
    Q, QT, R = np.diag([10.0, 100.0, 1.0, 1.0]), np.diag([500.0, 100.0, 10.0, 10.0]), 1.0

    def x_of(qq, vv):
        return ca.vertcat(qq[0], qq[1], vv[0], vv[1])

    def stage(s):  # the integrand at the step's end (rectangle rule, as nosnoc's stage values)
        e = x_of(s.q1, s.v1) - x_ref
        return ca.mtimes([e.T, Q, e]) + R * s.u0[0] ** 2

    def terminal_cost(Tv, qq, vv):
        e = x_of(qq, vv) - x_ref
        return ca.mtimes([e.T, QT, e])

    def make(N):
        return OptimalControlProblem(sys, N, T=T, q0=np.array([1.0, 0.0, 0.0]), v0=np.zeros(3), stage_cost=stage,
                                     terminal_cost=terminal_cost,
                                     path_constraints=lambda s: ca.vertcat(s.q1[0] - 5.0, -5.0 - s.q1[0]), **NOSNOC_GRID)

    def integrand(t, qq, vv, uu):
        e = np.column_stack([qq[:, 0], qq[:, 1], vv[:, 0], vv[:, 1]]) - x_ref
        return np.einsum("ki,ij,kj->k", e, Q, e) + R * uu[:, 0] ** 2

    def terminal(qq, vv):
        e = np.array([qq[0], qq[1], vv[0], vv[1]]) - x_ref
        return float(e @ QT @ e)

    return Example("cart_pole", "cart-pole swing-up with friction (nosnoc)", sys, np.array([1.0, 0.0, 0.0]),
                   np.zeros(3), T, make, integrand, terminal, 20, (20, 40, 80),
                   common=lambda q, v: np.array([q[0], q[1], v[0], v[1]]))


# ----------------------------------------------------------------------------- motor with friction
MOTOR = {"m1": 1.03, "m2": 0.56, "k": 2.4e3, "c": 0.0, "u_max": 5.0, "R": 2.0, "L": 2e-3, "K_F": 12.0, "K_S": 12.0,
         "F_R": 2.1, "T": 0.08, "target": 0.01}


def motor(mu: float = 0.21) -> Example:
    """nosnoc_py's linear motor with friction (examples/motor_with_friction): a slide m1 (guide friction
    F_R = 2.1 N) and a load m2 joined by a spring k, driven by the coil current I (L dI/dt = u - R I
    - K_S v1, force K_F I), |u| <= 5 V, from rest to rest at x1 = x2 = 0.01 m with I = 0 in
    T = 0.08 s, minimum int u^2 dt. The current is the rate of the charge Q, a coordinate of
    "mass" L (the electrical analogue), so the System is mechanical."""
    p = MOTOR
    q, v, u = ca.SX.sym("q", 4), ca.SX.sym("v", 4), ca.SX.sym("u", 1)
    x1, x2, y = q[0], q[1], q[3]
    v1, v2, current = v[0], v[1], v[2]
    Fn = p["F_R"] / mu
    F = ca.vertcat(-p["k"] * (x1 - x2) - p["c"] * (v1 - v2) + p["K_F"] * current,
                   p["k"] * (x1 - x2) + p["c"] * (v1 - v2),
                   u[0] - p["R"] * current - p["K_S"] * v1, -Fn)
    M = ca.diag(ca.SX([p["m1"], p["m2"], p["L"], 1.0]))
    sys = System(q, v, M, F, contacts=[Contact(gap=y, tangent=x1, mu=mu, name="guide")], control=u,
                 control_bounds=(np.array([-p["u_max"]]), np.array([p["u_max"]])), names=["x1", "x2", "Q", "y"])
    tg = p["target"]

    def make(N):
        return OptimalControlProblem(sys, N, T=p["T"], q0=np.zeros(4), v0=np.zeros(4), stage_cost=effort,
                                     terminal_constraints=lambda q, v: ca.vertcat(q[0] - tg, q[1] - tg, v[0], v[1],
                                                                                  v[2]), **NOSNOC_GRID)

    return Example("motor", "linear motor with friction (nosnoc)", sys, np.zeros(4), np.zeros(4), p["T"], make,
                   _effort, _zero, 30, (30, 60, 120), common=lambda q, v: np.array([q[0], q[1], v[0], v[1], v[2]]))


# ----------------------------------------------------------------------------- hopper
HOPPER = {"mb": 1.0, "ml": 0.1, "Ib": 0.25, "Il": 0.025, "mu": 0.45, "x_goal": 1.0, "height": 1.0, "T": 1.0}


def hopper(T: float = HOPPER["T"]) -> Example:
    """nosnoc_py's hopper (examples/hopper_robot): a body (x, y, theta) and a leg of length r, the foot
    on the floor (gap y - r cos theta, tangent x - r sin theta, mu = 0.45), the hip torque and the leg
    force as controls (|u| <= 50), tracking nosnoc's reference (a jump from x = 0.1 over height 1.0 to
    x = 1.0, a cubic spline through start, apex and end), Q = diag(100, 100, 20, 50, 0.1, ...),
    R = diag(0.01, 0.01), Q_T = diag(300, 300, 300, 300, 0.1, ...). The foot must not slip while
    loaded: the user complementarity 0 <= N perp v_T^2 >= 0 (nosnoc's path complementarity). nosnoc
    uses time freezing with a speed-of-time control; here T = 1 s of physical time."""
    from scipy.interpolate import CubicSpline

    p = HOPPER
    q, v, u = ca.SX.sym("q", 4), ca.SX.sym("v", 4), ca.SX.sym("u", 2)
    th, r = q[2], q[3]
    M = ca.diag(ca.SX([p["mb"] + p["ml"], p["mb"] + p["ml"], p["Ib"] + p["Il"], p["ml"]]))
    B = ca.vertcat(ca.horzcat(0, -ca.sin(th)), ca.horzcat(0, ca.cos(th)), ca.horzcat(1, 0), ca.horzcat(0, 1))
    F = ca.vertcat(0, -(p["mb"] + p["ml"]) * G, 0, 0) + ca.mtimes(B, u)
    foot = Contact(gap=q[1] - r * ca.cos(th), tangent=q[0] - r * ca.sin(th), mu=p["mu"], name="foot")
    sys = System(q, v, M, F, contacts=[foot], control=u, control_bounds=(-50 * np.ones(2), 50 * np.ones(2)),
                 names=["x", "y", "theta", "r"])
    q0 = np.array([0.1, 0.5, 0.0, 0.5])
    x0 = np.concatenate([q0, np.zeros(4)])
    x_mid = np.array([(p["x_goal"] - 0.1) / 2 + 0.1, p["height"], 0, 0.1, 0, 0, 0, 0])
    x_end = np.array([p["x_goal"], 0.5, 0, 0.5, 0, 0, 0, 0])
    spline = CubicSpline([0, 0.5, 1], [x0, x_mid, x_end])
    Q = np.diag([100.0, 100.0, 20.0, 50.0, 0.1, 0.1, 0.1, 0.1])
    QT = np.diag([300.0, 300.0, 300.0, 300.0, 0.1, 0.1, 0.1, 0.1])
    R = np.diag([0.01, 0.01])
    vT = ca.Function("vT", [q, v], [ca.mtimes(ca.jacobian(q[0] - r * ca.sin(th), q), v)])

    def make(N):
        def stage(s):  # the reference at the step's end, as nosnoc's stage-wise reference
            e = ca.vertcat(s.q1, s.v1) - spline(float(s.k + 1) / N)
            return ca.mtimes([e.T, Q, e]) + ca.mtimes([s.u0.T, R, s.u0])

        return OptimalControlProblem(
            sys, N, T=T, q0=q0, v0=np.zeros(4), stage_cost=stage, contact_law="gap",
            terminal_cost=lambda Tv, qq, vv: ca.mtimes([(ca.vertcat(qq, vv) - x_end).T, QT, ca.vertcat(qq, vv) - x_end]),
            path_constraints=lambda s: ca.vertcat(0.1 - s.q1[3], s.q1[3] - 0.5, -s.q1[0], s.q1[0] - p["x_goal"] - 0.1),
            complementarity=[(lambda s: s.p_N / s.h, lambda s: vT(s.q1, s.v1) ** 2)], **NOSNOC_GRID)

    def integrand(t, qq, vv, uu):
        e = np.column_stack([qq, vv]) - spline(t / T)
        return np.einsum("ki,ij,kj->k", e, Q, e) + np.einsum("ki,ij,kj->k", uu, R, uu)

    def terminal(qq, vv):
        e = np.concatenate([qq, vv]) - x_end
        return float(e @ QT @ e)

    return Example("hopper", "hopper jump (nosnoc's model and cost)", sys, q0, np.zeros(4), T, make, integrand,
                   terminal, 20, (20, 40))


# ----------------------------------------------------------------------------- two discs
DISCS = {"m1": 2.0, "m2": 1.0, "r1": 0.3, "r2": 0.2, "cv": 2.0, "eps": 0.1, "T": 3.0}


def two_discs() -> Example:
    """nosnoc_py's discs that switch places (examples/discs_exercise): disc 1 (m = 2, r = 0.3, actuated,
    |u| <= 20) at (1, 0) and disc 2 (m = 1, r = 0.2, not actuated) at (-1, 0), both with nosnoc's
    drag cv v / |v + eps|; targets swapped; nosnoc's tracking cost Q = diag(10, 10, 20, 20, 0.1 x 4),
    R = 0.1 I, Q_T = 100 Q; the frictionless contact between the discs, inelastic. T = 3 s. Solved from
    its own start (:func:`discs_start`, disc 1 sent around disc 2): measured at N = 30, the
    transcription reaches cost 222.05 (its theta step on the drag replays to 0.29), and the
    exact-phase shooting (4 Runge-Kutta steps per quarter segment, IPOPT's default 500 iterations)
    cost 204.27 with replay miss 1.6e-9 (on 8 steps it needed 3000 iterations); at N = 60 the
    transcription 215.46, replay 0.044; the shooting's second round stops at IPOPT's iteration limit
    with three segments shrunk to zero, and without them it ends at cost 208.358, replay 5.0e-12,
    J_replay 211.69 (before the pruning, on 8 steps with 3000 iterations, 209.26; nosnoc's control
    replays to 20488 and 7984 on this model at N = 30, 60)."""
    p = DISCS
    q, v, u = ca.SX.sym("q", 4), ca.SX.sym("v", 4), ca.SX.sym("u", 2)
    d = q[0:2] - q[2:4]
    dist = ca.norm_2(d)
    n = d / dist
    drag = p["cv"] * ca.vertcat(v[0:2] / ca.norm_2(v[0:2] + p["eps"]), v[2:4] / ca.norm_2(v[2:4] + p["eps"]))
    F = ca.vertcat(u, 0, 0) - drag
    contact = Contact(gap=dist - (p["r1"] + p["r2"]), tangent_jacobian=ca.horzcat(-n[1], n[0], n[1], -n[0]), mu=0.0,
                      name="discs")
    sys = System(q, v, ca.diag(ca.SX([p["m1"], p["m1"], p["m2"], p["m2"]])), F, contacts=[contact], control=u,
                 control_bounds=(-20 * np.ones(2), 20 * np.ones(2)), names=["x1", "y1", "x2", "y2"])
    q0 = np.array([1.0, 0.0, -1.0, 0.0])
    x_ref = np.array([-1.0, 0.0, 1.0, 0.0, 0, 0, 0, 0])
    Q = np.diag([10.0, 10.0, 20.0, 20.0, 0.1, 0.1, 0.1, 0.1])
    QT, R = 100 * Q, 0.1 * np.eye(2)

    def stage(s):
        e = ca.vertcat(s.q1, s.v1) - x_ref
        return ca.mtimes([e.T, Q, e]) + ca.mtimes([s.u0.T, R, s.u0])

    def make(N):
        return OptimalControlProblem(
            sys, N, T=p["T"], q0=q0, v0=np.zeros(4), stage_cost=stage,
            terminal_cost=lambda Tv, qq, vv: ca.mtimes([(ca.vertcat(qq, vv) - x_ref).T, QT,
                                                        ca.vertcat(qq, vv) - x_ref]), **NOSNOC_GRID)

    def integrand(t, qq, vv, uu):
        e = np.column_stack([qq, vv]) - x_ref
        return np.einsum("ki,ij,kj->k", e, Q, e) + np.einsum("ki,ij,kj->k", uu, R, uu)

    def terminal(qq, vv):
        e = np.concatenate([qq, vv]) - x_ref
        return float(e @ QT @ e)

    return Example("two_discs", "two discs switch places (nosnoc's model and cost)", sys, q0, np.zeros(4), p["T"],
                   make, integrand, terminal, 30, (30, 60), start=discs_start)


#: the path of the start :func:`discs_start`: disc 1 at these times and places (over disc 2, then
#: behind it), arriving behind it at DISCS_STRIKE[0] with the speed DISCS_STRIKE[1] to the right
DISCS_PATH = ((0.0, 1.0, 0.0), (0.4, 0.1, 0.7), (0.8, -1.3, 0.7), (1.4, -1.7, 0.0))
DISCS_STRIKE = (1.4, 3.5)
#: gains of the tracking (1/s^2, 1/s) and of the hold at the target after the strike
DISCS_GAINS = (20.0, 12.0, 6.0, 6.0)
#: the start's control is made on this many steps over T, whatever the problem's N
DISCS_START_STEPS = 30


def discs_start(pb):
    """A start that sends disc 1 around disc 2 and strikes it to the right: disc 1 tracks a path
    over disc 2 to behind it (:data:`DISCS_PATH`, a cubic spline, at rest at first and at the
    strike speed at its end) by a PD law on its acceleration, pushes on for 0.15 s, then is held
    at its target, one constant control per step of T / :data:`DISCS_START_STEPS` (the same start for
    every N), each step simulated by the event method; the control is then simulated at once on the
    problem's grid (:func:`lcp.ocp.guess.event_guess`). From the rest
    control the homotopy parks disc 1 against disc 2 (cost 8527.5 at N = 30), a local optimum.
    None where a simulation fails."""
    from scipy.interpolate import CubicSpline

    from lcp.model.control import ControlSchedule
    from lcp.ocp.guess import event_guess

    p = DISCS
    t_s, V = DISCS_STRIKE
    kp, kd, kp_hold, kd_hold = DISCS_GAINS
    path = np.array(DISCS_PATH)
    cs = CubicSpline(path[:, 0], path[:, 1:], bc_type=((1, np.zeros(2)), (1, np.array([V, 0.0]))))
    N, T = DISCS_START_STEPS, pb.T
    h = T / N
    q, v = np.array(pb.q0, dtype=float), np.array(pb.v0, dtype=float)
    u = np.zeros((N, 2))
    for k in range(N):
        t = k * h
        x1, v1 = q[:2], v[:2]
        if t < t_s:
            tm = t + 0.5 * h
            a = cs(tm, 2) + kp * (cs(tm) - x1) + kd * (cs(tm, 1) - v1)
        elif t < t_s + 0.15:
            a = np.array([10.0, 0.0])
        else:
            a = kp_hold * (np.array([-1.0, 0.0]) - x1) - kd_hold * v1
        drag = p["cv"] * v1 / np.linalg.norm(v1 + p["eps"])
        u[k] = np.clip(p["m1"] * a + drag, pb.u_min, pb.u_max)
        try:
            # (on the NumPy path, as the optimal control's own starts: lcp.ocp.options.START_RHS)
            sim = lcp.simulate(pb.system, h, method="event", control=ControlSchedule(np.array([0.0, h]), u[k:k + 1]),
                               q0=q, v0=v, t_eval=np.array([0.0, h]), rhs=START_RHS)
        except (ValueError, RuntimeError):
            return None
        if not sim.success:
            return None
        q, v = sim.q[-1].copy(), sim.v[-1].copy()
    return event_guess(pb, lambda t: u[min(int(t / h + 1e-9), N - 1)], T)


# ----------------------------------------------------------------------------- box tipped over an edge
def box_tip(w: float = 0.2, hgt: float = 0.4, m: float = 1.0, mu: float = 0.8, T: float = 1.0) -> Example:
    """A planar box (width w, height hgt, mass m) standing on two bottom corners (mu = 0.8), pushed by a
    horizontal force u >= 0 at its top-left corner, tipped over its bottom-right corner to lie on its
    right side (theta = -pi/2) at rest at T, minimum int u^2 dt. The four corners are contacts (the
    top ones start open), so the gap law holds: the bottom-left corner lifts, the top-right lands."""
    q, v, u = ca.SX.sym("q", 3), ca.SX.sym("v", 3), ca.SX.sym("u", 1)
    x, y, th = q[0], q[1], q[2]
    c, s = ca.cos(th), ca.sin(th)
    I = m * (w ** 2 + hgt ** 2) / 12

    def corner(a, b):  # body coordinates (a, b) about the centre
        return x + c * a - s * b, y + s * a + c * b

    corners = {"bottom_left": (-w / 2, -hgt / 2), "bottom_right": (w / 2, -hgt / 2), "top_right": (w / 2, hgt / 2),
               "top_left": (-w / 2, hgt / 2)}
    contacts = []
    for nm, (a, b) in corners.items():
        px, py = corner(a, b)
        contacts.append(Contact(gap=py, tangent=px, mu=mu, name=nm))
    px, py = corner(*corners["top_left"])
    B = ca.jacobian(px, q).T
    F = ca.vertcat(0, -m * G, 0) + B * u[0]
    sys = System(q, v, ca.diag(ca.SX([m, m, I])), F, contacts=contacts, control=u,
                 control_bounds=(np.array([0.0]), np.array([30.0])), names=["x", "y", "theta"])
    q0 = np.array([0.0, hgt / 2, 0.0])
    # lying on its right side: the centre at height w / 2, the former bottom-right corner where it was
    q_end = np.array([w / 2 + hgt / 2, w / 2, -np.pi / 2])

    def make(N):
        return OptimalControlProblem(sys, N, T=T, q0=q0, v0=np.zeros(3), stage_cost=effort, contact_law="gap",
                                     terminal_constraints=lambda qq, vv: ca.vertcat(qq[2] - q_end[2], vv), **NOSNOC_GRID)

    return Example("box_tip", "box tipped over an edge", sys, q0, np.zeros(3), T, make, _effort, _zero, 20, (20, 40))


# ----------------------------------------------------------------------------- ball bounced to a height
def ball_bounce(e: float = 0.5, u_max: float = 3.0, T: float = 0.6, target: float = 0.2) -> Example:
    """A unit ball (restitution e = 0.5) dropped from 1 m at rest, a vertical thrust |u| <= u_max, at
    height ``target`` at T after one bounce, minimum int u^2 dt. Free fall lands at sqrt(2 / g) =
    0.4515 s and would reach 0.2224 m at T; the thrust puts the landing on a node (the gap law's
    impulse, Newton's law) and the ball on the target. Moreau-Jean's default guess penetrates at the
    node after the landing; :meth:`~lcp.ocp.OptimalControlProblem.solve`'s second default start,
    the event method's simulation, does not."""
    q, v, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 1)
    sys = System(q, v, ca.DM.eye(2), ca.vertcat(0.0, -G + u[0]),
                 contacts=[Contact(gap=q[1], tangent=q[0], mu=0.0, e=e, name="floor")],
                 control=u, control_bounds=(np.array([-u_max]), np.array([u_max])), names=["x", "y"])
    q0 = np.array([0.0, 1.0])

    def make(N):
        return OptimalControlProblem(sys, N, T=T, q0=q0, v0=np.zeros(2), stage_cost=effort,
                                     terminal_constraints=lambda qq, vv: qq[1] - target, **NOSNOC_GRID)

    return Example("ball_bounce", f"ball bounced to {target} m (e = {e})", sys, q0, np.zeros(2), T, make, _effort,
                   _zero, 12, (12, 24))


EXAMPLES = {"point_on_plane": point_on_plane, "point_stick_slide": point_stick_slide, "block_chain2": block_chain,
            "block_chain7": block_chain7, "motor": motor, "cart_pole": cart_pole,
            "two_discs": two_discs, "box_tip": box_tip, "hopper": hopper, "ball_bounce": ball_bounce}
