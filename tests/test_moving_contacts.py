"""Time-dependent gaps and tangents: a moving table, a conveyor belt.

The model gives b(t, q) = (dg/dt, ds/dt); Moreau-Jean's local velocity is u = H v + b. References: the
moving table written with the table pinned by a rheonomous bilateral constraint (event method), and
the conveyor's closed form.
"""
import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import lcp
from lcp.model.system import Contact, System, moving_contact
from lcp.scenes.moving import conveyor, moving_table
from lcp.timestepping import compiled_step

A, W, E = 0.05, 6.0, 0.7
TABLE = dict(amplitude=A, omega=W, e=E, height=0.3, t_end=0.9)  # three impacts, no accumulation yet


def _table_speed(t):
    return A * W * np.cos(W * np.asarray(t))


def test_time_dependent_gap_and_tangent_accepted_with_their_rates():
    q, v, t = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("t")
    s = System(q, v, ca.SX.eye(2), ca.vertcat(0, -9.81), t=t,
               contacts=[Contact(gap=q[1] - 0.1 * ca.sin(3 * t), tangent=q[0] - 2 * t * q[1], mu=0.3, name="cam")])
    assert s.contacts_depend_on_t and not s.is_constant and not s.kinematics_is_constant
    assert moving_contact(s) == "cam"
    tt, qq = 0.7, np.array([0.2, 0.5])
    b = s.contact_rates(qq, tt)
    np.testing.assert_allclose(b, [-0.3 * np.cos(2.1), -2 * 0.5], rtol=0, atol=1e-15)
    np.testing.assert_allclose(s.gaps(qq, tt), [0.5 - 0.1 * np.sin(2.1)], rtol=0, atol=1e-15)
    # H depends on t too: the tangent row is (1, -2 t)
    np.testing.assert_allclose(s.contact_jacobian(qq, tt), [[0, 1], [1, -2 * tt]], rtol=0, atol=1e-15)
    with pytest.raises(ValueError, match="'cam' has a time-dependent gap"):
        s.gaps(qq)
    with pytest.raises(ValueError, match="'cam'"):
        s.contact_jacobian(qq)
    # a caller written for fixed contacts (g(q), H(q)) is refused, never handed g without b
    for fn in (s.gap_fn, s.H_fn):
        with pytest.raises(ValueError, match="'cam' has a time-dependent gap"):
            fn(qq)


def test_fixed_contacts_have_no_rate_and_keep_their_functions():
    sc = lcp.classical.bouncing_ball()
    s = sc.system
    assert not s.contacts_depend_on_t and moving_contact(s) is None and s.is_constant
    np.testing.assert_array_equal(s.contact_rates(sc.q0, 1.0), np.zeros(2))
    np.testing.assert_array_equal(s.gaps(sc.q0), s.gaps(sc.q0, 3.0))


def test_constant_tangent_rate_alone_makes_a_contact_move():
    # the belt: H and g are constant, only ds/dt = -V is not zero
    s = conveyor(V=1.5).system
    assert s.contacts_depend_on_t and not s.is_constant
    np.testing.assert_array_equal(s.contact_rates(np.zeros(2), 0.0), [0.0, -1.5])


def test_compiled_paths_do_not_apply():
    s = moving_table().system
    assert not compiled_step.applicable(s)
    r = lcp.simulate(moving_table(**TABLE), h=1e-3)
    assert r.success  # the Python loop ran it (the compiled step would have used g(q) = g0 + H q)


def test_second_order_scheme_refuses_moving_contacts():
    with pytest.raises(ValueError, match="'table' has a time-dependent gap"):
        lcp.simulate(moving_table(**TABLE), h=1e-3, scheme="order2")


def _impact_steps(r, h):
    """Steps whose impulse is an impact: the first loaded step of each contact phase."""
    pN = r.p_N[:, 0]
    prev = np.concatenate([[0.0], pN[:-1]])
    return np.flatnonzero((pN > 0) & (prev <= 0))


@pytest.mark.parametrize("theta", [0.5, 1.0])
def test_relative_velocity_after_impact_is_minus_e_times_before(theta):
    h = 1e-3
    r = lcp.simulate(moving_table(**TABLE), h=h, theta=theta)
    assert r.success and len(r.impacts) == 3
    ks = _impact_steps(r, h)
    assert ks.size == 3
    u_minus = r.v[ks, 1] - _table_speed(r.t[ks])
    u_plus = r.v[ks + 1, 1] - _table_speed(r.t[ks + 1])
    assert np.all(u_minus < -0.5)  # real impacts, approaching
    np.testing.assert_allclose(u_plus, -E * u_minus, rtol=1e-12, atol=0)
    # with a fixed table (u = H v) the same velocities would be off by the table's speed change
    assert np.all(np.abs((r.v[ks + 1, 1]) + E * r.v[ks, 1]) > 1e-4)


@pytest.fixture(scope="module")
def table_reference():
    ref = lcp.simulate(moving_table(pinned=True, **TABLE), method="event", rtol=1e-12, atol=1e-14)
    assert ref.success
    return ref


def _table_errors(ref, h):
    r = lcp.simulate(moving_table(**TABLE), h=h)
    assert r.success
    ti_ref = np.array([im.t for im in ref.impacts])
    ti = np.array([im.t for im in r.impacts])
    assert ti.size == ti_ref.size == 3
    # y against the reference between its events (the interpolation of the event output is exact
    # to its dense output; at the grid the reference is evaluated by the pinned run's own output)
    y_ref = np.interp(r.t, ref.t, ref.q[:, 1])
    away = np.min(np.abs(r.t[:, None] - ti_ref[None, :]), axis=1) > 0.02
    return np.abs(ti - ti_ref).max(), np.abs(r.q[away, 1] - y_ref[away]).max()


def test_reference_is_the_pinned_table(table_reference):
    # the pinned form holds the table on s(t) and the ball above it
    ref = table_reference
    np.testing.assert_allclose(ref.q[:, 2], A * np.sin(W * ref.t), rtol=0, atol=1e-9)
    assert np.all(ref.q[:, 1] - ref.q[:, 2] > -1e-9)


def test_moreau_jean_converges_to_the_pinned_reference(table_reference):
    e3 = _table_errors(table_reference, 1e-3)
    e4 = _table_errors(table_reference, 1e-4)
    # first order: ten times smaller steps, errors at least five times smaller
    assert e3[0] < 2e-3 and e4[0] < e3[0] / 5
    assert e4[1] < e3[1] / 5, (e3, e4)


@pytest.mark.slow
def test_moreau_jean_converges_to_the_pinned_reference_1e5(table_reference):
    e4 = _table_errors(table_reference, 1e-4)
    e5 = _table_errors(table_reference, 1e-5)
    assert e5[0] < e4[0] / 5 and e5[1] < e4[1] / 5, (e4, e5)


@settings(max_examples=8, deadline=None)
@given(V=st.floats(-2.0, 2.0).filter(lambda x: abs(x) > 0.05), v0=st.floats(-1.0, 1.0),
       mu=st.floats(0.1, 0.8))
def test_conveyor_block_reaches_the_belt_speed(V, v0, mu):
    sc = conveyor(V=V, mu=mu, v0=v0)
    h = 1e-3
    r = lcp.simulate(sc, h=h)
    assert r.success
    ex = sc.exact(r.t)
    # theta = 1/2: the velocity is exact on the grid (constant forces while sliding, then stuck on the
    # belt); the position only carries the step that contains the switch, O(h^2)
    scale = max(abs(V), abs(v0))
    np.testing.assert_allclose(r.v[:, 0], ex["xdot"], rtol=0, atol=1e-12 * max(1.0, scale))
    assert np.abs(r.q[:, 0] - ex["x"]).max() <= 2 * mu * 9.81 * h * h + 1e-12
    np.testing.assert_allclose(r.q[:, 1], 0.0, rtol=0, atol=1e-14)
    if sc.solution.t_stick > 2 * h:
        sliding = r.t < sc.solution.t_stick - h
        # the friction impulse drags the block at mu N h per step
        np.testing.assert_allclose(r.p_T[sliding[1:], 0], sc.solution.accel * h, rtol=1e-9)


def test_ball_riding_the_table_is_held_on_it_by_the_projection():
    # A w^2 = 0.45 < g: the ball put on the table with its speed rides it (e = 0); the projection
    # ("auto": on, the gap's speed varies) holds g(t, q) = 0 at its own time, t_k + h
    a, w = 0.05, 3.0
    sc = moving_table(amplitude=a, omega=w, e=0.0, height=1.0, t_end=3.0)
    sc.q0[1], sc.v0[1] = 0.0, a * w
    held = lcp.simulate(sc, h=1e-2)
    free = lcp.simulate(sc, h=1e-2, projection=False)
    assert held.success and free.success and held.stats.projections == 300 and free.stats.projections == 0
    gap = held.q[:, 1] - a * np.sin(w * held.t)
    assert np.abs(gap).max() < 1e-15
    # without it the velocity-level law leaves an O(h^2) gap (theta = 1/2): a bound, and not zero
    gap_free = free.q[:, 1] - a * np.sin(w * free.t)
    assert 1e-7 < np.abs(gap_free).max() < a * w ** 3 * 1e-4
    np.testing.assert_allclose(held.v[:, 1], a * w * np.cos(w * held.t), rtol=0, atol=1e-12)


def test_optimal_control_refuses_a_moving_contact_by_name():
    # the transcription writes the contact law with H and g of q only: dg/dt would be ignored
    import casadi as ca

    import lcp
    from lcp.ocp import OptimalControlProblem

    q, v, t, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("t"), ca.SX.sym("u")
    system = lcp.System(q, v, ca.SX.eye(2), ca.vertcat(u, -9.81),
                        contacts=[lcp.Contact(gap=q[1] - 0.1 * ca.sin(t), tangent=q[0], mu=0.3, name="table")],
                        t=t, control=u, control_bounds=(-5, 5))
    import pytest

    with pytest.raises(ValueError, match="contact 'table' has a time-dependent gap"):
        OptimalControlProblem(system, 4, q0=[0.0, 0.0], v0=[0.0, 0.0], T=1.0)
