"""The two discs that switch places (nosnoc_py's examples/discs_exercise): its default starts and
its nosnoc peer.

Under the rest control (the mid-range of |u| <= 20) nothing moves, so Moreau-Jean's and the event
method's simulations are the same start: it is solved once. nosnoc's own model of the example (its
hand-crafted time freezing) is checked against the package's System where both are smooth.
"""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

import lcp
from lcp.ocp import OptimalControlProblem
from lcp.ocp import solve as ocp_solve
from lcp.ocp.guess import event_guess
from studies._ocp_models import DISCS, two_discs


def test_the_rest_start_of_the_discs_is_solved_once():
    pb = two_discs().make(30)
    mj = pb.guess(u=np.zeros(2))
    ev = event_guess(pb, mj.u, pb.T)
    assert ev is not None and np.all(ev.q == pb.q0) and np.all(mj.q == pb.q0)
    assert ocp_solve.same_guess(mj, ev)
    labels = [s[0] for s in ocp_solve.default_starts(pb)]
    assert labels == [ocp_solve.MJ_START, ocp_solve.EVENT_START + " from sigma0 = 1"]


def test_guesses_differing_in_one_value_are_not_the_same():
    pb = two_discs().make(6)
    a = event_guess(pb, np.zeros(2), pb.T)
    for field in ("q", "v", "u", "p_N", "p_T"):
        b = event_guess(pb, np.zeros(2), pb.T)
        arr = getattr(b, field)
        arr[-1, -1] += 1e-9
        assert not ocp_solve.same_guess(a, b), field
        arr[-1, -1] -= 1e-9
        assert ocp_solve.same_guess(a, b), field


def test_a_ball_that_lands_keeps_both_starts():
    # dropped onto its floor, the ball's Moreau-Jean guess penetrates where the event guess lands
    # on the floor: two different starts
    q, v, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 1)
    ball = lcp.System(q, v, ca.DM.eye(2), ca.vertcat(0.0, -9.81 + u[0]),
                      contacts=[lcp.Contact(gap=q[1], tangent=q[0], mu=0.0, e=0.5, name="floor")],
                      control=u, control_bounds=([-3.0], [3.0]))
    pb = OptimalControlProblem(ball, 12, T=0.6, q0=[0.0, 1.0], v0=[0.0, 0.0], stage_cost=lcp.ocp.effort)
    labels = [s[0] for s in ocp_solve.default_starts(pb)]
    assert labels[:2] == [ocp_solve.MJ_START, ocp_solve.EVENT_START]


def test_nosnoc_discs_are_the_examples_discs():
    # nosnoc's model (studies._nosnoc_examples) against the System of studies._ocp_models.two_discs:
    # in its free mode (theta = (1, 0)) the same accelerations at random states and controls, and
    # its contact function |q1 - q2|^2 - (r1 + r2)^2 is g (g + 2 (r1 + r2)) with g the System's gap
    peers = pytest.importorskip("studies._nosnoc_examples")
    if not peers.available():
        pytest.skip("nosnoc (optional peer) not installed")
    import nosnoc as ns

    model = peers._discs(ns, ca, 4)[0]
    sysu = two_discs().system
    f = ca.Function("f", [model.x, model.u, model.z], [model.f_x[0]])
    c = ca.Function("c", [model.x], [model.c[0][0]])
    acc = ca.Function("a", [sysu.q_sym, sysu.v_sym, sysu.control_sym],
                      [ca.solve(sysu.mass_expr, sysu.force_expr + ca.mtimes(sysu.control_matrix_expr,
                                                                            sysu.control_sym))])
    rng = np.random.default_rng(7)
    R = DISCS["r1"] + DISCS["r2"]
    for _ in range(5):
        q, v, u = rng.uniform(-2, 2, 4), rng.uniform(-3, 3, 4), rng.uniform(-20, 20, 2)
        xdot = np.array(f(np.concatenate([q, v, [0.0]]), np.concatenate([u, [1.0]]), [1.0, 0.0])).ravel()
        np.testing.assert_allclose(xdot[:4], v, rtol=0, atol=0)
        np.testing.assert_allclose(xdot[4:8], np.array(acc(q, v, u)).ravel(), rtol=1e-12, atol=1e-12)
        assert xdot[8] == 1.0  # the clock runs at the speed of time
        g = float(sysu.gaps(q)[0])
        assert float(c(np.concatenate([q, v, [0.0]]))) == pytest.approx(g * (g + 2 * R), rel=1e-12, abs=1e-12)
