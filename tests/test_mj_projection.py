"""Moreau-Jean with position projection: nonlinear constraints kept to tolerance, linear systems
untouched, failures reported."""
import math

import casadi as ca
import numpy as np
import pytest

import lcp
from lcp.classical import pendulum
from lcp.timestepping.projection import PositionProjection, needs_projection
from lcp.scenes import jean_pratt
from lcp.model.system import Contact, System


def _length_error(res, L=1.0):
    return float(np.max(np.abs(np.hypot(res.q[:, 0], res.q[:, 1]) - L))) / L


def test_pendulum_keeps_its_length_and_reports_the_violation():
    sc = pendulum(periods=5)
    res = lcp.simulate(sc, h=1e-3)
    assert res.success, res.message
    assert _length_error(res) <= 1e-10
    assert res.stats.projections == res.stats.steps > 0
    assert 2 * res.stats.projections <= res.stats.projection_iterations <= 4 * res.stats.projections
    assert res.max_constraint_violation <= 1e-10 * 2  # |x^2 + y^2 - L^2| <= tol 2 L^2
    # the unprojected scheme drifts (the reason for the projection), and says so in its violation
    raw = lcp.simulate(sc, h=1e-3, projection=False)
    assert raw.success and raw.stats.projections == 0
    drift = float(np.max(np.abs(raw.q[:, 0] ** 2 + raw.q[:, 1] ** 2 - 1.0)))
    assert drift > 1e-2
    assert raw.max_constraint_violation == pytest.approx(drift, rel=1e-12)


@pytest.mark.slow
def test_pendulum_100_periods():
    sc = pendulum(periods=100)
    res = lcp.simulate(sc, h=1e-3, save_every=10)
    assert res.success, res.message
    assert _length_error(res) <= 1e-10
    assert res.max_constraint_violation <= 2e-10


def test_linear_systems_are_not_projected_and_unchanged():
    sc = jean_pratt(coordinates="full")  # a linear bilateral constraint
    assert not needs_projection(sc.system)
    auto = lcp.simulate(sc, 0.3, h=1e-3)
    off = lcp.simulate(sc, 0.3, h=1e-3, projection=False)
    assert auto.stats.projections == 0
    np.testing.assert_array_equal(auto.q, off.q)
    forced = lcp.simulate(sc, 0.3, h=1e-3, projection=True)
    assert forced.success and forced.stats.projections == forced.stats.steps
    np.testing.assert_allclose(forced.q, off.q, atol=1e-13)


def test_needs_projection_decides_from_the_jacobians():
    q, v, t = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("t")
    flat = System(q, v, ca.SX.eye(2), [0, -9.81], contacts=[Contact(gap=q[1] - 0.5 * q[0], tangent=q[0])])
    curved = System(q, v, ca.SX.eye(2), [0, -9.81], contacts=[Contact(gap=q[1] - q[0] ** 2, tangent=q[0])])
    moving = System(q, v, ca.SX.eye(2), [0, -9.81], constraints=[q[0] - ca.sin(t)], t=t)
    shifted = System(q, v, ca.SX.eye(2), [0, -9.81], constraints=[q[0] - 2 * t], t=t)
    assert [needs_projection(s) for s in (flat, curved, moving, shifted)] == [False, True, True, False]


def test_bead_inside_a_circular_track_stays_on_it():
    # a frictionless bead inside a circle of radius 1 (unilateral: gap 1 - x^2 - y^2 >= 0) moves as
    # the pendulum while the track pushes (60 degrees: N = m (g cos + L thd^2) > 0 throughout)
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    s = System(q, v, ca.SX.eye(2), [0, -9.81], contacts=[Contact(gap=1 - q[0] ** 2 - q[1] ** 2,
                                                               tangent_jacobian=ca.horzcat(-q[1], q[0]))])
    ref = pendulum(theta0=math.pi / 3)
    T = 2 * ref.solution.period
    errs = {}
    for h in (2e-3, 1e-3):
        res = lcp.simulate(s, T, h=h, q0=ref.q0, v0=ref.v0)
        assert res.success and res.stats.projections == res.stats.steps
        gaps = 1 - res.q[:, 0] ** 2 - res.q[:, 1] ** 2
        assert gaps.min() >= -2e-12 and gaps.max() <= 2e-12  # closed and loaded: held at g = 0
        assert not np.any(res.modes == -1)
        errs[h] = np.max(np.abs(res.q - ref.exact(res.t)["q"]))
    assert errs[1e-3] <= 0.6 * errs[2e-3]  # converges (first order: G taken at the step's start)
    raw = lcp.simulate(s, T, h=1e-3, q0=ref.q0, v0=ref.v0, projection=False)
    assert raw.max_constraint_violation > 1e-3  # the unprojected bead sinks into the track


def test_projection_failure_is_reported():
    # a cylinder x^2 + y^2 = 1 and a plane x = 2 never meet: the start is refused (lcp.model.start),
    # and the projection's Newton iteration cannot converge
    q, v = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
    s = System(q, v, ca.SX.eye(3), [0, 0, -9.81], constraints=[q[0] ** 2 + q[1] ** 2 - 1, q[0] - 2])
    with pytest.raises(ValueError, match="bilateral constraint 1 by 1.4"):
        lcp.simulate(s, 0.01, h=1e-3, q0=[0.6, 0.8, 0.0], v0=[0, 0, 0])
    assert not PositionProjection(s).project(0.0, np.array([0.6, 0.8, 0.0]))[1]
    # a circle shrinking to nothing at t = 0.1 (x^2 + y^2 = 1 - 10 t): the run stops there
    q, v, t = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("t")
    s = System(q, v, ca.SX.eye(2), [0, -9.81], t=t, constraints=q[0] ** 2 + q[1] ** 2 - 1 + 10 * t)
    res = lcp.simulate(s, 0.2, h=1e-3, q0=[0.6, 0.8], v0=[-3.0, -4.0])
    assert res.status == -5 and not res.success
    assert "projection did not converge" in res.message and "Step 99" in res.message
    assert res.t.size == 100  # nothing past the failure


def test_projector_contact_working_set():
    # a point below a parabola floor y >= x^2 is pushed out; one above it is left alone
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    s = System(q, v, ca.SX.eye(2), [0, -9.81], contacts=[Contact(gap=q[1] - q[0] ** 2, tangent=q[0])])
    P = PositionProjection(s)
    qp, ok, _, viol = P.project(0.0, np.array([0.5, 0.2]))
    assert ok and abs(qp[1] - qp[0] ** 2) <= 1e-12 and viol <= 1e-12
    # a small correction: Newton steps of least norm, about the linearized distance |g| / |grad g|
    d = np.array([0.5, 0.2]) - qp
    assert np.linalg.norm(d) <= 1.05 * 0.05 / math.hypot(1.0, 1.0)
    P.reset()
    above = np.array([0.5, 0.3])
    qa, ok, _, _ = P.project(0.0, above)
    assert ok and np.array_equal(qa, above)
    # held closed: pulled down onto the curve
    qc, ok, _, _ = P.project(0.0, above, closed=[True])
    assert ok and abs(qc[1] - qc[0] ** 2) <= 1e-12
