"""The compiled general loop on systems with Newton-Euler kinematics qdot = T(q) v (free rigid bodies
with unit quaternions): the Python loop's results bit for bit, quaternions on their sphere, and the
pieces of NumPy the kernel repeats (pairwise sums)."""
import casadi as ca
import numpy as np
import pytest

import lcp
from lcp.model.rigid_body import bodies_system, free_body
from lcp.model.system import Contact, System
from lcp.numerics.jit import HAVE_NUMBA
from lcp.scenes.rigid_bodies import dzhanibekov, tumbling_box
from lcp.timestepping import codegen

pytestmark = pytest.mark.skipif(not HAVE_NUMBA or codegen.c_compiler() is None,
                                reason="needs numba and a C compiler")


def _same(a, b):
    """Compiled and Python runs: the same states, impulses, modes, counters and message."""
    assert a.status == b.status and a.message == b.message
    for x, y in ((a.q, b.q), (a.v, b.v), (a.p_N, b.p_N), (a.p_T, b.p_T)):
        assert x.shape == y.shape
        assert np.array_equal(x, y), float(np.max(np.abs(x - y)))
    assert np.array_equal(a.modes, b.modes)
    assert a.stats.mode_counts == b.stats.mode_counts and a.stats.free_steps == b.stats.free_steps
    assert [(i.t, i.contact) for i in a.impacts] == [(i.t, i.contact) for i in b.impacts]


def _python_loop_forbidden(monkeypatch):
    from lcp.timestepping import moreau_jean

    def refuse(*args, **kwargs):
        raise AssertionError("the Python loop ran")

    monkeypatch.setattr(moreau_jean, "run_python_loop", refuse)


def _hand_multi_over(monkeypatch):
    """Steps with several active contacts handed to the Python side (as before the kernel solved
    them, tests/test_general_multicontact.py): the rest of the kernel is then checked bit for bit."""
    from lcp.timestepping import general_loop

    monkeypatch.setattr(general_loop, "_cone_multi", lambda solver: (0, 0))


def test_dzhanibekov_compiled_equals_python_loop(monkeypatch):
    sc = dzhanibekov()
    b = lcp.simulate(sc, 1.0, h=1e-3, fast=False)
    _python_loop_forbidden(monkeypatch)
    a = lcp.simulate(sc, 1.0, h=1e-3)
    _same(a, b)
    assert np.max(np.abs(np.linalg.norm(a.q[:, 3:7], axis=1) - 1)) <= 1e-15


@pytest.mark.parametrize("kw", [{}, {"mu": 0.0, "v0": (0.7, -0.4, 0.0)}, {"e": 0.5}])
def test_tumbling_box_compiled_equals_python_loop(monkeypatch, kw):
    # free fall, impacts on corners, sliding and resting on a face: the projection runs every step
    sc = tumbling_box(**kw)
    b = lcp.simulate(sc, 1.2, h=1e-3, fast=False)
    _python_loop_forbidden(monkeypatch)
    _hand_multi_over(monkeypatch)
    a = lcp.simulate(sc, 1.2, h=1e-3)
    assert b.p_N.sum() > 0 and b.stats.projections > 0  # it reached the floor, projected
    _same(a, b)
    assert np.max(np.abs(np.linalg.norm(a.q[:, 3:7], axis=1) - 1)) <= 1e-15


def test_two_bodies_and_quaternion_rows_of_another_form(monkeypatch):
    # two bodies (n_v = 12: the activation's sizes by NumPy's pairwise sums) and a body whose
    # quaternion rows are not B p (p0' + 0.1 x vx): no exponential map, p + h (T w)_p normalised
    a_body = free_body(1.0, [1.0, 2.0, 3.0], name="a")
    b_body = free_body(2.0, [1.0, 1.0, 1.5], name="b")
    contacts = []
    for body in (a_body, b_body):
        for r in ([0.3, 0.2, -0.4], [-0.3, -0.2, -0.4]):
            P = body.point(r)
            contacts.append(Contact(gap=P[2], tangent=ca.vertcat(P[0], P[1]), mu=0.4, name=f"{body.name}{r[0]}"))
    two = bodies_system([a_body, b_body], contacts, gravity=9.81)
    q0 = np.r_[0, 0, 0.5, 1.0, 0, 0, 0, 1, 2, 0.6, 0.6, 0.8, 0, 0]
    v0 = np.r_[0.1, 0, 0, 0.3, 5.0, 0.2, 0, 0, 1, 2.0, -1.0, 0.5]
    o = free_body(1.0, np.eye(3), name="o")
    T = o.kinematics
    T[3, 0] = T[3, 0] + 0.1 * o.q[0]
    odd = System(o.q, o.v, o.mass_matrix, o.gyroscopic, kinematics=T, unit_quaternions=(3,))
    qo, vo = np.r_[1.0, 0, 0, 1, 0, 0, 0], np.r_[1.0, 0, 0, 0.2, 0, 2.0]
    refs = [lcp.simulate(s, 0.5, h=1e-3, q0=q, v0=v, fast=False) for s, q, v in ((two, q0, v0), (odd, qo, vo))]
    _python_loop_forbidden(monkeypatch)
    _hand_multi_over(monkeypatch)
    assert refs[0].p_N.sum() > 0  # both bodies reached the floor
    for (s, q, v), ref in zip(((two, q0, v0), (odd, qo, vo)), refs):
        _same(lcp.simulate(s, 0.5, h=1e-3, q0=q, v0=v), ref)


@pytest.mark.parametrize("n", [0, 1, 7, 8, 9, 15, 16, 17, 127, 128, 129, 300, 1000, 4099])
def test_pairwise_sum_is_numpys(n):
    from lcp.timestepping.kinematic_kernels import pairwise_sum

    rng = np.random.default_rng(n)
    for _ in range(20):
        x = np.abs(rng.standard_normal(n) * 10.0 ** rng.integers(-8, 8, n))
        assert pairwise_sum(x, 0, n) == np.vstack([x, x]).sum(axis=1)[0]
