"""A state or a force that overflows stops every Moreau-Jean path the same way: status -2, the message
"The state became non-finite. Step k (t = ...)." at the same step, the same saved arrays, never an
exception from a contact solver handed infinities.

- the compiled single-contact step, the compiled many-contact loop (up to and beyond the 16
  contacts where the activation rule switches from Python's max to NumPy's) and the compiled loop
  of spatial contacts against the Python loop (``fast=False``);
- the activation rule's "every contact closes" test decides NaN predictions in the kernels as the
  Python rule does;
- a finite state whose entries' sum overflows is not taken for a non-finite one;
- a contact row that the overflow made zero (W = 0) is a solver failure, handled by the fallback in
  both loops alike, not a ZeroDivisionError.
"""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import lcp
from lcp.model.system import Contact, System
from lcp.numerics.jit import HAVE_NUMBA
from lcp.timestepping.activation import LIST_MAX_CONTACTS
from lcp.timestepping.compiled_kernels import all_closing


def _blocks(K, spatial, force_x=0.0, force_y=-9.81, mass=1.0):
    """K independent point masses on the floor (coordinates (x, y) or (x, z, y)), one contact each."""
    d = 3 if spatial else 2
    n = d * K
    q, v = ca.SX.sym("q", n), ca.SX.sym("v", n)
    f = np.zeros(n)
    f[0::d], f[d - 1::d] = force_x, force_y
    if spatial:
        contacts = [Contact(gap=q[3 * i + 2], tangent=ca.vertcat(q[3 * i], q[3 * i + 1]), mu=0.3, name=f"P{i}")
                    for i in range(K)]
    else:
        contacts = [Contact(gap=q[2 * i + 1], tangent=q[2 * i], mu=0.3, name=f"P{i}") for i in range(K)]
    return System(q, v, ca.diag(ca.SX(np.full(n, mass))), ca.SX(f), contacts=contacts)


def _start(K, spatial, what):
    d = 3 if spatial else 2
    q0, v0 = np.zeros(d * K), np.zeros(d * K)
    if what == "near_max":  # x runs past the largest float within a few steps
        q0[0], v0[0] = 1.79e308, 1e308
    elif what == "all_huge":  # finite, but the sum of the entries overflows
        v0[0::d] = 1.7e308
    return q0, v0


CASES = {  # name: (system arguments, start)
    "near_max": ({}, "near_max"),
    "sideways_force": ({"force_x": 1e308, "mass": 1e-10}, "rest"),
    "downward_force": ({"force_y": -1e308, "mass": 1e-10}, "rest"),
    "all_huge": ({}, "all_huge"),
}


def _same(a, b):
    assert a.status == b.status and a.message == b.message
    for name in ("t", "q", "v", "p_N", "p_T"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.shape == y.shape and np.array_equal(x, y, equal_nan=True), name
    assert np.array_equal(a.modes, b.modes)


@pytest.mark.skipif(not HAVE_NUMBA, reason="the compiled loops need numba")
@pytest.mark.parametrize("K, spatial", [(1, False), (3, False), (20, False), (1, True)])
@pytest.mark.parametrize("case", sorted(CASES))
def test_the_compiled_paths_stop_as_the_python_loop(K, spatial, case):
    kw, start = CASES[case]
    q0, v0 = _start(K, spatial, start)
    fast = lcp.simulate(_blocks(K, spatial, **kw), 0.2, h=1e-3, q0=q0, v0=v0)
    slow = lcp.simulate(_blocks(K, spatial, **kw), 0.2, h=1e-3, q0=q0, v0=v0, fast=False)
    assert fast.solver.endswith("(compiled)") and not slow.solver.endswith("(compiled)")
    if case == "all_huge":
        assert slow.status == 0, slow.message
    else:
        assert slow.status == -2 and slow.message.startswith("The state became non-finite. Step ")
    _same(fast, slow)


def test_a_finite_state_whose_sum_overflows_is_finite():
    """1.7e308 in three coordinates: their sum overflows, no entry does; the run goes on."""
    q0, v0 = _start(3, False, "all_huge")
    res = lcp.simulate(_blocks(3, False), 0.01, h=1e-3, q0=q0, v0=v0, fast=False)
    assert res.status == 0 and np.all(np.isfinite(res.q)) and res.q.shape[0] == 11
    res2 = lcp.simulate(_blocks(3, False), 0.01, h=1e-3, q0=q0, v0=v0, fast=False, scheme="order2")
    assert res2.status == 0 and np.all(np.isfinite(res2.q))


def _python_rule(pred):
    """The test of lcp.timestepping.activation.Activation: every predicted gap <= 0."""
    return (max(pred.tolist()) if pred.size <= LIST_MAX_CONTACTS else pred.max()) <= 0.0


@settings(max_examples=300, deadline=None)
@given(st.lists(st.one_of(st.floats(-1.0, 1.0), st.sampled_from([np.nan, np.inf, -np.inf, 0.0, -0.0])),
                min_size=1, max_size=24))
def test_the_kernels_every_contact_closes_test_is_the_python_rule(values):
    gap = np.array(values)
    m = gap.size
    zeros = np.zeros(m)
    rule = all_closing.py_func if hasattr(all_closing, "py_func") else all_closing
    # with u = 0 the prediction is the gap itself: (gap + 0) + 0 keeps NaN, inf and the sign of zero
    assert rule(m, gap, zeros, zeros, 0.5e-3, 0.5e-3) == _python_rule((gap + 0.5e-3 * zeros) + 0.5e-3 * zeros)


@pytest.mark.skipif(not HAVE_NUMBA, reason="compiled")
def test_the_compiled_every_contact_closes_test_is_the_python_rule():
    from numba import njit

    @njit
    def call(m, gap, u, a, b):
        return all_closing(m, gap, u, u, a, b)

    rng = np.random.default_rng(1)
    for m in (1, 2, 16, 17, 30):
        for _ in range(200):
            gap = rng.normal(size=m)
            gap[rng.random(m) < 0.2] = np.nan
            gap[rng.random(m) < 0.1] = np.inf
            u = np.zeros(m)
            assert call(m, gap, u, 0.5e-3, 0.5e-3) == _python_rule(gap), gap


def _bowl():
    """A point in a circular bowl: at |q| ~ 1e297 the norm in its gap overflows and the contact
    rows become zero (W = 0)."""
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    r = ca.norm_2(q)
    return System(q, v, ca.SX.eye(2), ca.vertcat(0, -9.81),
                  contacts=[Contact(gap=1.0 - r, tangent_jacobian=ca.horzcat(-q[1], q[0]) / r, mu=0.3)])


def test_a_zero_contact_row_is_a_solver_failure_not_an_exception():
    from lcp.contact.problem import ContactProblem
    from lcp.contact.solvers import EnumSolver

    sol = EnumSolver().solve(ContactProblem(np.zeros((2, 2)), np.array([-1.0, 0.5]), [0.3]))
    assert sol.status == -1 and "not positive" in sol.message
    from lcp.timestepping.compiled_kernels import enum_one  # the kernels' closed form: no case either

    assert enum_one(0.0, 0.0, 0.0, 1.0, -1.0, 0.5, 0.3)[2] == -1 and enum_one(1.0, 0.0, 0.0, 0.0, -1.0, 0.5, 0.3)[2] == -1


@pytest.mark.skipif(not HAVE_NUMBA, reason="the compiled general loop needs numba")
def test_an_overflowing_bowl_runs_the_same_in_both_loops_without_projection():
    """v0 = 1e300: from step 1 the gap's norm overflows (zero contact rows); the closed form hands
    those steps to the Python solver, whose fallback takes them, in both loops alike (no
    ZeroDivisionError from the closed form)."""
    from lcp.timestepping import codegen

    if codegen.c_compiler() is None:
        pytest.skip("needs a C compiler")
    kw = dict(h=1e-3, q0=[0.0, -1.0], v0=[1e300, 0.0], projection=False)
    fast = lcp.simulate(_bowl(), 0.05, **kw)
    slow = lcp.simulate(_bowl(), 0.05, fast=False, **kw)
    assert fast.stats.fallbacks == slow.stats.fallbacks > 0
    _same(fast, slow)
