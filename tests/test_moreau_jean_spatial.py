"""Moreau-Jean with spatial contacts (the Coulomb disk): exact references, invariants, the planar case."""
import math

import casadi as ca
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import lcp
from lcp.scenes.spatial_systems import incline_slide, jean_pratt_spatial, lateral_force_slide, plane_slide
from lcp.model.system import Contact, System

EXACT_SOLVERS = ["auto", "local", "nsgs", "newton", "tresca"]


def disk_residual(res, system):
    """Worst natural-map residual of every step, from the result alone (u = H v+, p from the result).

    Independent of the solver and of W: for a constant system H is constant, the post-step local
    velocity is H v_{k+1}, and r - proj_K(r - (u_N + mu |u_T|, u_T)) must vanish on every contact,
    in impulse units relative to the step's impulse scale."""
    H = system.contact_jacobian(np.zeros(system.n))
    m, off = system.n_contacts, system.tangent_offsets
    worst = 0.0
    for k in range(res.p_N.shape[0]):
        u = H @ res.v[k + 1]
        for j in range(m):
            if res.modes[k, j] < 0:
                continue
            pN, pT = res.p_N[k, j], res.p_T[k, off[j]:off[j + 1]]
            uN, uT = u[j], u[m + off[j]:m + off[j + 1]]
            rho = 1.0  # unit masses in these scenes: u and p share units up to the mass
            zN = pN - rho * (uN + system.mu[j] * np.linalg.norm(uT))
            zT = pT - rho * uT
            nz, s = np.linalg.norm(zT), system.mu[j]
            if nz <= s * zN:
                prN, prT = zN, zT
            elif s * nz <= -zN:
                prN, prT = 0.0, 0.0 * zT
            else:
                a = (zN + s * nz) / (1 + s * s)
                prN, prT = a, s * a * zT / nz
            scale = max(abs(pN), np.linalg.norm(pT), np.linalg.norm(uT), abs(uN), 1e-300)
            worst = max(worst, math.hypot(pN - prN, *(pT - prT)) / scale)
    return worst


@pytest.mark.parametrize("solver", EXACT_SOLVERS)
def test_spatial_jean_pratt_along_x_is_the_planar_scene(solver):
    for R, v0 in ((0.5, 1.0), (1.3, 0.8), (0.35, -1.7)):
        sp = jean_pratt_spatial(m=1.3, M=0.7, alpha=0.9, R=R, v0=(v0, 0.0))
        pl = lcp.scenes.jean_pratt(m=1.3, M=0.7, alpha=0.9, R=R, v0=v0)
        a = lcp.simulate(sp, 0.3, h=1e-3, solver=solver)
        b = lcp.simulate(pl, 0.3, h=1e-3)
        assert a.success and b.success, a.message
        assert np.max(np.abs(a.q[:, 0] - b.q[:, 0])) <= 1e-14
        assert np.max(np.abs(a.v[:, 0] - b.v[:, 0])) <= 1e-14
        assert np.max(np.abs(a.q[:, 2] - b.q[:, 1])) <= 1e-14
        assert np.all(a.q[:, 1] == 0.0) and np.all(a.v[:, 1] == 0.0)
        assert np.max(np.abs(a.p_N[:, 0] - b.p_N[:, 0])) <= 1e-14 * max(1.0, np.max(b.p_N))


def test_incline_first_order_or_better():
    sc = incline_slide(theta=0.4, v0=1.2)
    errs = []
    hs = [1e-2, 1e-3, 1e-4]
    for h in hs:
        res = lcp.simulate(sc, 2.0, h=h, save_every=max(1, int(round(1e-2 / h))))
        assert res.success, res.message
        ex = sc.exact(res.t)
        errs.append(max(np.max(np.abs(res.q[:, 0] - ex["x"])), np.max(np.abs(res.q[:, 1] - ex["z"]))))
        assert np.max(np.abs(res.q[:, 2])) <= 1e-14  # never leaves the incline
        assert res.stats.max_residual <= 1e-10
    orders = np.diff(np.log10(errs)) / np.diff(np.log10(hs))
    # first order: the friction direction of a step is that of its end velocity (measured 0.995, 0.9995)
    assert np.all(orders >= 0.99), (errs, orders)
    # the speed tends to v0/2 (launch across the incline, mu = tan theta)
    speed = np.hypot(res.v[-1, 0], res.v[-1, 1])
    assert abs(speed - sc.exact([2.0])["speed"][0]) <= 1e-3


@pytest.mark.parametrize("solver", EXACT_SOLVERS)
def test_oblique_launch_stops_without_creep(solver):
    sc = plane_slide(m=1.0, mu=0.4, v0=1.3, beta=0.7)
    res = lcp.simulate(sc, 3.0, h=1e-3, solver=solver)
    assert res.success, res.message
    ex = sc.exact(res.t)
    # theta = 1/2 is exact while sliding: the error comes from the stopping step (<= a h^2 / 8)
    bound = sc.solution.decel * 1e-6 / 8 * (1 + 1e-9) + 1e-15
    assert np.max(np.abs(np.hypot(res.q[:, 0] - ex["x"], res.q[:, 1] - ex["z"]))) <= bound
    stopped = res.t > sc.solution.t_stop + 1e-3
    assert np.all(res.v[stopped] == 0.0)
    assert disk_residual(res, sc.system) <= 1e-10


@pytest.mark.parametrize("t_end", [1e3, pytest.param(1e4, marks=pytest.mark.slow)])
def test_no_creep_after_the_stop(t_end):
    sc = plane_slide(m=2.5, mu=0.3, v0=1.0, beta=2.2)
    res = lcp.simulate(sc, t_end, h=0.1, save_every=1000)
    assert res.success, res.message
    assert np.all(res.v[1:] == 0.0)
    assert np.all(res.q[1:] == res.q[1])


def test_lateral_force_ends_in_stick():
    sc = lateral_force_slide(m=1.0, mu=0.5, F=(2.0, 1.0), v0=(-0.5, 1.5))
    res = lcp.simulate(sc, 1.5 * sc.solution.t_stop, h=1e-4, save_every=10)
    assert res.success, res.message
    ex = sc.exact(res.t)
    assert np.max(np.abs(res.q[:, 0] - ex["x"])) <= 1e-4
    assert np.max(np.abs(res.q[:, 1] - ex["z"])) <= 1e-4
    assert np.all(res.v[res.t > sc.solution.t_stop + 1e-3] == 0.0)


# launch angles of 1e-300 give velocity components whose products are subnormal: a stuck contact
# then keeps a 5e-324 residue (the smallest float), so angles are 0 or at least 1e-12 in size
_BETA = st.one_of(st.just(0.0), st.floats(1e-12, 3.1), st.floats(-3.1, -1e-12))


@given(m=st.floats(0.2, 5.0), mu=st.floats(0.05, 1.5), v0=st.floats(0.1, 3.0), beta=_BETA)
def test_plane_random_parameters(m, mu, v0, beta):
    sc = plane_slide(m=m, mu=mu, v0=v0, beta=beta)
    h = 1e-3
    res = lcp.simulate(sc, h=h)
    assert res.success, res.message
    ex = sc.exact(res.t)
    err = np.max(np.hypot(res.q[:, 0] - ex["x"], res.q[:, 1] - ex["z"]))
    assert err <= sc.solution.decel * h * h / 8 * (1 + 1e-9) + 1e-14 * v0 * sc.t_end
    assert np.all(res.v[res.t > sc.solution.t_stop + h] == 0.0)
    assert res.stats.max_residual <= 1e-10 * max(1.0, m * v0)


def test_mixed_planar_and_spatial_contacts():
    # a block on the floor (spatial contact) and a bead on a rail (planar), joined by a spring
    q, v = ca.SX.sym("q", 4), ca.SX.sym("v", 4)  # block (x, z, y), bead offset s along x
    k = 30.0
    spring = -k * (q[0] - q[3] - 1.0)
    force = ca.vertcat(spring, 0.0, -9.81, -spring - 9.81)
    system = System(q, v, mass=ca.SX.eye(4), force=force,
                    contacts=[Contact(gap=q[2], tangent=ca.vertcat(q[0], q[1]), mu=0.3, name="floor"),
                              Contact(gap=q[3] + 2.0, tangent_jacobian=ca.DM([[0, 1.0, 0, 0]]), mu=0.2, name="rail")],
                    names=("x", "z", "y", "s"))
    assert system.tangent_dims.tolist() == [2, 1]
    # theta = 1: the scheme's discrete energy is dissipated by springs and contacts alike (with
    # theta = 1/2 a step in which a contact sticks can gain O(h^2) of it)
    res = lcp.simulate(system, 1.0, h=1e-3, theta=1.0, q0=[0.0, 0.0, 0.0, -2.0], v0=[1.0, 0.8, 0.0, 0.0])
    assert res.success, res.message
    assert res.p_T.shape == (res.p_N.shape[0], 3)
    assert res.stats.max_residual <= 1e-10
    # the bead is lifted by the spring and lands again: Moreau-Jean's landing step penetrates by at
    # most h times the landing speed (velocity-level constraint), and never sinks further
    assert np.min(res.q[:, 2]) >= -1e-12
    assert np.min(res.q[:, 3] + 2.0) >= -1e-3 * np.max(np.abs(res.v[:, 3]))
    assert np.all(np.abs(np.diff(res.q[-100:, 3])) <= 1e-12)  # resting on the rail at the end
    # energy never increases (dissipative contacts, conservative spring and gravity)
    E = (0.5 * np.sum(res.v ** 2, axis=1) + 0.5 * k * (res.q[:, 0] - res.q[:, 3] - 1.0) ** 2
         + 9.81 * (res.q[:, 2] + res.q[:, 3]))
    assert np.all(np.diff(E) <= 1e-9 * max(1.0, E[0]))


def test_faceted_is_a_labelled_approximation():
    sc = plane_slide(v0=1.0, beta=0.3)
    res = lcp.simulate(sc, 0.5, h=1e-3, solver="faceted")
    assert "approximat" in res.message.lower() or "approximat" in res.solver.lower()


def test_planar_only_solver_and_unknown_name_are_refused():
    sc = plane_slide()
    with pytest.raises(ValueError, match="osqp.*spatial"):
        lcp.simulate(sc, 0.1, solver="osqp")
    with pytest.raises(ValueError, match="unknown solver"):
        lcp.simulate(sc, 0.1, solver="nope")


def test_degenerate_tangent_rows_name_the_contact():
    q, v = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
    with pytest.raises(ValueError, match="'foot'"):
        System(q, v, ca.SX.eye(3), ca.vertcat(0, 0, -9.81),
               contacts=[Contact(gap=q[2], tangent=ca.vertcat(q[0], 2 * q[0]), mu=0.3, name="foot")])
    with pytest.raises(ValueError, match="'heel'"):  # a tangent along the normal
        System(q, v, ca.SX.eye(3), ca.vertcat(0, 0, -9.81),
               contacts=[Contact(gap=q[2], tangent=ca.vertcat(q[0], q[2]), mu=0.3, name="heel")])
    with pytest.raises(ValueError, match="tangent_jacobian of toe"):
        System(q, v, ca.SX.eye(3), ca.vertcat(0, 0, -9.81),
               contacts=[Contact(gap=q[2], tangent_jacobian=ca.DM.ones(3, 3), mu=0.3, name="toe")])
    # dependent on q: checked at the initial state
    s = System(q, v, ca.SX.eye(3), ca.vertcat(0, 0, -9.81),
               contacts=[Contact(gap=q[2], tangent=ca.vertcat(q[0], q[0] * q[1]), mu=0.3, name="knee")])
    with pytest.raises(ValueError, match="'knee'"):
        lcp.simulate(s, 0.1, q0=[0.0, 0.0, 0.0], v0=[0.0, 0.0, 0.0])
