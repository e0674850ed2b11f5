"""Troesch's problem by LEM shooting (lem.troesch) against 20-digit reference slopes."""
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import solve_ivp

from lem.troesch import (STATUS_MESSAGES, TROESCH_REFERENCE, shoot, solve_troesch,
                         troesch_field)


def y_at_1(lam, s):
    """Independent check: solve_ivp (rtol 1e-13) from the slope LEM found."""
    r = solve_ivp(lambda x, y: [y[1], lam * np.sinh(lam * y[0])], (0.0, 1.0), [0.0, s],
                  method="DOP853", rtol=1e-13, atol=1e-15)
    return r.y[0, -1]


@pytest.mark.parametrize("lam,rel", [(0.5, 1e-9), (1.0, 1e-9), (5.0, 1e-6)])
def test_slopes_against_reference(lam, rel):
    res = solve_troesch(lam)
    assert res.status == 0 and res.success, res.message
    assert res.message == STATUS_MESSAGES[0]
    assert res.reference == TROESCH_REFERENCE[lam]
    assert res.relative_error <= rel
    assert abs(res.slope / TROESCH_REFERENCE[lam] - 1) == res.relative_error
    # what the solver claims is consistent with what it achieved
    assert res.slope_error_estimate <= rel * res.slope
    assert abs(res.residual) <= 1e-10
    assert abs(y_at_1(lam, res.slope) - 1.0) <= 1e-9 * max(1.0, res.dyds * res.slope)
    sol = res.solution
    assert sol.t[0] == 0.0 and sol.t[-1] == 1.0 and sol.y[0, 0] == 0.0
    assert res.n_segments == sol.n_restarts + 1


def test_restarts_are_what_make_lambda_5_work():
    # one expansion over [0, 1] (series in the initial data, about the origin) converges only
    # slowly for lambda = 5, and says so; restarts converge to 1e-12
    s = TROESCH_REFERENCE[5.0]
    plain = shoot(5.0, s, restart=None, degree=30, warn=False)
    assert plain.status in (1, -1) and plain.error_estimate[0, -1] > 1e-4
    assert abs(plain.y[0, -1] - 1.0) <= 2 * plain.error_estimate[0, -1]
    good = shoot(5.0, s)
    assert good.status == 0 and good.n_restarts >= 5
    assert abs(good.y[0, -1] - 1.0) <= 1e-9


def test_overshoot_puts_the_pole_inside_and_is_reported():
    # for lambda = 10 the reference solution has a pole at x = 1.00135; a slope 3 % larger moves it
    # inside [0, 1]: the engine must stop and say so, not return a number
    r = shoot(10.0, 1.03 * TROESCH_REFERENCE[10.0], warn=False, min_step=1e-7)
    assert r.status == -3 and r.t[-1] < 1.0
    assert r.y[0, -1] > 2.0  # it stopped on the way up the pole


@settings(max_examples=6)
@given(lam=st.floats(0.1, 2.0))
def test_boundary_condition_holds_for_other_lambdas(lam):
    res = solve_troesch(lam)
    assert res.status == 0
    assert abs(y_at_1(lam, res.slope) - 1.0) <= 1e-10


def test_bad_input():
    for lam in (0.0, -1.0, math.nan, math.inf, True):
        with pytest.raises(ValueError, match="lam"):
            solve_troesch(lam)
    with pytest.raises(ValueError, match="s0"):
        solve_troesch(1.0, s0=-0.5)
    with pytest.raises(ValueError, match="maxiter"):
        solve_troesch(1.0, maxiter=0)
    with pytest.raises(ValueError, match="xtol"):
        solve_troesch(1.0, xtol=0.0)
    assert troesch_field(2.0).n == 2


@pytest.mark.slow
def test_lambda_10_badly_conditioned():
    res = solve_troesch(10.0)
    assert res.status == 0
    assert res.relative_error <= 1e-6
    assert res.dyds > 1e4  # d y(1) / d s: the ill-conditioning of the shooting


@pytest.mark.parametrize("lam", [5.0, 10.0])
def test_lambda_5_and_10_to_1e_12(lam):
    # the shooting is ill-conditioned (dy(1)/ds ~ 1e5 at lambda = 10), but the LEM error estimate
    # of y(1), divided by it, still bounds the slope error; the target is 1e-12 relative
    res = solve_troesch(lam)
    assert res.status == 0 and res.failed_trials == 0
    assert res.relative_error <= 1e-12
    assert res.slope_error_estimate <= 1e-12 * res.slope
    # the last trial re-accepted every segment of the one before (step hints), none rejected
    assert res.solution.stats.n_rejected == 0


def test_start_from_either_side_of_the_root():
    # from above (the pole near x = 1, y(1) large) the Newton step on the pole-linearized map
    # must not creep; from below it is Newton's step on y(1) - 1
    ref = TROESCH_REFERENCE[5.0]
    for s0 in (1.15 * ref, 0.8 * ref):
        res = solve_troesch(5.0, s0=s0)
        assert res.status == 0 and res.relative_error <= 1e-12
        assert res.iterations <= 8


def test_step_hint_reuse_equals_a_fresh_solve():
    # a hinted trial accepts the same segments as an unhinted one when the hint is its own
    s = TROESCH_REFERENCE[5.0]
    fresh = shoot(5.0, s)
    hinted = shoot(5.0, s, step_hint=tuple(np.diff(fresh.restart_points)))
    assert hinted.stats.n_rejected == 0
    assert np.array_equal(hinted.restart_points, fresh.restart_points)
    assert np.array_equal(hinted.y, fresh.y)
    assert np.array_equal(hinted.error_estimate, fresh.error_estimate)
