"""Convergence order and friction of the optimal-control transcription, against closed forms.

A unit mass on a floor (gap law, the default; the contact stays closed), pushed horizontally from rest
to rest over d in T with minimum effort int u^2 dt:

- frictionless: the continuous optimum is 12 d^2 / T^3 (the double integrator's cubic); the
  piecewise-constant control on N uniform steps, integrated exactly, costs exactly
  12 d^2 / T^3 N^2 / (N^2 - 1), so the objective converges at order 2;
- with friction mu: sliding costs (mu g)^2 per second, so the block slides for L* and sticks the rest:
  J* = 4/3 c^2 L*, L* = (36 d^2 / c^2)^(1/4), c = mu g (the Jean-Pratt closed form with D = 1).
  With uniform steps the discrete Coulomb law lets a step that ends at rest carry less than the
  sliding friction (the cost can fall below J*): the replay refuses it (status -3). Free
  steps put every stop on a node; with the affine hold the transcription is exact.
"""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

import lcp
from lcp.ocp import OptimalControlProblem, effort

G = 9.81
D, T = 0.3, 1.0


def mass_on_floor(mu):
    q, v, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 1)
    return lcp.System(q, v, ca.DM.eye(2), ca.vertcat(u[0], -G),
                      contacts=[lcp.Contact(gap=q[1], tangent=q[0], mu=mu, name="floor")],
                      control=u, control_bounds=([-50.0], [50.0]))


def push(mu, N, **kw):
    return OptimalControlProblem(mass_on_floor(mu), N, T=T, q0=[0.0, 0.0], v0=[0.0, 0.0], stage_cost=effort,
                                 terminal_constraints=lambda q, v: ca.vertcat(q[0] - D, v[0]),
                                 **{"hold": "constant", "steps": "uniform", **kw})


def test_the_objective_converges_at_order_two_on_a_frictionless_floor():
    J = 12 * D * D / T ** 3
    gaps = []
    for N in (4, 8, 16):
        r = push(0.0, N).solve()
        assert r.problem.contact_law == "gap" and r.success, r.message
        assert r.cost == pytest.approx(J * N * N / (N * N - 1), rel=1e-9)
        assert r.replay.final_miss <= 1e-9 and np.max(np.abs(r.q[:, 1])) <= 1e-12
        gaps.append((r.cost - J) / J)
    orders = np.log2(np.array(gaps[:-1]) / np.array(gaps[1:]))
    assert np.all(orders >= 1.9), orders


def test_a_slide_with_friction_is_exact_with_free_steps_and_the_affine_hold():
    c = 0.5 * G
    J = 4.0 / 3.0 * c * c * (36 * D * D / (c * c)) ** 0.25
    r = push(0.5, 4, steps="free", hold="affine").solve()
    assert r.success, r.message
    assert abs(r.cost - J) <= 1e-9 * J
    assert r.replay.final_miss <= 1e-12


def test_uniform_steps_with_friction_are_refused_by_the_replay_and_say_where():
    # (at N = 4 the optimizer's cost, 19.04, is even below J* = 19.43: not a motion of the system)
    r = push(0.5, 8).solve(shooting=False)
    assert r.status == -3 and not r.success and r.replay.final_miss > 1e-6
    assert "at node" in r.message and "contact 'floor'" in r.message


def test_uniform_steps_with_friction_finished_by_the_shooting():
    """By default the exact-phase shooting puts the stops inside their uniform steps: success,
    replayed to 1e-8, and its cost (an exact motion under a piecewise-constant control) at or
    above the continuous optimum J* = 19.43 (the transcription's 19.04 at N = 4 was below it)."""
    r = push(0.5, 8).solve()
    assert r.success and "exact-phase shooting" in r.message, r.message
    assert r.replay.final_miss < 1e-8
    assert r.cost >= 19.43
