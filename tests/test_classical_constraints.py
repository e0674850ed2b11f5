"""The pendulum through a bilateral constraint and the Painleve rod (lcp.classical), against their
exact solutions and references: Moreau-Jean within its order, or the impulsive solution where the
smooth one does not exist; the event method where it applies."""
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import lcp
from lcp.classical import painleve_rod, pendulum


def observed_order(hs, errs):
    return float(np.polyfit(np.log(hs), np.log(errs), 1)[0])


def crossing_times(t, x):
    """Times where x crosses 0 downwards, linearly interpolated."""
    i = np.flatnonzero((x[:-1] > 0) & (x[1:] <= 0))
    return t[i] + x[i] / (x[i] - x[i + 1]) * (t[i + 1] - t[i])


# ----------------------------------------------------------------------------- pendulum
@pytest.mark.parametrize("theta0", [math.pi / 2, math.pi / 6, 2.5])
def test_pendulum_period_and_trajectory_converge(theta0):
    sc = pendulum(theta0=theta0, periods=1.5)
    T = sc.solution.period
    hs, per_err, traj_err = [2e-3, 1e-3, 5e-4], [], []
    for h in hs:
        res = lcp.simulate(sc, h=h)
        assert res.success, res.message
        assert np.max(np.abs(np.hypot(res.q[:, 0], res.q[:, 1]) - 1.0)) <= 1e-10
        tc = crossing_times(res.t, res.q[:, 0])
        per_err.append(abs(tc[1] - tc[0] - T) / T)  # one full swing
        first = res.t <= T
        traj_err.append(float(np.max(np.abs(res.q[first] - sc.exact(res.t[first])["q"]))))
    # Moreau-Jean imposes the constraint on v+ with G(q) at the step's start: first order
    assert 0.8 <= observed_order(hs, per_err) <= 1.3
    assert 0.8 <= observed_order(hs, traj_err) <= 1.3
    assert per_err[-1] <= 0.02


def test_pendulum_event_method():
    sc = pendulum(periods=3)
    res = lcp.simulate(sc, method="event")
    assert res.success, res.message
    assert np.max(np.abs(res.q - sc.exact(res.t)["q"])) <= 1e-8


def test_pendulum_validation():
    with pytest.raises(ValueError, match="theta0"):
        pendulum(theta0=math.pi)
    with pytest.raises(ValueError, match="L must"):
        pendulum(L=-1.0)


# ----------------------------------------------------------------------------- Painleve rod
def test_painleve_rod_consistent_sliding():
    sc = painleve_rod(mu=0.3, t_end=0.2)
    rod = sc.solution
    assert rod.regime == "sliding"
    hs, errs = [2e-3, 1e-3, 5e-4], []
    for h in hs:
        res = lcp.simulate(sc, h=h)
        assert res.success, res.message
        assert np.all(res.modes[:, 0] == lcp.contact.problem.SLIDE_NEG)
        ok = res.t <= min(0.2, rod.t_valid)
        errs.append(float(np.max(np.abs(res.q[ok] - rod.reference(res.t[ok])))))
    assert 0.8 <= observed_order(hs, errs) <= 1.3 and errs[-1] <= 5e-5


@pytest.mark.parametrize("omega0, regime", [(0.0, "inconsistent"), (8.0, "indeterminate")])
def test_painleve_rod_paradox_gives_the_tangential_impact(omega0, regime):
    sc = painleve_rod(mu=3.0, omega0=omega0, t_end=0.05)
    rod = sc.solution
    assert rod.regime == regime and rod.paradoxical
    p_star, dv_star = rod.tangential_impact()
    assert p_star[0] > 0 and abs(p_star[1]) <= rod.mu * p_star[0]  # admissible exactly here
    errs = []
    for h in (1e-3, 1e-4):
        res = lcp.simulate(sc, h=h)
        assert res.success, res.message
        # the first step carries the impulse that stops A at once (plus O(h) of smooth forces)
        assert res.modes[0, 0] == lcp.contact.problem.STICK
        p = np.array([res.p_N[0, 0], res.p_T[0, 0]])
        err = float(np.max(np.abs(p - p_star)))
        assert err <= 10 * h * np.max(np.abs(p_star))
        errs.append(err)
        H = sc.system.contact_jacobian(res.q[0])
        assert abs(H[1] @ res.v[1]) <= 1e-12  # A stopped (the step's kinematics)
        np.testing.assert_allclose(res.v[1] - sc.v0, dv_star, atol=20 * h)
    assert errs[1] <= 0.2 * errs[0]


def test_painleve_rod_event_method():
    # inconsistent: the impulse is the tangential impact; indeterminate: the non-uniqueness is said
    inc = painleve_rod(mu=3.0, t_end=0.05)
    res = lcp.simulate(inc, method="event")
    assert res.success, res.message
    imp = [i for i in res.impulses if i.kind == "tangential impact"]
    p_star, _ = inc.solution.tangential_impact()
    assert imp and np.allclose([imp[0].P_N, imp[0].P_T], p_star, rtol=1e-10)
    ind = painleve_rod(mu=3.0, omega0=8.0, t_end=0.05)
    res = lcp.simulate(ind, method="event")
    assert res.success and "non-unique" in res.message


@settings(deadline=None)  # examples: the profile's (conftest)
@given(theta0=st.floats(0.2, 1.3), mu=st.floats(0.0, 4.0), u0=st.floats(0.5, 2.0), sign=st.sampled_from([1.0, -1.0]))
def test_painleve_rod_random_parameters(theta0, mu, u0, sign):
    # omega0 = 0: b_N = -g < 0, so the rod slides consistently or the configuration is inconsistent
    sc = painleve_rod(mu=mu, theta0=theta0, u0=sign * u0, t_end=0.05)
    rod = sc.solution
    h = 1e-3
    res = lcp.simulate(sc, h=h)
    assert res.success, res.message
    if rod.paradoxical:
        p_star, _ = rod.tangential_impact()
        assert res.modes[0, 0] == lcp.contact.problem.STICK
        assert np.max(np.abs([res.p_N[0, 0] - p_star[0], res.p_T[0, 0] - p_star[1]])) <= 10 * h * max(1.0, np.max(np.abs(p_star)))
        return
    T = min(0.05, rod.t_valid)
    n = int(np.sum(res.t <= T))
    err = np.max(np.abs(res.q[:n] - rod.reference(res.t[:n])))
    if T < 20 * h:  # A stops (or lifts off) within a few steps: an O(h) error, not yet asymptotic
        assert err <= abs(u0) * h
        return
    half = lcp.simulate(sc, h=h / 2, save_every=2)
    estimate = np.max(np.abs(res.q[:n] - half.q[:n]))  # first order: the error is about twice this
    assert err <= 2.5 * estimate + 1e-12
