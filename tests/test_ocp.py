"""lcp.ocp: optimal control through frictional contact (MPCC, Scholtes homotopy, replay).

Reference values are closed-form (docs/models.md, forward sliding D a = u - c with
c = R (m+M) g and D = A (1 - kappa)):
- minimum time from rest to rest over d with |u| <= u_max: bang-bang, T* = sqrt(2 d (1/a1 + 1/a2)),
  a1 = (u_max - c)/D, a2 = (u_max + c)/D;
- minimum int u^2 dt: J* = 4/3 c^2 L*, L* = (36 D^2 d^2 / c^2)^(1/4);
- smallest peak normal force when stopping from v0 by T: (m+M) g + M tan(alpha) v0 / T.
"""
import math

import casadi as ca
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import lcp
from lcp.model.control import ControlSchedule
from lcp.ocp import (
    HomotopyOptions,
    OCPGuess,
    OCPResult,
    OptimalControlProblem,
    add_control,
    controlled_system,
    effort,
    replay,
    tangential_push,
)
from lcp.ocp.guess import resample
from lcp.model.schedule import AffineSchedule

G = 9.81
D_TARGET, U_MAX = 0.5, 20.0
R_REST = 0.5


def _consts(R):
    kappa = R / 2.0  # m = M = 1, alpha = pi/4: A = 2, M t = 1
    return R * 2 * G, 2.0 * (1.0 - kappa)


def t_star(R=R_REST, d=D_TARGET, umax=U_MAX):
    c, D = _consts(R)
    return math.sqrt(2 * d * (D / (umax - c) + D / (umax + c)))


def j_star(R=R_REST, d=D_TARGET):
    c, D = _consts(R)
    return 4.0 / 3.0 * c * c * (36 * D * D * d * d / (c * c)) ** 0.25


def rest_problem(N, objective="time", coordinates="reduced", **kw):
    sc = lcp.scenes.jean_pratt(R=R_REST, v0=0.0, coordinates=coordinates)
    # the uniform theta transcription with the constant hold (the subject of these tests; the
    # package's default for this system is free steps with the affine hold: test_ocp_gap_default)
    common = dict(control_matrix=tangential_push(sc.system), u_min=-U_MAX, u_max=U_MAX, hold="constant",
                  steps="uniform", terminal_constraints=lambda q, v: ca.vertcat(q[0] - D_TARGET, v[0]))
    common.update(kw)
    if objective == "time":
        return OptimalControlProblem(sc, N, T=1.0, free_time=True, T_bounds=(0.05, 5.0),
                                     terminal_cost=lambda T, q, v: T, **common)
    return OptimalControlProblem(sc, N, T=1.0, stage_cost=effort, **common)


def shock_problem(N, R=1.9, T=0.2):
    sc = lcp.scenes.jean_pratt(R=R, v0=1.0)
    return OptimalControlProblem(sc, N, control_matrix=tangential_push(sc.system), u_min=-39.0, u_max=39.0,
                                 T=T, max_cost=lambda s: s.N[0], terminal_constraints=lambda q, v: v[0],
                                 control_rate_weight=1e-6, hold="constant", steps="uniform")


@pytest.fixture(scope="module")
def min_time():
    return {N: rest_problem(N).solve() for N in (10, 20, 40)}


# ---------------------------------------------------------------------------------------- problem 1
def test_min_time_solution(min_time):
    for N, res in min_time.items():
        assert isinstance(res, OCPResult)
        assert res.success and res.status == 0, res.message
        assert res.complementarity_residual <= 1e-8
        assert res.lcp_residual <= 1e-8
        assert res.dynamics_residual <= 1e-10
        assert res.inactive_conflicts == 0
        # boundary conditions
        assert res.q[0, 0] == 0.0 and res.v[0, 0] == 0.0
        assert abs(res.q[-1, 0] - D_TARGET) <= 1e-9
        assert abs(res.v[-1, 0]) <= 1e-9
        assert np.max(np.abs(res.q[:, 1])) <= 1e-12  # the block never leaves the line
        # control bounds
        assert np.all(np.abs(res.u) <= U_MAX * (1 + 1e-12))
        # not better than the continuous bang-bang optimum, and close to it
        assert t_star() * (1 - 1e-9) <= res.T <= t_star() * (1 + 0.1 / N)
        # shape of the answer: slide forward all the way, stop in the last step
        assert np.all(res.modes[:-1, 0] == lcp.contact.problem.SLIDE_POS)
        assert np.all(res.N > 0)
        # piecewise-constant hold (the default): one control value per step
        assert res.t.shape == (N + 1,) and res.u.shape == (N, 1) and res.p_N.shape == (N, 1)
        assert res.hold == "constant" and isinstance(res.control, ControlSchedule)
        # the replay (event-driven, exact for constant forces) lands on the optimizer's final state
        assert res.replay.method == "event" and res.replay.final_miss <= 1e-9
        assert res.h == pytest.approx(res.T / N, rel=1e-14)


def test_min_time_bang_bang(min_time):
    res = min_time[40]
    u = res.u[:, 0]
    # bang-bang with one switch (one interval in between: the switch is tied to the grid)
    assert np.sum(np.abs(np.abs(u) - U_MAX) > 1e-6) <= 1
    assert np.all(np.diff(u) <= 1e-6)


def test_homotopy_history(min_time):
    res = min_time[20]
    relax = [s for s in res.homotopy if s.sigma > 0]
    sig = [s.sigma for s in relax]
    assert sig[0] == HomotopyOptions().sigma0 and np.allclose(np.diff(np.log10(sig)), -1.0)
    # the relaxation alone reaches the tolerance; the residual falls in proportion to sigma
    assert relax[-1].residual <= 1e-8 < relax[-2].residual
    assert all(s.max_product <= 1.01 * s.sigma for s in relax)
    assert all(s.success for s in res.homotopy)
    assert res.homotopy_steps == len(relax)
    assert res.homotopy[-1].sigma == 0.0  # the polishing solve
    assert res.iterations == sum(s.iterations for s in res.homotopy)
    # the cost rises towards the MPCC optimum as the relaxation tightens
    costs = [s.cost for s in relax]
    assert np.all(np.diff(costs) >= -1e-9)


def test_replay_same_h_reproduces_the_optimizer(min_time):
    for res in min_time.values():
        rp = replay(res, refine=1)
        assert rp.sim.success
        assert rp.max_error_q <= 1e-10
        assert rp.max_error_v <= 1e-9


def test_replay_mismatch_converges_with_N():
    # the linear hold: Moreau-Jean's position update is not exact for a linearly varying force
    # (this test pinned the old default hold; the constant hold below replays to round-off)
    lin = {N: rest_problem(N, hold="linear", replay_tol=None).solve() for N in (10, 20, 40)}
    errs = [replay(lin[N], refine=10).error_q[0] for N in (10, 20, 40)]
    assert errs[0] > errs[1] > errs[2]
    # second order: each doubling of N divides the mismatch by about 4
    assert errs[0] / errs[1] > 3.0 and errs[1] / errs[2] > 3.0
    assert errs[2] < 5e-4


def test_event_replay_agrees(min_time):
    pytest.importorskip("lcp.events")
    res = min_time[20]
    ev = replay(res, method="event")
    mj = replay(res, refine=20)
    assert ev.sim.success
    # the constant hold is replayed exactly by both: the stop falls on the final node
    assert np.max(np.abs(ev.q - mj.q)) < 1e-9
    assert ev.max_error_q < 1e-9


def test_min_effort():
    # free steps: with uniform steps the block's stop falls inside a step, where Moreau-Jean's
    # velocity-level stop is not the continuous one (the replay misses by ~1e-3 m and success is
    # refused); free steps put the stop on a node
    for N in (10, 20):
        res = rest_problem(N, "effort", steps="free", contact_law="velocity").solve(method="homotopy", sigma0=1.0)  # the old route (velocity law, sigma0 = 1): the free-step homotopy from u = 0 under the gap law is not robust yet
        assert res.success and res.complementarity_residual <= 1e-8
        assert abs(res.q[-1, 0] - D_TARGET) <= 1e-9 and abs(res.v[-1, 0]) <= 1e-9
        assert np.all(np.abs(res.u) <= U_MAX * (1 + 1e-12))
        assert j_star() <= res.cost <= j_star() * (1 + 1.0 / N)
        # the block sticks first and last: the optimizer does not push while it waits
        assert res.modes[0, 0] == lcp.contact.problem.STICK and res.modes[-1, 0] == lcp.contact.problem.STICK
        # u falls along the slide towards 0 (the last piece holds a ramp's tail: ~ 2c / slide steps)
        slide = res.u[_moving(res):, 0]
        assert np.all(np.diff(slide) < 0) and 0 <= slide[-1] < 0.2 * R_REST * 2 * G
        assert res.replay.final_miss <= 1e-9


def test_path_constraint_caps_the_normal_force():
    cap = 30.0
    # free steps: with the braking force capped, the stop falls inside a uniform step (replay miss
    # 1.6e-2 m, success refused); free steps put it on a node
    res = rest_problem(20, path_constraints=lambda s: s.N[0] - cap, steps="free",
                       contact_law="velocity").solve(method="homotopy", sigma0=1.0)  # the old route (velocity law, sigma0 = 1): the free-step homotopy from u = 0 under the gap law is not robust yet
    free = rest_problem(20).solve()
    assert res.replay.final_miss <= 1e-9
    assert res.success and res.complementarity_residual <= 1e-8
    assert res.N.max() <= cap + 1e-6
    assert free.N.max() > 39.0  # braking at -u_max presses the block with ~39.5 N
    assert res.T > free.T


def test_full_coordinates_match_reduced(min_time):
    res = rest_problem(20, coordinates="full").solve()
    assert res.success and res.complementarity_residual <= 1e-8
    assert res.T == pytest.approx(min_time[20].T, rel=1e-8)
    assert replay(res, refine=1).max_error_q <= 1e-10


def test_warm_start_from_another_N(min_time):
    res = rest_problem(40).solve(guess=min_time[20])
    assert res.success
    assert res.T == pytest.approx(min_time[40].T, rel=1e-8)


# ---------------------------------------------------------------------------------------- problem 2
def test_shock_avoidance_peak():
    R, T, N = 1.9, 0.2, 20
    sc = lcp.scenes.jean_pratt(R=R, v0=1.0)
    bound = 2 * G + 1.0 / T
    res = shock_problem(N, R, T).solve()
    assert res.success and res.complementarity_residual <= 1e-8
    assert res.peak == pytest.approx(bound, rel=1e-8)
    assert res.N.max() <= bound * (1 + 1e-8)
    assert abs(res.v[-1, 0]) <= 1e-9
    assert np.all(np.abs(res.u) <= 39.0 * (1 + 1e-12))
    assert sc.N0 / res.peak > 15  # 392 N uncontrolled
    # a constant deceleration: u just below the friction force R (m+M) g
    assert np.allclose(res.u[:, 0], R * 2 * G - 2 * (1 - sc.kappa) * 1.0 / T, atol=1e-3)
    rp = replay(res, refine=20)
    assert rp.sim.N.max() <= bound * 1.001
    assert rp.max_error_q <= 1e-6


# ---------------------------------------------------------------------------------------- general model
def test_two_contacts_block_chain():
    sc = lcp.scenes.block_chain(2, v0=[0.0, 0.0], k_spring=50.0, mu=0.3, damping=2.0)
    ocp = OptimalControlProblem(sc, 20, control_matrix=tangential_push(sc.system, 0), u_min=-15, u_max=15,
                                T=2.0, stage_cost=effort, replay_tol=0.05, hold="constant", steps="uniform",
                                terminal_constraints=lambda q, v: ca.vertcat(q[0] - 0.3, q[2] - 1.3, v[0], v[2]))
    res = ocp.solve()
    assert res.success and res.complementarity_residual <= 1e-8
    assert res.p_N.shape == (20, 2)
    assert np.abs(res.q[-1, [0, 2]] - [0.3, 1.3]).max() <= 1e-8
    assert set(np.unique(res.modes)) <= {lcp.contact.problem.STICK, lcp.contact.problem.SLIDE_POS,
                                         lcp.contact.problem.SLIDE_NEG}
    assert replay(res, refine=1).max_error_q <= 1e-9
    # springs: the theta = 1/2 step is not exact between switches, so the exact (event) replay
    # misses by the transcription's O(h^2) error, which success checks against replay_tol
    assert 1e-4 < res.replay.final_miss < 0.05


def test_controlled_system_and_push():
    sc = lcp.scenes.jean_pratt(v0=0.0)
    B = tangential_push(sc.system)
    assert np.array(ca.evalf(B)).ravel().tolist() == [1.0, 0.0]
    with pytest.warns(DeprecationWarning, match="controlled_system"):
        s = controlled_system(sc.system, B, [0.0, 1.0, 2.0], [0.0, 10.0, -10.0])
    assert s.force_depends_on_t
    assert s.force([0, 0], [0, 0], t=0.5)[0] == pytest.approx(5.0)
    assert s.force([0, 0], [0, 0], t=1.5)[0] == pytest.approx(0.0)
    assert s.force([0, 0], [0, 0], t=1.5)[1] == pytest.approx(-2 * G)


def test_guess_from_simulation():
    ocp = rest_problem(10)
    gs = ocp.guess(u=0.0)
    assert isinstance(gs, OCPGuess) and gs.source == "simulation"
    assert np.all(gs.q == 0.0)  # |u| = 0 < R (m+M) g: the block stays stuck
    assert gs.p_N[:, 0] == pytest.approx(2 * G * gs.T / 10)
    gs2 = ocp.guess(u=lambda t: 15.0, T=0.5)
    assert gs2.u.shape == (10, 1) and gs2.q[-1, 0] > 0  # one value per interval (constant hold)
    res = rest_problem(10).solve()
    assert np.array_equal(res.control(res.t[:-1]), res.u)
    assert np.array_equal(res.control(res.t[1:] - 1e-9 * res.h), res.u)


def test_failure_statuses():
    # too few stages and no polishing: the residual stays above tolerance
    # (the velocity law: under the gap law sigma = 1 lets the block hover and IPOPT fails instead)
    # (shooting=False: the transcription's own result; by default the exact-phase shooting
    # finishes both from the replay of their controls, as asserted below)
    res = rest_problem(10, contact_law="velocity").solve(sigma0=1.0, sigma_min=1e-3, polish=False, shooting=False)
    assert res.status == -2 and not res.success
    assert "residual" in res.message and res.complementarity_residual > 1e-8
    # an iteration cap that stops IPOPT in the first stage
    res = rest_problem(10).solve(max_iter=2, shooting=False)
    assert res.status == -1 and not res.success and "Stage 0" in res.message
    res = rest_problem(10, contact_law="velocity").solve(sigma0=1.0, sigma_min=1e-3, polish=False)
    assert res.success and "exact-phase shooting" in res.message and res.replay.final_miss < 1e-8
    assert "residual" in res.message.split("The transcription's result:")[1]
    with pytest.raises(ValueError, match="shooting"):
        rest_problem(10).solve(shooting="yes")


# ---------------------------------------------------------------------------------------- validation
@pytest.mark.parametrize("kw, name", [
    (dict(N=0), "N"), (dict(N=2.5), "N"), (dict(u_min=5.0, u_max=1.0), "u_min"),
    (dict(theta=0.3), "theta"), (dict(T=-1.0), "T"), (dict(T=10.0, free_time=True, T_bounds=(0.1, 1.0)), "T"),
    (dict(T_bounds=(2.0, 1.0)), "T_bounds"), (dict(control_matrix=np.ones(3)), "control_matrix"),
    (dict(stage_cost=3.0), "stage_cost"), (dict(control_rate_weight=-1.0), "control_rate_weight"),
])
def test_bad_problem_input(kw, name):
    sc = lcp.scenes.jean_pratt(v0=0.0)
    args = dict(N=10, control_matrix=tangential_push(sc.system))
    args.update(kw)
    N = args.pop("N")
    with pytest.raises(ValueError, match=name):
        OptimalControlProblem(sc, N, **args)


def test_bad_inputs_misc():
    sc = lcp.scenes.jean_pratt(v0=0.0)
    with pytest.raises(ValueError, match="control_matrix"):
        OptimalControlProblem(sc, 5, control_matrix=ca.vertcat(sc.system.v_sym[0], 0))
    with pytest.raises(ValueError, match="q0"):
        OptimalControlProblem(sc.system, 5, control_matrix=[1, 0])
    with pytest.raises(ValueError, match="contact"):
        tangential_push(sc.system, 3)
    for kw, name in [(dict(factor=1.5), "factor"), (dict(sigma0=1e-3, sigma_min=1e-2), "sigma_min"),
                     (dict(tol=0.0), "tol"), (dict(max_iter=0), "max_iter")]:
        with pytest.raises(ValueError, match=name):
            HomotopyOptions(**kw)
    ocp = rest_problem(5)
    with pytest.raises(ValueError, match="options"):
        ocp.solve(options=HomotopyOptions(), sigma0=0.5)
    with pytest.raises(ValueError, match="guess"):
        ocp.solve(guess=[1, 2, 3])
    bad = OptimalControlProblem(sc, 5, control_matrix=tangential_push(sc.system),
                                stage_cost=lambda s: ca.vertcat(s.u0, s.u1))
    with pytest.raises(ValueError, match="stage_cost"):
        bad.solve()
    res = rest_problem(5).solve()
    with pytest.raises(ValueError, match="refine"):
        replay(res, refine=0)
    with pytest.raises(ValueError, match="result"):
        replay("not a result")


# ---------------------------------------------------------------------------------------- controls in the model
def _controlled_jean_pratt(R=R_REST):
    sc = lcp.scenes.jean_pratt(R=R, v0=0.0)
    return sc, add_control(sc.system, tangential_push(sc.system), -U_MAX, U_MAX)


def test_system_control_input():
    sc, s = _controlled_jean_pratt()
    assert s.is_controlled and s.nu == 1
    assert np.array(s.control_bounds).ravel().tolist() == [-U_MAX, U_MAX]
    # the drift is the uncontrolled force; B is the push
    assert np.allclose(s.force([0, 0], [0, 0]), sc.system.force([0, 0], [0, 0]))
    with pytest.raises(ValueError, match="control"):
        lcp.simulate(s, 0.1, h=0.01, q0=[0, 0], v0=[0, 0])
    with pytest.raises(ValueError, match="control"):
        lcp.simulate(sc, 0.1, h=0.01, control=ControlSchedule([0, 0.1], [1.0]))
    with pytest.raises(ValueError, match="control_bounds"):
        s.with_control(ControlSchedule([0, 0.1], [25.0]))
    q, v, u = ca.SX.sym("q", 1), ca.SX.sym("v", 1), ca.SX.sym("u", 1)
    with pytest.raises(ValueError, match="affine"):
        lcp.System(q, v, mass=1.0, force=u * u, control=u)
    with pytest.raises(ValueError, match="affine"):
        lcp.System(q, v, mass=1.0, force=v * u, control=u)
    fixed = s.with_control(ControlSchedule([0.0, 0.1, 0.2, 0.3], [5.0, 5.0, -3.0]))
    assert fixed.breakpoints.tolist() == [0.2] and not fixed.is_controlled


def test_piecewise_constant_replay_integrates_the_impulse_exactly():
    # a pushed block slides forward: constant forces per piece, so theta = 1/2 is exact per step;
    # evaluating the control at both ends of a step would average neighbouring pieces instead
    sc, s = _controlled_jean_pratt()
    sched = ControlSchedule([0.0, 0.1, 0.2], [20.0, 15.0])
    mj = lcp.simulate(s, 0.2, h=0.05, q0=[0, 0], v0=[0, 0], control=sched)
    c, D = _consts(R_REST)
    a1, a2 = (20.0 - c) / D, (15.0 - c) / D
    v_exact = [0.0, 0.05 * a1, 0.1 * a1, 0.1 * a1 + 0.05 * a2, 0.1 * a1 + 0.1 * a2]
    assert np.allclose(mj.v[:, 0], v_exact, rtol=0, atol=1e-13)
    x_end = 0.5 * a1 * 0.01 + 0.1 * a1 * 0.1 + 0.5 * a2 * 0.01
    assert mj.q[-1, 0] == pytest.approx(x_end, abs=1e-13)
    ev = lcp.simulate(s, 0.2, method="event", q0=[0, 0], v0=[0, 0], control=sched)
    assert ev.q[-1, 0] == pytest.approx(x_end, abs=1e-12)


def test_ocp_takes_the_system_control():
    sc, s = _controlled_jean_pratt()
    ocp = OptimalControlProblem(s, 10, q0=sc.q0, v0=sc.v0, T=1.0, free_time=True, T_bounds=(0.05, 5.0),
                                terminal_cost=lambda T, q, v: T, hold="constant", steps="uniform",
                                terminal_constraints=lambda q, v: ca.vertcat(q[0] - D_TARGET, v[0]))
    res = ocp.solve()
    assert ocp.system is s and res.success
    old = rest_problem(10).solve()
    assert res.T == pytest.approx(old.T, rel=1e-10)
    # the result's control replays on the same System
    rp = lcp.simulate(s, res.T, h=res.h, q0=sc.q0, v0=sc.v0, control=res.control)
    # to IPOPT's tolerance (1e-10): the gap law holds the gap at the nodes, Moreau-Jean the velocity
    assert np.max(np.abs(rp.q - res.q)) <= 1e-10
    with pytest.raises(ValueError, match="control"):
        OptimalControlProblem(sc, 10)


# ---------------------------------------------------------------------------------------- the hold
def _moving(res):
    """Index of the first step in which the block moves."""
    return int(np.argmax(np.abs(res.v[1:, 0]) > 1e-9))


def test_no_ringing_before_the_block_moves():
    """While the block sticks, the dynamics only needs |u| <= c: the control is not determined by
    them and the cost alone picks it. With the constant hold the cost h sum u_k^2 decouples and
    its minimizer is u = 0 exactly. With the linear hold the cost (u_k^2 + u_k u_{k+1} +
    u_{k+1}^2) / 3 couples neighbours; its minimizer given the first moving value solves
    u_{k-1} + 4 u_k + u_{k+1} = 0, a geometric sequence of ratio -(2 - sqrt(3)): the ringing is
    the true discrete optimum of the linear-hold cost, an artefact of that parametrization."""
    const = rest_problem(20, "effort", steps="free", contact_law="velocity").solve(method="homotopy", sigma0=1.0)  # the old route (velocity law, sigma0 = 1): the free-step homotopy from u = 0 under the gap law is not robust yet
    k = _moving(const)
    assert k >= 2 and const.modes[0, 0] == lcp.contact.problem.STICK
    assert np.max(np.abs(const.u[:k, 0])) <= 1e-8
    # (the old route, which waits before it moves: from the defaults, the gap law and sigma0 = 1e-4,
    # the homotopy finds a better local optimum, 86.97 against 115.70 N^2 s, that moves first and
    # waits at the end, so there is no wait before the move to show the ringing on)
    lin = rest_problem(20, "effort", hold="linear", replay_tol=None, contact_law="velocity").solve(sigma0=1.0)
    k = _moving(lin)
    u = lin.u[: k + 1, 0]  # the node values up to the first step that moves
    assert np.all(np.sign(u[:-1]) != np.sign(u[1:]))  # alternating: the ringing
    # the exact minimizer given u_k: 2 u_0 + u_1 = 0 (free start), u_{j-1} + 4 u_j + u_{j+1} = 0
    A = np.diag(np.full(k, 4.0)) + np.diag(np.ones(k - 1), 1) + np.diag(np.ones(k - 1), -1)
    A[0, 0] = 2.0
    rhs = np.zeros(k)
    rhs[-1] = -u[-1]
    assert np.allclose(u[:-1], np.linalg.solve(A, rhs), rtol=0, atol=1e-6 * abs(u[-1]))
    assert u[-2] / u[-1] == pytest.approx(-(2 - math.sqrt(3)), rel=1e-2)


# ---------------------------------------------------------------------------------------- switches off the grid
@pytest.mark.parametrize("N", [4, 8])
def test_free_steps_min_time_is_exact(N):
    res = rest_problem(N, steps="free").solve()
    assert res.success, res.message
    assert res.T == pytest.approx(t_star(), rel=1e-9)
    assert res.replay.final_miss <= 1e-10
    # bang-bang: the switch sits on a node, the block stops exactly at T
    assert np.allclose(np.abs(res.u[:, 0]), U_MAX, rtol=1e-6) and res.u[0, 0] > 0 > res.u[-1, 0]
    assert res.steps.sum() == pytest.approx(res.T, rel=1e-14)


def test_free_steps_min_effort_converges():
    gaps = [(rest_problem(N, "effort", steps="free").solve().cost - j_star()) / j_star() for N in (10, 20)]
    assert 0 < gaps[1] < gaps[0] / 3  # second order in N (the staircase approximating a ramp)


def test_multistart_reports_every_start():
    res = rest_problem(8, steps="free", contact_law="velocity").solve_multistart(sigma0=1.0)  # the old route (velocity law, sigma0 = 1): the free-step homotopy from u = 0 under the gap law is not robust yet
    assert res.success and len(res.starts) == 4
    assert res.cost == min(s["cost"] for s in res.starts if s["success"])
    assert "distinct" in res.message and "start" in res.message


# ---------------------------------------------------------------------------------------- control schedules
def test_control_schedule_impulses_are_exact():
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.1, 1.0, 8))
    u = rng.normal(size=(7, 2))
    s = ControlSchedule(t, u)
    # a window across several pieces: sum of the overlaps times the piece values
    a, b = 0.5 * (t[1] + t[2]), 0.25 * t[5] + 0.75 * t[6]
    overl = np.clip(np.minimum(t[1:], b) - np.maximum(t[:-1], a), 0.0, None)
    assert np.allclose(s.impulse(a, b), overl @ u, rtol=0, atol=1e-14)
    assert np.array_equal(s(t[3]), u[3]) and np.array_equal(s.left(t[3]), u[2])  # right-continuous
    assert s.breakpoints.tolist() == t[1:-1].tolist()
    lin = ControlSchedule(t, rng.normal(size=(8, 1)), hold="linear")
    # the trapezoid per piece, exactly
    assert lin.impulse(t[0], t[-1])[0] == pytest.approx(np.sum(np.diff(t) * 0.5 * (lin.values[1:, 0] + lin.values[:-1, 0])),
                                                        rel=1e-14)
    mid = 0.5 * (t[2] + t[3])
    assert lin.impulse(t[2], mid)[0] == pytest.approx(0.5 * (mid - t[2]) * (lin.values[2, 0] + lin(mid)[0]), rel=1e-13)
    # the CasADi expression agrees with the NumPy evaluation
    ts = ca.SX.sym("t")
    f = ca.Function("u", [ts], [s.expression(ts)])
    for x in (t[0], t[2], 0.5 * (t[4] + t[5]), t[-1] + 1.0):
        assert np.allclose(np.array(f(x)).ravel(), s(x))


@pytest.mark.parametrize("args, name", [
    (([0.0, 1.0], [1.0, 2.0]), "values"), (([1.0, 0.0], [1.0]), "times"), (([0.0, 1.0], [np.nan]), "finite"),
    (([0.0, 1.0], [1.0], "cubic"), "hold"),
])
def test_control_schedule_bad_input(args, name):
    with pytest.raises(ValueError, match=name):
        ControlSchedule(*args)


# ---------------------------------------------------------------------------------------- the affine hold
def _affine_pieces(seed):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.1, 1.0, 7))
    return t, rng.normal(size=(12, 2))


@given(seed=st.integers(0, 2 ** 31))
def test_affine_schedule_integrates_exactly(seed):
    t, u = _affine_pieces(seed)
    s = AffineSchedule(t, u)
    a = np.random.default_rng(seed).uniform(t[0] - 0.5, t[-1] + 0.5, 2)
    a, b = a.min(), a.max()
    # Simpson's rule is exact on each affine piece (and on the constant ends outside [t0, tK])
    cuts = np.unique(np.clip(np.concatenate([[a, b], t]), a, b))
    ref = sum((y - x) / 6 * (s(x) + 4 * s(0.5 * (x + y)) + s.left(y)) for x, y in zip(cuts[:-1], cuts[1:]))
    assert np.allclose(s.impulse(a, b), ref, rtol=1e-12, atol=1e-12)
    k = 3  # right-continuous at the nodes, the left limit is the previous piece's end value
    assert np.array_equal(s(t[k]), u[2 * k]) and np.allclose(s.left(t[k]), u[2 * k - 1], rtol=1e-14)
    assert s.breakpoints.tolist() == t[1:-1].tolist()
    ts = ca.SX.sym("t")
    f = ca.Function("u", [ts], [s.expression(ts)])
    for x in (t[0] - 1.0, t[0], t[2], 0.3 * t[4] + 0.7 * t[5], t[-1], t[-1] + 1.0):
        assert np.allclose(np.array(f(x)).ravel(), s(x), rtol=1e-12, atol=1e-12)


def test_affine_schedule_continuous_pieces_are_no_breakpoints_and_bad_input():
    s = AffineSchedule([0.0, 1.0, 2.0, 3.0], [0.0, 1.0, 1.0, 2.0, 0.0, 0.0])  # one ramp, then a jump to 0
    assert s.breakpoints.tolist() == [2.0]
    for args, name in ((([0.0, 1.0], [1.0]), "values"), (([1.0, 0.0], [1.0, 2.0]), "times"),
                       (([0.0, 1.0], [1.0, np.nan]), "finite")):
        with pytest.raises(ValueError, match=name):
            AffineSchedule(*args)
    with pytest.raises(ValueError, match="hold"):
        AffineSchedule([0.0, 1.0], [1.0, 2.0], hold="linear")
    # lcp.simulate takes it: the impulse of each Moreau-Jean step is exact (a free mass, v = int u / m)
    q, v, u = ca.SX.sym("q", 1), ca.SX.sym("v", 1), ca.SX.sym("u", 1)
    sys = lcp.System(q, v, mass=2.0, force=u, control=u, control_bounds=(-5, 5))
    r = lcp.simulate(sys, 3.0, h=0.3, q0=[0.0], v0=[0.0], control=s)
    assert np.allclose(r.v[:, 0], s.integral(r.t)[:, 0] / 2.0, rtol=0, atol=1e-14)


def _affine_effort(N):
    uniform = rest_problem(N, "effort").solve(shooting=False)  # the transcription's phases as the guess
    pb = rest_problem(N, "effort", hold="affine", steps="free")
    return pb, pb.solve(uniform, sigma0=1e-4, factor=1e-2, max_iter=3000)


def test_affine_hold_min_effort_is_exact():
    """Free steps with the affine hold represent the optimum (a ramp 2c -> 0 over the slide, 0 while
    sticking) exactly and integrate it exactly: the continuous optimum at N = 10, replayed to round-off."""
    pb, res = _affine_effort(10)
    assert res.success and res.status == 0
    assert res.hold == "affine" and res.u.shape == (20, 1) and isinstance(res.control, AffineSchedule)
    assert abs(res.cost - j_star()) <= 1e-9 * j_star()
    assert res.replay.method == "event" and res.replay.final_miss <= 1e-10 and res.replay.node_miss <= 1e-10
    c, _ = _consts(R_REST)
    slide = np.flatnonzero(res.modes[:, 0] == lcp.contact.problem.SLIDE_POS)
    k0 = slide[0]
    assert res.u[2 * k0, 0] == pytest.approx(2 * c, rel=1e-7)  # the ramp starts at 2c
    assert np.all(np.abs(res.u[:2 * k0, 0]) <= 1e-8)  # no control (nor ringing) while it sticks first
    stop = k0 + 1 + np.flatnonzero(np.abs(res.v[k0 + 1:, 0]) <= 1e-12)[0]  # the block stops on a node
    L = res.t[stop] - res.t[k0]  # one slide of the optimal length L*, u back at 0 when it stops
    assert res.u[2 * stop - 1, 0] == pytest.approx(0.0, abs=1e-7)
    assert L == pytest.approx((36 * 1.5 ** 2 * D_TARGET ** 2 / c ** 2) ** 0.25, rel=1e-7)
    # resampled onto other grids and holds, a guess keeps the control
    for hold, rows in (("constant", 16), ("linear", 17), ("affine", 32)):
        gs = resample(res, 16, hold)
        assert gs.u.shape == (rows, 1) and np.max(gs.u) <= 2 * c + 1e-6
    gs = pb.guess(u=lambda t: 3.0 * t)
    assert gs.u.shape == (20, 1) and gs.u[1, 0] == pytest.approx(0.3)  # both ends of each step


def test_affine_hold_needs_the_trapezoid():
    with pytest.raises(ValueError, match="theta"):
        rest_problem(4, "effort", hold="affine", theta=1.0)
    with pytest.raises(ValueError, match="hold"):
        rest_problem(4, "effort", hold="cubic")


@pytest.mark.slow
def test_affine_hold_min_effort_at_N40():
    _, res = _affine_effort(40)
    assert res.success and abs(res.cost - j_star()) <= 1e-8 * j_star() and res.replay.final_miss <= 1e-10


def test_failure_message_quotes_the_kept_iterates_residual():
    """A homotopy that ends above its tolerance keeps the polished point when polishing lowers the
    residual: the message must quote that point's residual, not the one before polishing."""
    ocp = rest_problem(8, objective="effort")
    r = ocp.solve(options=HomotopyOptions(tol=1e-300, sigma_min=1e-6), method="homotopy", shooting=False)
    assert r.status == -2
    quoted = float(r.message.split("Residual ")[1].split(" ")[0])
    assert quoted == pytest.approx(r.complementarity_residual, rel=1e-2, abs=1e-300)


def test_multistart_passes_its_shooting_flag_to_every_start(monkeypatch):
    """solve_multistart(shooting=False) solves every start without the exact-phase shooting (a
    study row that shows its transcription's own result); a flag that is not a bool is refused."""
    from types import SimpleNamespace

    pb = rest_problem(10)
    seen = []

    def fake_solve(self, guess=None, options=None, shooting=True):
        seen.append(shooting)
        return SimpleNamespace(success=True, cost=1.0 + len(seen), status=0, message="Solved.")

    monkeypatch.setattr(type(pb), "solve", fake_solve)
    best = pb.solve_multistart(guesses=[("a", None), ("b", None)], shooting=False)
    assert seen == [False, False] and best.cost == 2.0
    seen.clear()
    pb.solve_multistart(guesses=[("a", None)])
    assert seen == [True]
    with pytest.raises(ValueError, match="shooting"):
        pb.solve_multistart(shooting="no")


def test_a_moreau_jean_replay_check_names_the_modes_where_it_misses():
    """The linear hold is replayed by Moreau-Jean: where that replay leaves the optimizer, the check
    still reads the replay's contact modes (its simulation's rows) and compares them; the
    amplification is measured for event replays only."""
    from lcp.ocp.replay import replay_check

    res = rest_problem(10, hold="linear", replay_tol=None).solve()
    rc = replay_check(res, 1e-14)
    assert rc.method.startswith("moreau-jean") and rc.final_miss > 1e-6
    assert "in step 0 every contact has the same mode in both" in rc.where
    assert math.isnan(rc.amplification)
