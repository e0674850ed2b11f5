"""nosnoc (FESD, IPOPT) on the examples of :mod:`studies.ocp_examples` where nosnoc_py has them.

The models and options are nosnoc_py's own examples, written in its Filippov (Stewart) form:
examples/cart_pole_with_friction (RADAU IIA n_s = 2, 2 finite elements per stage, T = 5 s),
examples/motor_with_friction (n_s = 2, 2 finite elements, comp_tol 1e-6, L2_RELAXED_SCALED step
equilibration, T = 0.08 s), the seven friction blocks of nosnoc's MATLAB examples (nosnoc_py has
them only as a simulation; its model and options are written here in nosnoc_py's form, RADAU IIA
n_s = 2, 3 finite elements per stage, T = 5 s), and the two-block chain of
:func:`studies._ocp_models.block_chain` in the same form as examples/friction_block (one switching
function per block velocity), and examples/discs_exercise (the two discs: its time freezing with
the clock pinned to the control grid, so that its horizon is the example's). The hopper of
nosnoc_py uses time freezing with a free speed of time (a different horizon), the point on a plane
needs the friction disk and the box is not one of nosnoc's examples: no peer is run for them
(:data:`NO_PEER` says why).

nosnoc is optional; :func:`available` says whether it imports. Imports the package's examples only
through :mod:`studies._ocp_models`' constants; nothing here is imported by ``lcp``.
"""
from __future__ import annotations

import contextlib
import copy
import importlib.util
import io
import time
from dataclasses import dataclass

import numpy as np

from lcp.model.control import ControlSchedule

__all__ = ["NO_PEER", "PEERS", "PeerResult", "available", "solve_peer"]

#: why an example has no nosnoc peer
NO_PEER = {
    "point_on_plane": "nosnoc_py 0.2.0 has no spatial (disk) friction model",
    "point_stick_slide": "nosnoc_py 0.2.0 has no spatial (disk) friction model",
    "hopper": "nosnoc_py's hopper uses time freezing with a speed-of-time control (another horizon); not run",
    "box_tip": "not one of nosnoc's examples",
    "ball_bounce": "nosnoc_py's restitution needs time freezing (another horizon); not run",
}


def available() -> bool:
    """Whether nosnoc can be imported (the optional ``ocp-peers`` extra)."""
    return importlib.util.find_spec("nosnoc") is not None


@dataclass
class PeerResult:
    """One nosnoc solve: its own objective, the control as a schedule on its stage grid, its final state
    in the example's common coordinates (``common``), status and times (s)."""

    name: str
    N: int
    objective: float
    control: ControlSchedule
    x_final: np.ndarray
    status: str
    ipopt_status: str
    complementarity: float
    build_time: float
    solve_time: float
    log: str = ""

    @property
    def total_time(self) -> float:
        return self.build_time + self.solve_time


def _opts(ns, N, T, n_s=2, fe=2, comp_tol=1e-8, step_eq=None):
    opts = ns.NosnocOpts()
    # the IPOPT options are a class-level dict shared by every instance: a copy per solve
    opts.opts_casadi_nlp = copy.deepcopy(ns.NosnocOpts.opts_casadi_nlp)
    opts.irk_scheme = ns.IrkSchemes.RADAU_IIA
    opts.n_s, opts.N_stages, opts.N_finite_elements, opts.terminal_time = n_s, N, fe, T
    opts.comp_tol = comp_tol
    opts.homotopy_update_slope = 0.1
    if step_eq is not None:
        opts.step_equilibration = getattr(ns.StepEquilibrationMode, step_eq)
    opts.print_level = 0
    return opts


def _cart_pole(ns, ca, N):
    from studies._ocp_models import G

    px, th, v, om, u = (ca.SX.sym(s) for s in ("px", "theta", "v", "om", "u"))
    q, qd = ca.vertcat(px, th), ca.vertcat(v, om)
    m1, m2, ell, Ff = 1.0, 0.1, 1.0, 2.0
    M = ca.vertcat(ca.horzcat(m1 + m2, m2 * ell * ca.cos(th)), ca.horzcat(m2 * ell * ca.cos(th), m2 * ell ** 2))
    C = ca.SX.zeros(2, 2)
    C[0, 1] = -m2 * ell * om * ca.sin(th)
    f_all = ca.vertcat(u, -m2 * G * ell * ca.sin(th)) - C @ qd
    f1 = ca.vertcat(qd, ca.inv(M) @ (f_all - ca.vertcat(Ff, 0)))
    f2 = ca.vertcat(qd, ca.inv(M) @ (f_all + ca.vertcat(Ff, 0)))
    x = ca.vertcat(q, qd)
    model = ns.NosnocModel(x=x, F=[ca.horzcat(f1, f2)], S=[np.array([[1], [-1]])], c=[v], x0=np.array([1.0, 0, 0, 0]),
                           u=u)
    x_ref = np.array([0, np.pi, 0, 0])
    Q, QT = np.diag([10, 100, 1, 1]), np.diag([500, 100, 10, 10])
    ocp = ns.NosnocOcp(lbu=np.array([-30.0]), ubu=np.array([30.0]),
                       f_q=(x - x_ref).T @ Q @ (x - x_ref) + u * u, f_terminal=(x - x_ref).T @ QT @ (x - x_ref),
                       lbx=-np.array([5.0, np.inf, np.inf, np.inf]), ubx=np.array([5.0, np.inf, np.inf, np.inf]))
    return model, ocp, _opts(ns, N, 5.0)


def _motor(ns, ca, N):
    from studies._ocp_models import MOTOR as p

    x1, x2, v1, v2, current, u = (ca.SX.sym(s) for s in ("x1", "x2", "v1", "v2", "I", "u"))
    x = ca.vertcat(x1, v1, x2, v2, current)
    A = np.array([[0, 1, 0, 0, 0],
                  [-p["k"] / p["m1"], -p["c"] / p["m1"], p["k"] / p["m1"], p["c"] / p["m1"], p["K_F"] / p["m1"]],
                  [0, 0, 0, 1, 0],
                  [p["k"] / p["m2"], p["c"] / p["m2"], -p["k"] / p["m2"], -p["c"] / p["m2"], 0],
                  [0, -p["K_S"] / p["L"], 0, 0, -p["R"] / p["L"]]])
    B = np.zeros((5, 1))
    B[-1, 0] = 1 / p["L"]
    C1 = np.array([0, -p["F_R"] / p["m1"], 0, 0, 0])
    f1, f2 = A @ x + B @ u + C1, A @ x + B @ u - C1
    model = ns.NosnocModel(x=x, F=[ca.horzcat(f1, f2)], S=[np.array([[1], [-1]])], c=[v1], x0=np.zeros(5), u=u)
    tg = p["target"]
    ocp = ns.NosnocOcp(lbu=-p["u_max"] * np.ones(1), ubu=p["u_max"] * np.ones(1), f_q=u ** 2,
                       g_terminal=x - np.array([tg, 0, tg, 0, 0]))
    return model, ocp, _opts(ns, N, p["T"], comp_tol=1e-6, step_eq="L2_RELAXED_SCALED")


def _chain(ns, ca, N, K=2):
    """The chain of :func:`studies._ocp_models.block_chain` (K unit blocks, springs k = 50 N/m at rest
    length 1 m, friction 0.3 g per block, the first block pushed, |u| <= 30 N, every block moved
    0.3 m to rest in 1 s, minimum int u^2 dt) in nosnoc's Stewart form: one switching function per
    block velocity, the first subsystem carrying the springs and the push (as
    examples/friction_block)."""
    from studies._ocp_models import G

    xs = [ca.SX.sym(f"x{i}") for i in range(K)]
    vs = [ca.SX.sym(f"v{i}") for i in range(K)]
    u = ca.SX.sym("u")
    k, c, spacing = 50.0, 0.3 * G, 1.0
    tension = [k * (xs[i + 1] - xs[i] - spacing) for i in range(K - 1)]
    acc = [(u if i == 0 else 0) + (tension[i] if i < K - 1 else 0) - (tension[i - 1] if i > 0 else 0)
           for i in range(K)]
    base = ca.vertcat(*vs, *acc)

    def friction(i, sign):  # the friction of block i in the region of sign(v_i) = -sign
        e = np.zeros(2 * K)
        e[K + i] = sign * c
        return ca.DM(e)

    F = [ca.horzcat(base - friction(0, 1), base + friction(0, 1))]
    F += [ca.horzcat(-friction(i, 1), friction(i, 1)) for i in range(1, K)]
    x = ca.vertcat(*xs, *vs)
    S = [np.array([[1], [-1]]) for _ in range(K)]
    x0 = np.concatenate([spacing * np.arange(K), np.zeros(K)])
    model = ns.NosnocModel(x=x, F=F, S=S, c=vs, x0=x0, u=u)
    ocp = ns.NosnocOcp(lbu=np.array([-30.0]), ubu=np.array([30.0]), f_q=u ** 2,
                       g_terminal=ca.vertcat(*[xs[i] - (x0[i] + 0.3) for i in range(K)], *vs))
    return model, ocp, _opts(ns, N, 1.0, comp_tol=1e-9)


def _chain7(ns, ca, N):
    """nosnoc's seven friction blocks (:data:`studies._ocp_models.CHAIN7`) in its own Stewart form: one
    switching function per block velocity, the springs, dampers and push in the first subsystem (nosnoc's
    variant without a separate f_0), RADAU IIA n_s = 2, three finite elements per stage, comp_tol 1e-7 (the
    homotopy's length follows from it in nosnoc_py), the stage cost integrated by nosnoc's Runge-Kutta
    quadrature."""
    from studies._ocp_models import CHAIN7 as p

    K = p["K"]
    q, v, u = ca.SX.sym("q", K), ca.SX.sym("v", K), ca.SX.sym("u")
    x = ca.vertcat(q, v)
    x_eq = p["spacing"] * np.arange(K)
    force = [-p["d"] * v[i] for i in range(K)]
    force[0] = force[0] - p["k"] * q[0] + u
    for i in range(1, K):
        s_ij = p["k"] * (q[i] - q[i - 1] - p["spacing"])
        force[i] = force[i] - s_ij
        force[i - 1] = force[i - 1] + s_ij
    base = ca.vertcat(v, *force)

    def friction(i):
        e = np.zeros(2 * K)
        e[K + i] = p["mu_fric"]
        return ca.DM(e)

    F = [ca.horzcat(base - friction(0), base + friction(0))]
    F += [ca.horzcat(-friction(i), friction(i)) for i in range(1, K)]
    S = [np.array([[1], [-1]]) for _ in range(K)]
    x0 = np.concatenate([x_eq + p["shift"], np.zeros(K)])
    model = ns.NosnocModel(x=x, F=F, S=S, c=[v[i] for i in range(K)], x0=x0, u=u)
    x_ref = np.concatenate([x_eq, np.zeros(K)])
    Q = np.diag(np.concatenate([p["Q_q"] * np.ones(K), p["Q_v"] * np.ones(K)]))
    e = x - x_ref
    box = np.concatenate([(x_eq[-1] + p["q_box"]) * np.ones(K), p["v_max"] * np.ones(K)])
    lbx = -np.concatenate([p["q_box"] * np.ones(K), p["v_max"] * np.ones(K)])
    ocp = ns.NosnocOcp(lbu=np.array([-p["u_max"]]), ubu=np.array([p["u_max"]]), f_q=e.T @ Q @ e + p["R"] * u * u,
                       f_terminal=p["P"] * (e.T @ Q @ e), lbx=lbx, ubx=box)
    return model, ocp, _opts(ns, N, p["T"], fe=3, comp_tol=1e-7)


def _discs(ns, ca, N):
    """nosnoc_py's examples/discs_exercise as published: the contact in its hand-crafted time-freezing
    form (where the discs overlap and approach, the positions stop and the velocities are pushed
    apart along the gradient of |q1 - q2|^2 - (r1 + r2)^2 at a_n = 10 until they separate), the
    speed of time a third control in [1, 25] and the clock pinned to the uniform control grid
    (time_freezing_tolerance 0, as its ``__main__``), so the speed of time is 1 and the numerical
    and physical horizons agree: the impact takes physical time (our event method's is instant).
    Step form (pss_mode STEP), implicit Euler (RADAU IIA n_s = 1), three finite elements per stage,
    seven homotopy steps from sigma 1 by 0.1, IPOPT max_iter 1000, velocity bounds |v| <= 5. Measured
    (loaded machine): N = 30 objective 113.83 in 58 s, N = 60 115.49 in 170 s; the event replay of its
    control (the package's inelastic impact) ends 3.9 and 2.3 from its final state."""
    from studies._ocp_models import DISCS as p

    q, v, t, u, sot = ca.SX.sym("q", 4), ca.SX.sym("v", 4), ca.SX.sym("t"), ca.SX.sym("u", 2), ca.SX.sym("sot")
    alpha, theta = ca.SX.sym("alpha", 2), ca.SX.sym("theta", 2)
    x = ca.vertcat(q, v)
    M = np.diag([p["m1"], p["m1"], p["m2"], p["m2"]])
    ubx = np.array([10, 10, 10, 10, 5, 5, 5, 5, np.inf])
    x0 = np.array([1.0, 0, -1.0, 0, 0, 0, 0, 0])
    Q = np.diag([10, 10, 20, 20, 0.1, 0.1, 0.1, 0.1])
    R = np.diag([0.1, 0.1])
    x_ref = np.array([-1.0, 0, 1.0, 0, 0, 0, 0, 0])
    e = x - x_ref
    f_c = ca.norm_2(q[0:2] - q[2:4]) ** 2 - (p["r1"] + p["r2"]) ** 2
    J_n = ca.jacobian(f_c, q).T
    drag = p["cv"] * ca.vertcat(v[0:2] / ca.norm_2(v[0:2] + p["eps"]), v[2:4] / ca.norm_2(v[2:4] + p["eps"]))
    f_v = ca.vertcat(u, 0, 0) - drag
    Minv = np.linalg.inv(M)
    f_x = sot * ca.vertcat(theta[0] * v, theta[0] * (Minv @ f_v) + theta[1] * (Minv @ J_n) * 10.0, 1)
    g_z = theta - ca.vertcat(alpha[0] + alpha[1] - alpha[0] * alpha[1], (1 - alpha[0]) * (1 - alpha[1]))
    model = ns.NosnocModel(x=ca.vertcat(x, t), f_x=[f_x], alpha=[alpha], c=[ca.vertcat(f_c, J_n.T @ v)],
                           x0=np.concatenate([x0, [0.0]]), u=ca.vertcat(u, sot), t_var=t, z=theta, z0=np.ones(2),
                           g_z=g_z)
    ocp = ns.NosnocOcp(lbu=np.array([-20.0, -20.0, 1.0]), ubu=np.array([20.0, 20.0, 25.0]),
                       f_q=sot * (e.T @ Q @ e + u.T @ R @ u), f_terminal=e.T @ (100 * Q) @ e, lbx=-ubx, ubx=ubx,
                       u_guess=np.array([0.0, 0.0, 1.0]))
    opts = _opts(ns, N, p["T"], n_s=1, fe=3, step_eq="HEURISTIC_MEAN")
    opts.pss_mode = ns.PssMode.STEP
    opts.use_fesd = True
    opts.sigma_0 = 1.0
    opts.homotopy_update_rule = ns.HomotopyUpdateRule.LINEAR
    opts.cross_comp_mode = ns.CrossComplementarityMode.COMPLEMENT_ALL_STAGE_VALUES_WITH_EACH_OTHER
    opts.mpcc_mode = ns.MpccMode.SCHOLTES_INEQ
    opts.opts_casadi_nlp["ipopt"]["max_iter"] = 1000
    opts.time_freezing = True
    opts.time_freezing_tolerance = 0.0
    opts.equidistant_control_grid = True
    opts.max_iter_homotopy = 7
    return model, ocp, opts


#: example name -> (builder, nosnoc's state -> the example's common coordinates)
PEERS = {
    "cart_pole": (_cart_pole, lambda x: np.asarray(x)[[0, 1, 2, 3]]),
    "motor": (_motor, lambda x: np.asarray(x)[[0, 2, 1, 3, 4]]),  # (x1, x2, v1, v2, I)
    "block_chain2": (_chain, lambda x: np.asarray(x)[[0, 1, 2, 3]]),
    # (x0..x6, v0..v6), as block_chain's common coordinates
    "block_chain7": (_chain7, lambda x: np.asarray(x, dtype=float)),
    # (q, v) without nosnoc's clock; its control (u, speed of time) replayed without the speed of time
    "two_discs": (_discs, lambda x: np.asarray(x, dtype=float)[:8]),
}
#: the columns of nosnoc's control that are the example's control (all where not listed)
CONTROL_COLUMNS = {"two_discs": [0, 1]}


def solve_peer(name: str, N: int) -> PeerResult:
    """nosnoc on example ``name`` with N control stages (ValueError for an example without a peer,
    ImportError without nosnoc)."""
    if name not in PEERS:
        raise ValueError(f"no nosnoc peer for {name!r}: {NO_PEER.get(name, 'unknown example')}")
    if not available():
        raise ImportError("nosnoc is not installed (pip install 'lcp-lem[ocp-peers]')")
    import casadi as ca
    import nosnoc as ns

    build, common = PEERS[name]
    log = io.StringIO()
    with contextlib.redirect_stdout(log):
        t0 = time.perf_counter()
        model, ocp, opts = build(ns, ca, int(N))
        solver = ns.NosnocSolver(opts, model, ocp)
        build_time = time.perf_counter() - t0
        t0 = time.perf_counter()
        r = solver.solve()
        solve_time = time.perf_counter() - t0
    w = r["w_sol"]
    comp = float(solver.problem.comp_res(w, solver.p_val).full()[0, 0])
    u = np.asarray(r["u_list"], dtype=float).reshape(int(N), -1)
    u = u[:, CONTROL_COLUMNS[name]] if name in CONTROL_COLUMNS else u
    t_u = np.asarray(r["t_grid_u"], dtype=float)
    return PeerResult(name=name, N=int(N), objective=float(r["cost_val"]) if "cost_val" in r else float("nan"),
                      control=ControlSchedule(t_u, u), x_final=common(np.asarray(r["x_out"], dtype=float).ravel()),
                      status=r["status"].name, ipopt_status=str(solver.solver.stats()["return_status"]),
                      complementarity=comp, build_time=build_time, solve_time=solve_time, log=log.getvalue())
