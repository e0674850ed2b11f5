"""The general model beyond Jean-Pratt: q-dependent kinematics and a q-dependent mass matrix."""
import casadi as ca
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import lcp
from lcp.model.system import Contact, System


def bowl(mu=0.0, radius=1.0, m=1.0, g=9.81):
    """A particle inside a circular bowl: gap = radius - |q| (nonlinear gap, varying normal)."""
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    r = ca.norm_2(q)
    return System(q, v, m * ca.SX.eye(2), ca.vertcat(0, -m * g),
                  contacts=[Contact(gap=radius - r, tangent_jacobian=ca.horzcat(-q[1], q[0]) / r, mu=mu)])


def pendulum_angle(t, theta0_dot, radius=1.0, g=9.81):
    sol = solve_ivp(lambda _, y: [y[1], -g / radius * np.sin(y[0])], (0, t[-1]), [0.0, theta0_dot],
                    t_eval=t, rtol=1e-12, atol=1e-12)
    return sol.y[0]


def test_frictionless_bowl_is_a_pendulum():
    s = bowl()
    assert not s.is_constant
    errs = []
    for h in (2e-3, 1e-3, 5e-4):
        res = lcp.simulate(s, 0.6, h=h, q0=[0.0, -1.0], v0=[1.5, 0.0], solver="lemke")
        assert res.success, res.message
        ang = np.arctan2(res.q[:, 0], -res.q[:, 1])
        errs.append(np.max(np.abs(ang - pendulum_angle(res.t, 1.5))))
        gap = 1.0 - np.hypot(res.q[:, 0], res.q[:, 1])
        # Moreau-Jean keeps the constraint at velocity level only: on a curved surface the
        # position drifts by O(h) per unit time (no projection yet), never more
        assert np.max(np.abs(gap)) < 2 * h
    assert errs[-1] < 5e-3 and errs[2] < errs[0] / 2.5  # first-order convergence


def test_rough_bowl_sticks_at_the_bottom():
    res = lcp.simulate(bowl(mu=0.5), 1.0, h=1e-3, q0=[0.0, -1.0], v0=[0.2, 0.0])
    assert res.success
    assert abs(res.v[-1]).max() < 1e-9  # stopped by friction
    assert res.stats.mode_counts["stick"] > 0


def test_osqp_and_lemke_agree_on_the_bowl():
    a = lcp.simulate(bowl(mu=0.3), 0.5, h=1e-3, q0=[0.0, -1.0], v0=[2.0, 0.0], solver="lemke")
    b = lcp.simulate(bowl(mu=0.3), 0.5, h=1e-3, q0=[0.0, -1.0], v0=[2.0, 0.0], solver="osqp")
    np.testing.assert_allclose(b.q, a.q, atol=1e-9)


def test_q_dependent_mass_matrix():
    # the Jean-Pratt block in coordinates (x, y) with a slide angle written through a q-dependent
    # mass matrix that is constant on the contact line y = 0: identical motion to the constant scene
    sc = lcp.scenes.jean_pratt(R=0.3, v0=1.2)
    q, v = sc.system.q_sym, sc.system.v_sym
    mass = sc.system.mass_expr * (1 + q[1] ** 2)
    s = System(q, v, mass, sc.system.force_expr, contacts=sc.system.contacts)
    assert not s.mass_is_constant
    a = lcp.simulate(sc, 0.4, h=1e-3)
    b = lcp.simulate(s, 0.4, h=1e-3, q0=sc.q0, v0=sc.v0)
    np.testing.assert_allclose(b.q, a.q, atol=1e-12)


def test_restitution_bounces():
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    s = System(q, v, ca.SX.eye(2), ca.vertcat(0, -9.81), contacts=[Contact(gap=q[1], tangent=q[0], mu=0.0, e=0.5)])
    res = lcp.simulate(s, 0.5, h=1e-4, q0=[0.0, 0.0], v0=[0.0, -2.0])
    # first step: impact with e = 1/2 sends it up at about 1 m/s
    assert res.v[1, 1] == pytest.approx(1.0, abs=2e-3)
    assert res.stats.free_steps > 0  # then flight with the contact inactive
