"""Impacts with restitution inside the optimal-control horizon (gap law: Newton's impact law at a node).

A ball (unit mass, e = 0.5) dropped from 1 m at rest, a vertical thrust |u| <= 3 N, T = 0.6 s. Free
fall lands at t1 = sqrt(2 / g) = 0.4515 s with u- = -4.43 m/s and leaves with -e u-; the thrust
moves the landing onto a node. The replay by the event method (its own impact law) checks it.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

import lcp
from lcp.ocp import OptimalControlProblem, effort

G = 9.81


def ball(e=0.5, umax=3.0):
    q, v, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 1)
    return lcp.System(q, v, ca.DM.eye(2), ca.vertcat(0.0, -G + u[0]),
                      contacts=[lcp.Contact(gap=q[1], tangent=q[0], mu=0.0, e=e, name="floor")],
                      control=u, control_bounds=([-umax], [umax]))


def _problem(N=12, **kw):
    return OptimalControlProblem(ball(), N, T=0.6, q0=[0.0, 1.0], v0=[0.0, 0.0], stage_cost=effort, **kw)


def test_a_ball_bounces_at_a_node_with_newtons_law():
    r = _problem().solve()
    assert r.success, r.message
    k = int(np.argmin(r.q[:, 1]))
    assert abs(r.q[k, 1]) <= 1e-12 and 0 < k < 12  # lands on a node
    assert r.q[-1, 1] > 0.1  # and flies up again
    assert r.replay.final_miss <= 1e-12 and r.replay.method == "event"


def test_a_ball_reaches_a_target_height_after_its_bounce():
    # from the solution without the target (the landing already on a node): a guess that keeps
    # its node impulse (Newton's law at the landing node) reaches targets below and above the free
    # flight's 0.2224 m
    free = _problem().solve()
    for target in (0.2, 0.24):
        r = _problem(terminal_constraints=lambda q, v, y=target: q[1] - y).solve(free)
        assert r.success, r.message
        assert abs(r.q[-1, 1] - target) <= 1e-9
        assert np.min(r.q[1:-1, 1]) <= 1e-12  # it bounced
        assert r.replay.final_miss <= 1e-9
