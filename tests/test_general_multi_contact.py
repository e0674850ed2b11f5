"""Steps with several active planar contacts solved inside the compiled general loop's kernel
(lcp.timestepping.planar_multi_kernels), against the Python loop: bit for bit where the solver's
sweeps converge before any Newton iteration (the box on its corners), to rounding where Newton
iterations were taken (the rocking block at rest, the slider-crank with clearance); the tangential
impulses of redundant contacts (a block flat on two sticking corners: only their sum is unique)
to the documented 1e-7. Every such step is counted in ``stats.kernel_multi_steps``, none goes back
to Python (``stats.python_steps``) unless the kernel cannot take it, and those that go back carry
the Python loop's notes."""
import math

import casadi as ca
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import lcp
from lcp.contact.problem import ContactProblem
from lcp.contact.solvers import AutoSolver
from lcp.model.system import Contact, System
from lcp.numerics.jit import HAVE_NUMBA
from lcp.scenes.bowl_rod import impacting_rod
from lcp.scenes.classical import box_on_corners, rocking_block
from lcp.scenes.slider_crank_clearance import slider_crank_clearance
from lcp.timestepping import codegen

pytestmark = pytest.mark.skipif(not HAVE_NUMBA or codegen.c_compiler() is None,
                                reason="needs numba and a C compiler")

_FAST = settings(max_examples=5, deadline=None, derandomize=True,
                 suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def _block(theta0=0.1, mu=2.0, e=0.0, b=0.1, h=0.4, m=1.0, g=9.81):
    """Housner's block (lcp.scenes.classical.rocking_block's system) with restitution e at both
    corners: (system, q0), released from rest tilted by theta0 about its left corner."""
    q, v = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
    c, s = ca.cos(q[2]), ca.sin(q[2])
    corners = [ca.vertcat(q[0] + a * c + h * s, q[1] + a * s - h * c) for a in (-b, b)]
    contacts = [Contact(gap=p[1], tangent=p[0], mu=mu, e=e, name=nm) for p, nm in zip(corners, ("back", "front"))]
    I = m * (4 * b * b + 4 * h * h) / 12
    system = System(q, v, ca.diag(ca.vertcat(m, m, I)), ca.vertcat(0, -m * g, 0), contacts=contacts)
    c0, s0 = math.cos(theta0), math.sin(theta0)
    return system, np.array([b * c0 - h * s0, b * s0 + h * c0, theta0])


def _block_on_belt(acc=1.0, amp=0.0005, omega=20.0, mu=0.5, b=0.1, h=0.4, m=1.0, g=9.81):
    """The block standing on both corners on a belt that starts from rest with acceleration
    ``acc`` and shakes vertically by amp sin(omega t): moving contacts (their rates b enter every
    step's problem). Below mu g and g b / h the block rides on both corners."""
    q, v, t = ca.SX.sym("q", 3), ca.SX.sym("v", 3), ca.SX.sym("t")
    c, s = ca.cos(q[2]), ca.sin(q[2])
    floor = amp * ca.sin(omega * t)
    corners = [ca.vertcat(q[0] + a * c + h * s, q[1] + a * s - h * c) for a in (-b, b)]
    contacts = [Contact(gap=p[1] - floor, tangent=p[0] - 0.5 * acc * t * t, mu=mu, name=nm)
                for p, nm in zip(corners, ("back", "front"))]
    I = m * (4 * b * b + 4 * h * h) / 12
    system = System(q, v, ca.diag(ca.vertcat(m, m, I)), ca.vertcat(0, -m * g, 0), contacts=contacts, t=t)
    return system, np.array([0.0, h, 0.0])


def _multi(r) -> int:
    """Steps with two or more active contacts (every step saved)."""
    return int(np.sum(np.sum(r.modes >= 0, axis=1) >= 2))


def _same_bits(a, b):
    assert a.status == b.status and a.message == b.message
    for name in ("t", "q", "v", "p_N", "p_T", "modes"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    for name in ("solver_calls", "free_steps", "iterations", "max_iterations", "mode_counts", "ambiguous_steps",
                 "fallbacks", "max_residual"):
        assert getattr(a.stats, name) == getattr(b.stats, name), name
    assert a.impacts == b.impacts


def _close(a, b, rtol=1e-12, split=None):
    """Agreement to rounding: status and message, positions, velocities, normal impulses and each
    step's sum of tangential impulses to ``rtol`` of their size; the tangential impulses contact by
    contact to ``split`` (None: rtol) of theirs."""
    assert a.status == b.status and a.message == b.message
    assert a.q.shape == b.q.shape
    for x, y in ((a.q, b.q), (a.v, b.v), (a.p_N, b.p_N), (a.p_T.sum(axis=1), b.p_T.sum(axis=1))):
        assert np.max(np.abs(x - y)) <= rtol * max(1.0, float(np.max(np.abs(y)))), float(np.max(np.abs(x - y)))
    assert np.max(np.abs(a.p_T - b.p_T)) <= (split or rtol) * max(1e-3, float(np.max(np.abs(b.p_T))))
    assert a.stats.solver_calls == b.stats.solver_calls and a.stats.free_steps == b.stats.free_steps
    assert [i.contact for i in a.impacts] == [i.contact for i in b.impacts]
    np.testing.assert_allclose([i.t for i in a.impacts], [i.t for i in b.impacts], rtol=0, atol=1e-12)


def _both(system_or_scene, t_end, h, **kw):
    b = lcp.simulate(system_or_scene, t_end, h=h, fast=False, **kw)
    a = lcp.simulate(system_or_scene, t_end, h=h, **kw)
    assert b.stats.kernel_multi_steps == 0 and b.stats.python_steps == 0
    return a, b


@pytest.mark.parametrize("kw", [dict(), dict(mu=1.2, push_height=0.45)], ids=["slides", "tips"])
def test_box_on_its_corners_bit_for_bit(kw):
    a, b = _both(box_on_corners(**kw), 1.2, 1e-3)
    _same_bits(a, b)
    assert _multi(b) > 500 and a.stats.kernel_multi_steps == _multi(b)
    assert a.stats.python_steps == 0


@pytest.mark.parametrize("e", [0.0, 0.5])
def test_impacting_rod_bit_for_bit(e):
    # the rod lands on one end, then the other, and slides on both (sweeps converge: same bits)
    a, b = _both(impacting_rod(e=e), 1.0, 1e-3)
    _same_bits(a, b)
    assert a.stats.kernel_multi_steps == _multi(b) > 50 and a.stats.python_steps == 0


def test_rocking_block_rocking_phase():
    a, b = _both(rocking_block(), 1.5, 1e-3)
    _close(a, b, 1e-13)
    assert a.stats.kernel_multi_steps == _multi(b) > 0 and a.stats.python_steps == 0
    assert a.stats.mode_counts == b.stats.mode_counts and len(a.impacts) == len(b.impacts) > 3


def test_rocking_block_at_rest():
    # the rocking dies out by t = 2.6 s; then both corners stick every step: Newton's matrix is
    # singular (four rows, three velocities) and only the tangential impulses' sum is unique
    a, b = _both(rocking_block(), 4.0, 1e-3)
    _close(a, b, 1e-12, split=1e-6)
    assert a.stats.kernel_multi_steps == _multi(b) > 300 and a.stats.python_steps == 0
    assert a.stats.mode_counts == b.stats.mode_counts
    for r in (a, b):  # at rest on both corners: y at the half-height, no rotation
        assert abs(r.q[-1, 1] - 0.4) <= 1e-9 and abs(r.q[-1, 2]) <= 1e-9 and np.max(np.abs(r.v[-1])) <= 1e-9
        assert np.all(r.modes[-1] == 1)


@pytest.mark.parametrize("e", [0.0, 0.5])
def test_rocking_block_with_restitution(e):
    system, q0 = _block(theta0=0.12, e=e)
    a, b = _both(system, 1.2, 1e-3, q0=q0, v0=np.zeros(3))
    _close(a, b, 1e-12, split=1e-6)
    assert a.stats.python_steps == 0 and a.stats.kernel_multi_steps == _multi(a) > 0


def test_block_on_a_moving_shaking_belt():
    # moving contacts: the belt carries the block along (stuck on both corners) while the floor
    # shakes; then a belt too fast for friction makes it slip
    # (without the position projection, which the compiled loop does not do on moving contacts)
    system, q0 = _block_on_belt()
    a, b = _both(system, 0.5, 1e-3, q0=q0, v0=np.zeros(3), projection=False)
    # stuck on both corners, the split of the tangential impulse is rounding: the Python loop's own
    # moves by up to 2e-4 of the largest p_T when q of its problem changes by one ulp
    _close(a, b, 1e-12, split=1e-3)
    assert a.stats.kernel_multi_steps == _multi(a) > 400 and a.stats.python_steps == 0
    assert abs(b.v[-1, 0] - 0.5) <= 1e-3  # carried at the belt's speed, acc t
    system, q0 = _block_on_belt(acc=2.2, mu=0.2)
    a, b = _both(system, 0.3, 1e-3, q0=q0, v0=np.zeros(3), projection=False)
    _close(a, b, 1e-12, split=1e-6)
    assert a.stats.kernel_multi_steps == _multi(a) > 200 and a.stats.python_steps == 0
    assert b.stats.mode_counts["slide-"] > 200


def test_slider_crank_with_clearance():
    # the slider's corners hit the guide from t = 0.026 s; two opposite corners at once are
    # redundant (their normals' velocities sum to a constant), solved by Newton with its shift
    a, b = _both(slider_crank_clearance(), 0.05, 1e-5)
    _close(a, b, 1e-12)
    # (one step of the Python loop activates a third corner, open, that the compiled loop's
    # rounding leaves inactive: a gap prediction at the activation threshold)
    assert a.stats.kernel_multi_steps == _multi(a) > 300 and a.stats.python_steps == 0


@_FAST
@given(mu=st.floats(0.15, 1.5), push=st.floats(0.1, 0.5))
def test_box_drawn_bit_for_bit(mu, push):
    a, b = _both(box_on_corners(mu=mu, push_height=push), 0.4, 1e-3)
    _same_bits(a, b)
    assert a.stats.kernel_multi_steps == _multi(b) and a.stats.python_steps == 0


@_FAST
@given(theta0=st.floats(0.02, 0.2), mu=st.floats(0.8, 3.0), e=st.sampled_from([0.0, 0.3, 0.7]))
def test_block_drawn_as_the_python_loop(theta0, mu, e):
    system, q0 = _block(theta0=theta0, mu=mu, e=e)
    a, b = _both(system, 0.6, 1e-3, q0=q0, v0=np.zeros(3))
    _close(a, b, 1e-11, split=1e-6)
    assert a.stats.kernel_multi_steps == _multi(a) and a.stats.python_steps == 0


@pytest.mark.parametrize("scene", [box_on_corners, rocking_block])
def test_nsgs_by_name(scene):
    # "nsgs": its sweeps alone (no Newton), the same kernel: the Python loop's bits (its steps with
    # one active contact are not the closed form's: the same kernel takes them, no bilateral
    # constraint here; tests/test_compiled_routes.py)
    a, b = _both(scene(), 1.2 if scene is box_on_corners else 3.2, 1e-3, solver="nsgs")
    _same_bits(a, b)
    assert _multi(b) > 10
    assert a.stats.kernel_multi_steps == _multi(b) + int(np.sum(np.sum(b.modes >= 0, axis=1) == 1))
    assert a.stats.python_steps == 0


def test_a_solver_the_kernel_does_not_take_runs_in_python():
    # an error target of the solver's own: every step with two active contacts goes back to Python
    solver = AutoSolver(error_tol=1e-11)
    a, b = _both(box_on_corners(), 0.3, 1e-3, solver=solver)
    _same_bits(a, b)
    assert a.stats.kernel_multi_steps == 0 and a.stats.python_steps == _multi(b) > 0


def test_failed_kernel_solves_go_back_with_the_python_notes():
    # a residual tolerance at the rounding level: Newton often stops short of it, and the Python
    # side retries those steps by Lemke (a fallback, counted); the kernel hands them back
    b = lcp.simulate(box_on_corners(), 0.3, h=1e-3, fast=False, solver=AutoSolver(residual_tol=1e-15))
    a = lcp.simulate(box_on_corners(), 0.3, h=1e-3, solver=AutoSolver(residual_tol=1e-15))
    # the box stuck on both corners is redundant: where one loop's step is Lemke's and the other's
    # Newton's, the split of the tangential impulse differs (their sum does not)
    _close(a, b, 1e-12, split=np.inf)
    assert a.stats.python_steps > 50 and a.stats.kernel_multi_steps > 50
    assert a.stats.python_steps + a.stats.kernel_multi_steps == _multi(a)
    # (a step whose Newton meets 1e-15 under one LU's rounding and not the other's may differ)
    assert 0 < a.stats.fallbacks <= a.stats.python_steps and abs(a.stats.fallbacks - b.stats.fallbacks) <= 5


def _random_step(rng, k, n):
    """A planar step of k contacts on n velocities as the kernel's column-major buffers."""
    r = 2 * k
    H = rng.standard_normal((r, n))
    SHt = np.diag(rng.uniform(0.5, 2.0, n)) @ H.T
    W = H @ SHt
    v = rng.standard_normal(n)
    dvf = rng.standard_normal(n) * 0.1 - 0.5 * (H[:k].T @ np.ones(k)) / k
    return r, W, H, SHt, v, dvf


@pytest.mark.parametrize("seed", range(10))
def test_kernel_solve_is_a_coulomb_solution(seed):
    from lcp.timestepping.planar_multi_kernels import planar_multi_step

    rng = np.random.default_rng(seed)
    k = 2 + seed % 3
    r, W, H, SHt, v, dvf = _random_step(rng, k, n=2 * k + 1 + seed % 2)
    n = v.size
    mu = rng.uniform(0.0, 1.0, k)
    istate, fstate = np.zeros(19, dtype=np.int64), np.zeros(3)
    dv, P, MD = np.empty(n), np.empty(2 * k), np.empty(k, dtype=np.int64)
    ok = planar_multi_step(np.arange(k), k, k, n, r, W.ravel(order="F"), H.ravel(order="F"), SHt.ravel(order="F"),
                           np.zeros(0), False, v, v + dvf, dvf, np.zeros(k), mu, np.zeros(k), 1e-10,
                           np.array([40, 20, 30, 10]), istate, fstate, dv, P, MD)
    if not ok:  # handed to Python: nothing counted
        assert istate[18] == 0 and istate[2] == 0
        return
    assert istate[18] == 1 and istate[2] == 1
    pb = ContactProblem(W, H @ (v + dvf), mu)
    assert pb.residual(P) <= 1e-9 * max(pb.scale, float(np.max(np.abs(P))))
    np.testing.assert_allclose(dv, dvf + SHt @ P, rtol=0, atol=1e-12 * max(1.0, float(np.max(np.abs(dv)))))
    ref = AutoSolver().solve(pb)
    assert ref.success
    assert np.max(np.abs(pb.velocity(P) - pb.velocity(ref.p))) <= 1e-8 * max(1.0, float(np.max(np.abs(pb.q))))
    np.testing.assert_array_equal(MD, pb.modes(P))


def _handed_steps(monkeypatch, scene, t_end):
    """(data, Python's answer) of each step with two or more active contacts that the compiled
    general loop hands to the Python contact step with its planar kernel switched off."""
    from lcp.timestepping import general_loop

    recs = []
    orig = general_loop.ContactStep.solve

    def solve(self, k, tk, active, v, vfree, dvf, SHt, W, H, uNm, b=None):
        out = orig(self, k, tk, active, v, vfree, dvf, SHt, W, H, uNm, b)
        if active.size >= 2:
            recs.append(((active.copy(), v.copy(), vfree.copy(), dvf.copy(), SHt.copy(), W.copy(), H.copy(),
                          uNm.copy(), np.asarray(self.mu, dtype=float), np.asarray(self.e, dtype=float)), out))
        return out

    with monkeypatch.context() as mp:
        mp.setattr(general_loop, "_planar_multi", lambda solver, asm: np.zeros(4, dtype=np.int64))
        mp.setattr(general_loop.ContactStep, "solve", solve)
        lcp.simulate(scene, t_end, h=1e-3)
    return recs


def _kernel(data, fn=None):
    from lcp.timestepping.planar_multi_kernels import planar_multi_step

    active, v, vfree, dvf, SHt, W, H, uNm, mu, e = data
    m, n, na = mu.size, v.size, active.size
    act = np.zeros(m, dtype=np.int64)
    act[:na] = active
    istate, fstate = np.zeros(19, dtype=np.int64), np.zeros(3)
    dv, P, MD = np.empty(n), np.empty(2 * m), np.empty(m, dtype=np.int64)
    ok = (fn or planar_multi_step)(act, na, m, n, H.shape[0], W.ravel(order="F"), H.ravel(order="F"),
                                   SHt.ravel(order="F"), np.zeros(0), False, v, vfree, dvf, uNm, mu, e, 1e-10,
                                   np.array([40, 20, 30, 10]), istate, fstate, dv, P, MD)
    return ok, dv, P[:2 * na], MD[:na], istate


def test_each_step_is_the_python_steps_bits(monkeypatch):
    recs = _handed_steps(monkeypatch, box_on_corners(), 0.3)
    assert len(recs) == 300
    for data, (dv_py, p_py, md_py, _, sol) in recs:
        ok, dv, p, md, istate = _kernel(data)
        assert ok and istate[3] == sol.iterations
        np.testing.assert_array_equal(dv, dv_py)
        np.testing.assert_array_equal(p, p_py)
        np.testing.assert_array_equal(md, md_py)


def test_newton_steps_near_a_mode_threshold_go_back(monkeypatch):
    # the resting block's steps take Newton iterations (to rounding: SuperLU there, LAPACK here);
    # with a margin that puts every mode decision "near its threshold" each of them goes back to
    # Python, counting nothing, while the box's steps (sweeps alone) stay in the kernel
    from lcp.timestepping import planar_multi_kernels as pmk

    rest = _handed_steps(monkeypatch, rocking_block(), 4.0)[-5:]
    box = _handed_steps(monkeypatch, box_on_corners(), 0.01)
    for data, (dv_py, p_py, md_py, _, sol) in rest:
        ok, dv, p, md, istate = _kernel(data)
        assert ok and sol.iterations > 20  # Newton's iteration after the 20 sweeps
        np.testing.assert_allclose(dv, dv_py, rtol=0, atol=1e-15)
        np.testing.assert_array_equal(md, md_py)
    monkeypatch.setattr(pmk, "MODE_MARGIN", 1e300)  # read at run time by the Python reference
    for data, _ in rest:
        ok, _, _, _, istate = _kernel(data, pmk.planar_multi_step.py_func)
        assert not ok and not istate.any()
    for data, (dv_py, _, _, _, _) in box:
        ok, dv, _, _, _ = _kernel(data, pmk.planar_multi_step.py_func)
        assert ok
        np.testing.assert_array_equal(dv, dv_py)
