"""Moreau-Jean on the Jean-Pratt scene: the outcomes of the contact core, against the exact solution."""
import math

import numpy as np
import pytest
from hypothesis import given, strategies as st

import lcp
from lcp.scenes import jean_pratt

from .conftest import N_RTOL, RESIDUAL_TOL, X_ROUNDING, Y_TOL
from .helpers import jean_pratt_errors

SOLVERS = ["enum", "lemke", "osqp"]


# h = 1e-5 by Lemke or OSQP takes seconds per case (a Python loop of ~1e4 steps): slow tests; the
# closed-form enumeration keeps the finest step in the default suite
EVERY_SOLVER_CASES = [pytest.param(solver, h, marks=pytest.mark.slow) if h == 1e-5 and solver != "enum"
                      else (solver, h) for h in (1e-2, 1e-3, 1e-4, 1e-5) for solver in SOLVERS]


@pytest.mark.parametrize("solver, h", EVERY_SOLVER_CASES)
@pytest.mark.parametrize("v0", [1.0, -1.0])
def test_default_scene_every_solver(solver, h, v0):
    sc = jean_pratt(v0=v0)
    t_end = 0.3 if h > 1e-5 else 1.1 * sc.tau0  # at h = 1e-5, stop a little after tau0 to keep CI fast
    res = lcp.simulate(sc, t_end, h=h, theta=0.5, solver=solver)
    assert res.success, res.message
    err = jean_pratt_errors(sc, res)
    assert err["x"] <= err["bound"] + X_ROUNDING
    assert err["y"] <= Y_TOL
    assert err["N_rel"] <= N_RTOL
    assert err["residual"] <= RESIDUAL_TOL
    # slide, then stick for ever
    modes = res.modes[:, 0]
    k_stop = int(np.argmax(modes == 1))
    assert np.all(modes[:k_stop] == (2 if v0 > 0 else 3)) and np.all(modes[k_stop:] == 1)


def test_stick_phase_force_is_weight():
    sc = jean_pratt()
    res = lcp.simulate(sc, 0.3, h=1e-3)
    stick = res.modes[:, 0] == 1
    np.testing.assert_allclose(res.N[stick][1:, 0], 2 * 9.81, rtol=1e-12)
    np.testing.assert_allclose(res.f[stick][1:, 0], 0.0, atol=1e-12)
    np.testing.assert_allclose(res.N[:100, 0], sc.N0, rtol=1e-12)


@given(m=st.floats(0.1, 10), M=st.floats(0.1, 10), alpha=st.floats(0.1, 1.4), kappa=st.floats(0.01, 0.95),
       v0=st.floats(0.2, 3) | st.floats(-3, -0.2), n=st.integers(5, 150), frac=st.floats(0.05, 0.95),
       solver=st.sampled_from(SOLVERS))
def test_bounds_hold_for_other_parameters(m, M, alpha, kappa, v0, n, frac, solver):
    t_a = math.tan(alpha)
    R = kappa * (m + M * t_a * t_a) / (M * t_a)
    sc = jean_pratt(m=m, M=M, alpha=alpha, R=R, v0=v0)
    h = sc.tau0 / (n + frac)  # the stop falls anywhere inside a step
    res = lcp.simulate(sc, sc.tau0 + 10 * h, h=h, solver=solver)
    assert res.success, res.message
    err = jean_pratt_errors(sc, res)
    scale = max(1.0, abs(sc.x_stop))
    assert err["x"] <= err["bound"] + X_ROUNDING * scale
    assert err["y"] <= Y_TOL * scale
    assert err["N_rel"] <= N_RTOL
    assert err["residual"] <= RESIDUAL_TOL * max(1.0, sc.N0 * h)


def test_default_R_does_not_hide_lift_off():
    # R = M t / (m + M) = 0.5 makes a lifted block decelerate like a sliding one (docs/models.md):
    # check y and N on a parameter set where that coincidence does not hold.
    sc = jean_pratt(m=2.0, M=0.7, alpha=0.9, R=0.35, v0=1.7)
    res = lcp.simulate(sc, h=1e-3, solver="osqp")
    err = jean_pratt_errors(sc, res)
    assert err["y"] <= Y_TOL and err["N_rel"] <= N_RTOL and err["x"] <= err["bound"] + X_ROUNDING


@pytest.mark.parametrize("theta,order", [(0.5, 2.0), (1.0, 1.0)])
def test_observed_convergence_order(theta, order):
    sc = jean_pratt(m=1.3, M=0.8, alpha=0.6, R=0.4, v0=1.0)
    hs = np.array([1e-2, 1e-3, 1e-4])
    errs = []
    for h in hs:
        # a grid offset keeps the stop time from falling on one fixed phase of the step
        res = lcp.simulate(sc, 1.2 * sc.tau0, h=h * (1 + 1 / 7), theta=theta)
        errs.append(np.max(np.abs(res.q[:, 0] - sc.exact(res.t)["x"])))
    slope = np.polyfit(np.log(hs), np.log(errs), 1)[0]
    assert abs(slope - order) < 0.35, (slope, errs)


@pytest.mark.parametrize("phi,v0", [(3.0, 1.0), (-12.0, 1.0), (12.0, -1.0), (-5.0, 0.0), (15.0, 0.0)])
def test_loaded_contact_converges_first_order(phi, v0):
    # stick under load, slip, and reversal: the reversal step costs O(h) (the discrete block
    # turns round at the end of the step containing the exact reversal), so the error is first order
    sc = jean_pratt(phi=phi, v0=v0)
    t_end = 0.6
    errs = []
    hs = np.array([4e-3, 4e-4, 4e-5]) * (1 + 1 / 7)  # off the round grid, so phases vary
    for h in hs:
        res = lcp.simulate(sc, t_end, h=h)
        assert res.success
        errs.append(np.max(np.abs(res.q[:, 0] - sc.exact(res.t)["x"])))
        assert np.max(np.abs(res.q[:, 1])) <= Y_TOL
    errs = np.array(errs)
    accel = max(abs(s.a) for s in sc.solution.segments)
    # one step of velocity error (at most |a| h per switch) carried over the horizon
    assert np.all(errs <= 2 * accel * hs * (t_end + hs) + 1e-12), errs
    assert errs[-1] <= errs[0] / 20 + 1e-13, errs


@pytest.mark.parametrize("R", [1.0, 1.5, 1.9, 1.99, 1.999, 2.0, 2.5])
@pytest.mark.parametrize("solver", SOLVERS)
def test_shock_sweep(R, solver):
    sc = jean_pratt(R=R)
    h = 1e-3
    for theta in (0.5, 1.0):
        res = lcp.simulate(sc, 0.05, h=h, theta=theta, solver=solver)
        assert res.success, res.message
        assert res.stats.max_residual <= RESIDUAL_TOL
        assert np.max(np.abs(res.q[:, 1])) <= Y_TOL
        if sc.kappa >= 1:
            assert res.v[1, 0] == pytest.approx(0.0, abs=1e-14)  # stopped within the first step
            assert res.p_N[0, 0] == pytest.approx(1.0 * 1.0 * 1.0 + h * 2 * 9.81, rel=1e-9)
            assert res.p_T[0, 0] == pytest.approx(-2.0 * 1.0, rel=1e-9)
            if theta == 1.0:
                assert np.max(np.abs(res.q[:, 0])) <= 1e-15  # x stays 0 (to rounding)
        elif theta == 0.5:
            err = jean_pratt_errors(sc, res)
            assert err["x"] <= err["bound"] + X_ROUNDING


def test_full_coordinates_match_reduced():
    kw = dict(m=1.7, M=0.6, alpha=0.8, R=0.4, v0=-1.2)
    a = lcp.simulate(jean_pratt(**kw), h=1e-3)
    for solver in SOLVERS:
        b = lcp.simulate(jean_pratt(coordinates="full", **kw), h=1e-3, solver=solver)
        assert b.success
        np.testing.assert_allclose(b.q[:, :2], a.q, atol=1e-12)
        np.testing.assert_allclose(b.p_N, a.p_N, atol=1e-12)
        # the slide constraint Y = y - x tan(alpha) holds on the whole trajectory
        np.testing.assert_allclose(b.q[:, 2], b.q[:, 1] - b.q[:, 0] * math.tan(0.8), atol=1e-12)


def test_general_path_matches_constant_fast_path():
    # a force that formally depends on t sends the system through the per-step CasADi assembly
    import casadi as ca

    sc = jean_pratt(R=0.3, v0=1.4)
    s = sc.system
    general = lcp.System(s.q_sym, s.v_sym, s.mass_expr, s.force_expr + 1e-300 * ca.sin(s.t_sym),
                         contacts=s.contacts, t=s.t_sym)
    assert sc.system.is_constant and not general.is_constant
    a = lcp.simulate(sc, 0.4, h=1e-3)
    b = lcp.simulate(general, 0.4, h=1e-3, q0=sc.q0, v0=sc.v0)
    np.testing.assert_allclose(b.q, a.q, atol=1e-13)
    np.testing.assert_allclose(b.p_T, a.p_T, atol=1e-13)


def test_result_contract():
    sc = jean_pratt()
    res = lcp.simulate(sc, 0.3, h=1e-2)
    n_pts = res.t.size
    assert res.q.shape == (n_pts, 2) and res.v.shape == (n_pts, 2)
    assert res.p_N.shape == (n_pts - 1, 1) and res.p_T.shape == (n_pts - 1, 1)
    assert res.t[-1] >= 0.3 - 1e-12 and res.success and res.status == 0
    assert res.stats.steps == n_pts - 1
    assert res.stats.solver_calls == res.stats.steps
    assert sum(res.stats.mode_counts.values()) == res.stats.steps
    assert res.stats.iterations > 0


@pytest.mark.parametrize("kw", [dict(), dict(v0=-1.0), dict(R=2.5), dict(phi=-12.0), dict(coordinates="full", R=0.3),
                                dict(m=0.3, M=4.0, alpha=1.2, R=0.2, v0=2.0)])
@pytest.mark.parametrize("theta", [0.5, 1.0])
def test_compiled_path_matches_python_loop(kw, theta):
    sc = jean_pratt(**kw)
    a = lcp.simulate(sc, h=1e-3, theta=theta)
    b = lcp.simulate(sc, h=1e-3, theta=theta, fast=False)
    assert a.solver.endswith("(compiled)") and b.solver == "auto"
    np.testing.assert_allclose(a.q, b.q, atol=1e-15)
    np.testing.assert_allclose(a.v, b.v, atol=1e-15)
    np.testing.assert_allclose(a.p_N, b.p_N, atol=1e-15)
    np.testing.assert_allclose(a.p_T, b.p_T, atol=1e-15)
    np.testing.assert_array_equal(a.modes, b.modes)
    assert a.stats.mode_counts == b.stats.mode_counts
    assert a.stats.max_residual <= RESIDUAL_TOL


def test_long_run_keeps_exactness_with_decimation():
    # 1e6 steps: compensated sums keep x within B h^2/8 and y at rounding level
    sc = jean_pratt()
    n = 1_000_000
    h = 0.3 / n
    res = lcp.simulate(sc, 0.3, h=h, save_every=1000)
    assert res.success and res.stats.steps == n
    assert res.q.shape == (n // 1000 + 1, 2) and res.p_N.shape == (n // 1000, 1)
    err = np.max(np.abs(res.q[:, 0] - sc.exact(res.t)["x"]))
    assert err <= sc.B * h * h / 8
    assert np.max(np.abs(res.q[:, 1])) <= Y_TOL


def test_decimated_python_loop_matches_full_run():
    sc = jean_pratt(R=0.3)
    full = lcp.simulate(sc, 0.5, h=1e-3, fast=False)
    dec = lcp.simulate(sc, 0.5, h=1e-3, fast=False, save_every=7)
    np.testing.assert_array_equal(dec.q, full.q[::7][: dec.q.shape[0]])
    np.testing.assert_array_equal(dec.p_N, full.p_N[6::7][: dec.p_N.shape[0]])
    np.testing.assert_allclose(dec.t, full.t[::7][: dec.t.size], rtol=1e-15)
