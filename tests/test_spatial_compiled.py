"""The compiled Moreau-Jean loop of independent spatial contacts (lcp.timestepping.compiled_spatial)
against the Python loop, and the exact deceleration and stop of sliding pucks."""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st

import lcp
from lcp.model.system import Contact, System
from lcp.numerics.jit import HAVE_NUMBA

pytestmark = pytest.mark.skipif(not HAVE_NUMBA, reason="the compiled loop needs numba")

G = 9.81


def pucks(K, mu=0.3, e=0.0, seed=0, m=1.0):
    """K point masses (x, z, y each) on the floor y = 0, one disk contact each; random in-plane
    launches from rest to 1.5 mu g (some stop within 1 s, some still slide), puck 0 at rest."""
    n = 3 * K
    q, v = ca.SX.sym("q", n), ca.SX.sym("v", n)
    mass = ca.SX(ca.DM(sp.csc_matrix(sp.eye(n) * m)))
    f = np.zeros(n)
    f[2::3] = -m * G
    contacts = [Contact(gap=q[3 * i + 2], tangent=ca.vertcat(q[3 * i], q[3 * i + 1]), mu=mu, e=e, name=f"P{i}")
                for i in range(K)]
    system = System(q, v, mass, ca.SX(f), contacts=contacts)
    rng = np.random.default_rng(seed)
    speed = rng.uniform(0, 1.5 * mu * G, K)
    speed[0] = 0.0
    ang = rng.uniform(0, 2 * np.pi, K)
    v0 = np.zeros(n)
    v0[0::3], v0[1::3] = speed * np.cos(ang), speed * np.sin(ang)
    return system, np.zeros(n), v0


def _agree(a, b, tol=1e-13):
    assert a.status == b.status == 0
    assert a.solver.endswith("(compiled)") and not b.solver.endswith("(compiled)")
    for name in ("q", "v", "p_N", "p_T"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.shape == y.shape
        assert np.max(np.abs(x - y), initial=0.0) <= tol * max(1.0, np.max(np.abs(y), initial=0.0)), name
    assert np.array_equal(np.asarray(a.modes), np.asarray(b.modes))
    assert a.stats.mode_counts == b.stats.mode_counts
    assert a.stats.free_steps == b.stats.free_steps
    assert len(a.impacts) == len(b.impacts)
    for x, y in zip(a.impacts, b.impacts):
        assert (x.contact, x.name) == (y.contact, y.name)
        assert abs(x.t - y.t) <= 1e-13 and abs(x.p_N - y.p_N) <= 1e-13 * max(1.0, abs(y.p_N))
        assert np.max(np.abs(np.asarray(x.p_T) - np.asarray(y.p_T))) <= 1e-13 * max(1.0, abs(y.p_N))


@pytest.mark.parametrize("K", [1, 3, 50])
def test_pucks_match_the_python_loop(K):
    system, q0, v0 = pucks(K)
    a = lcp.simulate(system, 0.6, h=1e-3, q0=q0, v0=v0)
    b = lcp.simulate(system, 0.6, h=1e-3, q0=q0, v0=v0, fast=False)
    _agree(a, b)
    counts = a.stats.mode_counts
    assert counts["stick"] > 0 and (counts["slide"] > 0 or K == 1)


def test_impacts_with_restitution_match_the_python_loop():
    system, q0, v0 = pucks(3, e=0.5, seed=2)
    q0[2::3] = [0.05, 0.02, 0.0]  # two pucks dropped, one resting
    v0[2::3] = [-1.0, -0.5, 0.0]
    a = lcp.simulate(system, 0.5, h=1e-3, q0=q0, v0=v0)
    b = lcp.simulate(system, 0.5, h=1e-3, q0=q0, v0=v0, fast=False)
    _agree(a, b)
    assert any(i.contact == 0 for i in a.impacts) and any(i.contact == 1 for i in a.impacts)
    # the bounce: Newton's law, the normal velocity after the first loaded step is -e times the one before
    k = int(np.flatnonzero(a.p_N[:, 0] > 0)[0])
    assert a.v[k + 1, 2] == pytest.approx(-0.5 * a.v[k, 2], rel=1e-12)
    # a velocity-level scheme: the landing step penetrates by at most h times the approach speed
    assert a.q[:, 2::3].min() >= -1e-3 * 1.0


def test_save_every_and_the_uncompiled_kernel_agree():
    system, q0, v0 = pucks(4, seed=3)
    a = lcp.simulate(system, 0.2, h=1e-3, q0=q0, v0=v0, save_every=7)
    full = lcp.simulate(system, 0.2, h=1e-3, q0=q0, v0=v0)
    np.testing.assert_array_equal(a.q, full.q[::7][: a.q.shape[0]])
    from lcp.contact.spatial_solvers import make_cone_solver
    from lcp.timestepping import compiled_spatial
    from lcp.timestepping.assembly import StepAssembly

    asm = StepAssembly(system, 1e-3, 0.5)
    py = compiled_spatial.moreau_jean_spatial(asm, q0, v0, 200, 1, make_cone_solver("auto"), True, compiled=False)
    np.testing.assert_array_equal(py.q, full.q)


@settings(max_examples=15, deadline=None)
@given(mu=st.floats(0.05, 1.0), speed=st.floats(0.1, 5.0), angle=st.floats(0.0, 2 * np.pi))
def test_a_sliding_puck_decelerates_at_mu_g_and_stops_on_time(mu, speed, angle):
    system, q0, v0 = pucks(1, mu=mu)
    u = np.array([np.cos(angle), np.sin(angle)])
    v0[:2] = speed * u
    h = 1e-3
    t_stop = speed / (mu * G)
    res = lcp.simulate(system, t_stop + 0.01, h=h, q0=q0, v0=v0)
    assert res.solver == "auto (compiled)"
    vt = res.v[:, :2]
    k_stop = int(np.ceil(speed / (mu * G * h) * (1 - 1e-12)))
    k = np.arange(k_stop)
    # before the stop: v_k = v0 - k mu g h u exactly to rounding, along the launch direction
    expect = v0[:2] - (k * (mu * G * h))[:, None] * u
    assert np.max(np.abs(vt[:k_stop] - expect)) <= 1e-12 * speed * max(1, k_stop) ** 0.5 * 10
    assert np.all(np.abs(res.v[:, 2]) <= 1e-15 * speed)
    # stopped at step ceil(|v0| / (mu g h)), and at rest (exactly) afterwards
    assert np.all(vt[k_stop:] == 0.0)
    assert np.all(np.linalg.norm(vt[:k_stop], axis=1) > 0.0)
    assert abs(k_stop * h - t_stop) <= h


def test_coupled_spatial_contacts_take_the_python_loop():
    # one body on two contacts: W couples them, so the Python loop runs
    q, v = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
    system = System(q, v, ca.SX.eye(3), ca.vertcat(0, 0, -G),
                    contacts=[Contact(gap=q[2], tangent=ca.vertcat(q[0], q[1]), mu=0.3, name="a"),
                              Contact(gap=q[2] + 1e-3 * q[0], tangent=ca.vertcat(q[0], q[1]), mu=0.3, name="b")])
    res = lcp.simulate(system, 0.01, h=1e-3, q0=[0.0, 0.0, 0.0], v0=[0.1, 0.0, 0.0])
    assert not res.solver.endswith("(compiled)")


def test_anisotropic_blocks_match_the_python_loop():
    # each body's mass block couples its coordinates: W_jj is full (local_disk3 and the Newton
    # refinement run, not the isotropic closed form)
    K = 6
    rng = np.random.default_rng(5)
    n = 3 * K
    q, v = ca.SX.sym("q", n), ca.SX.sym("v", n)
    blocks = []
    for _ in range(K):
        R = rng.normal(size=(3, 3))
        blocks.append(np.eye(3) + 0.3 * (R @ R.T))
    mass = ca.SX(ca.DM(sp.block_diag(blocks, format="csc")))
    f = np.zeros(n)
    f[2::3] = -G
    contacts = [Contact(gap=q[3 * i + 2], tangent=ca.vertcat(q[3 * i], q[3 * i + 1]), mu=0.4, name=f"B{i}")
                for i in range(K)]
    system = System(q, v, mass, ca.SX(f), contacts=contacts)
    v0 = np.zeros(n)
    v0[0::3], v0[1::3] = rng.uniform(-3, 3, K), rng.uniform(-3, 3, K)
    a = lcp.simulate(system, 0.8, h=1e-3, q0=np.zeros(n), v0=v0)
    b = lcp.simulate(system, 0.8, h=1e-3, q0=np.zeros(n), v0=v0, fast=False)
    _agree(a, b, tol=1e-12)
    assert a.stats.mode_counts["slide"] > 0 and a.stats.mode_counts["stick"] > 0


def test_a_step_the_kernel_cannot_finish_goes_to_the_python_step(monkeypatch):
    # the kernel run as plain Python (py_func), its closed form made to fail once: that step is
    # solved by the Python contact step and the kernel resumes; the run equals the Python loop's
    from lcp.contact.spatial_solvers import make_cone_solver
    from lcp.timestepping import compiled_spatial
    from lcp.timestepping.assembly import StepAssembly

    system, q0, v0 = pucks(3, seed=4)
    closed_form = compiled_spatial._isotropic
    calls = {"n": 0}

    def failing_once(*args):
        calls["n"] += 1
        if calls["n"] == 40:
            return np.nan, np.nan, np.nan, -1
        return closed_form(*args)

    monkeypatch.setattr(compiled_spatial, "_isotropic", failing_once)
    asm = StepAssembly(system, 1e-3, 0.5)
    a = compiled_spatial.moreau_jean_spatial(asm, q0, v0, 60, 1, make_cone_solver("auto"), True, compiled=False)
    b = lcp.simulate(system, 0.06, h=1e-3, q0=q0, v0=v0, fast=False)
    _agree(a, b)
    assert a.stats.fallbacks == 1 and "1 step(s) were solved by the Python solver 'auto'" in a.message


@pytest.mark.parametrize("K", [3, 80])
def test_springs_and_dampers_match_the_python_loop(K):
    # forces affine in the state (each puck tied to its origin by a spring and a damper): the free
    # velocity through S (dense, K = 3) or the sparse assembly (K = 80, 240 contact rows)
    n = 3 * K
    q, v = ca.SX.sym("q", n), ca.SX.sym("v", n)
    f = ca.SX.zeros(n)
    for i in range(K):
        for a in (0, 1):
            f[3 * i + a] = -40.0 * q[3 * i + a] - 0.5 * v[3 * i + a]
        f[3 * i + 2] = -G
    contacts = [Contact(gap=q[3 * i + 2], tangent=ca.vertcat(q[3 * i], q[3 * i + 1]), mu=0.3, name=f"S{i}")
                for i in range(K)]
    system = System(q, v, ca.SX(ca.DM(sp.csc_matrix(sp.eye(n)))), f, contacts=contacts)
    rng = np.random.default_rng(7)
    v0 = np.zeros(n)
    v0[0::3], v0[1::3] = rng.uniform(-2, 2, K), rng.uniform(-2, 2, K)
    a = lcp.simulate(system, 0.5, h=1e-3, q0=np.zeros(n), v0=v0)
    b = lcp.simulate(system, 0.5, h=1e-3, q0=np.zeros(n), v0=v0, fast=False)
    _agree(a, b, tol=1e-12)
    assert a.stats.mode_counts["slide"] > 0 and a.stats.mode_counts["stick"] > 0
