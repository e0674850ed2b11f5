"""Exact disk-friction slides in a plane (lcp.scenes.spatial_exact) against the reduced integration,
invariants, stop formulas, straight-line limits and bad input."""
import doctest
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.integrate import quad

import lcp.scenes.spatial_exact as se
from lcp.scenes.spatial_exact import (
    ConstantLoadSlide,
    InclineSlideExact,
    LateralForceSlideExact,
    PlaneSlideExact,
    reduced_reference,
)

#: closed form vs the tau-rescaled DOP853 integration, relative to s0 (velocities) and s0 t (positions)
REF_RTOL = 1e-12
#: identities of the closed form (conservation of s (1 + cos phi), energy balance)
INV_RTOL = 1e-13


def _max_rel(ex, t, st_, ref):
    L = ex.s0 * max(float(np.max(t)), 1e-300)
    pos = max(np.abs(st_[k] - ref[k]).max() for k in ("x", "y", "path")) / L
    vel = max(np.abs(st_[k] - ref[k]).max() for k in ("vx", "vy", "speed")) / ex.s0
    return pos, vel


SCENES = [
    InclineSlideExact(math.radians(30), 2.0),
    InclineSlideExact(math.radians(20), 1.5, launch_angle=2.5),
    InclineSlideExact(math.radians(30), 2.0, mu=0.3),
    InclineSlideExact(math.radians(30), 2.0, mu=1.0),
    PlaneSlideExact(1.0, 0.3, 9.81, 2.0, 0.7),
    LateralForceSlideExact(2.0, 0.4, 9.81, [1.0, 3.0], [2.0, -1.0]),
    LateralForceSlideExact(2.0, 0.4, 9.81, [1.0, 3.0], [-1.0, -3.0]),
    LateralForceSlideExact(2.0, 0.4, 9.81, [1.0, 3.0], [1.0, 3.0]),
]


@pytest.mark.parametrize("ex", SCENES, ids=lambda e: type(e).__name__)
def test_closed_form_matches_reduced_integration(ex):
    t = np.linspace(0.0, 2.0, 21)
    if math.isfinite(ex.t_stop):
        t = np.union1d(t, ex.t_stop * np.array([0.5, 0.99, 1 - 1e-6, 1.0]))
    ref = ex.reference(t)
    pos, vel = _max_rel(ex, t, ex.state(t), ref)
    assert pos <= REF_RTOL and vel <= REF_RTOL
    if math.isfinite(ex.t_stop):
        assert abs(ref["t_stop"] - ex.t_stop) <= REF_RTOL * ex.t_stop


def test_incline_invariant_and_limit_speed():
    v0 = 3.0
    inc = InclineSlideExact(math.radians(25), v0)
    t = np.concatenate([np.linspace(0, 5, 101), [20.0, 100.0, 1e4]])
    s = inc.state(t)
    # v (1 + cos phi) = speed + v_along_descent is conserved: v0 for a horizontal launch
    assert np.max(np.abs(s["speed"] + s["vx"] - v0)) <= INV_RTOL * v0
    assert inc.limit_speed == v0 / 2
    assert abs(s["speed"][-1] - v0 / 2) <= 1e-12
    assert abs(s["y"][-1] - inc.limit_drift) <= 1e-12 * inc.limit_drift
    assert inc.t_stop == math.inf
    assert np.all(np.diff(s["phi"][:-1]) < 0) and np.all(s["phi"][:-1] > 0)   # phi underflows at 1e4 s


@pytest.mark.parametrize("ex", SCENES, ids=lambda e: type(e).__name__)
def test_energy_balance(ex):
    t = np.linspace(0.0, 3.0, 61)
    s = ex.state(t)
    # kinetic energy change = work of the load - friction work a * (path length)
    lhs = 0.5 * (s["speed"] ** 2 - ex.s0 ** 2)
    rhs = ex.accel[0] * s["x"] + ex.accel[1] * s["y"] - ex.decel * s["path"]
    scale = ex.s0 ** 2 + np.hypot(*ex.accel) * ex.s0 * 3.0
    assert np.max(np.abs(lhs - rhs)) <= INV_RTOL * scale


def test_friction_work_is_the_integral_of_mu_N_speed():
    ex = LateralForceSlideExact(1.5, 0.5, 9.81, [2.0, 1.0], [0.5, 2.5])
    T = 0.8 * ex.t_stop
    work, _ = quad(lambda tt: ex.decel * float(ex.state(tt)["speed"]), 0.0, T, epsabs=0, epsrel=1e-13, limit=200)
    assert abs(ex.decel * float(ex.state(T)["path"]) - work) <= 1e-12 * work


def test_plane_stop_time_and_distance():
    m, mu, g, v0, beta = 2.0, 0.35, 9.81, 3.0, 1.1
    p = PlaneSlideExact(m, mu, g, v0, beta)
    assert p.t_stop == pytest.approx(v0 / (mu * g), rel=1e-15)
    assert p.stop_distance == pytest.approx(v0 ** 2 / (2 * mu * g), rel=1e-15)
    s = p.state([0.5 * p.t_stop, p.t_stop, 2 * p.t_stop, 100.0])
    d = v0 * 0.5 * p.t_stop - 0.5 * mu * g * (0.5 * p.t_stop) ** 2
    assert s["x"][0] == pytest.approx(d * math.cos(beta), rel=1e-14)
    assert s["y"][0] == pytest.approx(d * math.sin(beta), rel=1e-14)
    assert np.all(s["speed"][1:] == 0.0) and np.all(s["vx"][1:] == 0.0) and np.all(s["vy"][1:] == 0.0)
    assert np.hypot(s["x"][-1], s["y"][-1]) == pytest.approx(p.stop_distance, rel=1e-14)
    assert np.all(s["phi"] == beta)


def test_lateral_stop_time_formula():
    m, mu, g, F, v0 = 2.0, 0.4, 9.81, np.array([0.0, 3.0]), np.array([2.0, 0.5])
    sl = LateralForceSlideExact(m, mu, g, F, v0)
    f = np.hypot(*F) / m
    k = mu * g / f
    s0 = np.hypot(*v0)
    phi0 = math.atan2(2.0, 0.5)             # angle between v0 and F
    u0 = math.tan(phi0 / 2)
    C = 2 * s0 * u0 ** (1 - k) / (1 + u0 ** 2)   # s = C tan(phi/2)**k / sin(phi) at the launch
    t_star = C / (2 * f) * (u0 ** (k - 1) / (k - 1) + u0 ** (k + 1) / (k + 1))
    assert sl.k == pytest.approx(k, rel=1e-15)
    assert sl.t_stop == pytest.approx(t_star, rel=1e-13)
    s = sl.state([sl.t_stop, sl.t_stop + 1.0])
    assert np.all(s["speed"] == 0.0) and s["x"][0] == s["x"][1] and s["y"][0] == s["y"][1]
    assert s["phi"][0] == 0.0   # the velocity has turned onto F


def test_parametric_speed_law():
    # s = C tan(phi/2)**k / sin(phi) along the whole arc
    sl = LateralForceSlideExact(1.0, 0.5, 9.81, [3.0, 0.0], [0.0, 2.0])
    t = np.linspace(0, 0.99 * sl.t_stop, 50)
    s = sl.state(t)
    law = np.tan(s["phi"] / 2) ** sl.k / np.sin(s["phi"])
    C = s["speed"] / law
    assert np.max(np.abs(C / C[0] - 1)) <= 1e-12


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_straight_launch_along_and_against_the_load(sign):
    m, mu, g, F = 1.0, 0.5, 9.81, np.array([3.0, 0.0])
    sl = LateralForceSlideExact(m, mu, g, F, [sign * 2.0, 0.0])
    a, f = mu * g, 3.0
    dec = a - sign * f
    assert sl.t_stop == pytest.approx(2.0 / dec, rel=1e-15)
    t = np.linspace(0, sl.t_stop, 11)[:-1]
    s = sl.state(t)
    assert np.all(s["y"] == 0.0) and np.all(s["vy"] == 0.0)
    np.testing.assert_allclose(s["vx"], sign * (2.0 - dec * t), rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(s["x"], sign * (2.0 * t - 0.5 * dec * t * t), rtol=1e-14, atol=1e-15)
    assert np.all(s["phi"] == (0.0 if sign > 0 else math.pi))


def test_nearly_straight_launch_is_continuous():
    base = LateralForceSlideExact(1.0, 0.5, 9.81, [3.0, 0.0], [-2.0, 0.0])
    near = LateralForceSlideExact(1.0, 0.5, 9.81, [3.0, 0.0], [-2.0, 1e-9])
    assert near.t_stop == pytest.approx(base.t_stop, abs=1e-8)
    t = np.linspace(0, 1.0, 21)
    a, b = base.state(t), near.state(t)
    for key in ("x", "vx", "path"):
        np.testing.assert_allclose(a[key], b[key], atol=1e-7)


def test_incline_upward_launch_stops_and_sticks():
    inc = InclineSlideExact(math.radians(30), 2.0, launch_angle=math.pi)
    f = 9.81 * math.sin(math.radians(30))
    assert inc.t_stop == pytest.approx(2.0 / (2 * f), rel=1e-15)
    s = inc.state([inc.t_stop, 10.0])
    assert np.all(s["speed"] == 0.0) and s["x"][0] == s["x"][1]


def test_accelerating_slide_restarts_from_rest():
    # k < 1 launched up the slope: stop, then slip down with g (sin - mu cos)
    th, mu = math.radians(30), 0.2
    inc = InclineSlideExact(th, 1.0, mu=mu, launch_angle=math.pi)
    t = inc.t_stop + np.array([0.0, 0.5, 1.0])
    s = inc.state(t)
    acc = 9.81 * (math.sin(th) - mu * math.cos(th))
    np.testing.assert_allclose(s["vx"], acc * (t - inc.t_stop), rtol=1e-14, atol=1e-15)
    ref = inc.reference(t)
    np.testing.assert_allclose(s["x"], ref["x"], atol=1e-12)


def test_state_is_vectorised_and_shaped():
    inc = InclineSlideExact(math.radians(30), 2.0)
    t = np.linspace(0, 1, 6).reshape(2, 3)
    s = inc.state(t)
    assert set(s) == {"t", "x", "y", "vx", "vy", "speed", "phi", "path"}
    assert all(v.shape == (2, 3) for v in s.values())
    flat = inc.state(t.ravel())
    np.testing.assert_array_equal(s["x"].ravel(), flat["x"])
    assert inc.state(0.5)["x"].shape == ()


@given(theta=st.floats(0.05, 1.5), v0=st.floats(0.1, 10.0), phi0=st.floats(0.0, math.pi),
       mu_ratio=st.floats(0.2, 3.0))
def test_incline_hypothesis(theta, v0, phi0, mu_ratio):
    inc = InclineSlideExact(theta, v0, mu=mu_ratio * math.tan(theta), launch_angle=phi0)
    # k within rounding of 1 stops only after ~1e15 s: watch such slides over a bounded time
    T = 1.5 * inc.t_stop if inc.t_stop < 100 * v0 / 9.81 else min(2.0, 10 * v0 / 9.81)
    t = np.linspace(0, T, 7)
    s = inc.state(t)
    lhs = 0.5 * (s["speed"] ** 2 - v0 ** 2)
    rhs = inc.accel[0] * s["x"] - inc.decel * s["path"]
    assert np.max(np.abs(lhs - rhs)) <= 1e-12 * (v0 ** 2 + 9.81 * v0 * T)
    pos, vel = _max_rel(inc, t, s, inc.reference(t))
    assert pos <= 1e-11 and vel <= 1e-11


@given(m=st.floats(0.1, 10.0), mu=st.floats(0.05, 1.5), frac=st.floats(0.0, 0.95),
       angF=st.floats(-math.pi, math.pi), v=st.floats(0.1, 5.0), angv=st.floats(-math.pi, math.pi))
def test_lateral_force_hypothesis(m, mu, frac, angF, v, angv):
    g = 9.81
    F = frac * mu * m * g * np.array([math.cos(angF), math.sin(angF)])
    sl = LateralForceSlideExact(m, mu, g, F, v * np.array([math.cos(angv), math.sin(angv)]))
    assert math.isfinite(sl.t_stop) and sl.t_stop <= v / (mu * g * (1 - frac)) * (1 + 1e-12)
    assert sl.t_stop >= v / (mu * g * (1 + frac)) * (1 - 1e-12)
    t = np.append(np.linspace(0, sl.t_stop, 6), 2 * sl.t_stop)
    s = sl.state(t)
    assert s["speed"][-1] == 0.0 and s["speed"][-2] == 0.0
    pos, vel = _max_rel(sl, t, s, sl.reference(t))
    assert pos <= 1e-11 and vel <= 1e-11


@pytest.mark.parametrize("call, name", [
    (lambda: PlaneSlideExact(mu=-0.1), "mu"),
    (lambda: PlaneSlideExact(m=0.0), "m"),
    (lambda: PlaneSlideExact(v0=float("nan")), "v0"),
    (lambda: PlaneSlideExact(g=float("inf")), "g"),
    (lambda: InclineSlideExact(0.0, 1.0), "theta"),
    (lambda: InclineSlideExact(math.pi / 2, 1.0), "theta"),
    (lambda: InclineSlideExact(0.3, 1.0, mu=-1.0), "mu"),
    (lambda: InclineSlideExact(0.3, -1.0), "v0"),
    (lambda: InclineSlideExact(0.3, 1.0, launch_angle=4.0), "launch_angle"),
    (lambda: LateralForceSlideExact(1.0, 0.1, 9.81, [5.0, 0.0], [1.0, 0.0]), "F"),
    (lambda: LateralForceSlideExact(1.0, 0.1, 9.81, [0.1, 0.0, 0.0], [1.0, 0.0]), "F"),
    (lambda: LateralForceSlideExact(1.0, 0.1, 9.81, [0.1, 0.0], [1.0, np.nan]), "v0"),
    (lambda: ConstantLoadSlide([1.0, 0.0], -1.0, [1.0, 0.0]), "decel"),
    (lambda: reduced_reference([1.0], [1.0, 0.0], [0.0, 0.0], 1.0, rtol=0.0), "rtol"),
    (lambda: PlaneSlideExact().state([-1.0]), "t"),
])
def test_bad_input_names_the_parameter(call, name):
    with pytest.raises(ValueError, match=rf"\b{name}\b"):
        call()


def test_doctests():
    assert doctest.testmod(se).failed == 0
