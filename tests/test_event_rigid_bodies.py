"""The event method on rigid bodies in 3D (Newton-Euler kinematics qdot = T(q) v) with contacts at
material points and bilateral constraints: the tumbling box, a ball that slides then
rolls, a heavy top held at its pivot by three bilateral constraints."""
from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest
from hypothesis import assume, given, settings, strategies as st

import lcp
from lcp.model.kinematics import quat_exp, quat_mul
from lcp.model.rigid_body import bodies_system, free_body
from lcp.model.system import Contact


# ---------------------------------------------------------------------------- the tumbling box
@pytest.fixture(scope="module")
def box():
    sc = lcp.scenes.tumbling_box()
    res = lcp.simulate(sc, 2.0, method="event", n_eval=2001)
    return sc, res


def _free_flight(sc, t):
    """The exact free fall of the box: a parabola, p(t) = p0 (x) exp(t omega / 2) (omega constant:
    the cube's inertia is isotropic)."""
    g = sc.params["g"]
    x = sc.q0[:3] + t * sc.v0[:3] + np.array([0.0, 0.0, -0.5 * g * t * t])
    p = quat_mul(sc.q0[3:7], quat_exp(0.5 * t * sc.v0[3:]))
    return np.concatenate([x, p])


def _first_corner_landing(sc):
    """The first root of min corner gap on the exact free fall (bisection to rounding)."""
    from scipy.optimize import brentq

    ts = np.linspace(0.0, 1.0, 2001)
    gaps = np.array([sc.gap(_free_flight(sc, t)).min() for t in ts])
    k = int(np.argmax(gaps <= 0))
    return brentq(lambda t: sc.gap(_free_flight(sc, t)).min(), ts[k - 1], ts[k], xtol=1e-16, rtol=1e-15)


def test_box_free_fall_is_exact_and_first_impact_on_time(box):
    sc, res = box
    t_hit = _first_corner_landing(sc)
    assert res.events[0].kind == "impact"
    assert abs(res.t_events[0] - t_hit) <= 1e-12
    before = res.t < t_hit
    assert before.sum() > 300
    exact = np.array([_free_flight(sc, t) for t in res.t[before]])
    assert np.max(np.abs(res.q[before] - exact)) <= 1e-12
    assert np.max(np.abs(res.v[before, 3:] - sc.v0[3:])) <= 1e-12


def test_box_energy_never_increases_and_quaternion_stays_unit(box):
    sc, res = box
    E = np.array([sc.energy(q, v) for q, v in zip(res.q, res.v)])
    assert np.all(np.diff(E) <= 1e-12 * abs(E[0]))
    assert E[-1] < E[0] - 1.0  # the impacts and the sliding dissipate
    assert np.max(np.abs(np.linalg.norm(res.q[:, 3:7], axis=1) - 1.0)) <= 4e-16
    # no corner penetrates beyond the zero tests' length tolerance
    gaps = np.array([sc.gap(q) for q in res.q])
    assert gaps.min() >= -1e-9


def _rotation(sc, q):
    return np.array(ca.evalf(ca.substitute(sc.body.rotation, sc.body.quaternion, ca.DM(q[3:7]))), dtype=float)


def test_box_comes_to_rest_on_a_face(box):
    """Corner 0 lands, sticks, slips and slides; corner 4 lands; corners 2 and 6 land with them on
    the face z = -1/2 of the body: four sliding corners (redundant contacts: least-norm forces, said),
    which stop together and stick for good."""
    sc, res = box
    assert res.success, res.message
    impacts = [ev.contact for ev in res.events if ev.kind == "impact"]
    assert impacts[:2] == [0, 4]
    assert res.mode_sequence[-1] == ("stick", "open", "stick", "open", "stick", "open", "stick", "open")
    assert res.nonunique_forces >= 2 and "not unique" in res.message
    assert not res.phases[-1].forces_unique
    t_rest = res.phases[-1].t0
    assert 1.0 < t_rest < 1.3
    rest = res.t >= t_rest
    q, v = res.q[-1], res.v[-1]
    assert abs(q[2] - 0.5) <= 1e-9  # centre at half the side
    assert np.max(np.abs(_rotation(sc, q)[:, 2] - [0.0, 0.0, 1.0])) <= 1e-9  # the body's z axis vertical
    assert np.max(np.abs(res.v[rest])) <= 1e-12
    g = sc.gap(q)
    assert np.max(np.abs(g[[0, 2, 4, 6]])) <= 1e-12 and np.allclose(g[[1, 3, 5, 7]], 1.0, atol=1e-9)
    assert np.max(np.abs(res.q[rest] - q)) <= 1e-12  # at rest: nothing moves


def test_box_agrees_with_moreau_jean_as_h_shrinks(box):
    """Where the motion is determinate (corner 0 sticking just after the first impact, slipping,
    sliding; corner 4 landing) Moreau-Jean converges to the event method's trajectory: the
    post-impact state and the slide, q and v, within 5 h (measured 1.2 h at h = 1e-3, 3.3 h at
    1e-4: first order once the impact falls in the asymptotic regime), the landing within 2 h."""
    sc, res = box
    hs = (1e-3, 1e-4)
    errs, t_second = [], []
    for h in hs:
        mj = lcp.simulate(sc, 0.53, h=h, method="moreau-jean")
        err = 0.0
        for t_cmp in (0.38, 0.45):  # after the impact at 0.37616 (stick), after the slip at 0.38158
            i = int(np.searchsorted(res.t, t_cmp - 1e-12))
            assert res.t[i] == pytest.approx(t_cmp, abs=1e-15)
            k = int(round(t_cmp / h))
            assert mj.t[k] == pytest.approx(t_cmp, abs=1e-12)
            err = max(err, float(np.max(np.abs(np.concatenate([mj.q[k] - res.q[i], mj.v[k] - res.v[i]])))))
        errs.append(err)
        g4 = np.array([sc.gap(q)[4] for q in mj.q])
        t_second.append(float(mj.t[np.argmax(g4 <= 1e-9)]))
    assert errs[1] < errs[0] / 2  # shrinking with h
    for h, err in zip(hs, errs):
        assert err <= 5 * h
    t_ev = [ev.t for ev in res.events if ev.kind == "impact" and ev.contact == 4][0]
    for h, ts in zip(hs, t_second):
        assert abs(ts - t_ev) <= 2 * h


# ---------------------------------------------------------------------------- the ball
def _ball(m=1.0, r=0.1, mu=0.3, g=9.81):
    """A solid sphere on the plane z = 0, the contact at its lowest point: gap z - r, tangent
    velocity of the material point under the centre, v + omega_w x (-r e_z)."""
    b = free_body(m, 0.4 * m * r * r * np.eye(3), name="ball")
    R = b.rotation
    J = ca.vertcat(ca.horzcat(1, 0, 0, -r * R[1, :]), ca.horzcat(0, 1, 0, r * R[0, :]))
    c = Contact(gap=b.q[2] - r, tangent_jacobian=J, mu=mu, e=0.0, name="floor")
    return bodies_system([b], [c], gravity=g)


def _ball_exact(v0, r, mu, g):
    """Sliding ends at t* = |u0| / (mu g (1 + m r^2 / I)) = 2 |u0| / (7 mu g); the centre
    decelerates by mu g along the (constant) slip direction until then."""
    w = v0[3:]  # body = world frame at p0 = 1
    u0 = v0[:2] + np.array([-r * w[1], r * w[0]])
    ts = 2.0 * np.linalg.norm(u0) / (7.0 * mu * g)
    return ts, v0[:2] - mu * g * ts * u0 / np.linalg.norm(u0)


def test_box_stop_on_too_many_events_names_the_redundant_corners():
    """A run cut by max_events while four corners of a face are closed stops with status -4 and says
    which contacts are redundant, before the motion it could not finish."""
    sc = lcp.scenes.tumbling_box()
    res = lcp.simulate(sc, 2.0, method="event", max_events=5)
    assert res.status == -4 and not res.success
    assert "redundant" in res.message and "'corner0', 'corner2', 'corner4', 'corner6'" in res.message
    assert res.t[-1] <= res.t_events[-1]


@pytest.mark.slow
def test_box_rest_position_is_moreau_jean_limit(box):
    """The face slide (four redundant corners, least-norm forces) and the rest are Moreau-Jean's
    h -> 0 limit: the rest pose within 2 h (measured 1.7e-3 at h = 1e-3, 1.6e-4 at 1e-4), its
    rest time within 4 h of the event method's stop (1.15025 s)."""
    sc, res = box
    t_rest = res.phases[-1].t0
    for h in (1e-3, 1e-4):
        mj = lcp.simulate(sc, 1.25, h=h, method="moreau-jean")
        assert np.max(np.abs(mj.q[-1] - res.q[-1])) <= 2 * h
        still = np.max(np.abs(mj.v), axis=1) < 1e-9
        assert abs(mj.t[np.argmax(still)] - t_rest) <= 4 * h


@pytest.mark.parametrize("v0", [[2.0, 0.5, 0.0, 3.0, -10.0, 4.0], [-0.5, 1.0, 0.0, -20.0, 5.0, 0.0]])
def test_ball_slides_then_rolls_exactly(v0):
    r, mu, g = 0.1, 0.3, 9.81
    s = _ball(r=r, mu=mu, g=g)
    v0 = np.array(v0)
    q0 = np.array([0.0, 0.0, r, 1.0, 0.0, 0.0, 0.0])
    ts, vf = _ball_exact(v0, r, mu, g)
    res = lcp.simulate(s, 1.0, method="event", q0=q0, v0=v0, n_eval=101)
    assert res.success, res.message
    assert [e.kind for e in res.events] == ["stop"]
    assert res.mode_sequence == [("slide",), ("stick",)]
    assert abs(res.t_events[0] - ts) <= 1e-10
    assert np.max(np.abs(res.v[-1, :2] - vf)) <= 1e-10
    assert np.max(np.abs(res.q[:, 2] - r)) <= 1e-12 and np.max(np.abs(res.v[:, 2])) <= 1e-12
    # rolling: the contact point at rest, the kinetic energy constant afterwards
    H = s.contact_jacobian(res.q[-1])
    assert np.max(np.abs(H[1:] @ res.v[-1])) <= 1e-10
    after = res.t > ts + 1e-9
    Ek = np.array([s.kinetic_energy(q, v) for q, v in zip(res.q[after], res.v[after])])
    assert np.ptp(Ek) <= 1e-10 * Ek[0]


@settings(max_examples=4, deadline=None)
@given(speed=st.floats(0.2, 3.0), heading=st.floats(-math.pi, math.pi), wx=st.floats(-30.0, 30.0),
       wy=st.floats(-30.0, 30.0), wz=st.floats(-10.0, 10.0))
def test_ball_stop_time_over_throws(speed, heading, wx, wy, wz):
    """Any throw whose contact point slips: t* = 2|u0|/(7 mu g) and the final velocity to 1e-10."""
    r, mu, g = 0.1, 0.3, 9.81
    v0 = np.array([speed * math.cos(heading), speed * math.sin(heading), 0.0, wx, wy, wz])
    ts, vf = _ball_exact(v0, r, mu, g)
    assume(ts > 1e-3)
    res = lcp.simulate(_ball(r=r, mu=mu, g=g), ts + 0.05, method="event", q0=[0, 0, r, 1.0, 0, 0, 0], v0=v0,
                       t_eval=[0.0, ts + 0.05])
    assert res.success, res.message
    assert res.mode_sequence == [("slide",), ("stick",)]
    assert abs(res.t_events[0] - ts) <= 1e-10 * max(1.0, ts)
    assert np.max(np.abs(res.v[-1, :2] - vf)) <= 1e-10


def test_ball_moreau_jean_first_order():
    r, mu, g = 0.1, 0.3, 9.81
    s = _ball(r=r, mu=mu, g=g)
    v0 = np.array([2.0, 0.5, 0.0, 3.0, -10.0, 4.0])
    q0 = np.array([0.0, 0.0, r, 1.0, 0.0, 0.0, 0.0])
    _, vf = _ball_exact(v0, r, mu, g)
    errs = []
    for h in (2e-3, 1e-3):
        res = lcp.simulate(s, 0.5, h=h, method="moreau-jean", q0=q0, v0=v0)
        errs.append(float(np.max(np.abs(res.v[-1, :2] - vf))))
    assert errs[1] < 0.6 * errs[0] and errs[0] <= 2 * 2e-3  # O(h): 1.2 h measured


# ---------------------------------------------------------------------------- the heavy top
def test_heavy_top_on_three_bilateral_constraints():
    """A symmetric top as a free body whose pivot point is held at the origin by three bilateral
    constraints x + R(p) r = 0: the event method keeps the energy and the constraints."""
    m, g, L = 1.0, 9.81, 0.5
    J = np.diag([0.05, 0.05, 0.02])
    b = free_body(m, J, name="top")
    r_pivot = np.array([0.0, 0.0, -L])
    s = bodies_system([b], gravity=g, constraints=b.point(r_pivot))
    p0 = quat_exp(0.2 * np.array([1.0, 0.0, 0.0]))
    R0 = np.array(ca.evalf(ca.substitute(b.rotation, b.quaternion, ca.DM(p0))), dtype=float)
    w0 = np.array([0.0, 0.5, 20.0])
    q0 = np.concatenate([-R0 @ r_pivot, p0])
    v0 = np.concatenate([np.cross(R0 @ w0, -R0 @ r_pivot), w0])
    res = lcp.simulate(s, 3.0, method="event", q0=q0, v0=v0, n_eval=301)
    assert res.success, res.message
    E = np.array([0.5 * m * v[:3] @ v[:3] + 0.5 * v[3:] @ J @ v[3:] + m * g * q[2] for q, v in zip(res.q, res.v)])
    assert np.max(np.abs(E - E[0])) <= 1e-9 * abs(E[0])
    viol = np.array([np.array(s.constraints_fn(0.0, q)[0], dtype=float).ravel() for q in res.q])
    assert np.max(np.abs(viol)) <= 1e-10
    assert np.max(np.abs(np.linalg.norm(res.q[:, 3:7], axis=1) - 1.0)) <= 4e-16
    # the top precesses: its axis turns about the vertical
    axis = [np.array(ca.evalf(ca.substitute(b.rotation, b.quaternion, ca.DM(q[3:7]))), dtype=float)[:, 2]
            for q in res.q[[0, -1]]]
    assert math.degrees(math.acos(min(1.0, float(axis[0] @ axis[1])))) > 1.0


# ---------------------------------------------------------------------------- planar contacts
def _planar_ball(e, m=1.0, r=0.1, mu=0.3, g=9.81):
    """The sphere with a planar contact: one tangent, the x velocity of its lowest material point
    (the motion stays in the x-z plane, spinning about y)."""
    b = free_body(m, 0.4 * m * r * r * np.eye(3), name="ball")
    J = ca.horzcat(1, 0, 0, -r * b.rotation[1, :])
    return bodies_system([b], [Contact(gap=b.q[2] - r, tangent_jacobian=J, mu=mu, e=e, name="floor")], gravity=g)


def test_planar_contact_on_a_rigid_body_slides_then_rolls_exactly():
    r, mu, g = 0.1, 0.3, 9.81
    s = _planar_ball(0.0, r=r, mu=mu, g=g)
    assert not s.is_spatial
    v0 = np.array([2.0, 0.0, 0.0, 0.0, -10.0, 0.0])
    res = lcp.simulate(s, 1.0, method="event", q0=[0, 0, r, 1.0, 0, 0, 0], v0=v0, n_eval=101)
    assert res.success, res.message
    assert res.mode_sequence == [("slide+",), ("stick",)]
    u0 = v0[0] - r * v0[4]
    ts = 2 * abs(u0) / (7 * mu * g)
    assert abs(res.t_events[0] - ts) <= 1e-10
    assert abs(res.v[-1, 0] - (v0[0] - mu * g * ts)) <= 1e-10
    assert abs(res.v[-1, 0] - r * res.v[-1, 4]) <= 1e-10  # rolling: v = r omega_y


def test_spinning_ball_bounces_to_rolling():
    """Dropped spinning with e = 0.5: the bounces accumulate (resolved one by one, said in the
    message) at sqrt(2 h/g) (1 + 2e/(1 - e)); the angular momentum about the contact point is kept
    through the impacts and the slides, so the ball ends rolling at (5 v0 + 2 r omega0) / 7."""
    r, g, e = 0.1, 9.81, 0.5
    s = _planar_ball(e, r=r, g=g)
    h0, vx, wy = 1.0, 1.0, 5.0
    res = lcp.simulate(s, 2.0, method="event", q0=[0, 0, h0, 1.0, 0, 0, 0], v0=[vx, 0, 0, 0, wy, 0], n_eval=201)
    assert res.success, res.message
    assert "Newton-Euler kinematics" in res.message
    t1 = math.sqrt(2 * (h0 - r) / g)
    assert abs(res.t_events[0] - t1) <= 1e-12
    t_inf = t1 * (1 + 2 * e / (1 - e))
    impacts = [ev.t for ev in res.events if ev.kind == "impact"]
    assert len(impacts) > 10 and impacts[-1] < t_inf + 1e-6
    assert abs(res.q[-1, 2] - r) <= 1e-12 and abs(res.v[-1, 2]) <= 1e-9
    v_roll = (5 * vx + 2 * r * wy) / 7
    assert abs(res.v[-1, 0] - v_roll) <= 1e-9 and abs(res.v[-1, 4] * r - v_roll) <= 1e-9
