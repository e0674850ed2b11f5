"""Spatial contacts in the optimal-control transcription (lcp.ocp.spatial): the Coulomb disk law."""
import casadi as ca
import numpy as np
import pytest

from lcp.model.system import Contact, System
from lcp.ocp import OptimalControlProblem, effort

MU, G, T = 0.3, 9.81, 1.0
TARGET = (1.0, 0.5)


def point_on_plane(mu=MU):
    q, v, u = ca.SX.sym("q", 3), ca.SX.sym("v", 3), ca.SX.sym("u", 2)
    return System(q, v, ca.SX.eye(3), ca.vertcat(u[0], u[1], -G),
                  contacts=[Contact(gap=q[2], tangent=ca.vertcat(q[0], q[1]), mu=mu, name="point")],
                  control=u, control_bounds=(-20 * np.ones(2), 20 * np.ones(2)))


def problem(N, **kw):
    return OptimalControlProblem(point_on_plane(), N, T=T, q0=np.zeros(3), v0=np.zeros(3), stage_cost=effort,
                                 terminal_constraints=lambda q, v: ca.vertcat(q[0] - TARGET[0], q[1] - TARGET[1],
                                                                              v[0], v[1]), **kw)


def discrete_optimum(N):
    """Rest to rest over d in T with the constant hold on N uniform steps, sliding throughout along the
    straight line (friction mu g opposing the motion): the double integrator's discrete minimum effort
    12 d^2 N^2 / (T^3 (N^2 - 1)) plus the friction's (mu g)^2 T."""
    d = np.hypot(*TARGET)
    return 12 * d ** 2 * N ** 2 / (T ** 3 * (N ** 2 - 1)) + (MU * G) ** 2 * T


@pytest.mark.parametrize("N", [10, 20])
def test_point_on_plane_reaches_the_closed_form_and_replays(N):
    r = problem(N).solve()
    assert r.success, r.message
    assert abs(r.cost - discrete_optimum(N)) <= 1e-8 * r.cost
    assert r.replay.method == "event" and r.replay.final_miss <= 1e-9
    np.testing.assert_allclose(r.q[:, 1], 0.5 * r.q[:, 0], atol=1e-9)  # straight towards the target
    assert r.complementarity_residual <= 1e-8
    assert r.p_T.shape == (N, 2)
    # the friction is mu N on the rim, against the sliding direction, in every sliding step
    slide = r.modes[:, 0] == 4
    assert slide.sum() == N - 1
    fT = np.hypot(r.p_T[slide, 0], r.p_T[slide, 1])
    np.testing.assert_allclose(fT, MU * r.p_N[slide, 0], rtol=1e-7)
    np.testing.assert_allclose(r.p_T[slide, 1], 0.5 * r.p_T[slide, 0], atol=1e-9)
    assert np.all(r.p_T[slide, 0] < 0)


def test_point_on_plane_converges_to_the_continuous_optimum():
    d = np.hypot(*TARGET)
    ref = 12 * d ** 2 / T ** 3 + (MU * G) ** 2 * T
    costs = [problem(N).solve().cost for N in (10, 20)]
    assert costs[1] < costs[0]
    assert abs((costs[0] - ref) / (costs[1] - ref) - 399 / 99) < 1e-5  # N^2/(N^2 - 1)


def test_sticking_point_stays_put():
    """A push within the friction disk does not move the point: 0 effort, stick in every step."""
    ocp = OptimalControlProblem(point_on_plane(), 6, T=T, q0=np.zeros(3), v0=np.zeros(3), stage_cost=effort,
                                terminal_constraints=lambda q, v: ca.vertcat(q[0], q[1], v[0], v[1]))
    r = ocp.solve()
    assert r.success and r.cost <= 1e-10
    assert np.all(r.modes[:, 0] == 1)


@pytest.mark.parametrize("kw, match", [({"contact_law": "gap"}, "velocity law only"),
                                       ({"hold": "affine"}, "hold must be")])
def test_what_the_spatial_transcription_does_not_model_is_refused_by_name(kw, match):
    with pytest.raises(ValueError, match=f"contact 'point' is spatial.*{match}"):
        problem(4, **kw)


def stick_slide_stick(n):
    """T = 2 s exceeds the optimal slide time sqrt(6 d / (mu g)) = 1.51 s: the point sticks, slides and
    sticks. Sliding over n equal steps of the constant hold, the slide of length tau costs
    12 d^2 n^2 / ((n^2 - 1) tau^3) + (mu g)^2 tau, least at tau_n = (36 d^2 n^2 / ((n^2 - 1) (mu g)^2))^(1/4),
    where it is 4/3 (mu g)^2 tau_n (continuous: n -> infinity, 17.435213)."""
    d, c = np.hypot(*TARGET), MU * G
    tau = (36 * d ** 2 * n ** 2 / ((n * n - 1) * c * c)) ** 0.25
    return 4 / 3 * c * c * tau


@pytest.mark.parametrize("N", [6, 10])
def test_free_steps_put_the_stop_on_a_node_and_replay_exactly(N):
    """Free steps with the disk law's cross complementarity: the slide over N - 1 equal steps, the stop
    on a node, the rest in one sticking step; the event replay repeats it to round-off."""
    ocp = OptimalControlProblem(point_on_plane(), N, T=2.0, q0=np.zeros(3), v0=np.zeros(3), stage_cost=effort,
                                steps="free", terminal_constraints=lambda q, v: ca.vertcat(
                                    q[0] - TARGET[0], q[1] - TARGET[1], v[0], v[1]))
    r = ocp.solve()
    assert r.success, r.message
    assert r.cost == pytest.approx(stick_slide_stick(N - 1), rel=1e-10)
    assert r.replay.method == "event" and r.replay.final_miss <= 1e-12
    assert r.modes[:, 0].tolist() == [4] * (N - 2) + [1, 1]
    np.testing.assert_allclose(r.steps[:N - 2], r.steps[0], rtol=1e-8)


def test_uniform_steps_with_a_stop_off_the_grid_are_not_a_success():
    """The same problem on uniform steps: the stop falls inside a step, the replay misses (1.3e-2 at
    N = 10) and the solve says so (its lower cost is that of an inexact trajectory). The exact-phase
    shooting does not model spatial contacts and says so."""
    r = OptimalControlProblem(point_on_plane(), 10, T=2.0, q0=np.zeros(3), v0=np.zeros(3), stage_cost=effort,
                              terminal_constraints=lambda q, v: ca.vertcat(q[0] - TARGET[0], q[1] - TARGET[1],
                                                                           v[0], v[1])).solve()
    assert not r.success and r.status == -3
    assert "Exact-phase shooting not tried: spatial contacts are not modelled" in r.message
    assert r.replay.final_miss > 1e-3
    assert r.cost < stick_slide_stick(9)
