"""Straight slides of the spatial event method in closed form (lcp.events.spatial_closed_form):
exact to round-off against the scenes' closed forms; curved slides stay numerical."""
import math

import numpy as np
import pytest

import lcp
from lcp import scenes
from lcp.events.spatial_closed_form import STRAIGHT_TOL

EPS = np.finfo(float).eps


def _errors(sc, res):
    """Max |q - exact| and |v - exact| over the in-plane coordinates (columns 0 and 1)."""
    ex = sc.solution.state(res.t)
    eq = max(np.max(np.abs(res.q[:, 0] - ex["x"])), np.max(np.abs(res.q[:, 1] - ex["y"])))
    ev = max(np.max(np.abs(res.v[:, 0] - ex["vx"])), np.max(np.abs(res.v[:, 1] - ex["vy"])))
    return float(eq), float(ev)


STRAIGHT = [
    ("plane", lambda: scenes.plane_slide()),
    ("plane-beta", lambda: scenes.plane_slide(v0=2.0, mu=0.5, g=10.0, beta=2.3)),
    ("incline-up", lambda: scenes.incline_slide(phi0=math.pi)),
    ("incline-up-slips", lambda: scenes.incline_slide(theta=0.3, mu=0.5 * math.tan(0.3), phi0=math.pi)),
    ("lateral-aligned", lambda: scenes.lateral_force_slide(F=(2.0, 1.0), v0=(1.0, 0.5))),
    ("lateral-opposed", lambda: scenes.lateral_force_slide(F=(-2.0, 0.0), v0=(1.5, 0.0))),
]


@pytest.mark.parametrize("name,make", STRAIGHT, ids=[s[0] for s in STRAIGHT])
def test_straight_slide_exact_to_round_off(name, make):
    sc = make()
    T = sc.t_end
    res = lcp.simulate(sc, T, method="event", t_eval=np.linspace(0.0, T, 1001))
    assert res.success, res.message
    assert res.phases[0].integrator == "closed-form"
    assert all(p.integrator == "closed-form" for p in res.phases)
    t_stop = sc.solution.t_stop
    assert abs(res.t_events[0] - t_stop) <= 1e-14 * t_stop
    V = float(np.max(np.abs(res.v[:, :2])))
    L = float(np.max(np.abs(res.q[:, :2])))
    eq, ev = _errors(sc, res)
    assert eq <= 1e-14 * L and ev <= 1e-14 * V, (eq, ev)


def test_curved_slide_stays_numerical():
    sc = scenes.lateral_force_slide()
    res = lcp.simulate(sc, sc.t_end, method="event")
    assert res.phases[0].integrator == "DOP853"
    eq, ev = _errors(sc, res)
    assert eq < 2e-13 and ev < 2e-12
    assert abs(res.t_events[0] - sc.solution.t_stop) < 1e-13


@pytest.mark.parametrize("lateral", [1e-9, 1e-12])
def test_tiny_lateral_force_is_not_straight(lateral):
    # the cross product is far above rounding: the closed form must not be taken
    assert lateral / 2.0 > 100 * STRAIGHT_TOL
    sc = scenes.lateral_force_slide(F=(2.0, lateral), v0=(1.5, 0.0))
    res = lcp.simulate(sc, sc.t_end, method="event")
    assert res.success, res.message
    assert res.phases[0].integrator == "DOP853"
    eq, ev = _errors(sc, res)
    assert eq < 1e-12 and ev < 1e-12, (eq, ev)
    # and the lateral drift it produces is there (a straight closed form would give exactly 0)
    assert np.max(np.abs(res.q[:, 1])) > 0.0


def test_incline_across_stays_numerical():
    sc = scenes.incline_slide()   # launched across the slope: curved
    res = lcp.simulate(sc, 0.5, method="event")
    assert res.phases[0].integrator == "DOP853"
    eq, ev = _errors(sc, res)
    assert eq < 1e-13 and ev < 1e-12
