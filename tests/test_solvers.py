"""One-step solvers: the Coulomb law holds, the solvers agree, the K-block chain."""
import numpy as np
import pytest

import lcp
from lcp.contact.problem import OPEN, SLIDE_NEG, SLIDE_POS, STICK, ContactProblem
from lcp.contact.solvers import make_solver

from .conftest import RESIDUAL_TOL


def random_problem(rng, k, mu_max=1.0):
    n = 2 * k + rng.integers(0, 3)
    A = rng.standard_normal((n, n))
    A = A @ A.T + 0.5 * np.eye(n)  # mass matrix
    H = rng.standard_normal((2 * k, n))
    W = H @ np.linalg.solve(A, H.T)
    W = 0.5 * (W + W.T)
    q = rng.standard_normal(2 * k)
    mu = rng.uniform(0, mu_max, k)
    return ContactProblem(W, q, mu)


def test_enum_cases():
    W = np.eye(2)
    mu = np.array([0.5])
    cases = {
        OPEN: np.array([0.3, 1.0]),
        STICK: np.array([-1.0, 0.2]),
        SLIDE_POS: np.array([-1.0, 2.0]),
        SLIDE_NEG: np.array([-1.0, -2.0]),
    }
    for mode, q in cases.items():
        pb = ContactProblem(W, q, mu)
        sol = make_solver("enum").solve(pb)
        assert pb.modes(sol.p)[0] == mode
        assert sol.residual == 0.0


def test_painleve_step_has_stick_solution_only():
    # Jean-Pratt delassus operator at kappa = 1.25: the sliding branch would need p_N < 0
    sc = lcp.scenes.jean_pratt(R=2.5)
    A = sc.system.mass(sc.q0)
    H = sc.system.contact_jacobian(sc.q0)
    W = H @ np.linalg.solve(A, H.T)
    h = 1e-3
    vfree = sc.v0 + h * np.linalg.solve(A, sc.system.force(sc.q0, sc.v0))
    pb = ContactProblem(W, H @ vfree, np.array([2.5]))
    for name in ("enum", "lemke", "osqp"):
        sol = make_solver(name).solve(pb)
        assert sol.success
        assert pb.modes(sol.p)[0] == STICK
        np.testing.assert_allclose(sol.p, [1.0 + h * 2 * 9.81, -2.0], rtol=1e-12)


def test_osqp_failure_is_reported_not_hidden():
    rng = np.random.default_rng(0)
    pb = random_problem(rng, 3)
    sol = make_solver("osqp", osqp_max_iter=1, max_iter=1).solve(pb)
    assert not sol.success and ("OSQP status" in sol.message or "did not converge" in sol.message)


@pytest.mark.parametrize("K", [2, 3, 5, 7, 10])
def test_block_chain_osqp_agrees_with_lemke(K):
    rng = np.random.default_rng(K)
    sc = lcp.scenes.block_chain(K, m=rng.uniform(0.5, 2.0, K), mu=rng.uniform(0.1, 0.6, K),
                                v0=rng.uniform(-2, 2, K), k_spring=80.0)
    a = lcp.simulate(sc, 0.6, h=2e-3, solver="lemke")
    b = lcp.simulate(sc, 0.6, h=2e-3, solver="osqp")
    assert a.success and b.success, (a.message, b.message)
    np.testing.assert_allclose(b.p_N, a.p_N, atol=1e-8)
    np.testing.assert_allclose(b.p_T, a.p_T, atol=1e-8)
    assert a.stats.max_residual <= RESIDUAL_TOL and b.stats.max_residual <= RESIDUAL_TOL
    counts = a.stats.mode_counts
    assert counts["stick"] > 0 and counts["slide+"] + counts["slide-"] > 0  # a real stick-slip test
    assert np.max(np.abs(a.q[:, 1::2])) <= 1e-12  # blocks stay on the floor


def test_block_chain_energy_never_increases():
    sc = lcp.scenes.block_chain(4, k_spring=60.0, v0=[2.0, -1.0, 0.5, 0.0])
    res = lcp.simulate(sc, 1.5, h=1e-3)
    K = sc.params["k_spring"]
    x = res.q[:, 0::2]
    kin = 0.5 * np.sum(res.v[:, 0::2] ** 2, axis=1)
    pot = 0.5 * K * np.sum((np.diff(x, axis=1) - 1.0) ** 2, axis=1)
    E = kin + pot
    # theta = 1/2 is energy-neutral for the springs; friction only dissipates
    assert np.all(np.diff(E) <= 1e-10 * E[0])


def test_failing_solver_falls_back_to_an_exact_one_and_says_so():
    sc = lcp.scenes.block_chain(3)
    opts = dict(osqp_max_iter=1, max_iter=1)
    res = lcp.simulate(sc, 0.2, h=1e-3, solver="osqp", solver_options=opts)
    assert res.success and res.stats.fallbacks > 0
    assert "fallback solver 'lemke'" in res.message and "step 0" in res.message
    ref = lcp.simulate(sc, 0.2, h=1e-3, solver="lemke")
    np.testing.assert_allclose(res.q, ref.q, atol=1e-12)
    stop = lcp.simulate(sc, 0.2, h=1e-3, solver="osqp", solver_options=opts, fallback=False)
    assert not stop.success and stop.status == -1
    assert "Step 0 (t = 0)" in stop.message and stop.stats.steps == 0 and stop.t.size == 1


def test_acceptance_is_relative_to_tiny_impulses():
    # a problem whose impulses are ~1e-15: an answer off by 50 % must not pass as solved
    from lcp.contact.problem import ContactProblem
    from lcp.contact.solvers import OneStepSolver, StepSolution

    class Wrong(OneStepSolver):
        name = "wrong"

        def _solve(self, pb):
            return StepSolution(1.5 * np.array([1e-15, 0.0]))

    pb = ContactProblem(W=np.array([[1.0, 0.0], [0.0, 1.0]]), q=np.array([-1e-15, 0.0]), mu=np.array([0.5]))
    assert Wrong().solve(pb).status < 0
    ok = make_solver("enum").solve(pb)
    assert ok.success and ok.residual <= 1e-30
