"""The exact Jean-Pratt solution: reference numbers, the equations of motion, every regime."""
import math

import numpy as np
import pytest
from hypothesis import given, strategies as st

from lcp.scenes.jean_pratt_exact import JeanPrattExact
from lcp.scenes import jean_pratt


def test_reference_numbers():
    # docs/exact_solutions.md, reference parameters
    sc = jean_pratt()
    assert sc.kappa == 0.25
    assert sc.N0 == pytest.approx(26.16, rel=1e-12)
    assert sc.B == pytest.approx(6.54, rel=1e-12)
    assert sc.tau0 == pytest.approx(0.152905, abs=1e-6)
    assert sc.x_stop == pytest.approx(0.0764526, abs=1e-7)
    assert sc.x_stop == pytest.approx(0.5 / sc.B, rel=1e-14)  # 0.5 v0^2 / B, not the paper's 0.42
    rev = jean_pratt(v0=-1.0)
    assert rev.N0 == pytest.approx(15.696, rel=1e-12)
    assert rev.B == pytest.approx(3.924, rel=1e-12)
    assert rev.tau0 == pytest.approx(1 / 3.924, rel=1e-14)
    assert rev.x_stop == pytest.approx(-0.5 / 3.924, rel=1e-14)


def test_after_stop_block_sticks_with_weight_as_normal_force():
    sc = jean_pratt()
    e = sc.exact(np.array([0.2, 0.3, 5.0]))
    np.testing.assert_array_equal(e["x"], sc.x_stop)
    np.testing.assert_array_equal(e["xdot"], 0.0)
    np.testing.assert_array_equal(e["f"], 0.0)
    np.testing.assert_allclose(e["N"], 2 * 9.81, rtol=1e-15)  # (m + M) g, not 0 as printed
    np.testing.assert_array_equal(e["y"], 0.0)


def _check_equations(ex: JeanPrattExact, t):
    """A xdd = phi + f, N = (m+M) g - M t xdd, |f| <= R N, f opposes sliding, N >= 0."""
    e = ex(t)
    dt = 1e-7
    ok = np.ones(t.shape, bool)
    for ts in ex.switch_times():
        ok &= np.abs(t - ts) > 3 * dt
    xdd = (ex(t + dt)["xdot"] - ex(t - dt)["xdot"]) / (2 * dt)
    t_a = ex.tan
    scale = max(1.0, abs(ex.phi), ex.N_stick)
    np.testing.assert_allclose((ex.A * xdd)[ok], (ex.phi + e["f"])[ok], atol=1e-6 * scale)
    np.testing.assert_allclose(e["N"][ok], ((ex.m + ex.M) * ex.g - ex.M * t_a * xdd)[ok], atol=1e-6 * scale)
    assert np.all(e["N"] > 0)
    assert np.all(np.abs(e["f"]) <= ex.R * e["N"] * (1 + 1e-14))
    slide = e["xdot"] != 0
    np.testing.assert_allclose(e["f"][slide], -ex.R * e["N"][slide] * np.sign(e["xdot"][slide]), rtol=1e-13)


@given(m=st.floats(0.1, 10), M=st.floats(0.1, 10), alpha=st.floats(0.1, 1.4),
       kappa=st.floats(0.01, 0.95), v0=st.floats(0.1, 5) | st.floats(-5, -0.1))
def test_equations_of_motion_hold(m, M, alpha, kappa, v0):
    t_a = math.tan(alpha)
    R = kappa * (m + M * t_a * t_a) / (M * t_a)
    ex = JeanPrattExact(m=m, M=M, alpha=alpha, R=R, v0=v0)
    assert ex.kappa == pytest.approx(kappa, rel=1e-12)
    t = np.linspace(1e-6, 3 * ex.tau0, 301)
    _check_equations(ex, t)
    # stop: continuous x, zero velocity, distance v0|v0|/(2B)
    assert ex.x_stop == pytest.approx(v0 * abs(v0) / (2 * ex.B), rel=1e-12)
    assert ex(ex.tau0)["xdot"] == 0


@pytest.mark.parametrize("phi", [3.0, 9.0, -9.0, 12.0, -15.0, 25.0])
@pytest.mark.parametrize("v0", [1.0, -1.0, 0.0])
def test_loaded_contact_regimes(phi, v0):
    ex = JeanPrattExact(v0=v0, phi=phi)
    _check_equations(ex, np.linspace(1e-6, 2.0, 401))
    # continuity of x and xdot across switches
    for ts in ex.switch_times():
        a, b = ex(ts - 1e-12), ex(ts + 1e-12)
        assert abs(a["x"] - b["x"]) < 1e-9 and abs(a["xdot"] - b["xdot"]) < 1e-9
    modes = [s.mode for s in ex.segments]
    if abs(phi) <= 0.5 * 2 * 9.81:
        assert modes[-1] == "stick"
    else:
        assert modes[-1] == ("slide+" if phi > 0 else "slide-")
    if v0 != 0 and abs(phi) > 9.81 and np.sign(phi) != np.sign(v0):
        assert len(modes) == 2  # reversal


@pytest.mark.parametrize("R", [2.0, 2.5, 4.0])
def test_shock_for_kappa_at_least_one(R):
    ex = JeanPrattExact(R=R, v0=1.5)
    assert ex.kappa >= 1
    assert ex.tau0 == 0.0 and ex.x_stop == 0.0
    (ts, pN, pT), = ex.shocks
    assert ts == 0.0
    assert pN == pytest.approx(1.0 * 1.0 * 1.5, rel=1e-15)  # M tan(alpha) v0
    assert pT == pytest.approx(-2.0 * 1.5, rel=1e-15)  # -A v0
    assert ex.N0 == math.inf
    e = ex(np.array([0.0, 0.1]))
    np.testing.assert_array_equal(e["x"], 0.0)
    PN, PT = ex.impulse(0.0, 0.01)
    assert PN[0] == pytest.approx(1.5 + 0.01 * 2 * 9.81, rel=1e-14)
    assert PT[0] == pytest.approx(-3.0, rel=1e-14)


def test_kappa_one_is_exact_and_continuous():
    # tan(pi/4) is taken as 1 exactly, so R = 2 is kappa = 1 exactly (a shock), never 0.9999...
    assert JeanPrattExact(R=2.0).kappa == 1.0
    assert JeanPrattExact(R=2.0).shocks
    taus = [JeanPrattExact(R=2.0 * (1 - 10.0 ** -k)).tau0 for k in range(2, 13)]
    assert all(np.diff(taus) < 0) and taus[-1] < 1e-11  # tau0 -> 0 as kappa -> 1-
    xs = [JeanPrattExact(R=2.0 * (1 - 10.0 ** -k)).x_stop for k in range(2, 13)]
    assert xs[-1] < 1e-11 and all(np.isfinite(xs))


def test_reverse_motion_never_paradoxical():
    ex = JeanPrattExact(R=10.0, v0=-1.0)  # kappa = 5
    assert not ex.shocks
    assert ex.N0 == pytest.approx(2 * 9.81 / 6, rel=1e-14)


def test_lift_off_is_reported():
    with pytest.raises(ValueError, match="lifts the block off"):
        JeanPrattExact(phi=1000.0, v0=0.0)


def test_loaded_paradoxical_start_lifts_off_and_is_reported():
    # kappa = 1.25 and a load beyond the stick bound: neither stick nor slip, the block lifts off
    with pytest.raises(ValueError, match="lifts the block off"):
        JeanPrattExact(R=2.5, v0=0.0, phi=60.0)
