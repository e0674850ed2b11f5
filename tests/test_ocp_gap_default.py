"""The gap law as the default contact law of lcp.ocp, on the three Jean-Pratt problems.

The block starts on its floor (g(q0) = 0) and never leaves it, so the velocity law was exact for it;
the gap law must be too, from ``solve()``'s defaults: with the old first relaxation sigma0 = 1 the
relaxed pair N g <= sigma let the block hover (N > 0 with g > 0) and the homotopy failed. References
are closed forms (studies.optimal_control): minimum time T*, minimum effort J*, and the move-and-hold
effort, one affine-in-t slide out and one back, for any hold window.
"""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

import lcp
from lcp.ocp import HomotopyOptions, OptimalControlProblem, effort
from studies import optimal_control as so


def hold_window_problem(N, t_a, t_b, T, d=0.3, hold="auto", steps="auto"):
    """Move d, hold still at rest on [t_a, t_b], back to rest at 0 by T (nodes round(N t / T) pinned)."""
    sc, system = so.controlled_block()
    k_a, k_b = round(N * t_a / T), round(N * t_b / T)

    def at_rest(s):
        if k_a - 1 <= s.k < k_b:
            return ca.vertcat(s.q1[0] - d, s.v1[0])
        return ca.SX.zeros(0, 1)

    return OptimalControlProblem(system, N, q0=sc.q0, v0=sc.v0, T=T, stage_cost=effort, hold=hold, steps=steps,
                                 node_times={k_a: t_a, k_b: t_b}, path_equalities=at_rest, replay_tol=1e-6,
                                 terminal_constraints=lambda q, v: ca.vertcat(q[0], v[0]))


def hold_reference(t_a, t_b, T, d=0.3):
    return so.move_effort(t_a, d) + so.move_effort(T - t_b, d, backward=True)


def _check(r, value, ref, rel):
    assert r.problem.contact_law == "gap"
    assert r.success, r.message
    assert abs(value - ref) <= rel * ref, (value, ref)
    assert r.replay.final_miss <= 1e-8 and r.replay.path_violation <= 1e-8
    assert np.max(np.abs(r.q[:, 1])) <= 1e-9  # on the floor throughout: no hovering


def test_the_default_is_the_gap_law_and_a_small_first_relaxation():
    pb = so.rest_to_rest_problem(6, "time")
    assert pb.contact_law == "gap"
    assert HomotopyOptions().sigma0 <= 1e-4


def test_uniform_steps_do_not_hover():
    # the homotopy from the defaults on uniform steps: the block stays on its floor; T within the
    # uniform grid's error of T* (the switch falls inside a step)
    r = so.rest_to_rest_problem(12, "time", "constant", "uniform").solve()
    assert r.success, r.message
    assert np.max(np.abs(r.q[:, 1])) <= 1e-9
    assert so.min_time_bound() <= r.T <= so.min_time_bound() * 1.01
    assert r.homotopy[0].sigma == HomotopyOptions().sigma0


def test_min_time_exact_by_default():
    r = so.rest_to_rest_problem(8, "time", "constant", "free").solve()
    _check(r, r.T, so.min_time_bound(), 1e-6)


def test_min_effort_exact_by_default():
    r = so.rest_to_rest_problem(10, "effort", "affine", "free").solve()
    _check(r, r.cost, so.min_effort_bound(), 1e-6)


@pytest.mark.parametrize("N, window, T", [(12, (0.4, 0.6), 1.2), (10, (0.4, 0.6), 1.2)])
def test_hold_on_any_window(N, window, T):
    # N = 10: node 3 is pinned at 0.4 s, off the uniform grid (3 T / N = 0.36 s); the first pass
    # runs on the grid uniform between the pins. (Coarse grids can hold a local optimum of the
    # first pass's phases: N = 14 ends 8e-3 above, N = 13 on [0.5, 0.7], T = 1.3, 1.5e-2.)
    r = hold_window_problem(N, *window, T).solve()
    _check(r, r.cost, hold_reference(*window, T), 1e-6)
    assert r.t[round(N * window[0] / T)] == pytest.approx(window[0], abs=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize("N, window, T", [(40, (0.5, 0.7), 1.3), (40, (0.45, 0.7), 1.2), (40, (0.38, 0.62), 1.1),
                                         (40, (0.42, 0.6), 1.15)])
def test_the_three_problems_at_N40(N, window, T):
    # every setting the package's default: free steps and the affine hold (the pins make the hold's
    # steps free), method "auto"
    if window == (0.5, 0.7):
        r = so.rest_to_rest_problem(40, "time").solve()
        assert (r.problem.hold, r.problem.steps) == ("affine", "free")
        _check(r, r.T, so.min_time_bound(), 1e-6)
        r = so.rest_to_rest_problem(40, "effort").solve()
        _check(r, r.cost, so.min_effort_bound(), 1e-4)
        r = so.hold_problem(40).solve()
        _check(r, r.cost, so.hold_bound(), 1e-4)
    r = hold_window_problem(N, *window, T).solve()
    _check(r, r.cost, hold_reference(*window, T), 1e-4)


def _block_problem(**kw):
    sc, system = so.controlled_block()
    return OptimalControlProblem(system, 8, q0=sc.q0, v0=sc.v0, **{"stage_cost": effort, **kw})


def test_the_default_grid_is_free_steps_with_the_affine_hold():
    pb = _block_problem()
    assert (pb.hold, pb.steps) == ("affine", "free")
    # given one of the two, the other follows it
    assert (_block_problem(steps="uniform").hold, _block_problem(hold="constant").steps) == ("constant", "free")
    assert _block_problem(theta=1.0).hold == "constant"  # the affine hold's position update is theta = 1/2


def test_a_step_indexed_callable_keeps_uniform_steps_unless_pinned():
    # a window by step index would move in time on free steps: uniform, unless node_times pin it
    def window(s):
        return s.q1[0] - 0.1 if 3 <= s.k < 5 else ca.SX.zeros(0, 1)

    assert (_block_problem(path_equalities=window).steps, _block_problem(path_equalities=window).hold) == \
        ("uniform", "constant")
    assert _block_problem(path_equalities=window, node_times={3: 0.3, 5: 0.6}).steps == "free"
    ref = np.linspace(0.0, 0.2, 8)  # a reference sampled per step
    assert _block_problem(stage_cost=lambda s: (s.q1[0] - ref[s.k]) ** 2).steps == "uniform"
    # a time-dependent term is not step-indexed: t0 and h are the step's own (variables on free steps)
    assert _block_problem(stage_cost=lambda s: (s.q1[0] - s.t1) ** 2 + 0 * s.k).steps == "free"
    assert _block_problem(path_constraints=lambda s: s.q1[0] - 1.0).steps == "free"


def test_systems_without_planar_contacts_keep_uniform_steps():
    q, v, u = ca.SX.sym("q"), ca.SX.sym("v"), ca.SX.sym("u")
    free_mass = lcp.System(q, v, ca.SX(1.0), ca.SX(0.0), control=u)
    pb = OptimalControlProblem(free_mass, 6, q0=[0.0], v0=[0.0], stage_cost=effort)
    assert (pb.hold, pb.steps) == ("constant", "uniform")


def test_the_gap_law_lifts_off_when_asked():
    # the same block, lifted by an upward push: the gap law lets the contact open (the velocity
    # law would hold it closed); a sanity check that the default did not lose the flight
    sc = lcp.scenes.jean_pratt(v0=0.0)
    pb = OptimalControlProblem(sc, 10, control_matrix=ca.DM([[0.0], [1.0]]), u_min=0.0, u_max=60.0, T=0.5,
                               stage_cost=effort, steps="free",
                               path_equalities=lambda s: s.q1[1] - 0.05 if s.k == 4 else ca.SX.zeros(0, 1))
    r = pb.solve()
    assert pb.contact_law == "gap"
    assert r.success, r.message
    assert np.max(r.q[:, 1]) >= 0.05 - 1e-9 and r.replay.final_miss <= 1e-6


def test_a_solve_that_misses_its_tolerance_says_which_step_and_contact():
    from tests.test_ocp import rest_problem

    r = rest_problem(10, contact_law="velocity").solve(sigma0=1.0, sigma_min=1e-3, polish=False, shooting=False)
    assert r.status == -2
    assert "the Coulomb residual is largest in step" in r.message and "contact 'P'" in r.message
    k = int(r.message.split("largest in step ")[1].split(" ")[0])
    assert 0 <= k < 10 and f"(t = {r.t[k]:.6g})" in r.message


def test_a_tail_whose_replay_misses_falls_back_to_the_fixed_phase_solution(monkeypatch):
    # the min-time problem at N = 6, R = 0.5625: the relaxed tail lowers the cost from 0.45466 (the
    # fixed phases) to T*; made to fail its replay, the solve keeps the fixed-phase solution and says so
    import dataclasses

    from lcp.ocp import solve as solve_mod
    from tests.test_ocp_phases import _problem

    real, calls = solve_mod.replay_check, []

    def first_fails(res, tol):
        rc = real(res, tol)
        calls.append(res.cost)
        return dataclasses.replace(rc, final_miss=1.0) if len(calls) == 1 else rc

    monkeypatch.setattr(solve_mod, "replay_check", first_fails)
    ocp, T = _problem(0.5625, 0.5, 6, "time", steps="free", hold="constant")
    r = ocp.solve()
    assert len(calls) == 2 and calls[1] > calls[0]
    assert r.success and r.T == calls[1] and "failed its replay" in r.message


@pytest.mark.slow
def test_a_failure_on_the_free_steps_auto_chose_is_solved_on_uniform_steps():
    # two springy blocks: the free-step route ends 0.30 from its target on the replay (and its
    # shooting fails); the uniform steps' route, finished by the shooting, is exact
    sc = lcp.scenes.block_chain(2, v0=[0.0, 0.0], k_spring=50.0, mu=0.3, damping=2.0)
    pb = OptimalControlProblem(sc, 20, control_matrix=lcp.ocp.tangential_push(sc.system, 0), u_min=-15, u_max=15,
                               T=2.0, stage_cost=effort,
                               terminal_constraints=lambda q, v: ca.vertcat(q[0] - 0.3, q[2] - 1.3, v[0], v[2]))
    assert (pb.hold, pb.steps, pb.grid_fallback) == ("affine", "free", True)
    r = pb.solve()
    assert r.success, r.message
    assert (r.problem.hold, r.problem.steps) == ("constant", "uniform")
    assert "Solved on uniform steps with the constant hold" in r.message and "free steps" in r.message
    assert r.replay.final_miss <= 1e-9
