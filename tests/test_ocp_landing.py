"""The landing of an unstable trajectory's replay (lcp.ocp.landing): Newton steps on the control
against the event replay, and the check of the landed control with its integration error."""
import dataclasses

import casadi as ca
import numpy as np
import pytest

from lcp.model.system import Contact, System
from lcp.ocp import OptimalControlProblem
from lcp.ocp.landing import JOIN_ERROR, LANDING_RTOL, land, landable, landed
from lcp.ocp.replay import event_pieces, replay, replay_check


@pytest.fixture(scope="module")
def unstable():
    return _unstable()


def _unstable(T=14.0, N=8):
    """x'' = x + u on a frictionless floor that the block never leaves (y = 0), from x = 1 at
    velocity -1 (the stable manifold of u = 0: x = e^-t): growth e^t of any error, an amplification
    of about e^14 = 1.2e6 over the horizon."""
    q, v, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 1)
    F = ca.vertcat(q[0] + u[0], -1.0)
    sys = System(q, v, np.eye(2), F, contacts=[Contact(gap=q[1], tangent=q[0], mu=0.0, name="floor")],
                 control=u, control_bounds=(np.array([-10.0]), np.array([10.0])), names=["x", "y"])
    pb = OptimalControlProblem(sys, N, T=T, q0=np.array([1.0, 0.0]), v0=np.array([-1.0, 0.0]),
                               stage_cost=lambda s: s.u0[0] ** 2, replay_tol=None)
    res = pb.solve(pb.guess(u=0.0), shooting=False)
    pb.replay_tol = 1e-6
    return pb, res


def _exact(pb, res, u):
    """``res`` with control ``u`` and, as its optimizer's trajectory, the tight event replay of
    a control slightly off ``u`` (an optimizer whose trajectory errs by 1e-10 in the first push)."""
    off = u.copy()
    off[0, 0] += 1e-10
    ref = dataclasses.replace(res, u=off, control=pb.schedule(res.t, off))
    q, v, _ = event_pieces(ref, restart=True, n_eval=2, rtol=LANDING_RTOL)
    return dataclasses.replace(res, u=u, control=pb.schedule(res.t, u), q=q, v=v)


def test_a_control_whose_replay_misses_an_unstable_trajectory_is_landed_on_it(unstable):
    pb, res = unstable
    u = 1e-7 * np.sin(1.0 + np.arange(pb.control_rows))[:, None]
    out = _exact(pb, res, u)
    rc = replay_check(out, 1e-6)
    assert not rc.ok and rc.amplification > 1e5
    assert landable(rc, 1e-6)
    ld = land(out, 1e-6)
    assert ld is not None and ld.miss_after <= 1e-8
    assert 0.0 < ld.change < 1e-4  # (the optimizer's error was 1e-10 in a control)
    assert ld.u[0, 0] == u[0, 0]  # the last controls moved: the first one stays
    new, note = landed(out, rc, 1e-6)
    assert new is not None and new.replay.ok, note
    assert np.isfinite(new.replay.integration_error) and new.replay.integration_error < 1e-6
    assert new.replay.final_miss <= 1e-8
    assert "Newton steps on the control" in note
    # the landed control, replayed on its own, ends on the optimizer's final state
    q, v, _ = event_pieces(new, restart=True, n_eval=2, rtol=LANDING_RTOL)
    assert np.max(np.abs(q[-1] - out.q[-1])) <= 1e-8 and np.max(np.abs(v[-1] - out.v[-1])) <= 1e-8


def test_misses_that_are_not_conditioning_are_not_landed(unstable):
    pb, res = unstable
    u = 1e-7 * np.cos(np.arange(pb.control_rows))[:, None]
    out = _exact(pb, res, u)
    rc = replay_check(out, 1e-6)
    # a miss larger than the shooting's errors could explain: another trajectory
    far = dataclasses.replace(rc, final_miss=10 * JOIN_ERROR * rc.amplification)
    assert not landable(far, 1e-6)
    # a stable replay: its miss is the optimizer's own
    assert not landable(dataclasses.replace(rc, amplification=10.0), 1e-6)
    assert not landable(dataclasses.replace(rc, method="moreau-jean h=0.01"), 1e-6)
    assert not landable(dataclasses.replace(rc, path_violation=1.0), 1e-6)


def test_controls_at_their_bounds_are_not_moved(unstable):
    pb, res = unstable
    u = np.full((pb.control_rows, 1), 10.0)  # every control at its upper bound: nothing to move
    out = _exact(pb, res, u)
    assert land(out, 1e-6) is None
    rc = replay_check(out, 1e-6)
    new, note = landed(out, rc, 1e-6)
    assert new is None and "no control change" in note


def test_the_check_counts_its_integration_error(unstable):
    pb, res = unstable
    u = 1e-7 * np.cos(np.arange(pb.control_rows))[:, None]
    out = _exact(pb, res, u)
    rc = replay_check(out, 1.0, rtol=LANDING_RTOL, estimate_rtol=1e-10)
    assert rc.method == "event rtol=3e-14"
    assert replay_check(out, 1.0, rtol=LANDING_RTOL, restart=True).method == "event rtol=3e-14, restarted at every node"
    assert rc.integration_error > 0.0
    assert dataclasses.replace(rc, tol=0.5 * rc.integration_error).ok is False
    plain = replay_check(out, 1.0)
    assert np.isnan(plain.integration_error)


def test_replay_accepts_the_integrators_tolerance_in_one_integration(unstable):
    pb, res = unstable
    a = replay(res, method="event", n_eval=2, rtol=1e-10)
    b = replay(res, method="event", n_eval=2, rtol=LANDING_RTOL)
    assert a.pieces is not None and b.pieces is not None
    assert 0.0 < np.max(np.abs(a.q[-1] - b.q[-1])) < 1e-2


@pytest.mark.slow
def test_the_cart_pole_swings_up_at_n20_with_its_replay_landed():
    """nosnoc's cart-pole at N = 20: the shooting from the transcription's states swings the pole
    up (cost 571.12), but its replay missed by 5.6e-5 (an amplification of 1.7e6), and the solve
    returned the hanging pole (cost 6471.76). Landed: success, the replay within 1e-6 with its
    integration error counted."""
    from studies._ocp_models import EXAMPLES

    ex = EXAMPLES["cart_pole"]()
    pb = ex.make(20)
    res = pb.solve(ex.start(pb) if ex.start is not None else None, **ex.solve_kw)
    assert res.success, res.message
    assert res.cost < 600.0
    rc = res.replay
    assert rc.final_miss + rc.integration_error <= 1e-6
    assert "Newton steps on the control" in res.message
    assert abs(res.q[-1][1] - np.pi) < 0.1  # upright


@pytest.mark.slow
def test_the_cart_pole_swings_up_at_n40_on_a_hybrid_plan():
    """The cart-pole at N = 40: the shooting from the transcription's states (647.44) missed its
    replay by 5.1, the replay sticking 14 ms where the shooting slid. On the hybrid plan (the
    replay's phases where it follows) the shooting swings up (621.81) and is landed."""
    from studies._ocp_models import EXAMPLES

    ex = EXAMPLES["cart_pole"]()
    pb = ex.make(40)
    res = pb.solve(ex.start(pb) if ex.start is not None else None, **ex.solve_kw)
    assert res.success, res.message
    assert res.cost < 700.0
    assert res.message.startswith("Solved by exact-phase shooting on the") and "previous shooting's plan" in res.message
    # the replay of the transcription's control is another trajectory (143 times its objective):
    # the shooting from the transcription's states came first, not a round on the replay's phases
    assert "the shooting started from the transcription's states" in res.message
    assert res.replay.final_miss + res.replay.integration_error <= 1e-6
    assert abs(res.q[-1][1] - np.pi) < 0.1


def test_a_replay_from_a_later_node_repeats_the_restarted_replay(unstable):
    """event_pieces from node k with that node's state (restarted) gives the same later nodes as the
    restarted replay from the start, and asks for the state it starts from."""
    pb, res = unstable
    q, v, _ = event_pieces(res, restart=True, n_eval=2)
    q3, v3, pieces = event_pieces(res, restart=True, first=3, start=(q[3], v[3]), n_eval=2)
    assert len(pieces) == pb.N - 3 and q3.shape == (pb.N - 2, 2)
    assert np.array_equal(q3, q[3:]) and np.array_equal(v3, v[3:])
    with pytest.raises(ValueError, match="start"):
        event_pieces(res, restart=True, first=3, n_eval=2)
    with pytest.raises(ValueError, match="restarted"):
        event_pieces(res, first=3, start=(q[3], v[3]), n_eval=2)


def test_differences_swamped_by_the_replays_errors_are_taken_again_at_a_larger_step(unstable, monkeypatch):
    """A step so small that the replay's own errors swamp the differences does not land; the
    next step of FD_STEPS then does, on the same control. (This replay is smooth to rounding: its
    errors are emulated by rounding its states to 1e-9.)"""
    import lcp.ocp.landing as landing

    pb, res = unstable
    u = 1e-7 * np.sin(1.0 + np.arange(pb.control_rows))[:, None]
    out = _exact(pb, res, u)
    real = landing._replay

    def rounded(*args, **kw):
        q, v = real(*args, **kw)
        return np.round(q, 9), np.round(v, 9)

    monkeypatch.setattr(landing, "_replay", rounded)
    monkeypatch.setattr(landing, "FD_STEPS", (1e-16,))
    assert land(out, 1e-6) is None
    monkeypatch.setattr(landing, "FD_STEPS", (1e-16, 1e-6))
    ld = land(out, 1e-6)
    assert ld is not None and ld.miss_after <= 1e-8 and ld.change < 1e-4
