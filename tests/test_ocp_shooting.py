"""Exact-phase shooting (lcp.ocp.shooting): the phase sequence of the event replay, integrated exactly."""
import casadi as ca
import numpy as np
import pytest

import lcp
from lcp.contact.modes import SLIDE_POS, STICK
from lcp.ocp import OptimalControlProblem, effort
from lcp.ocp.replay import event_pieces
from lcp.ocp.shooting import (
    MODE_TOL,
    NotShootable,
    PhaseShooting,
    initial_point,
    phase_plan,
    solve_shooting,
)
from studies._ocp_models import EXAMPLES


@pytest.fixture(scope="module")
def motor_transcribed():
    """nosnoc's motor at N = 30, solved by the transcription only (its replay misses by 0.5)."""
    pb = EXAMPLES["motor"]().make(30)
    pb.replay_tol = None
    return pb, pb.solve()


def test_plan_follows_the_event_replay(motor_transcribed):
    """The plan's segments are the replay's phases, and integrating them from the transcription's
    control repeats the replay (single shooting through the same modes)."""
    pb, res = motor_transcribed
    plan = phase_plan(res)
    assert len(plan) == pb.N
    assert plan[0][0][0] == (STICK,) and plan[0][1][0] == (SLIDE_POS,)  # the coil's force builds up first
    for k, segs in enumerate(plan):
        assert sum(d for _, d, _ in segs) == pytest.approx(res.t[k + 1] - res.t[k], rel=1e-12)
    tr = PhaseShooting(pb, plan)
    x0 = initial_point(tr, res)
    _, _, q, v, u, _, _ = tr.unpack(x0)
    qr, vr, _ = event_pieces(res, restart=True)
    assert np.max(np.abs(q - qr)) < 1e-9 and np.max(np.abs(v - vr)) < 1e-8
    assert np.array_equal(u, res.u)
    assert tr.diagnose(x0)["dynamics"] < 1e-8


def test_motor_solved_to_its_replay(motor_transcribed):
    """The default solve ends in the shooting: success with a replay miss far below 1e-6 (the
    transcription's own: 0.5), the terminal conditions met, the modes admissible."""
    pb, res = motor_transcribed
    x, cost, diag, st, _, tr = solve_shooting(pb, res)
    assert st["return_status"] in ("Solve_Succeeded", "Solved_To_Acceptable_Level")
    assert diag["dynamics"] < 1e-9 and diag["residual"] < 1e-9
    pb2 = EXAMPLES["motor"]().make(30)
    out = pb2.solve()
    assert out.success, out.message
    assert "exact-phase shooting" in out.message
    assert out.replay.final_miss < 1e-7
    assert out.cost == pytest.approx(cost, rel=1e-6)
    assert abs(out.q[-1, 0] - 0.01) < 1e-9 and abs(out.v[-1, 0]) < 1e-9


def _record_solves(monkeypatch) -> list:
    """Every IPOPT solve the shooting makes, as (warm-started, max_iter, iterations, status), in a
    list filled while the test runs (``ca.nlpsol`` wrapped in :mod:`lcp.ocp.shooting`)."""
    import lcp.ocp.shooting as sh

    calls = []
    real = sh.ca.nlpsol

    def recording(name, plugin, nlp, opts):
        solver = real(name, plugin, nlp, opts)
        ip = opts["ipopt"]

        def call(**kw):
            out = solver(**kw)
            st = solver.stats()
            calls.append((ip.get("warm_start_init_point") == "yes", ip["max_iter"], st["iter_count"],
                          st["return_status"]))
            return out

        return type("Recorded", (), {"__call__": lambda self, **kw: call(**kw),
                                     "stats": lambda self: solver.stats()})()

    monkeypatch.setattr(sh.ca, "nlpsol", recording)
    return calls


def test_a_stalled_warm_correction_is_solved_again_cold(motor_transcribed, monkeypatch):
    """A warm-started defect correction that stops at its iteration cap is solved again from the same
    point with IPOPT's own start, and the shooting lands on the same optimum (the two discs at
    N = 30: warm corrections ran 500, 344 and 500 iterations where cold solves took 11 to 35)."""
    import lcp.ocp.shooting as sh

    calls = _record_solves(monkeypatch)
    pb, res = motor_transcribed
    _, cost_ref, _, _, _, _ = solve_shooting(pb, res)
    assert any(warm for warm, *_ in calls)  # the motor's shooting makes a warm correction
    assert all(status in ("Solve_Succeeded", "Solved_To_Acceptable_Level") for *_, status in calls)
    calls.clear()
    monkeypatch.setattr(sh, "WARM_MAX_ITER", 1)
    _, cost, diag, st, _, _ = solve_shooting(pb, res)
    stalled = [i for i, (warm, *_, status) in enumerate(calls) if warm and status == "Maximum_Iterations_Exceeded"]
    assert stalled, calls
    assert all(i + 1 < len(calls) and not calls[i + 1][0] for i in stalled)  # each followed by a cold solve
    assert st["return_status"] in ("Solve_Succeeded", "Solved_To_Acceptable_Level")
    assert diag["dynamics"] < 1e-9 and diag["residual"] < 1e-9
    assert cost == pytest.approx(cost_ref, rel=1e-9)


def test_cold_solves_from_a_solution_are_capped(motor_transcribed, monkeypatch):
    """A cold solve that starts from a solution (a stalled warm correction's retry, the refined
    steps' NLP) stops at NEAR_MAX_ITER iterations; the round's first solve keeps IPOPT's limit (the
    cart-pole at N = 40: such solves ran 500 iterations, 54 s and 139 s, and failed)."""
    import lcp.ocp.shooting as sh

    calls = _record_solves(monkeypatch)
    pb, res = motor_transcribed
    monkeypatch.setattr(sh, "WARM_MAX_ITER", 1)  # every warm correction stalls: a cold retry follows
    monkeypatch.setattr(sh, "NEAR_MAX_ITER", 3)
    solve_shooting(pb, res)
    cold = [c for c in calls if not c[0]]
    assert cold[0][1] == 500 and cold[0][3] in ("Solve_Succeeded", "Solved_To_Acceptable_Level"), calls
    assert len(cold) > 1 and all(c[1] == 3 and c[2] <= 3 for c in cold[1:]), calls


def test_the_correction_reaches_every_output_of_the_integrators(motor_transcribed):
    """The deferred correction is added to the Runge-Kutta outputs themselves: with it, every
    constraint row of the coarse NLP (the joins, the mode conditions at the interior check points,
    the force integrals) takes CVODES's value, not only the joins."""
    pb, res = motor_transcribed
    plan = phase_plan(res)
    check = PhaseShooting(pb, plan, check=True)
    coarse = PhaseShooting(pb, plan, substeps=1, like=check)
    x = initial_point(check, res)
    C = check.outputs(x) - coarse.outputs(x)
    assert C.size == coarse.n_corrections and np.max(np.abs(C)) > 1e-8  # one step per quarter: off
    g_cvodes = check.constraints(x)
    g_coarse = coarse.constraints(x)
    other = np.setdiff1d(np.arange(g_cvodes.size), check.defect_rows)
    assert np.max(np.abs(g_coarse[other] - g_cvodes[other])) > 1e-10  # the interior rows see the error
    g_corrected = np.array(coarse.g_fn(x, coarse.params(C))).ravel()
    assert np.max(np.abs(g_corrected - g_cvodes)) <= 1e-12 * max(1.0, np.max(np.abs(g_cvodes)))


def test_the_replay_miss_names_an_impact_the_optimizer_passed_through():
    """Where the modes agree at the start of the step before the first miss, the replay's impacts
    inside that step are named (the two discs at N = 30: the first shooting round's disc 1 passed
    1.5 mm into disc 2 between two check points of a free-flight phase; the replay hit it)."""
    from types import SimpleNamespace as NS

    from lcp.ocp.replay import _where
    from lcp.result import Impact

    result = NS(q=np.zeros((3, 2)), t=np.array([0.0, 0.1, 0.2]), modes=np.zeros((2, 1), dtype=int),
                problem=NS(system=NS(contacts=[NS(name="discs")])))
    q = np.zeros((3, 2))
    q[1:, 0] = 0.01
    rp = NS(q=q, pieces=[NS(modes=[np.zeros(1, dtype=int)], impacts=[Impact(0.0142, 0, "discs", 2.4, 0.0)]),
                         NS(modes=[np.zeros(1, dtype=int)], impacts=[])])
    text = _where(result, rp, 1e-6)
    assert "first misses by more than 1.0e-06 at node 1" in text
    assert text.endswith("in step 0 every contact has the same mode in both at its start, and inside it "
                         "the replay resolves an impact of contact 'discs' at t = 0.0142")
    rp.pieces[0].impacts = []
    assert _where(result, rp, 1e-6).endswith("in step 0 every contact has the same mode in both")


def _pushed_block(mu=0.3, T=1.0, N=6):
    """A block (1 kg) on a floor, pushed from rest to rest 0.2 m further with least effort: a slide
    that stops exactly at T (stick never admissible with |u| bound low)."""
    q, v, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 1)
    sys = lcp.System(q, v, ca.SX.eye(2), ca.vertcat(u[0], -9.81),
                     contacts=[lcp.Contact(gap=q[1], tangent=q[0], mu=mu)], control=u,
                     control_bounds=(np.array([-20.0]), np.array([20.0])))
    return OptimalControlProblem(sys, N, T=T, q0=np.zeros(2), v0=np.zeros(2), stage_cost=effort,
                                 terminal_constraints=lambda qq, vv: ca.vertcat(qq[0] - 0.2, vv[0]), steps="uniform", hold="constant")


def test_switch_inside_a_uniform_step():
    """Uniform steps cannot put the block's stop on a node: the transcription's replay misses, and
    the shooting places the switch inside its step (a segment boundary)."""
    pb = _pushed_block()
    res = pb.solve()
    assert res.success and "exact-phase shooting" in res.message, res.message
    assert res.replay.final_miss < 1e-8
    assert abs(res.q[-1, 0] - 0.2) < 1e-9 and abs(res.v[-1, 0]) < 1e-9
    assert "misses" in res.message.split("The transcription's result:")[1]  # what the transcription did


def test_exact_transcription_is_left_alone():
    """The Jean-Pratt block on free steps: the transcription is exact, no shooting."""
    from lcp.ocp import tangential_push
    sc = lcp.scenes.jean_pratt(v0=0.0)
    pb = OptimalControlProblem(sc, 4, control_matrix=tangential_push(sc.system), u_min=-20, u_max=20, T=0.5,
                               free_time=True, T_bounds=(0.05, 2.0), steps="free", terminal_cost=lambda T, q, v: T,
                               terminal_constraints=lambda q, v: ca.vertcat(q[0] - 0.2, v[0]), hold="constant")
    res = pb.solve()
    assert res.success and "shooting" not in res.message


def test_refusals_name_what_is_not_modelled():
    """Spatial contacts are refused by name; the user's pairs need their zero members."""
    sc = lcp.scenes.jean_pratt(v0=0.0)
    from lcp.ocp import tangential_push
    pb = OptimalControlProblem(sc, 4, control_matrix=tangential_push(sc.system), u_min=-20, u_max=20, T=0.5,
                               complementarity=[(lambda s: s.u0[0] + 20, lambda s: 20 - s.u0[0])], steps="uniform", hold="constant")
    with pytest.raises(ValueError, match="zeros"):
        PhaseShooting(pb, [[((STICK,), 0.125)]] * 4)
    with pytest.raises(NotShootable, match="spatial"):
        from lcp.ocp.shooting import refuse
        refuse(EXAMPLES["point_on_plane"]().make(4))


def test_plan_length_checked(motor_transcribed):
    pb, res = motor_transcribed
    with pytest.raises(ValueError, match="intervals"):
        PhaseShooting(pb, phase_plan(res)[:-1])


def test_impact_starts_a_segment_and_its_law_holds():
    """The ball bounced to a target (e = 0.5): the replay's impact starts a segment; the shooting
    from it keeps Newton's law there (u_N+ = -e u_N-) and replays to 1e-8, at the transcription's
    own cost (exact there: constant forces in flight)."""
    ex = EXAMPLES["ball_bounce"]()
    pb = ex.make(12)
    res = pb.solve()
    assert res.success and "shooting" not in res.message
    plan = phase_plan(res)
    hits = [(k, at) for k, segs in enumerate(plan) for _, _, at in segs if at]
    assert len(hits) == 1 and hits[0][1][0][0] == 0
    x, cost, diag, st, _, tr = solve_shooting(pb, res)
    assert st["return_status"] in ("Solve_Succeeded", "Solved_To_Acceptable_Level")
    assert diag["dynamics"] < 1e-10 and diag["residual"] < 1e-10
    assert cost == pytest.approx(res.cost, rel=1e-7)
    PN = x[tr.ix["PN"]].ravel()
    assert PN.size == 1 and PN[0] > 0
    from lcp.ocp.solve import _checked, result_of
    out = _checked(pb, result_of(pb, x, cost, diag, 0, "", [], 0.0, tr=tr), "shooting")
    assert out.status == 0 and out.replay.final_miss < 1e-8


def test_user_pairs_keep_their_zero_members():
    """A user pair (the mean normal force against the block's height, 0 <= N perp y >= 0) on the
    block whose stop falls inside a uniform step: the shooting keeps the transcription's zero member
    (y = 0 while pressed) and the pair holds on the replay."""
    pb = _pushed_block()
    pb.complementarity = [(lambda s: s.N, lambda s: s.q1[1])]
    pb.transcription = None
    res = pb.solve()
    assert res.success and "exact-phase shooting" in res.message, res.message
    assert res.replay.final_miss < 1e-8 and res.replay.path_violation < 1e-9


@pytest.mark.slow
def test_hopper_jumps_from_the_defaults():
    """nosnoc's hopper (N = 20): the transcription from the defaults misses its replay by 8e-2; the
    shooting (its no-slip foot a user pair with the zero members kept) jumps to 1e-10."""
    ex = EXAMPLES["hopper"]()
    res = ex.make(20).solve(**ex.solve_kw)
    assert res.success and "exact-phase shooting" in res.message, res.message
    # the foot's no-slip pair is one of the shooting's mode conditions, met to MODE_TOL (measured
    # 5.9e-15 at cost 13.3055, then 1.5e-9 at cost 13.3038 once a slide from rest stopped only below
    # a thousandth of the velocity zero test, which moved the event replays' starts by rounding)
    assert res.replay.final_miss < 1e-9 and res.replay.path_violation < MODE_TOL
    assert res.modes[0, 0] != 0 and np.all(res.modes[1:10, 0] == 0)  # stance, then flight


@pytest.mark.slow
def test_hopper_jumps_at_n40():
    """The hopper at N = 40: the homotopy fails, and the shooting's first round from its best point
    needs the correction of the interior check points (its mode conditions there ended 1.8e-8
    outside on the Runge-Kutta states alone)."""
    ex = EXAMPLES["hopper"]()
    res = ex.make(40).solve(**ex.solve_kw)
    assert res.success and "exact-phase shooting" in res.message, res.message
    assert res.replay.final_miss < 1e-8 and res.replay.path_violation < 1e-8
    assert np.any(res.modes[:, 0] == 0) and np.any(res.modes[:, 0] != 0)  # flight and stance


@pytest.mark.slow
def test_the_discs_corrections_converge_from_their_warm_starts():
    """nosnoc's two discs at N = 30 from the example's start: the shooting's warm-started
    corrections, under a monotone barrier from WARM_MU, converge. Under IPOPT's adaptive barrier
    (mu_init inert) they stalled and were solved again cold, and the shooting took 402 IPOPT
    iterations (18.8 s) to a slightly higher optimum, 204.268489."""
    ex = EXAMPLES["two_discs"]()
    pb = ex.make(30)
    res = pb.solve(ex.start(pb), **ex.solve_kw)
    assert res.success and "exact-phase shooting" in res.message, res.message
    assert res.replay.final_miss < 1e-9
    shooting = res.homotopy[-1]
    assert shooting.sigma == 0.0 and shooting.iterations <= 200, shooting
    assert res.cost < 204.2683


@pytest.mark.slow
def test_the_cart_pole_swings_up_at_n80():
    """nosnoc's cart-pole at N = 80: the 4-step shooting reaches the swing-up (5311.28). Its
    control's event replay restarted at every node chattered at a stick (Zeno: 52 events in
    0.06 s), and the 8-step retry was needed. Replayed in one integration, it lands at once."""
    ex = EXAMPLES["cart_pole"]()
    res = ex.make(80).solve(**ex.solve_kw)
    assert res.success, res.message
    assert res.cost < 5400 and res.replay.final_miss < 1e-8


@pytest.mark.slow
def test_steps_the_optimum_does_not_need_shrink_in_the_shooting():
    """Jean-Pratt minimum time at R = 1.0 (N = 20, the defaults): the push barely beats friction,
    the braking takes 1 % of T*. On the transcriptions' shortest step (0.05 T / N) the last steps
    braked past the stop and slid back, 7.8e-5 above the closed-form T*; the shooting's steps may
    shrink to almost nothing, and it lands on T*."""
    from studies import optimal_control as so

    sc, system = so.controlled_block(R=1.0)
    d = so.REST["d"]
    pb = OptimalControlProblem(system, 20, T=0.5, free_time=True, T_bounds=(0.05, 5.0),
                               terminal_cost=lambda T, q, v: T, q0=sc.q0, v0=sc.v0,
                               terminal_constraints=lambda q, v: ca.vertcat(q[0] - d, v[0]))
    r = pb.solve()
    T_star = so.min_time_bound(R=1.0)
    assert r.success, r.message
    assert T_star * (1 - 1e-9) <= r.T <= T_star * (1 + 1e-6), (r.T, T_star)
    assert r.replay.final_miss <= 1e-8 and np.max(np.abs(r.q[:, 1])) <= 1e-12  # no lift-off


def test_one_replay_over_the_schedule_matches_the_restarted_one(motor_transcribed):
    """A system without closed-form phases (the motor: DOP853 between events) is replayed by one
    event integration over the whole schedule; restarted at every node, the same nodes, modes and
    switches to the integrator's tolerance."""
    _, res = motor_transcribed
    q1, v1, whole = event_pieces(res)
    q2, v2, restarted = event_pieces(res, restart=True)
    assert len(whole) == len(restarted) == res.problem.N
    assert np.max(np.abs(q1 - q2)) <= 1e-11 and np.max(np.abs(v1 - v2)) <= 1e-11  # (measured: 5e-16, 5e-13)
    for a, b, h in zip(whole, restarted, np.diff(res.t)):
        assert a.t[0] == 0.0 and abs(a.t[-1] - h) <= 1e-12 * h
        assert [p.modes for p in a.phases] == [p.modes for p in b.phases]
        assert np.allclose([p.t1 for p in a.phases], [p.t1 for p in b.phases], rtol=0, atol=1e-9)



def test_a_force_of_t_is_replayed_at_its_own_times():
    """A block pushed by u + 4 sin(6 t): the event replay restarted at every node would integrate
    each interval from t = 0 (0.28 m off); it refuses by name, and the shooting's phase plan comes
    from the one integration, which agrees with a fine Moreau-Jean replay."""
    from lcp.model.system import Contact, System
    from lcp.ocp import replay

    q, v, u, t = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 1), ca.SX.sym("t")
    system = System(q, v, ca.SX.eye(2), ca.vertcat(u[0] + 4.0 * ca.sin(6.0 * t), -9.81),
                    contacts=[Contact(gap=q[1], tangent=q[0], mu=0.3, name="floor")], control=u,
                    control_bounds=(-10.0, 10.0), t=t)
    pb = OptimalControlProblem(system, 10, T=1.0, q0=np.zeros(2), v0=np.zeros(2), stage_cost=effort,
                               terminal_constraints=lambda q, v: ca.vertcat(q[0] - 0.3, v[0]))
    pb.replay_tol = None
    res = pb.solve(shooting=False)
    with pytest.raises(ValueError, match="depend on t"):
        event_pieces(res, restart=True)
    qe, _, pieces = event_pieces(res, n_eval=2)
    assert np.max(np.abs(replay(res, refine=400).q - qe)) < 1e-4  # (measured 1.5e-5: Moreau-Jean's error)
    plan = phase_plan(res)

    def runs(piece):  # the modes of the piece's phases of positive length, repeats merged
        names = [tuple(ph.modes) for ph in piece.phases if ph.t1 > ph.t0]
        return [m for i, m in enumerate(names) if i == 0 or m != names[i - 1]]

    assert [len(segs) for segs in plan] == [len(runs(p)) for p in pieces]
    assert np.allclose([sum(sg[1] for sg in segs) for segs in plan], np.diff(res.t), rtol=0, atol=1e-12)


def test_segments_shrunk_to_zero_are_pruned_with_their_impacts_moved():
    """The ball bounced to a target, its impact placed inside the interval before its node: where
    an iterate shrinks the segment before the impact to zero, the pruned plan has the impact at
    that interval's start; where it shrinks the segment the impact starts, the impact moves to the
    next interval's start. The durations and impulses are the iterate's, and the pruned plan's NLP
    starts with its phases joined (single shooting)."""
    from lcp.ocp.plans import iterate_of, pruned_plan

    pb = EXAMPLES["ball_bounce"]().make(12)
    res = pb.solve()
    plan = phase_plan(res)
    (k0,) = [k for k, segs in enumerate(plan) if segs[0][2]]  # the impact at node k0
    (md, h, at), (mp, hp, _) = plan[k0][0], plan[k0 - 1][0]
    plan[k0 - 1] = [(mp, 0.9 * hp, ()), (md, 0.1 * hp, at)]
    plan[k0] = [(md, h, ())]
    tr = PhaseShooting(pb, plan)
    x = initial_point(tr, res)
    assert pruned_plan(tr, x) is None  # nothing shrank
    d0, d1 = tr.ix["d"].ravel()
    PN = tr.ix["PN"].ravel()[0]
    x[PN] *= 1.01  # (the iterate's impulse, not the plan's, is carried)
    for zero, target in ((d0, k0 - 1), (d1, k0)):
        y = x.copy()
        y[zero], y[d0 + d1 - zero] = 1e-9 * hp, (1 - 1e-9) * hp
        new, removed = pruned_plan(tr, y)
        assert removed == 1
        assert [len(segs) for segs in new] == [1] * pb.N
        hits = [(k, at) for k, segs in enumerate(new) for _, _, at in segs if at]
        assert len(hits) == 1 and hits[0][0] == target
        assert hits[0][1][0][2] == pytest.approx(x[PN], rel=1e-15)
        for k, segs in enumerate(new):
            assert sum(d for _, d, _ in segs) == pytest.approx(res.t[k + 1] - res.t[k], rel=1e-12)
        check = PhaseShooting(pb, new, check=True)
        start = initial_point(check, iterate_of(tr, y))
        assert check.diagnose(start)["dynamics"] < 1e-10
    # an iterate far from feasible that shrinks every segment of an interval: nothing to keep there
    # (the pruned plan had an empty interval, and PhaseShooting.modes raised IndexError)
    y = x.copy()
    y[d0], y[d1] = 1e-9 * hp, 1e-9 * hp
    assert pruned_plan(tr, y) is None
    # an impact that would move past the horizon's end stays
    last = [list(segs) for segs in plan]
    last[-1] = [(md, 0.5 * hp, ()), (md, 0.5 * hp, at)]
    last[k0 - 1] = [(mp, hp, ())]
    tr = PhaseShooting(pb, last)
    y = initial_point(tr, res)
    d0, d1 = tr.ix["d"].ravel()
    y[d0], y[d1] = hp, 0.0
    assert pruned_plan(tr, y) is None


@pytest.mark.slow
def test_the_discs_at_n60_are_solved_once_shrunk_phases_are_pruned():
    """nosnoc's two discs at N = 60: the second shooting round (the replay's impacts) moves three
    switches onto nodes, their segments shrink to zero and IPOPT stops at its iteration limit
    (multipliers of 4e8). Solved again without those segments: success, replay far below 1e-6
    (before the pruning the solve failed, its best replay missing by 6.6e-2)."""
    ex = EXAMPLES["two_discs"]()
    pb = ex.make(60)
    res = pb.solve(ex.start(pb), **ex.solve_kw)
    assert res.success, res.message
    assert "shrank to zero length" in res.message
    assert res.replay.final_miss < 1e-9
    assert res.cost < 209.0


def test_a_replay_near_an_unstable_upright_reports_its_amplification():
    """The cart-pole's control held at zero from the upright at rest: the pole falls away from it
    exponentially (rate sqrt(g / l), about e^15 over 5 s), and the amplification of the replay's
    start errors says so; from the hanging pole the same control amplifies nothing. A check that
    misses on such a trajectory says, in its message, how exact the optimizer would have to be."""
    import copy
    import dataclasses

    from lcp.ocp.replay import amplification, replay
    from lcp.ocp.solve import _checked

    ex = EXAMPLES["cart_pole"]()
    pb = ex.make(20)
    pb.replay_tol = None
    res = pb.solve(pb.guess(u=np.zeros((pb.N, 1))), shooting=False)
    zero = np.zeros_like(res.u)
    hanging = dataclasses.replace(res, u=zero, control=pb.schedule(res.t, zero))
    assert amplification(hanging, replay(hanging, method="event", n_eval=2)) < 10.0
    up = copy.copy(pb)
    up.q0 = np.array([1.0, np.pi, 0.0])
    up.replay_tol = 1e-6
    upright = dataclasses.replace(hanging, problem=up)
    a = amplification(upright, replay(upright, method="event", n_eval=2))
    assert 1e5 < a < 1e9
    out = _checked(up, upright, "homotopy")  # (its optimizer's states: the hanging pole's)
    assert out.status == -3 and out.replay.amplification == pytest.approx(a, rel=1e-6)
    assert "The replay amplifies errors" in out.message


def test_a_hybrid_plan_takes_the_replays_phases_only_where_the_replay_follows():
    """The cart-pole at rest (the hanging pole, the cart stuck), its control raised just past the
    cart's friction (2 N) in one interval: the replay slides the cart there (by about 1e-8 m) while
    the result's own plan sticks throughout. Near 1e-4 the hybrid plan takes the replay's slide; at
    a nearness no node meets, it is the result's own plan again (None)."""
    import dataclasses

    from lcp.ocp.plans import hybrid_plan, plan_of_modes
    from lcp.ocp.replay import replay_check

    ex = EXAMPLES["cart_pole"]()
    pb = ex.make(20)
    pb.replay_tol = None
    res = pb.solve(pb.guess(u=np.zeros((pb.N, 1))), shooting=False)
    u = np.zeros_like(res.u)
    u[10] = 2.0 + 1e-6
    pushed = dataclasses.replace(res, u=u, control=pb.schedule(res.t, u))
    pushed.replay = replay_check(pushed, 1e-6)
    assert 0.0 < pushed.replay.final_miss < 1e-4
    own = plan_of_modes(pushed)
    assert all(segs[0][0] == (STICK,) for segs in own)
    plan = hybrid_plan(pushed, own, 1e-4)
    assert plan is not None
    assert (SLIDE_POS,) in [md for md, _, _ in plan[10]]
    assert all([md for md, _, _ in plan[k]] == [(STICK,)] for k in range(10))
    for k, segs in enumerate(plan):
        assert sum(d for _, d, _ in segs) == pytest.approx(res.t[k + 1] - res.t[k], rel=1e-12)
    assert hybrid_plan(pushed, own, 1e-300) is None
