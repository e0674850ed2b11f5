"""The gap law of the optimal control transcription (contacts that open and close) and the replay
check's messages, written after the replay."""
import casadi as ca
import numpy as np
import pytest

import lcp
from lcp.ocp import OptimalControlProblem, effort

G = 9.81


def point_mass(mu=0.5, umax=20.0):
    q, v, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 2)
    return lcp.System(q, v, ca.DM.eye(2), ca.vertcat(u[0], -G + u[1]),
                      contacts=[lcp.Contact(gap=q[1], tangent=q[0], mu=mu, name="floor")],
                      control=u, control_bounds=([-umax, -umax], [umax, umax]))


def test_a_mass_above_a_floor_solves_and_its_replay_is_exact():
    # thrust holds the mass 1 m above the floor while it moves 0.1 m: no contact ever closes.
    # The exact optimum: u_y = g throughout, u_x the minimum-effort ramp of a double integrator,
    # whose effort over T is 12 d^2 / T^3 (+ g^2 T).
    T, d, N = 0.3, 0.1, 10
    pb = OptimalControlProblem(point_mass(), N, T=T, q0=[0.0, 1.0], v0=[0.0, 0.0], stage_cost=effort,
                               terminal_constraints=lambda q, v: ca.vertcat(q - ca.DM([d, 1.0]), v))
    assert pb.contact_law == "gap"  # "auto": a contact starts open
    r = pb.solve()
    assert r.success, r.message
    assert np.all(r.p_N == 0.0) or np.max(np.abs(r.p_N)) < 1e-9
    assert r.replay.final_miss < 1e-9 and r.replay.where == ""
    # the default grid (free steps, affine hold) represents the double integrator's ramp exactly:
    # the continuous optimum (a piecewise-constant control would exceed it by up to 1/N^2)
    assert (r.problem.hold, r.problem.steps) == ("affine", "free")
    assert np.allclose(r.u[:, 1], G, atol=1e-6)
    cont = 12 * d * d / T ** 3 + G * G * T
    assert r.cost == pytest.approx(cont, rel=1e-9)
    assert "Replayed by event" in r.message and "within replay_tol" in r.message


def test_the_velocity_law_cannot_leave_the_floor_and_the_gap_law_can():
    # lift a resting mass 0.1 m and set it down again at rest: under the velocity law the contact
    # stays closed (the normal velocity at each step's end must be >= 0 and the force complementary
    # to it, so the mass can rise but not come down: infeasible or a failed replay); under the gap
    # law it lifts off, flies and lands, replayed exactly by the event method
    kw = dict(T=1.0, q0=[0.0, 0.0], v0=[0.0, 0.0], stage_cost=effort,
              path_equalities=lambda s: s.q1[1] - 0.1 if s.k == 4 else ca.SX.zeros(0, 1),
              terminal_constraints=lambda q, v: ca.vertcat(q - ca.DM([0.2, 0.0]), v))
    # frictionless, so that no stick-slip switch falls inside a uniform step
    gap = OptimalControlProblem(point_mass(mu=0.0), 10, contact_law="gap", **kw).solve()
    assert gap.success, gap.message
    assert gap.replay.final_miss < 1e-6
    assert np.max(gap.q[:, 1]) >= 0.1 - 1e-9
    assert np.min(gap.q[:, 1]) >= -1e-9
    vel = OptimalControlProblem(point_mass(mu=0.0), 10, contact_law="velocity", **kw).solve()
    assert not vel.success or np.max(vel.q[-1:, 1]) < 1e-9


def test_a_failed_replay_says_where_and_after_the_replay():
    # falling 0.2 m onto the floor and sliding on with uniform steps: the stick/slide switch falls
    # inside a step, the replay misses; the message says so, names the node and the contact, and
    # no longer claims that the replay miss is within tolerance
    pb = OptimalControlProblem(point_mass(), 10, T=1.0, q0=[0.0, 0.2], v0=[0.0, 0.0], stage_cost=effort,
                               terminal_constraints=lambda q, v: ca.vertcat(q - ca.DM([0.3, 0.0]), v))
    r = pb.solve()
    assert r.replay is not None
    if r.replay.ok:
        assert r.success and "within replay_tol" in r.message
    else:
        assert r.status == -3 and not r.success
        assert "replay miss are within tolerance" not in r.message
        assert "at node" in r.message and r.replay.where in r.message
        assert r.message.index("Replayed by") < r.message.index("Before the replay")


def test_contact_law_is_validated():
    with pytest.raises(ValueError, match="contact_law"):
        OptimalControlProblem(point_mass(), 4, q0=[0, 0], v0=[0, 0], contact_law="position")
