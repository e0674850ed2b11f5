"""One check of a start for both methods (lcp.model.start): a start within the tolerance is
projected onto the constraints and the message says so; beyond it a ValueError names the contact
or constraint; within rounding the start is taken as it is."""
import casadi as ca
import numpy as np
import pytest
from hypothesis import example, given, settings, strategies as st

import lcp
from lcp.model.start import START_TOL, consistent_start
from lcp.model.system import Contact, System
from lcp.scenes import jean_pratt

METHODS = ("moreau-jean", "event")


def _block(floor=0.0):
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    return System(q, v, ca.SX.eye(2), ca.vertcat(1.0, -9.81),
                  contacts=[Contact(gap=q[1] - floor, tangent=q[0], mu=0.1, name="floor")])


def _pendulum():
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    return System(q, v, ca.SX.eye(2), ca.vertcat(0, -9.81), constraints=q[0] ** 2 + q[1] ** 2 - 1)


@pytest.mark.parametrize("method", METHODS)
def test_a_block_deep_in_the_floor_is_refused(method):
    # it slid 10 cm inside the floor with success=True
    with pytest.raises(ValueError, match="penetrates contact 'floor' by 0.1"):
        lcp.simulate(_block(), 0.1, h=1e-3, method=method, q0=[0.0, -0.1], v0=[0.0, 0.0])
    with pytest.raises(ValueError, match="penetrates contact 'floor' by 0.1"):
        lcp.simulate(_block(floor=5.0), 0.1, h=1e-3, method=method, q0=[0.0, 4.9], v0=[0.0, 0.0])


@pytest.mark.parametrize("method", METHODS)
def test_a_scene_deep_in_the_floor_is_refused(method):
    # the constant-model paths (no System built) run the same check
    sc = jean_pratt()
    q0 = np.array(sc.q0, dtype=float)
    q0[1] = -0.1
    with pytest.raises(ValueError, match="penetrates contact"):
        lcp.simulate(sc, 0.1, method=method, q0=q0)


@pytest.mark.parametrize("method", METHODS)
def test_a_slight_penetration_is_projected_and_said(method):
    # 8.8e-7 below the floor (data rounded to a few digits): the event method refused it
    res = lcp.simulate(_block(), 0.05, h=1e-3, method=method, q0=[0.0, -8.8e-7], v0=[0.0, 0.0])
    assert res.success, res.message
    assert res.q[0, 1] == 0.0 and "start was projected" in res.message and "'floor'" in res.message
    assert np.min(res.q[:, 1]) >= 0.0


def test_a_scene_slightly_in_the_floor_is_projected():
    sc = jean_pratt()
    q0 = np.array(sc.q0, dtype=float)
    q0[1] -= 1e-6
    res = lcp.simulate(sc, 0.1, h=1e-3, q0=q0)
    assert res.success and "start was projected" in res.message
    assert sc.system.gaps(res.q[0])[0] == 0.0


@pytest.mark.parametrize("method", METHODS)
def test_a_violated_constraint_is_refused(method):
    # the pendulum jumped back onto its circle in the first step, with success=True
    with pytest.raises(ValueError, match="q0 violates bilateral constraint 0"):
        lcp.simulate(_pendulum(), 0.1, h=1e-3, method=method, q0=[0.6, -0.9], v0=[0.0, 0.0])
    with pytest.raises(ValueError, match="v0 violates the velocity form of bilateral constraint 0"):
        lcp.simulate(_pendulum(), 0.1, h=1e-3, method=method, q0=[0.6, -0.8], v0=[0.0, 1.0])


@pytest.mark.parametrize("method", METHODS)
def test_a_slightly_violated_constraint_is_projected(method):
    s = _pendulum()
    res = lcp.simulate(s, 0.05, h=1e-3, method=method, q0=[0.6, -0.8001], v0=[0.8, 0.6001])
    assert res.success, res.message
    assert "start was projected" in res.message and "q0 moved" in res.message and "v0 moved" in res.message
    q, v = res.q[0], res.v[0]
    assert abs(q @ q - 1) <= 64 * 2.3e-16 * 5 and abs(q @ v) <= 64 * 2.3e-16 * 2
    # the first step starts from the projected state: no jump
    assert np.max(np.abs(res.q[1] - res.q[0])) <= 1.2 * 1e-3 * np.max(np.abs(v)) + 1e-5


def test_a_consistent_start_is_taken_as_it_is():
    s = _pendulum()
    q0, v0 = np.array([0.6, -0.8]), np.array([0.8, 0.6])
    q, v, note = consistent_start(s, q0, v0)
    assert q is q0 and v is v0 and note is None
    # within rounding: untouched (a gap of -1e-199 at the origin, where |J||q| is zero)
    q, v, note = consistent_start(_block(), np.array([0.0, -1e-199]), np.zeros(2))
    assert note is None and q[1] == -1e-199


@settings(max_examples=40, deadline=None)
@given(rel=st.floats(1e-12, 1e-1), sign=st.sampled_from([-1.0, 1.0]), angle=st.floats(-3.0, 3.0))
@example(rel=1.192092896e-07, sign=-1.0, angle=0.0)  # (the bound taken at q0 failed by 3e-18)
def test_start_tolerance_is_relative_and_sharp(rel, sign, angle):
    """A pendulum start off its circle by ``rel`` of the constraint's size: projected (to rounding,
    with a note) within START_TOL, refused beyond it."""
    s = _pendulum()
    base = np.array([np.sin(angle), -np.cos(angle)])
    J = 2 * base
    size = np.abs(J) @ (np.abs(base) + 1.0 / np.max(np.abs(J))) + 1.0
    # move along the normal so that |phi| = rel * size (to first order; the check uses phi itself)
    r = (1 + sign * rel * size) ** 0.5
    q0 = r * base
    phi = abs(q0 @ q0 - 1)
    lim = np.abs(2 * q0) @ (np.abs(q0) + 1.0 / np.max(np.abs(2 * q0))) + 1.0
    if phi > START_TOL * lim:
        with pytest.raises(ValueError, match="bilateral constraint 0"):
            consistent_start(s, q0, np.zeros(2))
    else:
        q, v, note = consistent_start(s, q0, np.zeros(2))
        # rounding relative to the row's size at the projected point, where Newton stops (at q0,
        # inside the circle, the size is smaller: rel = 1.19e-7 left 5.684e-14 against a bound of
        # 5.6843e-14 there)
        lim_q = np.abs(2 * q) @ (np.abs(q) + 1.0 / np.max(np.abs(2 * q))) + 1.0
        assert abs(q @ q - 1) <= 64 * np.finfo(float).eps * lim_q
        if phi > 64 * np.finfo(float).eps * lim:
            assert note is not None and "bilateral constraint 0" in note
