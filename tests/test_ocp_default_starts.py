"""Default starts of ``OptimalControlProblem.solve()``: the stationary start and the pulse starts.

A solve that ends on its default start's own control with no control bound active stopped where it
began: with an exact friction law a push inside the friction cone moves nothing, so a system at
rest under the mid-range control u = 0 is a stationary point. Such a solve is repeated from the
same start at sigma0 = 1 and the lower-cost success kept (else a note says what it found). When
every mid-range start fails, a pulse start (a fraction of the mid-range push over the first part
of the horizon) chosen by its event simulation's distance from the terminal constraints is tried.
"""
from __future__ import annotations

from types import SimpleNamespace

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import lcp
from lcp.ocp import OptimalControlProblem
from lcp.ocp import solve as ocp_solve
from lcp.ocp.guess import (
    PULSE_FRACTIONS,
    PULSE_LEVELS,
    event_guess,
    pulse_controls,
    screened_start,
)

G = 9.81


def block(N=10, mu=0.5, umax=20.0, lo=None, target=1.0):
    """A unit block resting on a floor (mu m g = 4.9 N), pushed horizontally, a terminal cost on its
    position: u = 0 leaves it stuck, and a push below mu m g changes nothing (zero gradient)."""
    q, v, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 1)
    sys = lcp.System(q, v, ca.DM.eye(2), ca.vertcat(u[0], -G),
                     contacts=[lcp.Contact(gap=q[1], tangent=q[0], mu=mu, name="floor")],
                     control=u, control_bounds=([-umax if lo is None else lo], [umax]))
    return OptimalControlProblem(sys, N, T=1.0, q0=[0.0, 0.0], v0=[0.0, 0.0], contact_law="gap", hold="constant", steps="uniform",
                                 stage_cost=lambda s: 0.01 * s.u0[0] ** 2,
                                 terminal_cost=lambda T, q, v: 10 * (q[0] - target) ** 2 + v[0] ** 2)


@settings(max_examples=30, deadline=None)
@given(lo=st.floats(-50, 0), width=st.floats(1e-3, 100), frac=st.floats(0.0, 1.0))
def test_stuck_means_the_start_control_strictly_inside_its_bounds(lo, width, frac):
    hi = lo + width
    pb = SimpleNamespace(u_min=np.array([lo]), u_max=np.array([hi]))
    u0 = np.full((5, 1), lo + frac * width)
    inside = 1e-6 < frac < 1 - 1e-6
    assert ocp_solve.stuck_at_start(pb, SimpleNamespace(u=u0.copy()), SimpleNamespace(u=u0)) == inside
    moved = u0.copy()
    moved[2] += 1e-4 * width * (1 if frac < 0.5 else -1)
    assert not ocp_solve.stuck_at_start(pb, SimpleNamespace(u=moved), SimpleNamespace(u=u0))


def test_an_unbounded_control_is_stuck_only_where_it_did_not_move():
    pb = SimpleNamespace(u_min=np.array([-np.inf, 0.0]), u_max=np.array([np.inf, np.inf]))
    u0 = np.array([[0.0, 2.0], [0.0, 2.0]])
    assert ocp_solve.stuck_at_start(pb, SimpleNamespace(u=u0.copy()), SimpleNamespace(u=u0))
    u1 = u0.copy()
    u1[1, 0] = 1e-3
    assert not ocp_solve.stuck_at_start(pb, SimpleNamespace(u=u1), SimpleNamespace(u=u0))


def test_a_stuck_block_is_solved_again_from_the_larger_relaxation_and_says_so():
    pb = block()
    r = pb.solve()
    assert r.success, r.message
    # u = 0 keeps the block at rest (cost 10): the first solve ends on its start. From sigma0 = 1
    # the relaxed friction lets the block slide to the target for free (cost 1e-17), IPOPT then
    # stops at sigma = 0.1, and that solution's replay stays at rest: its objective is far above
    # the transcription's, so the exact-phase shooting starts from the transcription's states, and
    # pushes the block (cost 0.3604, exact replay)
    assert "a stationary point of the start" in r.message and "solved again from sigma0 = 1" in r.message
    assert "the shooting started from the transcription's states" in r.message
    assert r.cost < 0.37 and r.replay.final_miss <= 1e-12
    assert r.q[-1, 0] > 0.5 and np.max(r.u) > 4.9  # pushed past the friction


def test_a_users_sigma0_is_not_second_guessed():
    r = block().solve(sigma0=1e-4)
    assert "stationary point" not in r.message and all(s.sigma <= 1e-4 for s in r.homotopy)


def _pushed_to_one_metre():
    """A unit block pushed to rest at 1 m in 1 s against 4.9 N of friction, least effort, N = 10."""
    q, v, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 1)
    sys = lcp.System(q, v, ca.DM.eye(2), ca.vertcat(u[0], -G),
                     contacts=[lcp.Contact(gap=q[1], tangent=q[0], mu=0.5, name="floor")],
                     control=u, control_bounds=([-20.0], [20.0]))
    return OptimalControlProblem(sys, 10, T=1.0, q0=[0.0, 0.0], v0=[0.0, 0.0], contact_law="gap", hold="constant", steps="uniform",
                                 stage_cost=lambda s: s.u0[0] ** 2,
                                 terminal_constraints=lambda q, v: ca.vertcat(q[0] - 1.0, v[0]))


def test_a_solve_that_moves_is_not_repeated(monkeypatch):
    def refuse(*args, **kw):
        raise AssertionError("a solve that left its start was repeated")

    monkeypatch.setattr(ocp_solve, "unstuck", refuse)
    pb = _pushed_to_one_metre()  # the control leaves u = 0
    r = pb.solve()
    assert r.success, r.message
    assert abs(r.q[-1, 0] - 1.0) <= 1e-8 and np.max(np.abs(r.u)) > 0.5 * G  # above the friction


def test_pulse_controls_are_fractions_of_the_mid_range_push_held_then_released():
    pb = block(lo=0.0, umax=30.0)
    cands = pulse_controls(pb)
    assert len(cands) == len(PULSE_LEVELS) * len(PULSE_FRACTIONS) - 1
    tm = (np.arange(pb.N) + 0.5) * pb.T / pb.N
    for a, f, u in cands:
        assert not (a == 1.0 and f == 1.0)
        assert u.shape == (pb.N, 1)
        np.testing.assert_allclose(u[:, 0], np.where(tm < f * pb.T, a * 15.0, 0.0), rtol=0, atol=0)
    # symmetric bounds: the rest control is the mid-range one, no pulse to try
    assert pulse_controls(block(lo=-30.0, umax=30.0)) == []


def test_the_screened_pulse_meets_the_terminal_constraints_at_the_lowest_cost():
    # pushed from rest to stop at 0.2 m: every pulse that stops the block there beats those that do not
    q, v, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 1)
    sys = lcp.System(q, v, ca.DM.eye(2), ca.vertcat(u[0], -G),
                     contacts=[lcp.Contact(gap=q[1], tangent=q[0], mu=0.5, name="floor")],
                     control=u, control_bounds=([0.0], [30.0]))

    def term(q, v):
        return ca.vertcat(v[0])

    pb = OptimalControlProblem(sys, 10, T=1.0, q0=[0.0, 0.0], v0=[0.0, 0.0], contact_law="gap", hold="constant", steps="uniform",
                               stage_cost=lambda s: s.u0[0] ** 2, terminal_constraints=term)
    a, f, gs = screened_start(pb)
    viol = {}
    for a2, f2, u2 in pulse_controls(pb):
        g2 = event_guess(pb, u2, pb.T)
        viol[(a2, f2)] = abs(g2.v[-1, 0])
    assert viol[(a, f)] <= 1e-6
    # without a transcription the smaller push a f ranks the candidates that meet the constraints
    assert a * f == min(a2 * f2 for (a2, f2), vv in viol.items() if vv <= 1e-6)
    assert abs(gs.v[-1, 0]) <= 1e-6


@pytest.mark.slow
def test_the_box_tip_lands_on_its_side_from_the_pulse_start():
    # every mid-range start fails (15 N tumbles the box); the pulse start tips it onto its side and
    # the transcription meets the terminal constraints (its replay may still miss: the box's
    # pivot and landing fall between nodes)
    from studies._ocp_models import EXAMPLES

    r = EXAMPLES["box_tip"]().make(20).solve(shooting=False)
    assert "the pulse start nearest the terminal constraints" in r.message
    assert "from the event-method simulation of the mid-range control from sigma0 = 1" in r.message
    assert r.homotopy[-1].success and r.complementarity_residual <= 1e-8
    assert abs(r.q[-1, 2] + np.pi / 2) <= 1e-8 and np.max(np.abs(r.v[-1])) <= 1e-8
    # the effort is below the tipping threshold's held over the whole horizon: 2.45 N (m g w / 2 / h)
    assert r.cost < (G * 0.1 / 0.4) ** 2 * 1.0


def test_a_start_whose_result_fails_its_replay_does_not_end_the_starts(monkeypatch):
    # the first converged start's result is made to fail (as a replay miss would): the next default
    # start is solved, and its success is returned with the first one named
    pb = _pushed_to_one_metre()
    real, calls = ocp_solve.finished, []

    def first_fails(*args, **kw):
        res = real(*args, **kw)
        calls.append(res.cost)
        if len(calls) == 1:
            res.status = -3
        return res

    monkeypatch.setattr(ocp_solve, "finished", first_fails)
    # the block slides without impacts: both simulations of its push are the same start, which
    # default_starts solves once; it is solved twice here, the first result made to fail
    monkeypatch.setattr(ocp_solve, "same_guess", lambda a, b: False)
    r = pb.solve()
    assert len(calls) == 2 and r.success, r.message
    assert f"from the {ocp_solve.MJ_START}: its solution (cost {calls[0]:.10g}" in r.message
    assert f"Started from the {ocp_solve.EVENT_START}" in r.message
    assert abs(r.q[-1, 0] - 1.0) <= 1e-8 and r.replay.ok
