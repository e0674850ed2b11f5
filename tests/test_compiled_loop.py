"""The compiled Moreau-Jean loop (lcp.timestepping.compiled_loop) against the Python loop (fast=False).

Same activation rule, same contact problems, same branch refinement: the trajectories agree to
rounding (the sums run in another order than BLAS's), the modes, mode counts and impacts exactly.
"""
import casadi as ca
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import lcp
from lcp.timestepping import compiled_loop
from lcp.classical import stacked_blocks
from lcp.scenes import Scene, block_chain
from lcp.model.system import Contact, System

pytest.importorskip("numba")


def jean_pratt_copies(K, R=0.5, g=9.81):
    """K independent reduced Jean-Pratt systems (alpha = pi/4, m = M = 1) as one System."""
    n = 2 * K
    q, v = ca.SX.sym("q", n), ca.SX.sym("v", n)
    blk = np.array([[2.0, -1.0], [-1.0, 2.0]])
    system = System(q, v, ca.SX(np.kron(np.eye(K), blk)), ca.SX(np.tile([0.0, -2 * g], K)),
                    contacts=[Contact(gap=q[2 * i + 1], tangent=q[2 * i], mu=R, name=f"P{i}") for i in range(K)])
    v0 = np.zeros(n)
    v0[0::2] = 1.0 + np.arange(K) / K
    return Scene(system, np.zeros(n), v0, 1.0, f"jp_{K}")


def raised_floor_chain(K, e=0.5, floor=0.2, k_spring=30.0, mu=0.4):
    """K blocks joined by springs dropped from staggered heights onto a floor at y = ``floor``, with
    restitution ``e``: impacts at different times, bounces (lift-off), then slip and stick."""
    n = 2 * K
    q, v = ca.SX.sym("q", n), ca.SX.sym("v", n)
    F = [ca.SX(0)] * n
    for i in range(K):
        F[2 * i + 1] = ca.SX(-9.81)
    for i in range(K - 1):
        tension = k_spring * (q[2 * i + 2] - q[2 * i] - 1.0)
        F[2 * i] = F[2 * i] + tension
        F[2 * i + 2] = F[2 * i + 2] - tension
    contacts = [Contact(gap=q[2 * i + 1] - floor, tangent=q[2 * i], mu=mu, e=e, name=f"b{i}") for i in range(K)]
    system = System(q, v, ca.SX(np.eye(n)), ca.vertcat(*F), contacts=contacts)
    q0 = np.zeros(n)
    q0[0::2] = np.arange(K) * 1.05
    q0[1::2] = floor + 0.01 * (1 + np.arange(K) % 3)
    v0 = np.zeros(n)
    v0[0] = 1.5
    return Scene(system, q0, v0, 1.0, f"raised_{K}")


def run_both(scene, t_end, **kw):
    fast = lcp.simulate(scene, t_end, fast=True, **kw)
    slow = lcp.simulate(scene, t_end, fast=False, **kw)
    assert fast.solver.endswith("(compiled)") and not slow.solver.endswith("(compiled)")
    return fast, slow


def assert_same(fast, slow, rtol=1e-12):
    assert fast.status == slow.status == 0, (fast.message, slow.message)
    assert fast.q.shape == slow.q.shape
    sq = max(1.0, float(np.max(np.abs(slow.q))))
    sv = max(1.0, float(np.max(np.abs(slow.v))))
    sp_ = max(1e-300, float(np.max(np.abs(slow.p_N))))
    assert np.max(np.abs(fast.q - slow.q)) <= rtol * sq
    assert np.max(np.abs(fast.v - slow.v)) <= rtol * sv
    assert np.max(np.abs(fast.p_N - slow.p_N)) <= rtol * sp_
    assert np.max(np.abs(fast.p_T - slow.p_T)) <= rtol * sp_
    np.testing.assert_array_equal(np.asarray(fast.modes), np.asarray(slow.modes))
    assert fast.stats.mode_counts == slow.stats.mode_counts
    assert fast.stats.steps == slow.stats.steps and fast.stats.free_steps == slow.stats.free_steps
    assert fast.stats.solver_calls == slow.stats.solver_calls
    assert [(i.contact, i.name) for i in fast.impacts] == [(i.contact, i.name) for i in slow.impacts]
    for a, b in zip(fast.impacts, slow.impacts):
        assert abs(a.t - b.t) <= 1e-12 and abs(a.p_N - b.p_N) <= rtol * sp_ and abs(a.p_T - b.p_T) <= rtol * sp_
    np.testing.assert_array_equal(fast.t, slow.t)


@pytest.mark.parametrize("K", [2, 5, 30])
@pytest.mark.parametrize("h", [1e-2, 1e-3, 1e-4])
def test_block_chain_equals_python_loop(K, h):
    sc = block_chain(K)
    fast, slow = run_both(sc, min(1.0, 400 * h), h=h)
    assert_same(fast, slow)
    assert fast.stats.mode_counts["stick"] > 0 and fast.stats.mode_counts["slide+"] > 0


@pytest.mark.parametrize("make", [lambda: block_chain(110), lambda: jean_pratt_copies(110)])
def test_sparse_assembly_equals_python_loop(make):
    """>= 200 contact rows: the sparse assembly (free velocity through the factors of W_h)."""
    sc = make()
    fast, slow = run_both(sc, 0.03, h=1e-3)
    assert_same(fast, slow)


@pytest.mark.parametrize("solver", ["auto", "nsgs"])
def test_jean_pratt_copies_equal_python_loop_and_stop(solver):
    sc = jean_pratt_copies(6)
    fast, slow = run_both(sc, 0.8, h=1e-3, solver=solver)
    assert_same(fast, slow)
    # every copy slides, then sticks (its initial speed 1 + i/K is spent before 0.8 s)
    assert np.all(np.abs(fast.v[-1]) < 1e-12)
    assert np.all(np.abs(fast.q[:, 1::2]) < 1e-12)  # no lift-off, no sinking


def test_stacked_blocks():
    for sc in (stacked_blocks(4), stacked_blocks(2, mu=[0.5, 0.3], push=20.0)):
        fast, slow = run_both(sc, 0.5, h=1e-3)
        assert_same(fast, slow)
        ex = sc.exact(fast.t)
        assert np.max(np.abs(fast.q - ex["q"])) < 1e-3  # the scheme's O(h) error against the exact motion
        # the stack stays on its supports: no sinking beyond rounding
        assert np.min(fast.q[:, 1::2] - sc.q0[1::2]) > -1e-12


@pytest.mark.parametrize("e", [0.0, 0.5])
@pytest.mark.parametrize("h", [1e-3, 2e-4])
def test_raised_floor_impacts_and_lift_off(e, h):
    sc = raised_floor_chain(5, e=e)
    fast, slow = run_both(sc, 0.4, h=h)
    assert_same(fast, slow)
    assert len(fast.impacts) >= 5  # every block lands
    opened = np.any((np.asarray(fast.modes) == -1)[1:] & (np.asarray(fast.modes) >= 0)[:-1])
    if e > 0:  # the bounces lift the blocks off again
        assert opened
    assert fast.stats.free_steps > 0


def test_save_every_and_nsgs_options():
    sc = raised_floor_chain(4, e=0.3)
    fast, slow = run_both(sc, 0.3, h=1e-3, save_every=7, solver="nsgs",
                          solver_options={"residual_tol": 1e-11, "max_sweeps": 500})
    assert_same(fast, slow)
    assert fast.q.shape[0] == 300 // 7 + 1
    assert len(fast.impacts) == len(slow.impacts) >= 4  # impacts are recorded whatever is saved


@given(K=st.integers(2, 6), mu=st.floats(0.05, 1.0), k_spring=st.one_of(st.just(0.0), st.floats(1e-3, 200.0)), push=st.floats(-3.0, 3.0),
       h=st.sampled_from([3e-3, 1e-3, 3e-4]))
def test_random_chains_equal_python_loop(K, mu, k_spring, push, h):
    v0 = np.zeros(K)
    v0[0] = push
    sc = block_chain(K, mu=mu, k_spring=k_spring, v0=v0)
    fast, slow = run_both(sc, 60 * h, h=h)
    assert_same(fast, slow, rtol=1e-11)


def test_kernel_as_plain_python_equals_compiled():
    from lcp.timestepping.assembly import StepAssembly
    from lcp.contact.solvers import make_solver

    sc = raised_floor_chain(3, e=0.5)
    asm = StepAssembly(sc.system, 1e-3, 0.5)
    args = (asm, sc.q0, sc.v0, 80, 1, make_solver("auto"), True)
    a = compiled_loop.moreau_jean_loop(*args)
    b = compiled_loop.moreau_jean_loop(*args, compiled=False)
    assert_same(a, b, rtol=0.0)


def test_without_numba_the_python_loop_runs(monkeypatch):
    sc = block_chain(3)
    fast = lcp.simulate(sc, 0.2, h=1e-3)
    monkeypatch.setattr(compiled_loop, "HAVE_NUMBA", False)
    res = lcp.simulate(sc, 0.2, h=1e-3)
    assert res.solver == "auto" and res.status == 0
    assert_same(fast, res)


@pytest.mark.parametrize("solver", ["auto", "nsgs"])
def test_stalled_step_goes_to_the_python_solver(monkeypatch, solver):
    """NSGS limited to one sweep cannot finish a coupled chain's steps: each such step is solved by
    the Python solver (auto: NSGS + Newton; nsgs: its own sweeps, then Lemke as the fallback), the
    compiled loop resumes after it, and the trajectory is the Python loop's."""
    sc = stacked_blocks(4)  # each contact carries the blocks above it: strongly coupled
    opts = {}
    if solver == "auto":
        monkeypatch.setattr(compiled_loop, "AUTO_MAX_SWEEPS", 1)
        # the compiled Newton finish off, so that the Python solver takes them (tests/test_compiled_routes.py)
        monkeypatch.setattr(compiled_loop, "newton_params", lambda solver: None)
    else:
        opts = {"solver_options": {"max_sweeps": 1}}
    fast, slow = run_both(sc, 0.1, h=1e-3, solver=solver, **opts)
    assert_same(fast, slow, rtol=1e-11)
    assert fast.stats.fallbacks > 0
    assert "solved by the Python solver" in fast.message and "compiled NSGS stopped after 1 sweeps" in fast.message
    if solver == "nsgs":
        assert "fallback solver 'lemke'" in fast.message


def test_failing_step_stops_like_the_python_loop(monkeypatch):
    sc = stacked_blocks(3)
    opts = {"h": 1e-3, "solver": "nsgs", "solver_options": {"max_sweeps": 1}, "fallback": False}
    fast, slow = run_both(sc, 0.1, **opts)
    assert fast.status == slow.status == -1
    assert fast.stats.steps == slow.stats.steps
    assert fast.q.shape == slow.q.shape and np.max(np.abs(fast.q - slow.q)) <= 1e-12


@pytest.mark.parametrize("K", [3, 5, 10])
def test_stack_runs_compiled_with_the_direct_branch_solve(K):
    """A stack couples every contact to its neighbours as strongly as to itself: the branch
    refinement's Gauss-Seidel sweeps do not converge in BRANCH_MAX_SWEEPS, and every step used to
    go to the Python solver (1e5 steps: 15 s, and a drift of the gaps by 1e-19 a step). The direct
    solve of the branch system keeps the steps compiled and equal to Lemke's."""
    from lcp.classical import stacked_blocks

    sc = stacked_blocks(K, height=0.1)
    res = lcp.simulate(sc, 0.5, h=1e-2, solver="auto")
    ref = lcp.simulate(sc, 0.5, h=1e-2, solver="lemke")
    assert res.success and ref.success
    assert res.stats.fallbacks <= 1, res.message  # at most the cold first step, NSGS's 500 sweeps
    np.testing.assert_allclose(res.q, ref.q, rtol=0, atol=1e-15)
    np.testing.assert_allclose(res.p_N, ref.p_N, rtol=1e-12, atol=0)
