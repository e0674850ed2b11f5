"""Optimal control along curved gaps under the gap law (lcp.ocp.transcription, "Curved gaps").

A frictionless unit point pushed along x (force u, gravity g) slides along a curve from rest to rest
with minimum int u^2 dt: the floor y = x^2 / 2 (a bowl) and the top of the unit circle (a convex
obstacle, gap |q - c| - 1). Without the position stabilisation the theta step over-determines a
loaded step on a curve and the homotopy stopped on the Coulomb residual (0.11 on the bowl). Now the
residual meets the tolerance, the point stays on its curve at every node, and the event replay
misses the final state by the step's second-order error (a quarter when N doubles).
"""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from lcp.model.system import Contact, System
from lcp.ocp import OptimalControlProblem, effort

G = 9.81


def point_on_curve(kind, N, replay_tol=1e-2):
    q, v, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 1)
    if kind == "bowl":
        gap, q0, xT = q[1] - q[0] ** 2 / 2, np.zeros(2), 1.0
    elif kind == "flat":
        gap, q0, xT = q[1], np.zeros(2), 1.0
    else:  # over the top of the unit circle centred at (0, -1), from x = -0.3 to x = 0.3
        gap, q0, xT = ca.sqrt(q[0] ** 2 + (q[1] + 1) ** 2) - 1.0, np.array([-0.3, np.sqrt(0.91) - 1]), 0.3
    sys = System(q, v, ca.SX.eye(2), ca.vertcat(u[0], -G), contacts=[Contact(gap=gap, tangent=q[0], mu=0.0)],
                 control=u, control_bounds=(np.array([-30.0]), np.array([30.0])), names=["x", "y"])
    # uniform steps, constant hold: the curved-gap theta step's own order (the default grid is free)
    return OptimalControlProblem(sys, N, T=1.0, q0=q0, v0=np.zeros(2), stage_cost=effort, replay_tol=replay_tol,
                                 hold="constant", steps="uniform",
                                 terminal_constraints=lambda qq, vv: ca.vertcat(qq[0] - xT, vv, qq[1] - q0[1] - (
                                     xT ** 2 / 2 if kind == "bowl" else 0.0)))


def _on_curve(pb, r):
    gaps = np.array([pb.system.gaps(qk) for qk in r.q])
    assert np.max(np.abs(gaps)) <= 1e-9
    assert np.min(r.p_N) > 0  # loaded throughout: no flight
    # each step ends moving along the curve, so the next needs no impulse at its node (the
    # over-determined step had impulses up to 1e-3 N s at every node)
    uN = [pb.system.contact_jacobian(qk)[0] @ vk for qk, vk in zip(r.q, r.v)]
    assert np.max(np.abs(uN)) <= 1e-6


def test_flat_gaps_keep_the_plain_step():
    pb = point_on_curve("flat", 6)
    r = pb.solve()
    assert pb.transcription.curved.size == 0 and "eta" not in pb.transcription.ix
    assert r.status == 0 and r.replay.final_miss <= 1e-12


def test_bowl_converges_at_second_order():
    misses = []
    for N in (20, 40):
        pb = point_on_curve("bowl", N)
        r = pb.solve()
        assert list(pb.transcription.curved) == [0]
        assert r.status == 0, r.message
        assert r.homotopy[-1].residual <= 1e-8
        _on_curve(pb, r)
        misses.append(r.replay.final_miss)
    assert 3.0 <= misses[0] / misses[1] <= 5.0, misses


@pytest.mark.slow
def test_convex_obstacle():
    pb = point_on_curve("circle", 40)
    r = pb.solve()
    assert r.status == 0, r.message
    _on_curve(pb, r)
    assert r.replay.final_miss <= 1e-2


def test_landing_on_a_curved_floor_meets_newton_and_coulomb():
    """A point (mu = 0.5) dropped from 0.22 m above the bowl y = x^2 / 2 at x = 0.6, steered to rest at
    the bottom in 1 s (N = 20): it lands at a node with an impulse, then slides along the curve
    under a force. The node's impulse acts along the contact Jacobian at the node, and the
    diagnosis measures it so (measuring it with the step's mean Jacobian, as the curved step's
    forces act, read a residual 0.019 and the solve ended with status -2)."""
    q, v, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 1)
    sys = System(q, v, ca.SX.eye(2), ca.vertcat(u[0], -G), contacts=[Contact(gap=q[1] - q[0] ** 2 / 2, tangent=q[0],
                                                                          mu=0.5)],
                 control=u, control_bounds=(np.array([-30.0]), np.array([30.0])), names=["x", "y"])
    pb = OptimalControlProblem(sys, 20, T=1.0, q0=np.array([0.6, 0.4]), v0=np.zeros(2), stage_cost=effort,
                               replay_tol=1e-2, terminal_constraints=lambda qq, vv: ca.vertcat(qq[0], vv), steps="uniform", hold="constant")
    r = pb.solve()
    assert r.status == 0, r.message
    assert r.complementarity_residual <= 1e-8
    gaps = np.array([pb.system.gaps(qk)[0] for qk in r.q])
    k = int(np.argmax(gaps <= 1e-9))  # the landing node
    assert 2 <= k <= 6 and np.max(np.abs(gaps[k:])) <= 1e-9
    assert np.all(r.p_N[k:, 0] > 0) and np.all(r.p_N[:k, 0] == pytest.approx(0.0, abs=1e-9))
    assert r.replay.final_miss <= 1e-3  # second order on the curve (measured 2.7e-4)


@pytest.mark.slow
def test_box_tipped_over_its_corner_from_a_tipping_guess():
    """studies._ocp_models.box_tip at N = 20 from the event simulation of a push that tips the box
    (4 N for 0.3 s): the box pivots on its bottom-right corner (stuck but for the last step before
    the landing), its bottom-left corner lifts in the first steps, the top-right corner lands at a node with
    an impulse that stops the box, which then rests on its side. The Coulomb law reads the pivot's
    velocity with the step's end Jacobian (with the start's the homotopy stalled at residual 0.87).
    The transcription's own solution: without the exact-phase shooting, which replaces it by a
    solution on its replay's phases (where the step before the landing carries a normal impulse on
    the landing corner, 0.09)."""
    from lcp.ocp.guess import event_guess
    from studies._ocp_models import box_tip

    ex = box_tip()
    pb = ex.make(20)
    r = pb.solve(event_guess(pb, lambda t: 4.0 if t < 0.3 else 0.0, 1.0), shooting=False)
    assert r.complementarity_residual <= 1e-8, r.message
    gaps = np.array([pb.system.gaps(qk) for qk in r.q])
    pivot, land = 1, 2
    assert np.max(np.abs(gaps[:, pivot])) <= 1e-9  # the pivot stays on the floor
    k_land = int(np.argmax(gaps[:, land] <= 1e-9))
    assert 5 <= k_land < 20 and np.all(gaps[k_land:, land] <= 1e-9)
    assert np.all(r.p_N[:k_land, land] == pytest.approx(0.0, abs=1e-9))
    assert np.max(np.abs(r.v[k_land + 1:])) <= 1e-8  # at rest after the landing impulse
    # the bottom-left corner lifts in the first two steps and stays lifted (the transcription's
    # solution has it at -2.8e-17 at node 1, zero to rounding, and 6.9e-3 at node 2)
    assert np.min(gaps[1:, 0]) >= -1e-12 and np.min(gaps[2:, 0]) > 0
    # the step's second-order error: the replay misses, by a few mm, not by the box
    assert r.replay.final_miss <= 2e-2


@pytest.mark.slow
def test_hopper_from_the_defaults_meets_the_coulomb_law():
    """studies._ocp_models.hopper at N = 20 from solve()'s defaults: the Coulomb residual of the
    returned point is at rounding level. The impulses at the nodes act along the node's own contact
    Jacobian, so the diagnosis measures them with that Jacobian's Delassus operator (with the step's
    mean Jacobian of the curved foot it read 0.016 at a touchdown that meets Newton's and Coulomb's
    laws). The replay still misses by the step's error and the touchdowns' timing (8e-2)."""
    from studies._ocp_models import hopper

    pb = hopper().make(20)
    r = pb.solve()
    assert r.complementarity_residual <= 1e-8, r.message
    assert r.dynamics_residual <= 1e-8
