"""Radau IIA collocation in the optimal-control transcription (``integrator="radau"``).

The tableau is checked against the quadrature order conditions; the transcription's order against
a smooth problem whose objective has no control-discretization error (the control is fixed by its
bounds, the objective a terminal cost), the reference from an adaptive integrator at 1e-13.
"""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import lcp
from lcp.model.system import Contact, System
from lcp.ocp import OptimalControlProblem, effort, tangential_push
from lcp.ocp.collocation import radau_tableau

G = 9.81


@pytest.mark.parametrize("s", [1, 2, 3, 4])
def test_tableau_meets_the_order_conditions(s):
    c, A, b = radau_tableau(s)
    assert c[-1] == 1.0 and np.all(np.diff(c) > 0)
    for k in range(1, 2 * s):  # b integrates polynomials of degree 2s - 2 exactly (Radau quadrature)
        assert np.sum(b * c ** (k - 1)) == pytest.approx(1.0 / k, abs=1e-13)
    for k in range(1, s + 1):  # stage order s: A c^(k-1) = c^k / k
        np.testing.assert_allclose(A @ c ** (k - 1), c ** k / k, atol=1e-13)
    np.testing.assert_array_equal(A[-1], b)  # stiffly accurate


def test_tableau_nodes_of_three_stages():
    c, _, _ = radau_tableau(3)
    np.testing.assert_allclose(c, [(4 - np.sqrt(6)) / 10, (4 + np.sqrt(6)) / 10, 1.0], atol=1e-14)


def _pendulum(u_fixed=0.8):
    q, v, u = ca.SX.sym("q"), ca.SX.sym("v"), ca.SX.sym("u")
    return System(q, v, ca.SX(1.0), -G * ca.sin(q) - 0.3 * v + u, control=u,
                  control_bounds=(np.array([u_fixed]), np.array([u_fixed])))


def _pendulum_errors(integrator, s, Ns, T=2.0, q0=2.5):
    ref = solve_ivp(lambda t, y: [y[1], -G * np.sin(y[0]) - 0.3 * y[1] + 0.8], (0, T), [q0, 0.0],
                    rtol=1e-13, atol=1e-13).y[:, -1]
    J_ref = ref[0] ** 2 + 0.1 * ref[1] ** 2
    errs = []
    for N in Ns:
        pb = OptimalControlProblem(_pendulum(), N, T=T, q0=[q0], v0=[0.0], replay_tol=None,
                                   terminal_cost=lambda Tv, q, v: q[0] ** 2 + 0.1 * v[0] ** 2,
                                   integrator=integrator, stages=s)
        r = pb.solve()
        assert r.status >= 0, r.message
        errs.append(abs(r.cost - J_ref))
    return np.array(errs)


@pytest.mark.parametrize("integrator, s, order", [("theta", 2, 2), ("radau", 2, 3), ("radau", 3, 5)])
def test_objective_converges_with_the_order_of_the_step(integrator, s, order):
    # measured (N = 8, 16, 32): theta 2.29, radau s = 2 2.90, s = 3 4.91
    Ns = (8, 16, 32)
    errs = _pendulum_errors(integrator, s, Ns)
    observed = -np.polyfit(np.log(Ns), np.log(errs), 1)[0]
    assert observed >= order - 0.5, (errs, observed)
    if integrator == "radau":
        assert errs[-1] < _pendulum_errors("theta", 2, Ns[-1:])[0] / 20


def test_radau_replays_the_pendulum_to_its_order():
    pb = OptimalControlProblem(_pendulum(), 32, T=2.0, q0=[2.5], v0=[0.0], replay_tol=1e-5,
                               terminal_cost=lambda Tv, q, v: q[0] ** 2, integrator="radau", stages=3)
    r = pb.solve()
    assert r.success, r.message  # the event replay within 1e-5 (measured 7.4e-7)
    assert r.replay.final_miss <= 2e-6


def test_block_pushed_to_rest_exact_with_radau():
    # the Jean-Pratt block (constant forces) pushed from rest to rest 0.2 m in minimum time, free
    # steps: the switches on nodes, radau is exact between them as the theta step is
    sc = lcp.scenes.jean_pratt(v0=0.0)
    pb = OptimalControlProblem(sc, 4, control_matrix=tangential_push(sc.system), u_min=-20, u_max=20, T=0.5,
                               free_time=True, T_bounds=(0.05, 2.0), steps="free", integrator="radau", stages=2,
                               terminal_cost=lambda T, q, v: T,
                               terminal_constraints=lambda q, v: ca.vertcat(q[0] - 0.2, v[0]))
    r = pb.solve()
    assert pb.contact_law == "velocity"
    assert r.success, r.message
    assert r.T == pytest.approx(0.281085, abs=1e-6)
    assert r.replay.final_miss <= 1e-8


def test_block_min_effort_exact_with_radau_and_the_affine_hold():
    # stick, slide, stick from rest to rest 0.5 m in 1 s: the affine hold's forces are affine in t
    # within a phase, which two stages integrate exactly (continuous optimum 86.905749 N^2 s)
    sc = lcp.scenes.jean_pratt(v0=0.0)
    pb = OptimalControlProblem(sc, 6, control_matrix=tangential_push(sc.system), u_min=-20, u_max=20, T=1.0,
                               stage_cost=effort, steps="free", hold="affine", integrator="radau", stages=2,
                               terminal_constraints=lambda q, v: ca.vertcat(q[0] - 0.5, v[0]))
    r = pb.solve()
    assert r.success, r.message
    assert r.cost == pytest.approx(86.905749, abs=1e-6)
    assert r.replay.final_miss <= 1e-9


@pytest.mark.parametrize("case, message", [
    ("name", "integrator must be 'theta' or 'radau'"),
    ("stages", "stages must be an integer in 1..4"),
    ("gap", "supports the velocity law only"),
    ("restitution", "does not support restitution"),
    ("bilateral", "does not support bilateral constraints"),
])
def test_refused_by_name(case, message):
    q, v, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u")
    e = 0.5 if case == "restitution" else 0.0
    cons = q[0] - q[1] if case == "bilateral" else None
    sys_ = System(q, v, ca.SX.eye(2), ca.vertcat(u, -G), contacts=[Contact(gap=q[1], tangent=q[0], mu=0.3, e=e)],
                  constraints=cons, control=u, control_bounds=(np.array([-1.0]), np.array([1.0])))
    q0 = [0.0, 0.1] if case == "gap" else [0.0, 0.0]
    kw = {"integrator": "rk4"} if case == "name" else {"integrator": "radau", "stages": 5 if case == "stages" else 2}
    with pytest.raises(ValueError, match=message):
        OptimalControlProblem(sys_, 4, q0=q0, v0=[0.0, 0.0], **kw)


def _fixed_phase_solved(r):
    """The fixed-phase solve (the first pass's phases placed by the step lengths) succeeded by itself:
    no fallback to the homotopy (whose message would say that the fixed-phase solve failed first)."""
    return "(Fixed-phase solve: the guess's mode sequence." in r.message and "failed first" not in r.message


def test_fixed_phase_solve_succeeds_on_the_minimum_time_block():
    from studies import optimal_control as so
    sc, system = so.controlled_block()
    pb = OptimalControlProblem(system, 12, q0=sc.q0, v0=sc.v0, T=0.5, free_time=True, T_bounds=(0.05, 5.0),
                               steps="free", hold="constant", integrator="radau", stages=2, replay_tol=1e-6,
                               terminal_cost=lambda T, q, v: T,
                               terminal_constraints=lambda q, v: ca.vertcat(q[0] - 0.5, v[0]))
    r = pb.solve()
    assert r.success, r.message
    assert _fixed_phase_solved(r), r.message
    assert r.T == pytest.approx(so.min_time_bound(), rel=1e-6)


def test_fixed_phase_solve_succeeds_on_the_minimum_effort_block():
    # stick, slide, stick from rest to rest 0.5 m in 1 s (continuous optimum 86.905749 N^2 s)
    sc = lcp.scenes.jean_pratt(v0=0.0)
    pb = OptimalControlProblem(sc, 6, control_matrix=tangential_push(sc.system), u_min=-20, u_max=20, T=1.0,
                               stage_cost=effort, steps="free", hold="affine", integrator="radau", stages=2,
                               terminal_constraints=lambda q, v: ca.vertcat(q[0] - 0.5, v[0]))
    r = pb.solve()
    assert r.success, r.message
    assert _fixed_phase_solved(r), r.message
    assert r.cost == pytest.approx(86.905749, abs=1e-6)


def test_fixed_phase_solve_after_a_hold_at_rest_reaches_the_optimum():
    # move out, hold at rest on [t_a, t_b], move back (the velocity law): the slide back starts by a
    # jump of the control at the pinned node, and the first pass leaves a stick step after the hold
    # that the fixed-phase solve can only shrink to the minimum length until it is merged into the slide
    from studies import optimal_control as so
    sc, system = so.controlled_block()
    N, T, t_a, t_b, d = 12, 1.2, 0.4, 0.6, 0.3
    k_a, k_b = round(N * t_a / T), round(N * t_b / T)

    def at_rest(s):
        if k_a - 1 <= s.k < k_b:
            return ca.vertcat(s.q1[0] - d, s.v1[0])
        return ca.SX.zeros(0, 1)

    pb = OptimalControlProblem(system, N, q0=sc.q0, v0=sc.v0, T=T, stage_cost=effort, hold="affine", steps="free",
                               node_times={k_a: t_a, k_b: t_b}, path_equalities=at_rest, replay_tol=1e-6,
                               integrator="radau", stages=2, terminal_constraints=lambda q, v: ca.vertcat(q[0], v[0]))
    r = pb.solve()
    assert r.success, r.message
    assert _fixed_phase_solved(r), r.message
    ref = so.move_effort(t_a, d) + so.move_effort(T - t_b, d, backward=True)
    assert abs(r.cost - ref) <= 1e-6 * ref, (r.cost, ref)
