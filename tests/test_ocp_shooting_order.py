"""The order of the exact-phase shooting's starts: from the transcription's states first when its
event replay is another trajectory (its objective far above the transcription's)."""
import casadi as ca
import numpy as np
import pytest

from lcp.model.system import Contact, System
from lcp.ocp import OptimalControlProblem
from lcp.ocp.replay import node_objective
from lcp.ocp.solve import FAR_REPLAY, replay_objective_ratio
from studies.optimal_control import rest_to_rest_problem


@pytest.mark.parametrize("objective", ["effort", "time"])
def test_the_objective_on_the_nodes_is_the_transcriptions_cost(objective):
    """On the theta transcription's own nodes the rule is its cost; the Jean-Pratt block's event
    replay is exact, so the ratio is 1."""
    res = rest_to_rest_problem(10, objective, "constant", "uniform").solve()
    assert res.success, res.message
    assert node_objective(res, res.q, res.v) == pytest.approx(res.cost, rel=1e-12)
    assert replay_objective_ratio(res) == pytest.approx(1.0, rel=1e-9)


def _unstable_with_target(N=8, T=6.0):
    """x'' = x + u on a frictionless floor, from the stable manifold x = e^-t (start errors grow as
    e^t), asked to end at x = 0.2 at rest: the theta transcription's replay ends 0.14 away."""
    q, v, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 1)
    F = ca.vertcat(q[0] + u[0], -1.0)
    sys = System(q, v, np.eye(2), F, contacts=[Contact(gap=q[1], tangent=q[0], mu=0.0, name="floor")],
                 control=u, control_bounds=(np.array([-10.0]), np.array([10.0])), names=["x", "y"])
    return OptimalControlProblem(sys, N, T=T, q0=np.array([1.0, 0.0]), v0=np.array([-1.0, 0.0]),
                                 stage_cost=lambda s: s.u0[0] ** 2,
                                 terminal_cost=lambda T, q, v: (q[0] - 0.2) ** 2 + v[0] ** 2)


def test_a_replay_far_from_the_transcription_starts_the_shooting_from_its_states():
    pb = _unstable_with_target()
    raw = pb.solve(pb.guess(u=0.0), shooting=False)
    assert raw.status == -3 and raw.replay.final_miss > 0.1
    assert replay_objective_ratio(raw) > FAR_REPLAY
    # the objective on the replay's nodes is the terminal cost of where the replay ends
    qN, vN = raw.replay.pieces[-1].q[-1], raw.replay.pieces[-1].v[-1]
    h = np.diff(raw.t)
    u0 = raw.u[0::2, 0] if raw.hold == "affine" else raw.u[:, 0]  # each step's u0
    effort = float(np.sum(h * u0 ** 2))
    ratio = (effort + (qN[0] - 0.2) ** 2 + vN[0] ** 2) / node_objective(raw, raw.q, raw.v)
    assert replay_objective_ratio(raw) == pytest.approx(ratio, rel=1e-9)
    res = pb.solve(pb.guess(u=0.0))
    assert res.success, res.message
    assert res.message.startswith("Solved by exact-phase shooting on the") and "transcription's own modes" in res.message
    assert "the shooting started from the transcription's states, before the replay's phases" in res.message
    assert res.replay.final_miss <= 1e-6
