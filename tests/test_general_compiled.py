"""The compiled Moreau-Jean loop for general systems (lcp.timestepping.general_loop): the same results
as the Python loop to rounding, the same statuses and messages, and the Python loop where no C
compiler is found."""
import math

import casadi as ca
import numpy as np
import pytest

import lcp
from lcp.model.system import Contact, System
from lcp.numerics.jit import HAVE_NUMBA
from lcp.scenes.classical import painleve_rod, rocking_block, slider_crank
from lcp.timestepping import codegen

pytestmark = pytest.mark.skipif(not HAVE_NUMBA or codegen.c_compiler() is None,
                                reason="needs numba and a C compiler")


def bowl(mu=0.3, radius=1.0, g=9.81, force=None, t=None):
    """A point in a circular bowl (curved gap, normal turning with q)."""
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    r = ca.norm_2(q)
    F = ca.vertcat(0, -g) if force is None else force
    return System(q, v, ca.SX.eye(2), F, t=t,
                  contacts=[Contact(gap=radius - r, tangent_jacobian=ca.horzcat(-q[1], q[0]) / r, mu=mu)])


def forced_bowl():
    t = ca.SX.sym("t")
    return bowl(force=ca.vertcat(3 * ca.sin(5 * t), -9.81), t=t)


def spatial_bowl(mu=0.3, radius=1.0, g=9.81, e=0.0):
    """A ball in a spherical bowl: one spatial contact whose normal and tangents turn with q."""
    q, v = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
    r = ca.norm_2(q)
    t1 = ca.vertcat(-q[1], q[0], 0) / ca.norm_2(q[:2])
    t2 = ca.cross(q / r, t1)
    return System(q, v, ca.SX.eye(3), ca.vertcat(0, 0, -g),
                  contacts=[Contact(gap=radius - r, tangent_jacobian=ca.horzcat(t1, t2).T, mu=mu, e=e)])


def _scene(name):
    if name == "bowl":
        return bowl(), [0.0, -1.0], [2.0, 0.0], 1.0, 1e-3
    if name == "bowl_rough":
        return bowl(mu=0.6), [0.3, -math.sqrt(0.91)], [0.1, 0.0], 1.0, 1e-3
    if name == "forced_bowl":
        return forced_bowl(), [0.0, -1.0], [0.5, 0.0], 1.0, 1e-3
    if name == "slider_crank":
        s = slider_crank()
        return s.system, s.q0, s.v0, 0.2, 1e-4
    if name == "rocking_block":
        s = rocking_block()
        return s.system, s.q0, s.v0, 1.0, 1e-3
    if name == "painleve_rod":
        s = painleve_rod()
        return s.system, s.q0, s.v0, s.t_end, 1e-3
    if name == "spatial_bowl":
        return spatial_bowl(), [0.3, 0.0, -math.sqrt(0.91)], [0.0, 1.0, 0.0], 0.3, 1e-3
    if name == "spatial_drop":  # dropped into the bowl with restitution: impacts, flights, slides
        return spatial_bowl(e=0.5), [0.3, 0.1, -0.5], [0.5, 1.0, 0.0], 1.0, 1e-3
    raise KeyError(name)


def _rel(a, b):
    if a.size == 0:
        return 0.0
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(a)), 1e-300))


@pytest.mark.parametrize("name", ["bowl", "bowl_rough", "forced_bowl", "slider_crank", "rocking_block",
                                  "painleve_rod", "spatial_bowl", "spatial_drop"])
@pytest.mark.parametrize("projection", [False, "auto"])
def test_same_results_as_the_python_loop(name, projection):
    system, q0, v0, t_end, h = _scene(name)
    if projection and name == "slider_crank":
        t_end = 0.05
    kw = dict(h=h, q0=q0, v0=v0, projection=projection)
    ref = lcp.simulate(system, t_end, fast=False, **kw)
    got = lcp.simulate(system, t_end, **kw)
    assert got.status == ref.status and got.message == ref.message
    assert got.q.shape == ref.q.shape
    for x, y in ((got.q, ref.q), (got.v, ref.v), (got.p_N, ref.p_N), (got.p_T, ref.p_T)):
        assert _rel(x, y) <= 1e-12
    assert np.array_equal(np.asarray(got.modes), np.asarray(ref.modes))
    assert got.stats.projections == ref.stats.projections
    assert got.stats.projection_iterations == ref.stats.projection_iterations
    assert got.max_constraint_violation == pytest.approx(ref.max_constraint_violation, rel=1e-6, abs=1e-15)
    assert got.stats.mode_counts == ref.stats.mode_counts
    assert (got.stats.free_steps, got.stats.solver_calls) == (ref.stats.free_steps, ref.stats.solver_calls)
    assert [(i.contact, round(i.t, 12)) for i in got.impacts] == [(i.contact, round(i.t, 12)) for i in ref.impacts]
    for a, b in zip(got.impacts, ref.impacts):
        assert np.allclose(a.p_T, b.p_T, rtol=1e-12, atol=1e-15) and np.shape(a.p_T) == np.shape(b.p_T)


@pytest.mark.parametrize("name", ["bowl", "spatial_drop"])
def test_one_contact_steps_stay_compiled(monkeypatch, name):
    # the closed form (planar) and the local disk solve (spatial) run in the kernel: no step of
    # these scenes goes back to the Python contact step
    from lcp.timestepping import contact_step

    calls = []
    orig = contact_step.ContactStep.solve
    monkeypatch.setattr(contact_step.ContactStep, "solve", lambda self, *a: calls.append(1) or orig(self, *a))
    system, q0, v0, t_end, h = _scene(name)
    res = lcp.simulate(system, t_end, h=h, q0=q0, v0=v0, projection=False)
    assert res.success and res.stats.solver_calls > 0 and not calls
    if name == "spatial_drop":
        assert res.impacts and all(np.shape(i.p_T) == (2,) for i in res.impacts)


def test_the_general_loop_is_the_path_taken(monkeypatch):
    from lcp.timestepping import general_loop, python_loop

    calls = []
    monkeypatch.setattr(python_loop, "run_python_loop", lambda *a, **k: calls.append(1))
    system, q0, v0, _, h = _scene("bowl")
    res = lcp.simulate(system, 0.05, h=h, q0=q0, v0=v0, projection=False)
    assert res.success and not calls
    assert general_loop.applicable(system, type("A", (), {"schedule": None})(), object()) is None


def test_projected_moving_contacts_say_they_ran_the_python_loop():
    from lcp.scenes.moving import moving_table

    sc = moving_table()
    res = lcp.simulate(sc.system, 0.02, h=1e-3, q0=sc.q0, v0=sc.v0, projection=True)
    assert res.success and "compiled general loop does not project systems with moving contacts" in res.message
    free = lcp.simulate(sc.system, 0.3, h=1e-3, q0=sc.q0, v0=sc.v0, projection=False)
    ref = lcp.simulate(sc.system, 0.3, h=1e-3, q0=sc.q0, v0=sc.v0, projection=False, fast=False)
    assert free.message == ref.message and _rel(free.q, ref.q) <= 1e-12 and len(free.impacts) == len(ref.impacts)


def test_failure_is_reported_at_the_same_step():
    # a force with a pole the block runs into: the step acceptance rejects the same step
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    F = ca.vertcat(1e-3 / (q[0] - 0.5), -9.81)
    s = System(q, v, ca.SX.eye(2), F, contacts=[Contact(gap=q[1], tangent=q[0], mu=0.1)])
    kw = dict(h=1e-3, q0=[0.0, 0.0], v0=[2.0, 0.0], projection=False)
    ref = lcp.simulate(s, 1.0, fast=False, **kw)
    got = lcp.simulate(s, 1.0, **kw)
    assert ref.status == -7
    assert (got.status, got.message) == (ref.status, ref.message)
    assert _rel(got.q, ref.q) <= 1e-12


def test_solver_failure_same_message():
    # a Lemke solver allowed one pivot and no fallback: the contact step fails, in the same step
    system, q0, v0, t_end, h = _scene("rocking_block")
    kw = dict(h=h, q0=q0, v0=v0, solver="lemke", solver_options={"max_pivots": 1}, fallback=False)
    ref = lcp.simulate(system, t_end, fast=False, **kw)
    got = lcp.simulate(system, t_end, **kw)
    assert ref.status == -1
    assert (got.status, got.message) == (ref.status, ref.message)
    assert got.q.shape == ref.q.shape and _rel(got.q, ref.q) <= 1e-12


def test_nonfinite_force_same_message():
    # a force that becomes NaN past x = 0.3: the step's data are not finite, named as in the Python loop
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    r = ca.norm_2(q)
    s = System(q, v, ca.SX.eye(2), ca.vertcat(ca.sqrt(0.3 - q[0]), -9.81),
               contacts=[Contact(gap=1.0 - r, tangent_jacobian=ca.horzcat(-q[1], q[0]) / r, mu=0.3)])
    kw = dict(h=1e-3, q0=[0.0, -1.0], v0=[2.0, 0.0])
    ref = lcp.simulate(s, 1.0, fast=False, **kw)
    got = lcp.simulate(s, 1.0, **kw)
    assert ref.status == -2 and "not finite" in ref.message
    assert (got.status, got.message) == (ref.status, ref.message)
    assert got.q.shape == ref.q.shape and _rel(got.q, ref.q) <= 1e-12


def test_without_a_compiler_the_python_loop_runs_with_a_warning(monkeypatch):
    monkeypatch.setenv("CC", "/nonexistent/lcp-no-such-cc")
    system, q0, v0, _, h = _scene("bowl")  # a new System: nothing compiled for it yet
    with pytest.warns(RuntimeWarning, match="/nonexistent/lcp-no-such-cc"):
        got = lcp.simulate(system, 0.05, h=h, q0=q0, v0=v0, projection=False)
    ref = lcp.simulate(system, 0.05, h=h, q0=q0, v0=v0, projection=False, fast=False)
    assert got.success and np.array_equal(got.q, ref.q)  # both the Python loop


def test_library_is_cached_by_source(tmp_path, monkeypatch):
    monkeypatch.setenv("LCP_CACHE_DIR", str(tmp_path))
    a, b = bowl(mu=0.1), bowl(mu=0.7)  # mu is not in the step's C code: one library
    la, lb = codegen.step_library(a), codegen.step_library(b)
    assert la is not None and lb is not None
    assert len(list(tmp_path.glob("lcp_general_step_*.so"))) == 1


def test_two_threads_on_one_system_agree_with_one():
    from concurrent.futures import ThreadPoolExecutor

    system, q0, v0, t_end, h = _scene("bowl_rough")
    ref = lcp.simulate(system, t_end, h=h, q0=q0, v0=v0)
    with ThreadPoolExecutor(2) as pool:
        runs = list(pool.map(lambda _: lcp.simulate(system, t_end, h=h, q0=q0, v0=v0), range(4)))
    assert all(np.array_equal(r.q, ref.q) and np.array_equal(r.v, ref.v) for r in runs)  # one machine, one BLAS


def test_impact_buffer_and_save_every(monkeypatch):
    # impacts flushed from a full buffer in order; every third state kept, as the Python loop keeps them
    from lcp.timestepping import general_loop

    monkeypatch.setattr(general_loop, "_IMPACT_BUFFER", 2)
    system, q0, v0, t_end, h = _scene("spatial_drop")
    kw = dict(h=h, q0=q0, v0=v0, save_every=3)
    ref = lcp.simulate(system, t_end, fast=False, **kw)
    got = lcp.simulate(system, t_end, **kw)
    assert len(ref.impacts) > 2
    assert [i.contact for i in got.impacts] == [i.contact for i in ref.impacts]
    assert np.allclose([(i.t, i.p_N) for i in got.impacts], [(i.t, i.p_N) for i in ref.impacts], rtol=1e-12)
    assert _rel(got.q, ref.q) <= 1e-12 and _rel(got.p_T, ref.p_T) <= 1e-12
