"""Property-based tests over random systems and states (hypothesis).

Each property runs with the default profile in the normal suite, and with 1000 examples in the
slow-marked variant (``python -m pytest -m slow``).
"""
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import lcp
from lcp.contact.problem import ContactProblem
from lcp.scenes import jean_pratt
from lcp.contact.solvers import make_solver

from .conftest import RESIDUAL_TOL

THOROUGH = settings(max_examples=1000, deadline=None)


def random_problem(seed, k, mu_max=1.0):
    rng = np.random.default_rng(seed)
    n = 2 * k + int(rng.integers(0, 3))
    A = rng.standard_normal((n, n))
    A = A @ A.T + 0.5 * np.eye(n)  # a mass matrix
    H = rng.standard_normal((2 * k, n))
    W = H @ np.linalg.solve(A, H.T)
    return ContactProblem(0.5 * (W + W.T), rng.standard_normal(2 * k), rng.uniform(0, mu_max, k))


# ----------------------------------------------------------------------------- Coulomb and Signorini
def coulomb_and_signorini(seed, k):
    pb = random_problem(seed, k)
    for name in ["lemke", "osqp", "auto"] + (["enum"] if k == 1 else []):
        sol = make_solver(name).solve(pb)
        assert sol.success, (name, sol.message)
        assert sol.residual <= RESIDUAL_TOL * max(1.0, pb.scale)
        p, u = sol.p, pb.velocity(sol.p)
        pN, pT, uN, uT = p[:k], p[k:], u[:k], u[k:]
        tol = 1e-9 * max(1.0, pb.scale, float(np.abs(u).max()))
        assert np.all(pN >= -tol) and np.all(uN >= -tol)  # Signorini
        assert np.all(np.abs(pN * uN) <= tol * max(1.0, float(np.abs(p).max())))
        assert np.all(np.abs(pT) <= pb.mu * pN + tol)  # the friction cone
        sliding = np.abs(uT) > 1e-7 * max(1.0, float(np.abs(u).max()))
        np.testing.assert_allclose(pT[sliding], -pb.mu[sliding] * pN[sliding] * np.sign(uT[sliding]), atol=10 * tol)


@given(seed=st.integers(0, 2**32 - 1), k=st.integers(1, 4))
def test_coulomb_and_signorini(seed, k):
    coulomb_and_signorini(seed, k)


@pytest.mark.slow
@THOROUGH
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(1, 4))
def test_coulomb_and_signorini_thorough(seed, k):
    coulomb_and_signorini(seed, k)


# ----------------------------------------------------------------------------- solvers agree
def solvers_agree(seed):
    pb = random_problem(seed, 1)
    e = make_solver("enum").solve(pb)
    assert e.success
    if e.ambiguous:
        return  # several solutions: agreement is not expected, each is checked above
    for name in ("lemke", "osqp"):
        np.testing.assert_allclose(make_solver(name).solve(pb).p, e.p, atol=1e-9 * max(1.0, pb.scale))


@given(seed=st.integers(0, 2**32 - 1))
def test_solvers_agree(seed):
    solvers_agree(seed)


@pytest.mark.slow
@THOROUGH
@given(seed=st.integers(0, 2**32 - 1))
def test_solvers_agree_thorough(seed):
    solvers_agree(seed)


# ----------------------------------------------------------------------------- energy
params = dict(m=st.floats(0.1, 10), M=st.floats(0.1, 10), alpha=st.floats(0.1, 1.4), kappa=st.floats(0.01, 0.95),
              v0=st.floats(-3, 3), phi_ratio=st.floats(-2, 2), theta=st.sampled_from([0.5, 1.0]),
              solver=st.sampled_from(["auto", "lemke", "osqp"]))


def energy_never_increases(m, M, alpha, kappa, v0, phi_ratio, theta, solver):
    t = math.tan(alpha)
    R = kappa * (m + M * t * t) / (M * t)
    phi = phi_ratio * R * (m + M) * 9.81  # stick, slip and reversal
    sc = jean_pratt(m=m, M=M, alpha=alpha, R=R, v0=v0, phi=phi)
    tau = sc.tau0 if sc.solution is not None and 1e-6 < sc.tau0 < math.inf else 0.3  # None: lift-off
    h = tau / 30.3
    res = lcp.simulate(sc, 3 * tau, h=h, theta=theta, solver=solver)
    assert res.success, res.message
    A = sc.system.mass(sc.q0)
    T = 0.5 * np.einsum("ki,ij,kj->k", res.v, A, res.v)
    V = (m + M) * 9.81 * res.q[:, 1] - phi * res.q[:, 0]
    dE = np.diff(T + V)
    tol = 1e-11 * max(1.0, float(np.max(np.abs(T))), float(np.max(np.abs(V))))  # rounding of T and V
    if theta == 1.0:
        assert np.all(dE <= tol)  # dE = p.u+ - |v+ - v-|^2_A / 2 <= 0
    else:
        # dE = p.(u+ + u-)/2 exactly; Coulomb gives p.u+ <= 0, so dE <= max(p.u-, 0) / 2 = O(h^2)
        work = res.p_N[:, 0] * res.v[:-1, 1] + res.p_T[:, 0] * res.v[:-1, 0]
        assert np.all(dE <= 0.5 * np.maximum(work, 0.0) + tol)


@given(**params)
def test_energy_never_increases(**kw):
    energy_never_increases(**kw)


@pytest.mark.slow
@THOROUGH
@given(**params)
def test_energy_never_increases_thorough(**kw):
    energy_never_increases(**kw)


# ----------------------------------------------------------------------------- unit scaling
scales = st.integers(-4, 4).map(lambda k: 2.0**k)


def unit_scaling(m, M, alpha, kappa, v0, phi_ratio, theta, solver, L, Ms, T):
    """Rescaling lengths by L, masses by Ms and times by T rescales the answer exactly."""
    t = math.tan(alpha)
    R = kappa * (m + M * t * t) / (M * t)
    g = 9.81
    phi = phi_ratio * R * (m + M) * g
    base = jean_pratt(m=m, M=M, alpha=alpha, R=R, v0=v0, phi=phi, g=g)
    tau = base.tau0 if base.solution is not None and 1e-6 < base.tau0 < math.inf else 0.3  # None: lift-off
    h = tau / 20.3
    a = lcp.simulate(base, 2 * tau, h=h, theta=theta, solver=solver)
    F = Ms * L / T**2
    scaled = jean_pratt(m=m * Ms, M=M * Ms, alpha=alpha, R=R, v0=v0 * L / T, phi=phi * F, g=g * L / T**2)
    b = lcp.simulate(scaled, 2 * tau * T, h=h * T, theta=theta, solver=solver)
    assert a.success and b.success
    # powers of two commute with rounding: the scaled run is the same computation
    np.testing.assert_allclose(b.q, a.q * L, rtol=1e-13, atol=1e-13 * L * max(1.0, float(np.abs(a.q).max())))
    np.testing.assert_allclose(b.v, a.v * L / T, rtol=1e-13, atol=1e-13 * L / T * max(1.0, float(np.abs(a.v).max())))
    np.testing.assert_allclose(b.p_N, a.p_N * Ms * L / T, rtol=1e-12, atol=1e-13 * Ms * L / T)
    np.testing.assert_array_equal(b.modes, a.modes)


@given(**params, L=scales, Ms=scales, T=scales)
def test_unit_scaling(**kw):
    unit_scaling(**kw)


@pytest.mark.slow
@THOROUGH
@given(**params, L=scales, Ms=scales, T=scales)
def test_unit_scaling_thorough(**kw):
    unit_scaling(**kw)
