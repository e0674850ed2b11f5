"""Frictionless contacts (mu = 0) in the optimal control transcriptions.

A frictionless contact has no friction variables in the NLP: its friction blocks (the step's and the
impulse's Coulomb pairs, the affine hold's force rates) stay in x at a fixed zero, so that every block
keeps its (N, m) shape and the reported friction impulses are zeros, and enter no constraint and no
cost. With friction everywhere nothing is fixed. A frictionless push is then solved against its closed
form: with no friction the horizontal motion of a block (on its floor, or landing on it) is a double
integrator whatever the contact does, so the minimum effort is the least-norm control of the discrete
double integrator, which the theta = 1/2 step integrates exactly.
"""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

import lcp
from lcp.ocp import OptimalControlProblem
from lcp.ocp.collocation import RadauTranscription
from lcp.ocp.transcription import FRICTION_BLOCKS, Transcription

G = 9.81


def _point(mu_floor, mu_wall, m=1.0, e=0.0):
    """A point of mass m in the plane under gravity, pushed by (ux, uy), above a floor (y >= 0) and
    right of a wall (x >= -1)."""
    q, v, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 2)
    contacts = [lcp.Contact(gap=q[1], tangent=q[0], mu=mu_floor, e=e, name="floor"),
                lcp.Contact(gap=q[0] + 1.0, tangent=q[1], mu=mu_wall, e=e, name="wall")]
    return lcp.System(q, v, m * ca.DM.eye(2), ca.vertcat(u[0], u[1] - m * G), contacts=contacts, control=u,
                      control_bounds=([-50.0, -50.0], [50.0, 50.0]))


def _used_columns(tr):
    """Indices of the NLP variables that appear in a constraint or in the cost."""
    x = tr.nlp["x"]
    jac = ca.jacobian(ca.vertcat(tr.nlp["g"], tr.nlp["f"]), x)
    return set(jac.sparsity().get_col())


def _friction_columns(tr, contact):
    return np.concatenate([tr.ix[k].reshape(-1, tr.pb.system.n_contacts)[:, contact]
                           for k in FRICTION_BLOCKS if k in tr.ix])


@pytest.mark.parametrize("options", [
    {"contact_law": "gap", "hold": "affine", "steps": "free"},     # impulses, force rates, cross pairs
    {"contact_law": "gap", "hold": "constant", "steps": "uniform"},
    {"contact_law": "velocity", "hold": "constant", "steps": "free"},
])
def test_a_frictionless_contact_has_no_friction_variables(options):
    pb = OptimalControlProblem(_point(0.5, 0.0), 5, T=1.0, q0=[0.0, 0.0], v0=[0.0, 0.0], stage_cost=lcp.ocp.effort,
                               **options)
    tr = Transcription(pb)
    used = _used_columns(tr)
    wall, floor = _friction_columns(tr, 1), _friction_columns(tr, 0)
    assert wall.size >= 6 * pb.N
    assert np.all(tr.lbx[wall] == 0.0) and np.all(tr.ubx[wall] == 0.0)
    assert not used & set(wall.tolist())
    # the floor keeps its friction: free multipliers, all in the law
    assert np.all(tr.ubx[floor] > 0.0) and set(floor.tolist()) <= used
    # every variable that is not fixed enters the problem, and no constraint is constant
    free = np.flatnonzero(tr.lbx < tr.ubx)
    assert set(free.tolist()) <= used
    rows = set(ca.jacobian(tr.nlp["g"], tr.nlp["x"]).sparsity().row())
    assert rows == set(range(tr.lbg.size))


def test_with_friction_everywhere_nothing_is_fixed():
    pb = OptimalControlProblem(_point(0.5, 0.2), 5, T=1.0, q0=[0.0, 0.0], v0=[0.0, 0.0], stage_cost=lcp.ocp.effort,
                               contact_law="gap", hold="affine", steps="free")
    tr = Transcription(pb)
    for k in FRICTION_BLOCKS & set(tr.ix):
        assert np.all(tr.lbx[tr.ix[k].ravel()] < tr.ubx[tr.ix[k].ravel()]), k


def test_radau_frictionless_contact_has_no_friction_variables():
    pb = OptimalControlProblem(_point(0.0, 0.3), 4, T=1.0, q0=[0.0, 0.0], v0=[0.0, 0.0], stage_cost=lcp.ocp.effort,
                               integrator="radau", stages=2, contact_law="velocity", steps="free")
    tr = RadauTranscription(pb)
    used = _used_columns(tr)
    floor, wall = _friction_columns(tr, 0), _friction_columns(tr, 1)
    assert np.all(tr.ubx[floor] == 0.0) and not used & set(floor.tolist())
    assert np.all(tr.ubx[wall] > 0.0) and set(wall.tolist()) <= used
    assert set(ca.jacobian(tr.nlp["g"], tr.nlp["x"]).sparsity().row()) == set(range(tr.lbg.size))


def _least_effort(N, T, m, d):
    """The minimum of int u^2 dt over piecewise-constant u on N equal steps taking the double
    integrator m x'' = u from rest at 0 to rest at d: the least-norm solution of its two linear
    conditions (x_N, v_N), exact under the theta = 1/2 step."""
    h = T / N
    j = np.arange(N)
    A = np.vstack([np.full(N, h / m), h * h / m * (N - j - 0.5)])
    u = A.T @ np.linalg.solve(A @ A.T, np.array([0.0, d]))
    return u, h * float(u @ u)


def _frictionless_block(m):
    q, v, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 1)
    floor = lcp.Contact(gap=q[1], tangent=q[0], mu=0.0, name="floor")
    return lcp.System(q, v, m * ca.DM.eye(2), ca.vertcat(u[0], -m * G), contacts=[floor], control=u,
                      control_bounds=([-50.0], [50.0]))


def _assert_least_effort(res, N, T, m, d):
    """Solved, with the closed form's least effort and control (:func:`_least_effort`); returns that control."""
    u_star, J_star = _least_effort(N, T, m, d)
    assert res.success, res.message
    assert res.cost == pytest.approx(J_star, rel=1e-7)
    np.testing.assert_allclose(res.u[:, 0], u_star, rtol=1e-5, atol=1e-6 * np.max(np.abs(u_star)))
    return u_star


@pytest.mark.parametrize("N, d, m", [(6, 0.5, 2.0), (9, -0.3, 0.5)])
def test_a_frictionless_block_pushed_to_a_target_meets_the_closed_form(N, d, m):
    T = 1.0
    pb = OptimalControlProblem(_frictionless_block(m), N, T=T, q0=[0.0, 0.0], v0=[0.0, 0.0],
                               stage_cost=lcp.ocp.effort, hold="constant", steps="uniform",
                               terminal_constraints=lambda q, v: ca.vertcat(q[0] - d, v[0]))
    res = pb.solve()
    _assert_least_effort(res, N, T, m, d)
    # the floor carries the weight and no friction: p_T zeros of shape (N, m)
    assert res.p_T.shape == (N, 1) and np.all(res.p_T == 0.0)
    np.testing.assert_allclose(res.p_N[:, 0], m * G * res.steps, rtol=1e-8)
    np.testing.assert_allclose(res.q[:, 1], 0.0, atol=1e-10)


def test_a_frictionless_landing_keeps_the_tangential_velocity():
    # a point released at the height from which it lands at T / 2 (a node), pushed horizontally to
    # x = d at rest at T, lands inelastically on a frictionless floor: the impact removes the normal
    # velocity only, so the horizontal motion and the optimal push are those of the closed form
    m, T, N, d = 1.5, 1.0, 8, 0.4
    t_land = T / 2
    y0 = G * t_land ** 2 / 2
    q, v, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 1)
    floor = lcp.Contact(gap=q[1], tangent=q[0], mu=0.0, e=0.0, name="floor")
    sys = lcp.System(q, v, m * ca.DM.eye(2), ca.vertcat(u[0], -m * G), contacts=[floor], control=u,
                     control_bounds=([-50.0], [50.0]))
    pb = OptimalControlProblem(sys, N, T=T, q0=[0.0, y0], v0=[0.0, 0.0], stage_cost=lcp.ocp.effort,
                               hold="constant", steps="uniform", contact_law="gap",
                               terminal_constraints=lambda qq, vv: ca.vertcat(qq[0] - d, vv[0]))
    res = pb.solve()
    u_star = _assert_least_effort(res, N, T, m, d)
    k = N // 2  # the landing node: the velocity before the impulse is the free fall's
    assert res.v[k, 1] == pytest.approx(-G * t_land, rel=1e-9)
    np.testing.assert_allclose(res.v[k + 1:, 1], 0.0, atol=1e-8)
    np.testing.assert_allclose(res.q[k:, 1], 0.0, atol=1e-9)
    # the horizontal velocity runs through the landing as the double integrator's
    vx = np.concatenate([[0.0], np.cumsum(res.steps * u_star / m)])
    np.testing.assert_allclose(res.v[:, 0], vx, atol=1e-7)
    assert res.p_T.shape == (N, 1) and np.all(res.p_T == 0.0)
    assert res.replay is not None and res.replay.final_miss <= 1e-6


@pytest.mark.slow
def test_the_discs_going_around_meet_their_contact_law_at_every_node():
    # two_discs at N = 30 from its start around disc 2 (studies._ocp_models.discs_start): without the
    # row u_N(v_k+) >= -g_k / (theta T / N) of curved contacts a node touched disc 2 approaching it
    # with no impulse (the chord through disc 2), and the homotopy ended with the Coulomb residual
    # 0.51; with it the transcription meets its own law
    from lcp.ocp.complementarity import run_homotopy
    from lcp.ocp.guess import x0_from_guess
    from lcp.ocp.options import HomotopyOptions
    from studies._ocp_models import two_discs

    ex = two_discs()
    pb = ex.make(30)
    gs = ex.start(pb)
    assert gs is not None
    tr = Transcription(pb)
    P0 = np.concatenate([[0.0], pb.q0, pb.v0])
    x, cost, diag, status, message, _ = run_homotopy(tr, x0_from_guess(pb, tr, gs), P0, HomotopyOptions(), {})
    assert status == 0, message
    assert diag["residual"] <= 1e-8
    _, _, q, v, _, _, _ = tr.unpack(x)
    vplus = np.array(tr.aux(x, P0), dtype=float).T
    for k in range(pb.N):
        if pb.system.gaps(q[k])[0] <= 1e-9:
            assert pb.system.contact_jacobian(q[k])[0] @ vplus[k] >= -1e-9, k
    # the strike: disc 2 leaves its start towards its target
    assert q[-1, 2] > 0.5


def test_the_discs_start_goes_around_and_strikes():
    # studies._ocp_models.discs_start: disc 1 passes over disc 2, never overlaps it at a node, strikes it to the right, and the same control at N = 30 and 60
    from studies._ocp_models import two_discs

    ex = two_discs()
    g30, g60 = ex.start(ex.make(30)), ex.start(ex.make(60))
    assert g30 is not None and g60 is not None
    np.testing.assert_array_equal(np.repeat(g30.u, 2, axis=0), g60.u)
    gaps = np.array([ex.system.gaps(q)[0] for q in g30.q])
    assert np.min(gaps) >= -1e-12
    over = (np.abs(g30.q[:, 0] - g30.q[:, 2]) < 0.3) & (g30.q[:, 1] - g30.q[:, 3] > 0.5)
    assert np.any(over)
    assert g30.q[-1, 2] > 0.5 and g30.q[-1, 0] < -0.5  # swapped sides
