"""Lemke's method against brute-force enumeration of complementary bases."""
import itertools

import numpy as np
import pytest
from hypothesis import given, strategies as st

from lcp.contact.lemke import lemke


def brute_force(M, q):
    """All solutions of LCP(M, q) by enumerating the 2^n complementary index sets."""
    n = q.size
    sols = []
    for mask in itertools.product([0, 1], repeat=n):
        J = np.flatnonzero(mask)  # z_J free, w_J = 0
        z = np.zeros(n)
        if J.size:
            try:
                z[J] = np.linalg.solve(M[np.ix_(J, J)], -q[J])
            except np.linalg.LinAlgError:
                continue
        w = M @ z + q
        if np.all(z >= -1e-9) and np.all(w >= -1e-9):
            sols.append(z)
    return sols


def p_matrix(rng, n):
    # positive definite but not symmetric: a P-matrix, so the LCP has exactly one solution
    S = rng.standard_normal((n, n))
    K = rng.standard_normal((n, n))
    return S @ S.T + 0.1 * np.eye(n) + (K - K.T)


@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 7))
def test_unique_solution_of_p_matrix_lcp(seed, n):
    rng = np.random.default_rng(seed)
    M = p_matrix(rng, n)
    q = rng.standard_normal(n)
    r = lemke(M, q)
    assert r.success, r.message
    (z_ref,) = brute_force(M, q)
    np.testing.assert_allclose(r.z, z_ref, atol=1e-9 * max(1.0, np.abs(z_ref).max()))
    assert r.residual <= 1e-10 * max(1.0, np.abs(q).max())


@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 6))
def test_degenerate_right_hand_sides(seed, n):
    rng = np.random.default_rng(seed)
    M = p_matrix(rng, n)
    q = np.round(rng.standard_normal(n))  # many exact zeros and ties
    q[0] = -1.0
    r = lemke(M, q)
    assert r.success
    assert r.residual <= 1e-10
    assert np.all(r.z >= 0) and np.all(r.w >= -1e-10)


def test_trivial_and_known_cases():
    r = lemke(np.eye(3), np.array([1.0, 2.0, 0.0]))
    assert r.success and r.pivots == 0 and not r.z.any()
    r = lemke(np.array([[2.0, 1.0], [1.0, 2.0]]), np.array([-5.0, -6.0]))
    np.testing.assert_allclose(r.z, [4 / 3, 7 / 3], rtol=1e-14)


def test_ray_termination_is_reported():
    # -I with q < 0: no solution exists, Lemke must say so rather than return garbage
    r = lemke(-np.eye(2), np.array([-1.0, -1.0]))
    assert not r.success and r.status == 1 and "ray" in r.message


def test_copositive_contact_lcp():
    # the frictional contact LCP is not a P-matrix LCP; Lemke still solves it
    from lcp.contact.problem import ContactProblem

    W = np.array([[2.0, 1.0], [1.0, 1.5]])
    for q in ([-1.0, 2.0], [-1.0, -0.1], [0.5, 1.0], [-3.0, 0.0]):
        pb = ContactProblem(W, np.array(q), np.array([0.4]))
        M, b = pb.to_lcp()
        r = lemke(M, b)
        assert r.success
        assert pb.residual(pb.from_lcp(r.z)) <= 1e-12


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_bad_input(bad):
    with pytest.raises(ValueError, match="finite"):
        lemke(np.eye(2), np.array([bad, 1.0]))
    with pytest.raises(ValueError, match="shape"):
        lemke(np.eye(3), np.ones(2))
