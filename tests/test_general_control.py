"""The compiled general loop (lcp.timestepping.general_loop) on systems with a control schedule
whose control matrix B does not depend on q: each step's control correction is computed before the
run and the results are the Python loop's bit for bit; a B(t, q) that depends on q runs there too
(its correction computed each step: tests/test_compiled_control.py)."""
import casadi as ca
import numpy as np
import pytest

import lcp
from lcp.model.control import ControlSchedule
from lcp.model.schedule import AffineSchedule
from lcp.model.system import Contact, System
from lcp.numerics.jit import HAVE_NUMBA
from lcp.timestepping import codegen, general_loop
from lcp.timestepping.assembly import StepAssembly

pytestmark = pytest.mark.skipif(not HAVE_NUMBA or codegen.c_compiler() is None,
                                reason="needs numba and a C compiler")


def controlled_bowl(e=0.0, q_dependent=False, drag=0.0, kinked=False):
    """A point in a circular bowl pushed by a control force u (2 components); ``drag``: a quadratic
    drag (a force not affine in v: no force check under a schedule, as the Python loop); ``kinked``:
    the drag |v| v, whose derivative is NaN at v = 0 (a step that fails)."""
    q, v, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 2)
    r = ca.norm_2(q)
    push = ca.vertcat(u[0] * (1 + q[1] ** 2), u[1]) if q_dependent else u
    return System(q, v, ca.SX.eye(2), ca.vertcat(0, -9.81) + push
                  - drag * (ca.norm_2(v) if kinked else ca.dot(v, v)) * v, control=u, control_bounds=(-100, 100),
                  contacts=[Contact(gap=1.0 - r, tangent_jacobian=ca.horzcat(-q[1], q[0]) / r, mu=0.3, e=e)])


SCHEDULES = {
    "constant": ControlSchedule([0.0, 0.13, 0.41, 0.7], [[2.0, 0.0], [-3.0, 1.0], [0.5, -2.0]]),
    "linear": ControlSchedule([0.0, 0.2, 0.45, 0.7], [[0.0, 0.0], [4.0, 1.0], [-2.0, 3.0], [1.0, 0.0]],
                              hold="linear"),
    "affine": AffineSchedule([0.0, 0.25, 0.7], [[1.0, 0.0], [3.0, 2.0], [-2.0, 1.0], [0.0, -1.0]]),
    # pushes the point up out of the bowl (lift-off), then lets it fall back (impacts)
    "lift_off": ControlSchedule([0.0, 0.1, 0.25, 0.7], [[0.0, 0.0], [0.0, 20.0], [1.0, 0.0]]),
}


def _pair(system, t_end, q0, v0, h, monkeypatch, **kw):
    calls = []
    real = general_loop.run_general_loop

    def counted(*a, **k):
        calls.append(1)
        return real(*a, **k)

    monkeypatch.setattr(general_loop, "run_general_loop", counted)
    fast = lcp.simulate(system, t_end, h=h, q0=q0, v0=v0, fast=True, **kw)
    slow = lcp.simulate(system, t_end, h=h, q0=q0, v0=v0, fast=False, **kw)
    return fast, slow, len(calls)


def _same(a, b):
    assert a.status == b.status and a.message == b.message
    for name in ("t", "q", "v", "p_N", "p_T", "modes"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.shape == y.shape and np.array_equal(x, y), name
    assert [(i.t, i.contact, i.p_N) for i in a.impacts] == [(i.t, i.contact, i.p_N) for i in b.impacts]


@pytest.mark.parametrize("name", sorted(SCHEDULES))
@pytest.mark.parametrize("e, drag", [(0.0, 0.0), (0.5, 0.0), (0.0, 0.4)])
def test_scheduled_control_bit_for_bit(name, e, drag, monkeypatch):
    system = controlled_bowl(e=e, drag=drag).with_control(SCHEDULES[name])
    assert general_loop.applicable(system, StepAssembly(system, 1e-3, 0.5), None) is None
    fast, slow, calls = _pair(system, 0.7, [0.0, -1.0], [0.5, 0.0], 1e-3, monkeypatch)
    assert calls == 1
    assert slow.success, slow.message
    _same(fast, slow)
    if name == "lift_off":  # the contact opened and closed again
        assert slow.stats.free_steps > 0 and (e == 0.0 or len(slow.impacts) > 0)


def test_q_dependent_control_matrix_runs_compiled(monkeypatch):
    system = controlled_bowl(q_dependent=True).with_control(SCHEDULES["constant"])
    assert general_loop.applicable(system, StepAssembly(system, 1e-3, 0.5), None) is None
    fast, slow, calls = _pair(system, 0.3, [0.0, -1.0], [0.5, 0.0], 1e-3, monkeypatch)
    assert calls == 1
    _same(fast, slow)


def test_failure_same_status(monkeypatch):
    """A step whose data turn non-finite (|v| v at v = 0): the same status and message at the same step."""
    system = controlled_bowl(drag=0.4, kinked=True).with_control(SCHEDULES["linear"])
    fast, slow, calls = _pair(system, 0.7, [0.0, -1.0], [0.5, 0.0], 1e-3, monkeypatch)
    assert calls == 1 and slow.status == -2
    _same(fast, slow)


def test_overflow_same_status(monkeypatch):
    """An overflowing state (NaN gaps): no contact closes in either loop, and both stop non-finite."""
    system = controlled_bowl().with_control(SCHEDULES["lift_off"])
    fast, slow, calls = _pair(system, 0.7, [0.0, -1.0], [1e300, 0.0], 1e-3, monkeypatch)
    assert calls == 1 and slow.status == -2 and "Step 1 (t = 0.001)" in slow.message
    assert fast.status == slow.status and fast.message == slow.message
    for name in ("t", "q", "v", "p_N", "p_T"):  # the last saved state is NaN in both
        x, y = getattr(fast, name), getattr(slow, name)
        assert x.shape == y.shape and np.array_equal(x, y, equal_nan=True), name
    assert np.array_equal(fast.modes, slow.modes)


def test_constant_matrices_not_run_here(monkeypatch):
    """A scheduled block on a flat floor (constant matrices, a force of t): the Python loop's
    increment is assembled from the constant matrices, not the step Function: not run here (the
    constant compiled loop runs it: tests/test_compiled_control.py)."""
    q, v, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 1)
    block = System(q, v, ca.SX.eye(2), ca.vertcat(u, -9.81), control=u, control_bounds=(-50, 50),
                   contacts=[Contact(gap=q[1], tangent_jacobian=ca.horzcat(1, 0), mu=0.3)])
    system = block.with_control(ControlSchedule([0.0, 0.13, 0.5], [[2.0], [-3.0]]))
    assert general_loop.applicable(system, StepAssembly(system, 1e-3, 0.5), None) == "control"
    fast, slow, calls = _pair(system, 0.5, [0.0, 0.0], [0.5, 0.0], 1e-3, monkeypatch)
    assert calls == 0 and fast.solver == "auto (compiled)"
    _same(fast, slow)
