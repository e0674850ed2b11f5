"""Redundant contact rows in the exact-phase shooting: a box resting on two stuck corners.

Four rows (two normal, two tangential) on three velocities: the tangential rows coincide. The
accelerations are unique (zero), the normal forces too, the split of the friction between the two
corners is not. The static solution, with a horizontal push u at the top-left corner (height hgt
above the floor, corners w apart, mass m): N_left = (m g - 2 hgt u / w) / 2, N_right = (m g +
2 hgt u / w) / 2, T_left + T_right = -u; a split within both cones exists iff |u| <= mu m g (and
the box does not tip iff N_left >= 0, u <= m g w / (2 hgt)).
"""
from types import SimpleNamespace

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import lcp
from lcp.contact.modes import OPEN, SLIDE_NEG, SLIDE_POS, STICK
from lcp.ocp import OptimalControlProblem
from lcp.ocp.phase_dynamics import (
    NotShootable,
    impact_rows,
    independent_rows,
    mode_dynamics,
)
from lcp.ocp.shooting import PhaseShooting, initial_point, plan_keys

G, W, HGT, M = 9.81, 0.2, 0.4, 1.0


def _box(mu):
    """The planar box of the box-tip example with its two bottom corners as contacts, pushed
    horizontally at its top-left corner."""
    q, v, u = ca.SX.sym("q", 3), ca.SX.sym("v", 3), ca.SX.sym("u", 1)
    x, y, th = q[0], q[1], q[2]
    c, s = ca.cos(th), ca.sin(th)
    contacts = [lcp.Contact(gap=y + s * a - c * HGT / 2, tangent=x + c * a + s * HGT / 2, mu=mu, name=nm)
                for nm, a in (("left", -W / 2), ("right", W / 2))]
    push_x = x - c * W / 2 - s * HGT / 2
    F = ca.vertcat(0, -M * G, 0) + ca.jacobian(push_x, q).T * u[0]
    inertia = M * (W ** 2 + HGT ** 2) / 12
    return lcp.System(q, v, ca.diag(ca.SX([M, M, inertia])), F, contacts=contacts, control=u,
                      control_bounds=(np.array([0.0]), np.array([10.0])))


def _problem(mu, N=4, target=3.0):
    """Least squares of the push against ``target``, the box at rest from the start."""
    return OptimalControlProblem(_box(mu), N, T=0.4, q0=np.array([0.0, HGT / 2, 0.0]), v0=np.zeros(3),
                                 stage_cost=lambda st_: ca.sum1((st_.u0 - target) ** 2), contact_law="gap",
                                 hold="constant", steps="uniform")


REST = np.array([0.0, HGT / 2, 0.0])


@settings(max_examples=15, deadline=None)
@given(u=st.floats(0.0, 2.4), mu=st.floats(0.1, 1.0))
def test_resting_box_static_solution(u, mu):
    """Both corners stuck: one tangential row dropped, zero acceleration, the exact normal forces,
    the total friction -u for every z, and the null direction moves force between the corners
    without changing the generalized force."""
    pb = _problem(mu)
    modes = (STICK, STICK)
    keep = independent_rows(pb, modes, 0.0, REST)
    assert keep == (0, 1, 2)  # both normals, the left corner's tangential row
    a, lamN, lamT, acc, Z, res = (np.array(o, dtype=float).ravel() if i != 4 else np.array(o, dtype=float)
                                  for i, o in enumerate(mode_dynamics(pb, modes, keep)(0.0, REST, np.zeros(3), [u])))
    assert np.max(np.abs(a)) < 1e-12 and np.max(np.abs(acc)) < 1e-12
    n_left, n_right = (M * G - 2 * HGT * u / W) / 2, (M * G + 2 * HGT * u / W) / 2
    assert lamN == pytest.approx([n_left, n_right], abs=1e-12)
    assert Z.shape == (4, 1) and np.max(np.abs(Z[:2])) == 0.0  # only the friction split is free
    assert np.max(np.abs(res)) < 1e-12  # the dropped row's velocity, acceleration, C Z
    # the proportional split (admissible whenever u <= mu m g) is lambda + Z z for one z
    want = -u * np.array([n_left, n_right]) / (M * G)
    z = np.linalg.lstsq(Z[2:], want - lamT, rcond=None)[0]
    assert Z[2:] @ z + lamT == pytest.approx(want, abs=1e-12)
    assert np.sum(lamT) == pytest.approx(-u, abs=1e-12)


def test_full_rows_are_kept_where_independent():
    """One stuck corner, or two sliding: no row dropped (the plans without redundancy as before)."""
    pb = _problem(0.5)
    assert independent_rows(pb, (STICK, OPEN), 0.0, REST) is None
    assert independent_rows(pb, (SLIDE_POS, SLIDE_POS), 0.0, REST) is None


def test_indeterminate_mode_is_refused():
    """A point on a floor carrying two contacts with the same rows. Both sliding the same way: the
    normal rows coincide and so do their force columns (H_N' - mu H_T'), one is dropped and the
    motion is unique. Sliding opposite ways (modes no replay gives, but a plan may): the rows
    coincide, the force columns do not, the accelerations are not unique: refused, not guessed."""
    q, v, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 1)
    sys = lcp.System(q, v, ca.SX.eye(2), ca.vertcat(u[0], -G), control=u,
                     contacts=[lcp.Contact(gap=q[1], tangent=q[0], mu=0.5), lcp.Contact(gap=q[1], tangent=q[0], mu=0.5)])
    pb = OptimalControlProblem(sys, 2, T=0.2, q0=np.zeros(2), v0=np.zeros(2), contact_law="gap",
                               steps="uniform", hold="constant")
    assert independent_rows(pb, (SLIDE_POS, SLIDE_POS), 0.0, np.zeros(2)) == (0,)
    a = np.array(mode_dynamics(pb, (SLIDE_POS, SLIDE_POS), (0,))(0.0, np.zeros(2), [1.0, 0.0], [3.0])[0]).ravel()
    assert a == pytest.approx([3.0 - 0.5 * G, 0.0], abs=1e-12)  # the slide's exact acceleration
    with pytest.raises(NotShootable, match="not unique"):
        independent_rows(pb, (SLIDE_POS, SLIDE_NEG), 0.0, np.zeros(2))


@pytest.mark.parametrize("mu, u_star", [(0.2, 0.2 * M * G), (0.8, M * G * W / (2 * HGT))])
def test_shooting_finds_the_static_limit(mu, u_star):
    """The push nearest 3 N that keeps both corners stuck: mu m g when sliding limits it (only a
    split of the friction between the corners reaches it: the left corner alone holds less), m g
    w / (2 hgt) when tipping does (the left normal force zero)."""
    pb = _problem(mu)
    plan = [[((STICK, STICK), 0.1, ())]] * pb.N
    guess = SimpleNamespace(t=np.linspace(0.0, 0.4, pb.N + 1), u=np.full((pb.N, 1), 1.0), T=0.4)
    keys = plan_keys(pb, plan, guess)
    assert keys == [[((0, 1, 2), None)]] * pb.N
    check = PhaseShooting(pb, plan, check=True, keys=keys)
    x0 = initial_point(check, guess)
    assert check.diagnose(x0)["dynamics"] < 1e-12 and check.diagnose(x0)["residual"] < 1e-12
    tr = PhaseShooting(pb, plan, substeps=4, keys=keys)
    solver = ca.nlpsol("s", "ipopt", tr.nlp, {"print_time": False, "ipopt": {"print_level": 0, "sb": "yes", "tol": 1e-10}})
    sol = solver(x0=x0, lbx=tr.lbx, ubx=tr.ubx, lbg=tr.lbg, ubg=tr.ubg, p=tr.params())
    assert solver.stats()["return_status"] == "Solve_Succeeded"
    x = np.array(sol["x"]).ravel()
    _, _, q, v, u, _, _ = tr.unpack(x)
    assert np.max(np.abs(u - u_star)) < 1e-6
    assert np.max(np.abs(q - REST)) < 1e-12 and np.max(np.abs(v)) < 1e-12
    diag = check.diagnose(x)
    assert diag["dynamics"] < 1e-10 and diag["residual"] < 1e-7
    # the mean forces are an admissible distribution's: total friction -u, each within its cone
    pN, fT = x[tr.ix["pN"]].reshape(pb.N, 2), x[tr.ix["fT"]].reshape(pb.N, 2)
    assert np.sum(fT, axis=1) == pytest.approx(-u.ravel(), abs=1e-8)
    assert np.all(np.abs(fT) <= mu * pN + 1e-7)


def test_flat_landing_impulses_split_freely():
    """The box landing flat on both corners at 1 m/s, both impulses sticking: four velocity rows
    on three velocities, one tangential row dropped from the impact law. The shooting's impulses
    stop the box (total normal impulse m, total tangential zero), each within its cone, and the
    dropped row holds in the check."""
    pb = OptimalControlProblem(_box(0.5), 2, T=0.2, q0=REST, v0=np.array([0.0, -1.0, 0.0]),
                               stage_cost=lambda st_: ca.sum1((st_.u0 - 1.0) ** 2), contact_law="gap",
                               hold="constant", steps="uniform")
    impacts = ((0, STICK, 0.5, 0.0), (1, STICK, 0.5, 0.0))
    assert impact_rows(pb.system, impacts, REST) == (0, 1, 2)
    plan = [[((STICK, STICK), 0.1, impacts)], [((STICK, STICK), 0.1, ())]]
    guess = SimpleNamespace(t=np.array([0.0, 0.1, 0.2]), u=np.zeros((2, 1)), T=0.2)
    keys = plan_keys(pb, plan, guess)
    assert keys == [[((0, 1, 2), (0, 1, 2))], [((0, 1, 2), None)]]
    check = PhaseShooting(pb, plan, check=True, keys=keys)
    tr = PhaseShooting(pb, plan, substeps=4, keys=keys)
    assert check.n_constraints > tr.n_constraints  # the dropped rows, held in the check only
    solver = ca.nlpsol("s", "ipopt", tr.nlp, {"print_time": False, "ipopt": {"print_level": 0, "sb": "yes", "tol": 1e-10}})
    sol = solver(x0=initial_point(check, guess), lbx=tr.lbx, ubx=tr.ubx, lbg=tr.lbg, ubg=tr.ubg, p=tr.params())
    assert solver.stats()["return_status"] == "Solve_Succeeded"
    x = np.array(sol["x"]).ravel()
    PN, PT = x[tr.ix["PN"]].ravel(), x[tr.ix["PT"]].ravel()
    assert np.sum(PN) == pytest.approx(M * 1.0, abs=1e-9) and np.sum(PT) == pytest.approx(0.0, abs=1e-9)
    assert np.all(np.abs(PT) <= 0.5 * PN + 1e-9)
    # the normal impulses split evenly: the moment balance of a landing that leaves no rotation
    assert PN == pytest.approx([M / 2, M / 2], abs=1e-9)
    _, _, _, v, u, _, _ = tr.unpack(x)
    assert np.max(np.abs(v[1:])) < 1e-12 and np.max(np.abs(u - 1.0)) < 1e-6  # (v[0]: before the landing)
    diag = check.diagnose(x)
    assert diag["dynamics"] < 1e-10 and diag["residual"] < 1e-9


@pytest.mark.slow
def test_box_tip_example_solves_from_the_defaults():
    """The box tipped over an edge (studies' example, N = 20, default starts): its transcription's
    replay misses, the shooting's last phase rests the box on two stuck corners (redundant rows)
    and succeeds, replayed by the event method within 1e-6, on its side at rest at T."""
    from studies._ocp_models import box_tip

    res = box_tip().make(20).solve()
    assert res.success and res.status >= 0, res.message
    assert "exact-phase shooting" in res.message
    assert res.replay.method == "event" and res.replay.final_miss <= 1e-6
    assert res.q[-1, 2] == pytest.approx(-np.pi / 2, abs=1e-9) and np.max(np.abs(res.v[-1])) < 1e-9
    assert np.all(res.p_N >= -1e-9)
