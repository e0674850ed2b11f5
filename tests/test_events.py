"""Event-driven integration (lcp.events): numbers against the exact Jean-Pratt solution and invariants."""
import math

import casadi as ca
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

import lcp
from lcp.events import EventOptions, EventResult, event_driven
from lcp.scenes.jean_pratt_exact import JeanPrattExact
from lcp.model.system import Contact, System

X_EXACT = 1e-13  # |x(t) - exact| at the output times
T_STOP = 1e-14  # |t_stop - tau0| <= T_STOP * max(1, tau0)


def run(scene, **kw):
    res = lcp.simulate(scene, scene.t_end, method="event", **kw)
    assert isinstance(res, EventResult)
    assert res.success, res.message
    return res


def x_error(scene, res):
    ex = scene.exact(res.t)
    return float(np.max(np.abs(res.q[:, 0] - ex["x"])))


# ------------------------------------------------------------------------ default and reverse scenes
@pytest.mark.parametrize("coordinates", ["reduced", "full"])
@pytest.mark.parametrize("v0", [1.0, -1.0])
def test_default_and_reverse_scene_to_machine_precision(coordinates, v0):
    sc = lcp.scenes.jean_pratt(v0=v0, coordinates=coordinates)
    res = run(sc)
    assert res.t.size == 1000
    assert x_error(sc, res) <= X_EXACT
    ex = sc.exact(res.t)
    assert np.max(np.abs(res.v[:, 0] - ex["xdot"])) <= 1e-13
    assert np.max(np.abs(res.q[:, 1])) <= 1e-15  # y: the contact never opens
    assert len(res.t_events) == 1
    assert abs(res.t_events[0] - sc.tau0) <= T_STOP * max(1.0, sc.tau0)
    assert res.mode_sequence == [("slide+" if v0 > 0 else "slide-",), ("stick",)]
    assert res.integrators == ["closed-form"]
    assert res.impulses == []
    # contact forces: N0 while sliding, (m + M) g after
    np.testing.assert_allclose(res.force_N[:, 0], ex["N"], rtol=1e-13)
    np.testing.assert_allclose(res.force_T[:, 0], ex["f"], rtol=1e-13, atol=1e-13)


def test_result_has_moreau_jean_form_and_impulses_match_exact():
    sc = lcp.scenes.jean_pratt()
    res = run(sc)
    mj = lcp.simulate(sc, sc.t_end, h=1e-3)
    for name in ("t", "q", "v", "p_N", "p_T", "modes", "status", "message", "success", "stats", "t_events"):
        assert hasattr(res, name)
    assert res.q.shape == (res.t.size, 2) and res.v.shape == res.q.shape
    assert res.p_N.shape == res.p_T.shape == res.modes.shape == (res.t.size - 1, 1)
    assert mj.p_N.shape[1] == res.p_N.shape[1]
    PN, PT = sc.solution.impulse(res.t[:-1], res.t[1:])
    np.testing.assert_allclose(res.p_N[:, 0], PN, rtol=1e-12)
    np.testing.assert_allclose(res.p_T[:, 0], PT, rtol=1e-12, atol=1e-15)
    assert res.method == "event" and res.solver == "enumerate"
    assert res.stats.steps == 2 and res.stats.fallbacks == 0 and res.stats.max_residual <= 1e-12


def test_t_eval_is_honoured():
    sc = lcp.scenes.jean_pratt()
    t = np.array([0.0, sc.tau0, 0.2, 0.3])
    res = lcp.simulate(sc, 0.3, method="event", t_eval=t)
    np.testing.assert_array_equal(res.t, t)
    assert abs(res.q[1, 0] - sc.x_stop) <= 1e-16
    assert res.modes[1, 0] == 1  # right limit at the stop: stick


# ------------------------------------------------------------------------ shocks and the limit kappa -> 1
@pytest.mark.parametrize("R", [2.0, 2.5, 3.0])
@pytest.mark.parametrize("coordinates", ["reduced", "full"])
def test_kappa_at_least_one_gives_one_tangential_impact_then_stick(R, coordinates):
    sc = lcp.scenes.jean_pratt(R=R, coordinates=coordinates)
    assert sc.kappa >= 1.0  # R = 2 is kappa = 1 exactly (tan(pi/4) = 1)
    res = run(sc)
    assert len(res.impulses) == 1
    imp = res.impulses[0]
    M, t, A, v0 = 1.0, 1.0, 2.0, 1.0
    assert imp.t == 0.0 and imp.kind == "tangential impact"
    assert abs(imp.P_N - M * t * v0) <= 1e-12 * M * t * v0
    assert abs(imp.P_T + A * v0) <= 1e-12 * A * v0
    assert res.t_events == [0.0]
    assert res.mode_sequence == [("stick",)]
    assert res.stats.fallbacks == 1
    assert np.max(np.abs(res.q[:, 0])) <= 1e-15 and np.max(np.abs(res.v[:, 0])) <= 1e-15
    assert x_error(sc, res) <= X_EXACT
    # the shock is in the first output interval's impulse, as in the exact solution
    PN, PT = sc.solution.impulse(res.t[:-1], res.t[1:])
    np.testing.assert_allclose(res.p_N[:, 0], PN, rtol=1e-12)


@pytest.mark.parametrize("k", [6, 9, 12])
def test_kappa_just_below_one_is_continuous_with_the_shock(k):
    R = 2.0 * (1.0 - 10.0 ** -k)
    sc = lcp.scenes.jean_pratt(R=R)
    res = run(sc)
    assert np.all(np.isfinite(res.q)) and np.all(np.isfinite(res.p_N))
    assert res.mode_sequence == [("slide+",), ("stick",)] and res.impulses == []
    assert x_error(sc, res) <= X_EXACT
    # the stop time is ill-conditioned like 1 / (1 - kappa); it is still tiny and close to tau0
    assert abs(res.t_events[0] - sc.tau0) <= 1e-14 * max(1.0, sc.tau0) + 1e-3 * sc.tau0
    # the smooth slide delivers the shock's impulses in the first output interval: beyond the
    # static (m + M) g t1, the normal impulse is tau0 (N0 - (m + M) g) = M tan(alpha) v0 for every kappa
    excess_N = res.p_N[0, 0] - 2 * 9.81 * res.t[1]
    assert abs(excess_N - 1.0) <= 1e-9
    assert abs(res.p_T[0, 0] + 2.0) <= 1e-9


def test_kappa_one_is_not_decided_by_rounding():
    """kappa = 1 exactly: the sliding branch has zero effective normal mass, whatever the rounding."""
    a = run(lcp.scenes.jean_pratt(R=2.0))
    b = run(lcp.scenes.jean_pratt(R=2.0, coordinates="full"))
    assert [i.kind for i in a.impulses] == [i.kind for i in b.impulses] == ["tangential impact"]


# ------------------------------------------------------------------------ loaded contact (phi != 0)
@pytest.mark.parametrize("phi, v0, sequence", [
    (5.0, 0.0, [("stick",)]),  # loaded stick holds exactly (no creep)
    (12.0, 0.0, [("slide+",)]),  # load beyond the friction bound: slip from rest
    (5.0, -1.0, [("slide-",), ("stick",)]),  # slide against the load, stop, stick
    (12.0, -1.0, [("slide-",), ("slide+",)]),  # slide, stop, reversal
    (-12.0, 1.0, [("slide+",), ("slide-",)]),
    (-5.0, 1.0, [("slide+",), ("stick",)]),
])
@pytest.mark.parametrize("coordinates", ["reduced", "full"])
def test_loaded_contact_stick_slip_reversal(phi, v0, sequence, coordinates):
    sc = lcp.scenes.jean_pratt(phi=phi, v0=v0, coordinates=coordinates, t_end=0.5)
    res = run(sc)
    assert res.mode_sequence == sequence
    assert x_error(sc, res) <= 1e-12
    sw = sc.switch_times()
    np.testing.assert_allclose(res.t_events, sw, rtol=1e-14, atol=1e-15)
    if sequence == [("stick",)]:
        assert np.max(np.abs(res.q[:, 0])) <= 1e-16  # stick under load holds: no creep
        np.testing.assert_allclose(res.force_T[:, 0], -phi, rtol=1e-14)


# ------------------------------------------------------------------------ property-based
@settings(max_examples=20, deadline=None)
@given(m=st.floats(0.1, 10), M=st.floats(0.1, 10), alpha=st.floats(0.1, 1.4), kappa=st.floats(0.01, 0.95),
       v0=st.floats(0.1, 5.0), sign=st.sampled_from([1.0, -1.0]), load=st.floats(-1.5, 1.5))
def test_random_jean_pratt_against_exact(m, M, alpha, kappa, v0, sign, load):
    # kappa >= 0.01: the sliding deceleration is then not much smaller than the free acceleration
    # it results from (their ratio, ~kappa, conditions the stop time: relative error ~ eps / kappa)
    t = math.tan(alpha)
    A = m + M * t * t
    R = kappa * A / (M * t)
    g = 9.81
    phi = load * R * (m + M) * g  # |load| <= 1 sticks after the stop, > 1 slips or reverses
    try:
        sol = JeanPrattExact(m=m, M=M, alpha=alpha, R=R, v0=sign * v0, g=g, phi=phi)
    except ValueError:
        assume(False)  # the load lifts the block: no exact solution to compare with
    tau = sol.switch_times()
    horizon = 1.5 * tau[-1] if tau.size else 1.0
    sc = lcp.scenes.jean_pratt(m=m, M=M, alpha=alpha, R=R, v0=sign * v0, g=g, phi=phi, t_end=max(horizon, 0.1))
    res = run(sc)
    ex = sc.exact(res.t)
    scale = max(1.0, float(np.max(np.abs(ex["x"]))))
    # a loaded slide's acceleration is a difference phi -+ R (m+M) g: near |load| = 1 it cancels,
    # and both the exact formula and the integrator lose digits in proportion
    RN = R * (m + M) * g
    cond = max([1.0] + [(abs(phi) + RN) / abs(phi - math.copysign(RN, sg.v0 if sg.v0 else phi))
                        for sg in sol.segments if sg.mode != "stick" and sg.a != 0])
    # a light block under a heavy, steep slide has an ill-conditioned mass matrix (cond ~ 250 for
    # m = 0.1, M = 4, alpha = 1.16); the accelerations solved from it lose digits in proportion
    cond = max(cond, float(np.linalg.cond(sc.system.mass(np.zeros(2)))))
    assert np.max(np.abs(res.q[:, 0] - ex["x"])) <= 1e-12 * scale * max(1.0, cond / 10)
    assert np.max(np.abs(res.q[:, 1])) <= 1e-12 * scale
    # the stop time divides by the deceleration, ~kappa times the accelerations it comes from
    np.testing.assert_allclose(res.t_events, tau, rtol=1e-13 * max(1.0, cond / 10, 0.1 / kappa), atol=1e-15)


# ------------------------------------------------------------------------ the general model
def test_scipy_phases_reproduce_the_closed_form():
    sc = lcp.scenes.jean_pratt(phi=12.0, v0=-1.0, t_end=0.5, coordinates="full")
    res = run(sc, smooth="scipy")
    assert res.integrators == ["DOP853"]
    assert x_error(sc, res) <= 1e-12
    np.testing.assert_allclose(res.t_events, sc.switch_times(), rtol=1e-13)


def warped_jean_pratt(R=0.5, phi=0.0):
    """Jean-Pratt in the coordinates (x, z) with the gap y = z + z^3: q-dependent mass, nonlinear gap.

    The motion is the Jean-Pratt motion (the gap stays 0), so the exact solution applies.
    """
    m = M = 1.0
    t, g = 1.0, 9.81
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    J = ca.diag(ca.vertcat(1, 1 + 3 * q[1] ** 2))
    Ared = ca.SX(np.array([[m + M * t * t, -M * t], [-M * t, m + M]]))
    Jdot_v = ca.vertcat(0, 6 * q[1] * v[1] ** 2)
    force = ca.mtimes(J.T, ca.vertcat(phi, -(m + M) * g)) - ca.mtimes([J.T, Ared, Jdot_v])
    return System(q, v, ca.mtimes([J.T, Ared, J]), force,
                  contacts=[Contact(gap=q[1] + q[1] ** 3, tangent=q[0], mu=R)])


def test_q_dependent_mass_and_nonlinear_gap():
    system = warped_jean_pratt()
    assert not system.is_constant
    res = lcp.simulate(system, 0.3, method="event", q0=np.zeros(2), v0=np.array([1.0, 0.0]), n_eval=200)
    assert res.success and res.integrators == ["DOP853"]
    ex = JeanPrattExact(R=0.5)(res.t)
    assert np.max(np.abs(res.q[:, 0] - ex["x"])) <= 1e-12
    assert abs(res.t_events[0] - 0.1529051987767584) <= 1e-14
    np.testing.assert_allclose(res.force_N[:, 0], ex["N"], rtol=1e-10)


def test_flight_impact_slide_stop():
    """A thrown block: a gap closing (impact with friction impulse), a slide, a stop."""
    g, mb, mu, vx, vy = 9.81, 2.0, 0.3, 3.0, 2.0
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    system = System(q, v, mb * ca.SX.eye(2), ca.vertcat(0, -mb * g),
                    contacts=[Contact(gap=q[1], tangent=q[0], mu=mu)])
    res = lcp.simulate(system, 1.5, method="event", q0=np.zeros(2), v0=np.array([vx, vy]))
    T = 2 * vy / g
    vx1 = vx - mu * vy  # sliding impact: |P_T| = mu P_N, P_N = m vy
    assert res.mode_sequence == [("open",), ("slide+",), ("stick",)]
    np.testing.assert_allclose(res.t_events, [T, T + vx1 / (mu * g)], rtol=1e-15)
    (imp,) = res.impulses
    assert imp.kind == "impact"
    np.testing.assert_allclose([imp.P_N, imp.P_T], [mb * vy, -mu * mb * vy], rtol=1e-14)
    x_stop = vx * T + vx1 ** 2 / (2 * mu * g)
    assert abs(res.q[-1, 0] - x_stop) <= 1e-14 * x_stop
    assert np.min(res.q[:, 1]) >= 0.0


@pytest.mark.parametrize("mode_solver", ["enumerate", "lemke"])
def test_block_chain_agrees_with_moreau_jean_to_first_order(mode_solver):
    sc = lcp.scenes.block_chain(3, t_end=0.6)
    errs = []
    for h in (2e-3, 2e-4):
        mj = lcp.simulate(sc, h=h)
        ev = lcp.simulate(sc, method="event", t_eval=mj.t, mode_solver=mode_solver)
        assert ev.success and ev.integrators == ["DOP853"]
        errs.append(float(np.max(np.abs(mj.q - ev.q))))
    assert errs[1] <= errs[0] / 5  # at least first order
    assert errs[1] <= 1e-4
    modes = {m for ph in ev.phases for m in ph.modes}
    assert {"stick", "slide+"} <= modes  # the chain sticks and slips


def test_block_chain_invariants():
    sc = lcp.scenes.block_chain(3)
    res = lcp.simulate(sc, method="event")
    assert res.success
    # blocks stay on the floor, friction within the cone, stops are events
    assert np.max(np.abs(res.q[:, 1::2])) <= 1e-12
    mu, N = 0.3, 9.81
    assert np.all(np.abs(res.force_T) <= mu * res.force_N + 1e-9)
    np.testing.assert_allclose(res.force_N, N, rtol=1e-12)
    stops = [e for e in res.events if e.kind == "stop"]
    for e in stops:
        i = int(np.searchsorted(res.t, e.t))
        assert i == res.t.size or res.t[i] >= e.t
    assert all(e.kind in ("stop", "slip") for e in res.events)


# ------------------------------------------------------------------------ bad input
def test_bad_input_names_the_parameter():
    sc = lcp.scenes.jean_pratt()
    with pytest.raises(ValueError, match="unknown option.*known options"):
        lcp.simulate(sc, 0.3, method="event", stepsize=1e-3)
    with pytest.raises(ValueError, match="t_end"):
        event_driven(sc.system, sc.q0, sc.v0, 0.0)
    with pytest.raises(ValueError, match="t_end"):
        event_driven(sc.system, sc.q0, sc.v0, float("nan"))
    with pytest.raises(ValueError, match="q0"):
        event_driven(sc.system, [float("nan"), 0.0], sc.v0, 0.3)
    with pytest.raises(ValueError, match="t_eval"):
        event_driven(sc.system, sc.q0, sc.v0, 0.3, t_eval=[0.0, 0.5])
    with pytest.raises(ValueError, match="t_eval"):
        EventOptions(t_eval=[0.2, 0.1])
    with pytest.raises(ValueError, match="smooth"):
        EventOptions(smooth="rk4")
    with pytest.raises(ValueError, match="rtol"):
        EventOptions(rtol=-1.0)
    with pytest.raises(ValueError, match="closed-form"):
        lcp.simulate(lcp.scenes.block_chain(2), method="event", smooth="closed-form")
    with pytest.raises(ValueError, match="penetrates"):
        event_driven(sc.system, np.array([0.0, -1e-2]), sc.v0, 0.3)


# ------------------------------------------------------------------------ time-dependent load: located events
def ramp_jean_pratt(c, R=0.5):
    """Jean-Pratt (m = M = 1, alpha = pi/4) with a growing horizontal load phi = c t."""
    q, v, t = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("t")
    mass = ca.SX(np.array([[2.0, -1.0], [-1.0, 2.0]]))
    return System(q, v, mass, ca.vertcat(c * t, -2 * 9.81), contacts=[Contact(gap=q[1], tangent=q[0], mu=R)], t=t)


def test_stick_to_slip_when_the_load_reaches_the_friction_bound():
    c, R, Ns, A, kappa = 20.0, 0.5, 2 * 9.81, 2.0, 0.25
    res = lcp.simulate(ramp_jean_pratt(c, R), 1.0, method="event", q0=np.zeros(2), v0=np.zeros(2))
    assert res.success and res.integrators == ["DOP853"]
    assert res.mode_sequence == [("stick",), ("slide+",)]
    (ev,) = res.events
    ts = R * Ns / c  # |phi| = R (m + M) g
    assert ev.kind == "slip" and abs(ev.t - ts) <= 1e-14
    # then A (1 - kappa) xdd = c (t - ts): x = c (t - ts)^3 / (6 A (1 - kappa))
    dt = np.maximum(res.t - ts, 0.0)
    assert np.max(np.abs(res.q[:, 0] - c * dt ** 3 / (6 * A * (1 - kappa)))) <= 1e-13
    assert np.max(np.abs(res.q[:, 1])) <= 1e-15


def test_lift_off_when_the_normal_force_reaches_zero():
    c, R, Ns, A, kappa = 100.0, 0.5, 2 * 9.81, 2.0, 0.25
    res = lcp.simulate(ramp_jean_pratt(c, R), 0.6, method="event", q0=np.zeros(2), v0=np.array([5.0, 0.0]))
    assert res.success and res.mode_sequence == [("slide+",), ("open",)]
    (ev,) = res.events
    # N = Ns - M tan(alpha) xdd = 0 with A (1 - kappa) xdd = c t - R Ns
    t_lift = (R * Ns + A * (1 - kappa) * Ns) / c
    assert ev.kind == "lift-off" and abs(ev.t - t_lift) <= 1e-14
    after = res.t > t_lift
    assert np.all(res.q[after, 1] > 0) and np.all(res.force_N[after] == 0.0)
    assert np.all(res.force_N[~after, 0] > 0)


# ------------------------------------------------------------------------ per-system caches (constant systems)
def _same_result(a, b):
    for name in ("t", "q", "v", "p_N", "p_T", "modes", "force_N", "force_T"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert (a.status, a.message, a.solver, a.t_events) == (b.status, b.message, b.solver, b.t_events)
    assert (a.events, a.impulses, a.phases, a.stats) == (b.events, b.impulses, b.phases, b.stats)


@pytest.mark.parametrize("coordinates", ["reduced", "full"])
def test_a_warm_system_gives_the_results_of_a_fresh_one(coordinates):
    """The mode problems, phase data, projections and the mass check are kept per System object;
    a System used for other states, horizons and options before gives exactly the results of a
    fresh one."""
    kw = dict(coordinates=coordinates, t_end=0.5)
    warm = lcp.scenes.jean_pratt(**kw)
    for phi, v0, R in ((0.0, 1.0, 2.5), (12.0, -1.0, 0.5), (5.0, 0.0, 0.5), (-12.0, 1.0, 0.5), (0.0, -1.0, 1.9)):
        sc = lcp.scenes.jean_pratt(phi=phi, v0=v0, R=R, **kw)
        for opts in ({}, {"mode_solver": "lemke", "n_eval": 37}, {"t_eval": [0.0, 0.01, 0.2, 0.5]}):
            fresh = lcp.scenes.jean_pratt(phi=phi, v0=v0, R=R, **kw)
            a = lcp.simulate(fresh, method="event", **opts)
            # the warm system: same mass matrix and contact, other forces -> a System of its own;
            # reuse this scene's system for another initial state first, then for this one
            lcp.simulate(sc.system, sc.t_end, method="event", q0=sc.q0, v0=-sc.v0, **opts)
            b = lcp.simulate(sc, method="event", **opts)
            c = lcp.simulate(sc, method="event", **opts)
            _same_result(a, b)
            _same_result(b, c)
    lcp.simulate(warm, method="event")
    _same_result(lcp.simulate(warm, method="event"), lcp.simulate(lcp.scenes.jean_pratt(**kw), method="event"))


def test_a_warm_system_still_checks_the_initial_state():
    sc = lcp.scenes.jean_pratt()
    assert run(sc).success  # the mass matrix is now known to be fine: only q0 and v0 are checked
    with pytest.raises(ValueError, match="q0 must be finite"):
        event_driven(sc.system, [float("nan"), 0.0], sc.v0, 0.3)
    with pytest.raises(ValueError, match="v0 must be finite"):
        event_driven(sc.system, sc.q0, [float("inf"), 0.0], 0.3)
    with pytest.raises(ValueError, match=r"q0 must have shape \(2,\)"):
        event_driven(sc.system, np.zeros(3), sc.v0, 0.3)
    with pytest.raises(ValueError, match="penetrates"):
        event_driven(sc.system, np.array([0.0, -1e-2]), sc.v0, 0.3)
    with pytest.raises(ValueError, match="t_eval must be a non-empty array of finite times"):
        event_driven(sc.system, sc.q0, sc.v0, 0.3, t_eval=[0.0, float("nan"), 0.2])
    with pytest.raises(ValueError, match="t_eval must be strictly increasing"):
        event_driven(sc.system, sc.q0, sc.v0, 0.3, t_eval=[0.0, 0.2, 0.2])
    with pytest.raises(ValueError, match="t_eval must be strictly increasing"):
        event_driven(sc.system, sc.q0, sc.v0, 0.3, t_eval=[-0.1, 0.2])
    with pytest.raises(ValueError, match="impact_solver|unknown solver"):
        event_driven(sc.system, sc.q0, sc.v0, 0.3, impact_solver="no-such-solver")


def test_results_are_independent_arrays():
    """Cached per-system data are never handed out: results can be modified freely."""
    sc = lcp.scenes.jean_pratt()
    a = run(sc)
    ref = run(sc)
    for name in ("t", "q", "v", "p_N", "p_T", "modes", "force_N", "force_T"):
        arr = getattr(a, name)
        assert arr.flags.writeable, name
        arr[...] = 0
    _same_result(run(sc), ref)
    assert ref.q.flags.c_contiguous and ref.v.flags.c_contiguous
