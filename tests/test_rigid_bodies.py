"""Free rigid bodies in 3D: Newton-Euler kinematics qdot = T(q) v with unit quaternions
(lcp.model.kinematics, lcp.model.rigid_body, lcp.scenes.rigid_bodies), by both methods."""
import math

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import lcp
from lcp.model.forces import applied_forces, point_force, point_velocity
from lcp.model.kinematics import advance_positions, quat_exp, quat_mul
from lcp.model.rigid_body import bodies_system, free_body
from lcp.model.system import Contact, System
from lcp.scenes.rigid_bodies import dzhanibekov, euler_period, tumbling_box

EPS = np.finfo(float).eps


def _body_system(**kw):
    b = free_body(2.0, np.diag([1.0, 2.0, 2.5]), name="b")
    return b, bodies_system([b], **kw)


# ---------------------------------------------------------------- the System's kinematics
def test_default_kinematics_is_the_identity():
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    s = System(q, v, mass=ca.SX.eye(2), force=ca.vertcat(0, -9.81))
    assert not s.has_kinematics and s.n_q == s.n == 2 and s.unit_quaternions == ()
    assert np.array_equal(np.array(s.kinematics_fn(0.0, [1.0, 2.0])), np.eye(2))
    assert np.array_equal(np.array(s.qdot_fn(0.0, [1.0, 2.0], [3.0, -4.0])).ravel(), [3.0, -4.0])
    assert s.velocity_names == s.names


def test_free_body_sizes_and_functions():
    b, s = _body_system(gravity=9.81)
    assert (s.n_q, s.n, s.unit_quaternions, s.has_kinematics) == (7, 6, (3,), True)
    assert s.names[3] == "b.p0" and s.velocity_names[3] == "b.wx"
    q = np.r_[1.0, 2.0, 3.0, quat_exp([0.1, 0.2, 0.3])]
    w = np.array([0.5, -1.0, 2.0])
    qdot = np.array(s.qdot_fn(0.0, q, np.r_[1.0, 1.0, 1.0, w])).ravel()
    # p' = 1/2 p (x) (0, omega)
    assert np.allclose(qdot[3:], 0.5 * quat_mul(q[3:], np.r_[0.0, w]), rtol=0, atol=1e-15)
    assert np.array_equal(qdot[:3], [1.0, 1.0, 1.0])
    assert s.mass(q).shape == (6, 6) and s.force(q, np.r_[0, 0, 0, w]).shape == (6,)


def test_contact_jacobian_is_in_v_space():
    b = free_body(1.0, np.eye(3) / 6, name="c")
    r = [0.5, -0.5, 0.5]
    P = b.point(r)
    s = bodies_system([b], contacts=[Contact(gap=P[2], tangent=ca.vertcat(P[0], P[1]), mu=0.3, name="k")])
    q = np.r_[0.3, -0.2, 1.0, quat_exp([0.2, -0.4, 0.1])]
    v = np.array([0.3, -1.0, 0.7, 2.0, -1.0, 0.5])
    H = s.contact_jacobian(q)
    assert H.shape == (3, 6)
    vel = np.array(ca.Function("pv", [b.q, b.v], [b.point_velocity(r)])(q, v)).ravel()
    assert np.allclose(H @ v, [vel[2], vel[0], vel[1]], rtol=0, atol=1e-14)


@pytest.mark.parametrize("bad, match", [
    (ca.SX.eye(6), "shape"),                          # not n_q x n_v
    ("velocity", "must not depend on the velocities"),
    (np.full((7, 6), np.nan), "finite"),
    (np.zeros((7, 6)), "full column rank"),
])
def test_bad_kinematics_named(bad, match):
    q, v = ca.SX.sym("q", 7), ca.SX.sym("v", 6)
    T = ca.repmat(v.T, 7, 1) if isinstance(bad, str) else bad
    with pytest.raises(ValueError, match=f"kinematics.*{match}|{match}.*kinematics|kinematics"):
        System(q, v, mass=ca.SX.eye(6), force=ca.SX.zeros(6), kinematics=T)
    with pytest.raises(ValueError, match=match):
        System(q, v, mass=ca.SX.eye(6), force=ca.SX.zeros(6), kinematics=T)


def test_kinematics_rank_checked_at_the_start():
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    s = System(q, v, mass=ca.SX.eye(2), force=ca.SX.zeros(2), kinematics=ca.diag(ca.vertcat(1, q[0])))
    s.check_state([1.0, 0.0], [0.0, 0.0])
    with pytest.raises(ValueError, match="kinematics.*full column rank"):
        s.check_state([0.0, 0.0], [0.0, 0.0])


def test_bad_quaternions_and_shapes_named():
    body = free_body(1.0, np.eye(3), name="k")
    q, v, T = body.q, body.v, body.kinematics
    with pytest.raises(ValueError, match="unit_quaternions"):
        System(q, v, mass=ca.SX.eye(6), force=ca.SX.zeros(6), kinematics=T, unit_quaternions=(4,))
    with pytest.raises(ValueError, match="velocity_names"):
        System(q, v, mass=ca.SX.eye(6), force=ca.SX.zeros(6), kinematics=T, velocity_names=["a"])
    with pytest.raises(ValueError, match="mass"):
        System(q, v, mass=ca.SX.eye(7), force=ca.SX.zeros(6), kinematics=T)
    with pytest.raises(ValueError, match="tangent_jacobian"):
        System(q, v, mass=ca.SX.eye(6), force=ca.SX.zeros(6), kinematics=T,
               contacts=[Contact(gap=q[2], tangent_jacobian=ca.SX.ones(2, 7), name="c")])
    _, s = _body_system()
    with pytest.raises(ValueError, match=r"q0 must have shape \(7,\)"):
        s.check_state(np.zeros(6), np.zeros(6))
    with pytest.raises(ValueError, match=r"v0 must have shape \(6,\)"):
        s.check_state(np.r_[0, 0, 0, 1.0, 0, 0, 0], np.zeros(7))


def test_start_quaternion_normalised_or_refused():
    _, s = _body_system()
    q0 = np.r_[0.0, 0.0, 0.0, 1.0 + 1e-9, 0.0, 0.0, 0.0]
    r = lcp.simulate(s, 0.01, h=0.01, q0=q0, v0=np.zeros(6))
    assert r.success and "normalised" in r.message and "b.p0" in r.message
    assert r.q[0, 3] == 1.0
    r = lcp.simulate(s, 0.01, h=0.01, q0=np.r_[0, 0, 0, 1.0 + 1e-17, 0, 0, 0], v0=np.zeros(6))
    assert "normalised" not in r.message  # rounding: silently
    with pytest.raises(ValueError, match="unit quaternion at coordinate 'b.p0'"):
        lcp.simulate(s, 0.01, h=0.01, q0=np.r_[0, 0, 0, 1.1, 0, 0, 0], v0=np.zeros(6))


def test_paths_without_kinematics_refuse_by_name():
    sc = tumbling_box()
    with pytest.raises(ValueError, match="order2.*kinematics"):
        lcp.simulate(sc, 0.01, h=1e-3, scheme="order2")
    # (the event method handles kinematics with contacts: tests/test_event_rigid_bodies.py)
    from lcp.batch import simulate_batch

    with pytest.raises(ValueError, match="kinematics"):
        simulate_batch([sc], 0.01, h=1e-3)
    free = dzhanibekov()  # no contact: the transcription's planar-only check does not answer first
    with pytest.raises(ValueError, match="optimal-control.*kinematics"):
        lcp.ocp.OptimalControlProblem(free.system, 4, q0=free.q0, v0=free.v0)


def test_with_control_keeps_kinematics():
    b = free_body(1.0, np.eye(3), name="u")
    u = ca.SX.sym("u", 1)
    s = System(b.q, b.v, b.mass_matrix, b.gyroscopic + 2 * ca.vertcat(u, 0, 0, 0, 0, 0), control=u,
               kinematics=b.kinematics, unit_quaternions=(3,))
    from lcp.model.control import ControlSchedule

    c = s.with_control(ControlSchedule([0.0, 1.0], [2.0]))
    assert c.has_kinematics and c.n_q == 7 and c.unit_quaternions == (3,)
    r = lcp.simulate(c, 1.0, h=0.25, q0=[0, 0, 0, 1.0, 0, 0, 0], v0=np.zeros(6))
    assert r.q[-1, 0] == pytest.approx(2.0 * 2 / 2, abs=1e-14)  # u = 2 on twice the force, unit mass


# ---------------------------------------------------------------- lcp.forces in v-space
def test_point_force_in_v_space_gives_the_body_torque():
    b = free_body(1.0, np.eye(3), name="f")
    r_body = np.array([0.0, 1.0, 0.0])
    F = np.array([0.0, 0.0, 3.0])
    Q = point_force(b.q, b.point(r_body), F, kinematics=b.kinematics)
    p = quat_exp([0.3, -0.2, 0.4])
    Qn = np.array(ca.Function("Q", [b.q], [Q])(np.r_[1.0, 2.0, 3.0, p])).ravel()
    R = np.array(ca.Function("R", [b.q], [b.rotation])(np.r_[0, 0, 0, p]))
    assert np.allclose(Qn[:3], F, atol=1e-15)
    assert np.allclose(Qn[3:], np.cross(r_body, R.T @ F), atol=1e-14)  # body-frame torque r x F_body
    tot = applied_forces(b.q, [(b.point(r_body), F), (b.position, [1.0, 0, 0])], kinematics=b.kinematics)
    assert tot.shape == (6, 1)
    pv = point_velocity(b.q, b.v, b.point(r_body), kinematics=b.kinematics)
    x = np.r_[1.0, 2.0, 3.0, p]
    vv = np.array([0.1, 0.2, 0.3, 1.0, -2.0, 0.5])
    assert np.allclose(np.array(ca.Function("a", [b.q, b.v], [pv])(x, vv)).ravel(),
                       np.array(ca.Function("b", [b.q, b.v], [b.point_velocity(r_body)])(x, vv)).ravel(), atol=1e-15)


# ---------------------------------------------------------------- the position update
def test_exponential_map_is_exact_for_constant_omega():
    _, s = _body_system()
    p0 = quat_exp([0.1, 0.5, -0.2])
    q = np.r_[0.0, 0.0, 0.0, p0]
    w = np.array([1.0, 2.0, -3.0, 0.7, -1.1, 2.3])
    for _ in range(100):
        q, _ = advance_positions(s, 0.0, q, w, 0.01)
    exact = quat_mul(p0, quat_exp(0.5 * 1.0 * w[3:]))
    assert np.allclose(q[3:], exact, rtol=0, atol=1e-14)
    assert np.allclose(q[:3], w[:3], rtol=0, atol=1e-14)
    assert abs(np.linalg.norm(q[3:]) - 1) <= 2 * EPS


# ---------------------------------------------------------------- the Dzhanibekov flip
def _flip_times(r, sc):
    """Zero crossings of the intermediate component w2, each by one Newton step on Euler's equation
    w2' = (I3 - I1)/I2 w3 w1 from the nearest output (error O(dt^3): an inflection of w2 there)."""
    I1, I2, I3 = sc.params["moments"]
    w = r.v[:, 3:]
    i = np.flatnonzero(np.sign(w[:-1, 1]) != np.sign(w[1:, 1]))
    out = []
    for k in i:
        j = k if abs(w[k, 1]) < abs(w[k + 1, 1]) else k + 1
        out.append(r.t[j] - w[j, 1] / ((I3 - I1) / I2 * w[j, 2] * w[j, 0]))
    return np.array(out)


def test_dzhanibekov_event_method_conserves_and_flips():
    sc = dzhanibekov()
    r = lcp.simulate(sc, 10.0, method="event", n_eval=4001)
    assert r.success and r.integrators == ["DOP853"]
    E = np.array([sc.energy(q, v) for q, v in zip(r.q, r.v)])
    L = np.array([np.linalg.norm(sc.angular_momentum(q, v)) for q, v in zip(r.q, r.v)])
    assert np.max(np.abs(E / E[0] - 1)) < 1e-10
    assert np.max(np.abs(L / L[0] - 1)) < 1e-10
    assert np.max(np.abs(np.linalg.norm(r.q[:, 3:], axis=1) - 1)) < 1e-14
    # the flip: the intermediate-axis component changes sign, every half period of Euler's equations
    assert r.v[0, 4] > 5 and r.v[:, 4].min() < -5
    tf = _flip_times(r, sc)
    assert tf.size >= 2
    assert np.allclose(np.diff(tf), sc.flip_period, rtol=1e-8, atol=0)
    # the world-frame angular momentum vector itself is fixed, while the body turns over
    L0 = sc.angular_momentum(r.q[0], r.v[0])
    assert np.allclose([sc.angular_momentum(q, v) for q, v in zip(r.q[::400], r.v[::400])], L0, rtol=0,
                       atol=1e-10 * np.linalg.norm(L0))


def test_dzhanibekov_moreau_jean_drift_scales_with_h_squared():
    sc = dzhanibekov()
    drift = {}
    for h in (0.02, 0.01):
        r = lcp.simulate(sc, 2.0, h=h)
        assert r.success
        E = np.array([sc.energy(q, v) for q, v in zip(r.q, r.v)])
        drift[h] = np.max(np.abs(E / E[0] - 1))
        assert drift[h] < 5 * h ** 2  # measured 2.42 h^2 (spin 6 rad/s)
        assert np.max(np.abs(np.linalg.norm(r.q[:, 3:], axis=1) - 1)) < 1e-14
    assert 3.5 < drift[0.02] / drift[0.01] < 4.5  # second order


def test_euler_period_matches_the_linearised_motion_about_the_major_axis():
    # small wobble about the axis of largest moment: 2 pi / (w3 sqrt((I3 - I1)(I3 - I2)/(I1 I2)))
    I = (1.0, 2.0, 3.0)
    T = euler_period(I, [1e-7, 1e-7, 2.0])
    assert T == pytest.approx(2 * math.pi / (2.0 * math.sqrt(2.0 * 1.0 / 2.0)), rel=1e-12)
    # and about the minor axis (M^2 < 2 E I2: the roles of I1 and I3 exchanged)
    T = euler_period(I, [2.0, 1e-7, 1e-7])
    assert T == pytest.approx(2 * math.pi / (2.0 * math.sqrt(1.0 * 2.0 / 6.0)), rel=1e-12)
    with pytest.raises(ValueError, match="distinct"):
        euler_period((1.0, 1.0, 2.0), [1.0, 1.0, 1.0])


@settings(max_examples=8, deadline=None)
@given(st.floats(1.0, 3.0), st.floats(1.0, 3.0), st.floats(1.0, 3.0),
       st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3), st.floats(-1.0, 1.0))
def test_torque_free_invariants_hold_for_any_body(a, b, c, w, turn):
    I = np.sort([a, b, c])
    if I[0] + I[1] < I[2] * 1.01:
        I[2] = 0.99 * (I[0] + I[1])
    # a general inertia tensor: the principal moments turned by a rotation
    R = _rotation(quat_exp([turn, 0.5 * turn, -turn]))
    J = R @ np.diag(I) @ R.T
    J = 0.5 * (J + J.T)
    body = free_body(1.0, J, name="h")
    s = bodies_system([body])
    q0 = np.r_[0.0, 0.0, 0.0, quat_exp([0.2, -0.1, 0.3])]
    v0 = np.r_[0.1, 0.0, 0.0, w]
    r = lcp.simulate(s, 1.0, method="event", q0=q0, v0=v0, n_eval=11)
    E = 0.5 * np.einsum("ij,jk,ik->i", r.v[:, 3:], J, r.v[:, 3:])
    L = np.array([body.angular_momentum(q, v) for q, v in zip(r.q, r.v)])
    scale = max(abs(E[0]), 1e-300)
    assert np.max(np.abs(E - E[0])) <= 1e-10 * scale + 1e-300
    assert np.max(np.abs(L - L[0])) <= 1e-10 * max(np.linalg.norm(L[0]), 1e-300)
    assert np.max(np.abs(np.linalg.norm(r.q[:, 3:], axis=1) - 1)) < 1e-14
    assert np.allclose(r.q[-1, :3], [0.1, 0.0, 0.0], rtol=0, atol=1e-13)


def _rotation(p):
    w, x, y, z = p
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


# ---------------------------------------------------------------- the tumbling box
@pytest.fixture(scope="module")
def box_run():
    sc = tumbling_box()
    return sc, lcp.simulate(sc, 2.0, h=1e-3)


def test_box_free_fall_is_exact(box_run):
    sc, r = box_run
    g, p0 = sc.params["g"], sc.q0[3:]
    gaps = np.array([sc.gap(q) for q in r.q])
    k = int(np.argmax(gaps.min(axis=1) <= 1e-12))  # the first state in contact
    assert k > 300
    free = slice(0, k - 1)  # states before the step that met the floor
    t = r.t[free]
    assert np.all(r.p_N[: k - 2] == 0)
    assert np.allclose(r.q[free, 2], sc.q0[2] - g * t ** 2 / 2, rtol=0, atol=1e-13)  # the parabola
    assert np.allclose(r.q[free, 0], sc.v0[0] * t, rtol=0, atol=1e-13)
    w = sc.v0[3:]  # a cube (isotropic inertia): omega constant, the rotation p0 (x) exp(t omega / 2)
    assert np.allclose(r.v[free, 3:], w, rtol=0, atol=1e-13)
    exact = np.array([quat_mul(p0, quat_exp(0.5 * tt * w)) for tt in t])
    assert np.allclose(r.q[free, 3:], exact, rtol=0, atol=1e-12)


def test_box_energy_never_increases_and_comes_to_rest_on_a_face(box_run):
    sc, r = box_run
    assert r.success
    E = np.array([sc.energy(q, v) for q, v in zip(r.q, r.v)])
    assert np.max(np.diff(E)) <= 1e-12 * abs(E[0])
    # rest on a face: centre at half the side, the body's axes aligned with the world's up to a turn
    # about z, four corners on the floor with gaps 0, at rest
    assert abs(r.q[-1, 2] - 0.5 * sc.params["side"]) < 1e-6
    R = _rotation(r.q[-1, 3:])
    assert np.max(np.abs(np.abs(R[2]) - np.abs(np.round(R[2])))) < 1e-6  # one body axis along z
    gaps = sc.gap(r.q[-1])
    assert np.sum(np.abs(gaps) < 1e-9) == 4
    assert np.max(np.abs(r.v[-1])) < 1e-9
    assert np.max(np.abs(np.linalg.norm(r.q[:, 3:], axis=1) - 1)) < 1e-14


def test_box_loaded_contacts_do_not_penetrate(box_run):
    sc, r = box_run
    h = r.h
    gaps = np.array([sc.gap(q) for q in r.q[1:]])
    loaded = r.p_N > 0
    assert loaded.any()
    assert np.min(gaps[loaded]) >= -h ** 2


def test_box_without_friction_keeps_horizontal_momentum_exactly():
    sc = tumbling_box(mu=0.0, v0=(0.7, -0.4, 0.0))
    r = lcp.simulate(sc, 1.0, h=1e-3)
    assert r.success and r.p_N.sum() > 0  # it did hit the floor
    assert np.all(r.v[:, 0] == 0.7) and np.all(r.v[:, 1] == -0.4)


def test_sweep_and_plot_take_fewer_velocities_than_coordinates():
    import matplotlib

    matplotlib.use("Agg")
    tab = lcp.sweep(lambda spin: dzhanibekov(spin=spin, t_end=0.1), {"spin": [5.0, 6.0]}, h=0.01)
    assert tab["success"].all()
    assert np.allclose(tab["v_v4"], [5.0, 6.0], rtol=1e-3)  # the intermediate axis, still spinning
    sc = dzhanibekov(t_end=0.1)
    r = lcp.simulate(sc, h=0.01)
    fig = r.plot(sc.system)
    labels = [ln.get_label() for ln in fig.axes[1].get_lines()]
    assert labels == list(sc.system.velocity_names)
    import matplotlib.pyplot as plt

    plt.close(fig)


def test_kinematics_not_finite_at_the_start_named():
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    s = System(q, v, mass=ca.SX.eye(2), force=ca.SX.zeros(2), kinematics=ca.diag(ca.vertcat(1, 1 / q[0])))
    with pytest.raises(ValueError, match="kinematics T.*not finite"):
        lcp.simulate(s, 0.1, h=0.01, q0=[0.0, 0.0], v0=[0.0, 0.0])
    with pytest.raises(ValueError, match="v must be a column.*kinematics"):
        System(q, ca.SX.sym("v", 2, 2), mass=ca.SX.eye(2), force=ca.SX.zeros(2), kinematics=ca.SX.eye(2))
    # a kinematics of a system (here the identity written out): the same motion as without it
    r1 = lcp.simulate(System(q, v, mass=ca.SX.eye(2), force=ca.vertcat(1.0, -q[1]), kinematics=ca.SX.eye(2)),
                      1.0, h=0.01, q0=[0.0, 1.0], v0=[0.5, 0.0])
    r0 = lcp.simulate(System(q, v, mass=ca.SX.eye(2), force=ca.vertcat(1.0, -q[1])), 1.0, h=0.01, q0=[0.0, 1.0],
                      v0=[0.5, 0.0])
    assert np.allclose(r1.q, r0.q, rtol=0, atol=1e-14) and np.allclose(r1.v, r0.v, rtol=0, atol=1e-14)


def test_start_penetrating_within_tolerance_is_projected_in_v_space():
    kw = dict(angle=0.3, tilt=(1.0, 0.0, 0.0), v0=(0.0, 0.0, 0.0), omega0=(0.0, 0.0, 0.0))
    probe = tumbling_box(height=1.0, **kw)
    H = 1.0 - float(min(probe.gap(probe.q0))) - 1e-5  # the lowest corners 1e-5 below the floor
    sc = tumbling_box(height=H, **kw)
    assert min(sc.gap(sc.q0)) == pytest.approx(-1e-5, abs=1e-12)
    r = lcp.simulate(sc, 0.002, h=1e-3)
    assert r.success and "projected" in r.message and "corner" in r.message
    assert min(sc.gap(r.q[0])) >= -1e-15
    assert abs(np.linalg.norm(r.q[0, 3:]) - 1) <= 2 * EPS
    assert np.max(np.abs(r.q[0] - sc.q0)) < 1e-4
    with pytest.raises(ValueError, match="penetrates contact 'corner"):
        lcp.simulate(tumbling_box(height=0.3, **kw), 0.01, h=1e-3)


def test_quaternion_rows_of_another_form_fall_back_to_projection():
    # p0' = (1/2 p (x) (0, omega))_0 + 0.1 x vx: rows of T w that are not linear in p, so no
    # exponential map; the update is then p + h (T w)_p, projected onto the sphere
    b = free_body(1.0, np.eye(3), name="o")
    T = b.kinematics
    T[3, 0] = T[3, 0] + 0.1 * b.q[0]  # adds 0.1 x vx to p0' (any T of full rank is allowed)
    s = System(b.q, b.v, b.mass_matrix, b.gyroscopic, kinematics=T, unit_quaternions=(3,))
    q = np.r_[1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]
    w = np.array([1.0, 0.0, 0.0, 0.0, 0.0, 2.0])
    q1, _ = advance_positions(s, 0.0, q, w, 0.01)
    p = q[3:] + 0.01 * np.r_[0.1, 0.0, 0.0, 0.0] + 0.01 * 0.5 * quat_mul(q[3:], np.r_[0.0, w[3:]])
    assert np.allclose(q1[3:], p / np.linalg.norm(p), rtol=0, atol=1e-15)
    # the standard rows: the exponential map, exactly
    s0 = bodies_system([b])
    q2, _ = advance_positions(s0, 0.0, q, w, 0.01)
    assert np.allclose(q2[3:], quat_exp([0.0, 0.0, 0.01]), rtol=0, atol=1e-16)


def test_event_method_ends_phases_at_the_force_breakpoints():
    from lcp.model.control import ControlSchedule

    b = free_body(1.0, np.eye(3), name="c")
    u = ca.SX.sym("u", 1)
    s = System(b.q, b.v, b.mass_matrix, b.gyroscopic + ca.vertcat(2 * u, 0, 0, 0, 0, 0), control=u,
               kinematics=b.kinematics, unit_quaternions=(3,))
    c = s.with_control(ControlSchedule([0.0, 0.5, 1.0], [2.0, -2.0]))  # a = 4 then -4
    r = lcp.simulate(c, 1.0, method="event", q0=[0, 0, 0, 1.0, 0, 0, 0], v0=[0, 0, 0, 0, 0, 1.0], t_eval=[0, 0.5, 1.0])
    assert r.success and [(ph.t0, ph.t1) for ph in r.phases] == [(0.0, 0.5), (0.5, 1.0)]
    assert np.allclose(r.q[:, 0], [0.0, 0.5, 1.0], rtol=0, atol=1e-13)
    assert np.allclose(r.v[:, 0], [0.0, 2.0, 0.0], rtol=0, atol=1e-13)
    assert np.allclose(r.q[-1, 3:], quat_exp([0, 0, 0.5]), rtol=0, atol=1e-13)  # spin 1 rad/s about z for 1 s


def test_position_update_function_matches_the_python_update():
    from lcp.model.kinematics import position_update_function

    bodies = [free_body(1.0, [1.0, 2.0, 2.5], name=f"u{i}") for i in range(2)]
    s = bodies_system(bodies)
    f = position_update_function(s)
    rng = np.random.default_rng(3)
    for _ in range(5):
        q = np.concatenate([np.r_[rng.uniform(-1, 1, 3), quat_exp(rng.uniform(-1, 1, 3))] for _ in range(2)])
        w = rng.uniform(-3, 3, 12)
        h = 10 ** rng.uniform(-4, -1)
        ref, _ = advance_positions(s, 0.0, q, w, h)
        assert np.allclose(np.array(f(0.0, q, w, h)).ravel(), ref, rtol=0, atol=4 * EPS)
    # world-frame angular velocity, p' = 1/2 (0, omega) (x) p: also of the exponential map's form
    b = bodies[0]
    p = b.quaternion
    left = ca.vertcat(ca.horzcat(-p[1], -p[2], -p[3]), ca.horzcat(p[0], p[3], -p[2]),
                      ca.horzcat(-p[3], p[0], p[1]), ca.horzcat(p[2], -p[1], p[0]))
    sw = System(b.q, b.v, b.mass_matrix, ca.SX.zeros(6), kinematics=ca.diagcat(ca.SX.eye(3), 0.5 * left),
                unit_quaternions=(3,))
    q0 = np.r_[0.0, 0.0, 0.0, quat_exp([0.3, 0.1, -0.2])]
    q1 = np.array(position_update_function(sw)(0.0, q0, np.r_[0, 0, 0, 0.4, -0.2, 1.0], 0.1)).ravel()
    assert np.allclose(q1[3:], quat_mul(quat_exp(0.05 * np.r_[0.4, -0.2, 1.0]), q0[3:]), rtol=0, atol=1e-15)
    # rows of another form: refused by name
    T = b.kinematics
    T[3, 0] = T[3, 0] + 0.1 * b.q[0]
    with pytest.raises(ValueError, match="kinematics: the rows of the unit quaternion at q\\[3:7\\]"):
        position_update_function(System(b.q, b.v, b.mass_matrix, ca.SX.zeros(6), kinematics=T, unit_quaternions=(3,)))
