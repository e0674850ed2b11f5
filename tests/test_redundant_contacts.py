"""Redundant contacts in the event method: non-unique forces are chosen to satisfy the contact law.

When the closed contacts' constraint rows are dependent (opposed corner pairs of a slider in a guide
without clearance, a box between a floor and a ceiling, a corner given twice) the forces of a mode
form a polytope, and the reported ones must lie in it: N >= 0, |f| <= mu N, friction against the
sliding. The least-norm solution of the mode's linear equations alone has N1 = -N3 on opposed
contacts (it was reported, and with friction it fed energy in). References:

- the slider-crank without clearance, mu = 0: the ideal slider-crank (lcp.scenes.slider_crank, a
  model with bilateral loop constraints and no contacts) by the event method;
- the same with mu = 0.01: rigid contacts leave the squeeze between opposed corners undetermined,
  and the friction grows with it; the least-norm forces are the least squeeze (the guide pushes from
  one side only), whose motion is the reduced equation of the crank with the guide's reaction
  lambda and a friction -mu |lambda| sign(slider velocity), integrated here by DOP853;
- boxes: the weight and friction are carried exactly (closed forms).
"""
import math

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import solve_ivp

import lcp
from lcp.classical import slider_crank_clearance
from lcp.events import event_driven
from lcp.model.system import Contact, System
from lcp.scenes.classical import slider_crank
from lcp.scenes.slider_crank_clearance import slider_crank_clearance_energy

G = 9.81
T = 0.01
TS = np.linspace(0.0, T, 11)


# ----------------------------------------------------------------------------- slider-crank, c = 0
@pytest.fixture(scope="module", params=[0.0, 0.01], ids=["mu=0", "mu=0.01"])
def zero_clearance(request):
    sc = slider_crank_clearance(c=0.0, omega3=0.0, mu=request.param, t_end=T)
    return sc, lcp.simulate(sc, T, method="event", t_eval=TS)


def test_zero_clearance_forces_satisfy_the_contact_law(zero_clearance):
    sc, ev = zero_clearance
    assert ev.success, ev.message
    N, f = ev.force_N, ev.force_T
    scale = np.max(np.abs(N))
    assert scale > 1.0  # the guide carries the slider (measured 17.7 N at most)
    assert np.min(N) >= -1e-12 * scale  # was -8.8 (N1 = -N3 on the opposed corners)
    mu = sc.params["mu"]
    assert np.all(np.abs(f) <= mu * N + 1e-12 * scale)
    # the corners slide with the slider (backwards from the dead centre): friction pushes forwards
    assert np.all(f[1:] >= -1e-12 * scale)
    # the guide pushes from one side at a time (no squeeze between opposed corners 1-3, 2-4)
    assert np.all(np.minimum(N[:, 0], N[:, 2]) <= 1e-12 * scale)
    assert np.all(np.minimum(N[:, 1], N[:, 3]) <= 1e-12 * scale)


def test_zero_clearance_energy_never_rises(zero_clearance):
    sc, ev = zero_clearance
    E = slider_crank_clearance_energy(sc.params, ev.q, ev.v)
    # the event method's integrator tolerance (rtol 1e-12) on |E| = 7.5 J; friction takes
    # 1.3e-2 J over 0.01 s at mu = 0.01 (it was given 1.6e-5 J)
    assert np.max(np.diff(E)) <= 1e-10 * np.max(np.abs(E))
    if sc.params["mu"] > 0:
        assert E[-1] < E[0] - 1e-3


def test_zero_clearance_frictionless_is_the_ideal_slider_crank(zero_clearance):
    sc, ev = zero_clearance
    if sc.params["mu"] > 0:
        pytest.skip("the ideal crank has no friction (the frictional reference is the next test)")
    p = sc.params
    ideal = slider_crank(l1=p["l1"], l2=p["l2"], m1=p["m1"], m2=p["m2"], m3=p["m3"], J1=p["J1"], J2=p["J2"],
                         g=p["g"], omega0=p["omega1"], t_end=T)
    ref = lcp.simulate(ideal, T, method="event", t_eval=TS)
    assert ref.success, ref.message
    assert "the motion is unique" in ev.message
    # measured 1.9e-13 rad and 4.5e-11 rad/s (of 150 rad/s)
    assert np.max(np.abs(ev.q[:, :2] - ref.q[:, :2])) < 1e-9
    assert np.max(np.abs(ev.v[:, :2] - ref.v[:, :2])) < 1e-9 * np.max(np.abs(ref.v))
    assert np.max(np.abs(ev.q[:, 2])) < 1e-15  # the slider does not tilt


def least_squeeze_reference(sc):
    """(theta1, theta2, rates) of the crank with the guide's reaction lambda on P_y = 0 and the
    friction -mu |lambda| sign(P_x') on the slider (sliding backwards, P_x' < 0, for t > 0)."""
    p = sc.params
    l1, l2, mu = p["l1"], p["l2"], p["mu"]

    def rhs(t, y):
        w = y[2:]
        q, v = np.array([y[0], y[1], 0.0]), np.array([w[0], w[1], 0.0])
        A, F = sc.system.mass(q)[:2, :2], sc.system.force(q, v)[:2]
        s1, c1, s2, c2 = math.sin(y[0]), math.cos(y[0]), math.sin(y[1]), math.cos(y[1])
        Gy = np.array([l1 * c1, l2 * c2])  # dP_y/d(theta1, theta2)
        dPx = np.array([-l1 * s1, -l2 * s2])
        for sig in (1.0, -1.0):  # the sign of lambda, checked
            # A qdd = F + lambda (Gy + mu sig dPx): friction +mu |lambda| on the backward slide
            K = np.zeros((3, 3))
            K[:2, :2], K[:2, 2], K[2, :2] = A, -(Gy + mu * sig * dPx), Gy
            x = np.linalg.solve(K, np.concatenate([F, [l1 * s1 * w[0] ** 2 + l2 * s2 * w[1] ** 2]]))
            if sig * x[2] >= 0:
                break
        return np.concatenate([w, x[:2]])

    y0 = np.concatenate([sc.q0[:2], sc.v0[:2]])
    return solve_ivp(rhs, (0.0, T), y0, method="DOP853", rtol=1e-13, atol=1e-14, t_eval=TS)


def test_zero_clearance_with_friction_is_the_least_squeeze_motion(zero_clearance):
    sc, ev = zero_clearance
    if sc.params["mu"] == 0:
        pytest.skip("frictionless: the previous test")
    ref = least_squeeze_reference(sc)
    assert ref.success
    # measured 2.2e-13 rad and 5.4e-11 rad/s
    assert np.max(np.abs(ev.q[:, :2] - ref.y[:2].T)) < 1e-9
    assert np.max(np.abs(ev.v[:, :2] - ref.y[2:].T)) < 1e-9 * np.max(np.abs(ref.y[2:]))
    # the message says that the motion rests on the choice of forces
    assert "motion depends on this choice" in ev.message and "least squeeze" in ev.message


# ----------------------------------------------------------------------------- boxes
def box(corners, m=2.0, w=1.0, h=0.5, mu=0.3, push=0.0):
    """A planar box (x, y, theta) of width w and height h; ``corners`` lists (sx, sy, name): the
    corner (sx w/2, sy h/2) against the floor y = 0 (sy = -1) or the ceiling y = h (sy = +1).
    A horizontal force ``push`` acts at the centre."""
    q, v = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
    x, y, th = q[0], q[1], q[2]
    cs, sn = ca.cos(th), ca.sin(th)
    contacts = []
    for sx, sy, name in corners:
        cx = x + cs * sx * w / 2 - sn * sy * h / 2
        cy = y + sn * sx * w / 2 + cs * sy * h / 2
        contacts.append(Contact(gap=cy if sy < 0 else h - cy, tangent=cx, mu=mu, name=name))
    return System(q, v, mass=ca.diag(ca.vertcat(m, m, m * (w * w + h * h) / 12)),
                  force=ca.vertcat(push, -m * G, 0), contacts=contacts)


FLOOR = [(-1, -1, "rear"), (1, -1, "front")]
CEILING = [(-1, 1, "rear top"), (1, 1, "front top")]


@pytest.mark.parametrize("mu", [0.0, 0.3])
def test_box_on_a_duplicated_corner_shares_the_weight(mu):
    m = 2.0
    sysm = box(FLOOR + [(-1, -1, "rear again")], m=m, mu=mu)
    res = event_driven(sysm, [0.0, 0.25, 0.0], np.zeros(3), 1.0, n_eval=5)
    assert res.success, res.message
    assert res.nonunique_forces == 1 and "the motion is unique" in res.message
    assert np.max(np.abs(res.q - res.q[0])) <= 1e-15 and np.max(np.abs(res.v)) <= 1e-15
    N = res.force_N
    np.testing.assert_allclose(N.sum(axis=1), m * G, rtol=1e-14)
    # moments: the rear corner (twice) carries half; the least-norm split gives each copy a quarter
    np.testing.assert_allclose(N, np.tile([m * G / 4, m * G / 2, m * G / 4], (N.shape[0], 1)), rtol=1e-13)
    assert np.all(np.abs(res.force_T) <= 1e-13)


@pytest.mark.parametrize("mu", [0.0, 0.5])
def test_box_between_floor_and_ceiling_rests_on_the_floor(mu):
    m = 2.0
    res = event_driven(box(FLOOR + CEILING, m=m, mu=mu), [0.0, 0.25, 0.0], np.zeros(3), 1.0, n_eval=5)
    assert res.success, res.message
    assert np.max(np.abs(res.q - res.q[0])) <= 1e-15 and np.max(np.abs(res.v)) <= 1e-15
    N = res.force_N
    # the floor carries the weight, the ceiling nothing (the least-norm forces of the equations
    # alone were +- m g / 4 on the ceiling and 3 m g / 4 on the floor)
    assert np.all(N >= -1e-13 * m * G)
    np.testing.assert_allclose(N[:, :2], m * G / 2, rtol=1e-13)
    assert np.all(np.abs(N[:, 2:]) <= 1e-13 * m * G)
    np.testing.assert_allclose(N[:, :2].sum(axis=1) - N[:, 2:].sum(axis=1), m * G, rtol=1e-14)


def test_box_sliding_between_floor_and_ceiling_takes_the_least_friction():
    m, mu, v0 = 2.0, 0.3, 1.5
    res = event_driven(box(FLOOR + CEILING, m=m, mu=mu), [0.0, 0.25, 0.0], [v0, 0.0, 0.0], 1.0,
                       t_eval=np.linspace(0.0, 1.0, 41))
    assert res.success, res.message
    # the least squeeze: friction mu m g from the floor alone, x = v0 t - mu g t^2 / 2 to the stop.
    # (The friction's torque about the centre is taken by the floor's corners, and the ceiling's
    # open: the decision says that several motions were consistent; an "impact" without impulse
    # may be noted where the tilt's rounding, 1e-16, closes a ceiling corner.)
    t_stop = v0 / (mu * G)
    stops = [e.t for e in res.events if e.kind == "stop"]
    assert len(stops) == 1 and abs(stops[0] - t_stop) <= 1e-12 and res.impulses == []
    t = res.t
    ts = np.minimum(t, t_stop)
    np.testing.assert_allclose(res.q[:, 0], v0 * ts - mu * G * ts ** 2 / 2, rtol=1e-13, atol=1e-15)
    sliding = t < t_stop
    N, f = res.force_N[sliding], res.force_T[sliding]
    assert np.all(N >= -1e-13 * m * G)
    np.testing.assert_allclose(N.sum(axis=1), m * G, rtol=1e-13)  # no squeeze
    assert np.all(np.abs(N[:, 2:]) <= 1e-13 * m * G)
    np.testing.assert_allclose(f.sum(axis=1), -mu * m * G, rtol=1e-13)
    assert np.all(f * v0 <= 1e-13)  # friction against the sliding
    assert "motions were consistent" in res.message
    # energy: never rises
    E = 0.5 * m * res.v[:, 0] ** 2
    assert np.all(np.diff(E) <= 1e-13)


def test_frictionless_box_gliding_between_floor_and_ceiling():
    # the corners slide (folded into the problem with a zero friction unknown, whose f = 0 rows
    # are equalities of the force polytope): the floor carries the weight, the ceiling nothing
    m, v0 = 2.0, 1.5
    res = event_driven(box(FLOOR + CEILING, m=m, mu=0.0), [0.0, 0.25, 0.0], [v0, 0.0, 0.0], 1.0, n_eval=11)
    assert res.success, res.message
    np.testing.assert_allclose(res.q[:, 0], v0 * res.t, rtol=1e-14)
    N = res.force_N
    assert np.all(N >= -1e-13 * m * G)
    np.testing.assert_allclose(N[:, :2], m * G / 2, rtol=1e-13)
    assert np.all(np.abs(N[:, 2:]) <= 1e-13 * m * G)


def test_a_pulling_normal_force_is_never_reported_silently(monkeypatch):
    # the phase's forces replaced by the least-norm solution of the mode's equations alone (the
    # defect fixed above, N1 = -N3): the result's message names the pulling contact
    import lcp.events.phases as phases
    from lcp.events.indeterminate import BranchForces, branch_forces

    def equations_only(pb, check, branch):
        bf = branch_forces(pb, check, branch)
        return None if bf is None else BranchForces(bf.p0, bf.nullity, False, bf.p0, bf.Z)

    monkeypatch.setattr(phases, "branch_forces", equations_only)
    sc = slider_crank_clearance(c=0.0, omega3=0.0, mu=0.0, t_end=T)
    ev = lcp.simulate(sc, T, method="event", t_eval=TS)
    assert np.min(ev.force_N) < -1.0
    assert "< 0: the reported forces there violate the contact law" in ev.message, ev.message


# ----------------------------------------------------------------------------- Moreau-Jean, c = 0
@pytest.mark.parametrize("solver", ["auto", "lemke", "nsgs"])
def test_moreau_jean_without_clearance_explains_the_rebound_it_cannot_meet(solver):
    # At h = 1e-5 the drift of the q-dependent normals makes the lower corners approach at
    # -1.9e-5 m/s and the upper ones separate as fast; u_N of opposed corners sums to that
    # constant whatever the impulses, so u_N+ >= e |u_N-| on one side with u_N+ >= 0 on the other
    # has no solution (an LP confirms): the failure is right, and the message says why.
    sc = slider_crank_clearance(c=0.0, omega3=0.0, mu=0.0, t_end=T)
    res = lcp.simulate(sc, 0.002, h=1e-5, solver=solver)
    assert res.status == -1 and not res.success
    assert "Without the Newton restitution" in res.message and "'corner 3'" in res.message, res.message
    # without restitution the same steps solve, towards the ideal crank (2.5e-5 rad at t = 2 ms)
    sc0 = slider_crank_clearance(c=0.0, omega3=0.0, mu=0.0, e=0.0, t_end=T)
    res0 = lcp.simulate(sc0, 0.002, h=1e-5, solver=solver)
    assert res0.success, res0.message
    assert np.max(np.abs(res0.q[:, 0] - sc0.exact(res0.t)["q"][:, 0])) < 1e-4


# ----------------------------------------------------------------------------- the force polytope
@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1))
def test_opposed_pairs_get_the_least_norm_nonnegative_forces(seed):
    # Two pairs of opposed contacts (normals a, b, -a, -b) on a random 3-dof body, sliding and
    # frictionless (folded as the event method does: f = 0 as equalities). The equations fix only
    # d = (N1 - N3, N2 - N4); the least-norm forces with N >= 0 put |d_i| on one side of each pair.
    from lcp.contact.problem import ContactProblem, SLIDE_POS, STICK
    from lcp.events.indeterminate import branch_forces

    rng = np.random.default_rng(seed)
    a, b = rng.normal(size=3), rng.normal(size=3)
    L = rng.normal(size=(3, 3)) + 3 * np.eye(3)
    Minv = np.linalg.inv(L @ L.T)
    H = np.vstack([a, b, -a, -b, rng.normal(size=(4, 3))])
    W = H @ Minv @ H.T
    q = H @ rng.normal(size=3)
    pb = ContactProblem(W, q, np.zeros(4))
    bf = branch_forces(pb, [STICK] * 4, [SLIDE_POS] * 4)
    assert bf is not None and bf.nullity == 2 and bf.admissible
    d = np.linalg.lstsq(np.column_stack([a, b]).T @ Minv @ np.column_stack([a, b]), -q[:2], rcond=None)[0]
    N = np.array([max(d[0], 0.0), max(d[1], 0.0), max(-d[0], 0.0), max(-d[1], 0.0)])
    scale = max(np.max(np.abs(N)), 1e-300)
    np.testing.assert_allclose(bf.p[:4], N, rtol=0, atol=1e-9 * scale)
    assert np.all(np.abs(bf.p[4:]) <= 1e-12 * scale)


def test_zero_clearance_mode_decision_by_lemke_gives_the_same_answer(zero_clearance):
    sc, ev = zero_clearance
    lem = lcp.simulate(sc, T, method="event", t_eval=TS, mode_solver="lemke")
    assert lem.success, lem.message
    assert np.max(np.abs(lem.q - ev.q)) <= 1e-12 and np.min(lem.force_N) >= -1e-12 * np.max(lem.force_N)
