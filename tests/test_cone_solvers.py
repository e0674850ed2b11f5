"""Spatial one-step solvers against exact solutions, against each other and against the planar ones."""
import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given
from hypothesis import strategies as st

from lcp.contact.spatial_problem import ConeContactProblem
from lcp.contact.spatial_solvers import CONE_SOLVERS, ConeAutoSolver, FacetedSolver, make_cone_solver
from lcp.contact.problem import ContactProblem
from lcp.contact.law import natural_map_error
from lcp.contact.solvers import make_solver

from .test_cone_problem import constructed, spd

EXACT = ["nsgs", "newton", "tresca", "auto"]


def independent_residual(pb, p):
    """The disk natural map written out contact by contact, without the problem's own kernels."""
    W = pb.W.toarray() if sp.issparse(pb.W) else pb.W
    u = W @ p + pb.q
    res = 0.0
    for j in range(pb.k):
        t = pb.tangent_slices[j]
        pN, pT, uN, uT = p[j], p[t], u[j], u[t]
        z = pT - pb.rhoT[j] * uT
        s = pb.mu[j] * max(pN, 0.0)
        if np.linalg.norm(z) > s:
            z = z * s / np.linalg.norm(z)
        res = max(res, abs(min(pN, pb.rhoN[j] * uN)), float(np.linalg.norm(pT - z)))
    return res


def check_exact(sol, pb, rtol=1e-10):
    assert sol.status == 0, sol.message
    scale = max(pb.scale, float(np.max(np.abs(sol.p))))
    assert independent_residual(pb, sol.p) <= rtol * scale
    assert sol.residual <= rtol * scale
    assert natural_map_error(pb.W, pb.q, pb.mu, sol.p, dims=pb.dims) <= 1e-9


# ----------------------------------------------------------------- constructed answers
@pytest.mark.parametrize("name", ["local", *EXACT])
@pytest.mark.parametrize("q, expected", [
    ([0.5, 1.0, 1.0], [0.0, 0.0, 0.0]),               # open
    ([-1.0, 0.3, -0.2], [2.0, -0.6, 0.4]),             # stick: |q_T|/w_T <= mu p_N
    ([-1.0, 3.0, 4.0], [2.0, -0.6, -0.8]),             # slide against q_T, |p_T| = mu p_N
])
def test_block_on_plane(name, q, expected):
    """W = diag(1/m, 1/m, 1/m) with m = 2, mu = 0.5."""
    pb = ConeContactProblem(np.eye(3) / 2.0, np.array(q), [0.5], [2])
    sol = make_cone_solver(name).solve(pb)
    check_exact(sol, pb)
    np.testing.assert_allclose(sol.p, expected, rtol=1e-13, atol=1e-15)


@pytest.mark.parametrize("name", ["local", *EXACT])
def test_coupled_block_known_sliding_direction(name):
    """A coupled 3 x 3 W; the answer is built from a chosen sliding direction d = (0.6, -0.8)."""
    W = np.array([[2.0, 0.3, -0.2], [0.3, 1.5, 0.4], [-0.2, 0.4, 1.0]])
    mu, pN, lam, d = 0.3, 1.7, 0.9, np.array([0.6, -0.8])
    p = np.concatenate([[pN], -mu * pN * d])
    u = np.concatenate([[0.0], lam * d])
    pb = ConeContactProblem(W, u - W @ p, [mu], [2])
    sol = make_cone_solver(name).solve(pb)
    check_exact(sol, pb)
    np.testing.assert_allclose(sol.p, p, rtol=1e-12, atol=1e-14)
    assert pb.modes(sol.p).names.tolist() == ["SLIDE"]


def problem(dims, seed, mu_max, cond=4.0, sparse=False):
    rng = np.random.default_rng(seed)
    k = len(dims)
    n = k + sum(dims)
    W, mu = spd(rng, n, cond), rng.uniform(0, mu_max, k)
    q, p, _ = constructed(W, mu, dims, rng)
    return ConeContactProblem(sp.csr_matrix(W) if sparse else W, q, mu, dims), p


@given(dims=st.lists(st.sampled_from([1, 2]), min_size=1, max_size=30), seed=st.integers(0, 2**32 - 1),
       sparse=st.booleans())
def test_random_spd_all_exact_solvers(dims, seed, sparse):
    """Random SPD W, mixed dims, small mu (unique solution): every exact solver reaches 1e-10
    (checked independently) and they all find the constructed solution."""
    pb, p_exact = problem(dims, seed, mu_max=0.1, cond=3.0, sparse=sparse)
    scale = max(pb.scale, float(np.max(np.abs(p_exact))))
    names = EXACT + (["local"] if len(dims) == 1 else [])
    for name in names:
        sol = make_cone_solver(name).solve(pb)
        check_exact(sol, pb)
        np.testing.assert_allclose(sol.p, p_exact, atol=1e-8 * scale, err_msg=name)


@given(dims=st.lists(st.sampled_from([1, 2]), min_size=1, max_size=20), seed=st.integers(0, 2**32 - 1),
       mu_max=st.floats(0.1, 1.5))
def test_random_spd_large_friction(dims, seed, mu_max):
    """Larger mu (solutions may not be unique): each exact solver still returns a solution."""
    pb, _ = problem(dims, seed, mu_max=mu_max, cond=20.0)
    for name in ("nsgs", "newton", "auto"):
        check_exact(make_cone_solver(name).solve(pb), pb)


@given(k=st.integers(1, 15), seed=st.integers(0, 2**32 - 1))
def test_planar_problems_match_planar_solvers(k, seed):
    """dims all 1: the same answers as lcp.contact.solvers' planar solvers (unique: small mu)."""
    pb, _ = problem([1] * k, seed, mu_max=0.1, cond=3.0)
    planar = ContactProblem(pb.W, pb.q, pb.mu)
    ref = make_solver("lemke").solve(planar)
    assert ref.success
    scale = max(pb.scale, float(np.max(np.abs(ref.p))))
    for name in EXACT + (["local"] if k == 1 else []):
        sol = make_cone_solver(name).solve(pb)
        check_exact(sol, pb)
        np.testing.assert_allclose(sol.p, ref.p, atol=1e-9 * scale, err_msg=name)
        assert sol.residual == pytest.approx(planar.residual(sol.p), rel=1e-12, abs=1e-15 * scale)


def test_faceted_is_labelled_and_converges():
    """The polygon law approaches the disk as n_facets grows; the answer says it is approximate."""
    W = np.array([[2.0, 0.3, -0.2], [0.3, 1.5, 0.4], [-0.2, 0.4, 1.0]])
    mu, pN, d = 0.3, 1.7, np.array([np.cos(0.37), np.sin(0.37)])
    p = np.concatenate([[pN], -mu * pN * d])
    pb = ConeContactProblem(W, np.concatenate([[0.0], 0.9 * d]) - W @ p, [mu], [2])
    errors = []
    for nf in (4, 16, 64, 256):
        sol = FacetedSolver(n_facets=nf).solve(pb)
        assert sol.status == 1 and "approximate" in sol.message and sol.success
        assert sol.residual == pytest.approx(pb.residual(sol.p))
        errors.append(float(np.max(np.abs(sol.p - p))))
        # a polygon direction is off by at most half a facet angle: the impulse by about mu p_N pi / n
        assert errors[-1] <= 2.0 * mu * pN * np.pi / nf
    assert errors[-1] < 0.1 * errors[0], errors


def test_faceted_exact_for_planar_contacts():
    pb, p = problem([1, 1, 1], 7, mu_max=0.1, cond=3.0)
    sol = make_cone_solver("faceted").solve(pb)
    assert sol.status == 1
    np.testing.assert_allclose(sol.p, p, atol=1e-10 * max(pb.scale, np.max(np.abs(p))))


def test_auto_never_faceted():
    auto = ConeAutoSolver()
    parts = [auto.local, auto.nsgs, auto.newton]
    assert not any(isinstance(s, FacetedSolver) for s in parts)
    pb, _ = problem([2, 1, 2, 2], 3, mu_max=0.5)
    sol = auto.solve(pb)
    assert sol.status == 0 and "approximate" not in sol.message
    assert auto._tresca is None or not isinstance(auto._tresca, FacetedSolver)


def test_painleve_reports_failure():
    """A one-contact problem without solution: status < 0, never a wrong answer."""
    W = np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    pb = ConeContactProblem(W, np.array([-1.0, 1.0, 0.0]), [1.0], [2])
    for name in ("local", "nsgs", "newton", "auto"):
        sol = make_cone_solver(name).solve(pb)
        assert sol.status < 0, (name, sol.p, sol.residual)


def test_bad_input():
    with pytest.raises(ValueError, match="unknown cone solver"):
        make_cone_solver("lemke")
    with pytest.raises(ValueError, match="n_facets"):
        make_cone_solver("faceted", n_facets=2)
    with pytest.raises(ValueError, match="tol"):
        make_cone_solver("tresca", tol=-1.0)
    with pytest.raises(ValueError, match="max_sweeps"):
        make_cone_solver("nsgs", max_sweeps=0)
    with pytest.raises(ValueError, match="invalid options"):
        make_cone_solver("newton", bogus=1)
    with pytest.raises(ValueError, match="residual_tol"):
        make_cone_solver("nsgs", residual_tol=0.0)
    with pytest.raises(TypeError, match="ConeContactProblem"):
        make_cone_solver("nsgs").solve(ContactProblem(np.eye(2), np.zeros(2), [0.1]))
    assert set(CONE_SOLVERS) == {"auto", "local", "nsgs", "newton", "tresca", "faceted"}


def test_local_applies_to_one_contact_only():
    pb, _ = problem([2, 2], 1, mu_max=0.3)
    sol = make_cone_solver("local").solve(pb)
    assert sol.status == -3


def test_no_contacts():
    pb = ConeContactProblem(np.zeros((0, 0)), np.zeros(0), [], [])
    for name in CONE_SOLVERS:
        assert make_cone_solver(name).solve(pb).p.shape == (0,)


def test_warm_start_and_with_q():
    """Keyed problems: the second solve of a nearby q starts from the first answer (fewer sweeps);
    the Tresca workspace is reused; with_q copies solve like fresh problems."""
    pb, _ = problem([2] * 12, 5, mu_max=0.4, cond=10.0)
    pb = ConeContactProblem(pb.W, pb.q, pb.mu, pb.dims, key="chain")
    nsgs = make_cone_solver("nsgs")
    first = nsgs.solve(pb)
    pb2 = pb.with_q(pb.q * (1 + 1e-6))
    second = nsgs.solve(pb2)
    check_exact(first, pb)
    check_exact(second, pb2)
    assert second.iterations < first.iterations
    tresca = make_cone_solver("tresca")
    check_exact(tresca.solve(pb), pb)
    check_exact(tresca.solve(pb2), pb2)
    assert len(tresca._cache) == 1
    fresh = ConeContactProblem(pb.W, pb2.q, pb.mu, pb.dims)
    np.testing.assert_allclose(make_cone_solver("newton").solve(fresh).p, second.p, atol=1e-9 * pb2.scale)


def test_plain_python_sweep_agrees():
    pb, _ = problem([2, 1, 2], 11, mu_max=0.1, cond=3.0)
    a = make_cone_solver("nsgs", compiled=False).solve(pb)
    b = make_cone_solver("nsgs").solve(pb)
    check_exact(a, pb)
    np.testing.assert_allclose(a.p, b.p, atol=1e-12 * pb.scale)


def test_sliding_chain_sparse_mixed():
    """A chain of 40 blocks coupled by springs (sparse tridiagonal-block W), some sliding."""
    rng = np.random.default_rng(2)
    k = 40
    dims = np.where(np.arange(k) % 3 == 0, 1, 2)
    n = k + int(dims.sum())
    L = sp.diags([np.full(n, 2.5), np.full(n - 1, -0.6), np.full(n - 1, -0.6)], [0, -1, 1], format="csr")
    W = (L @ L.T).tocsr()
    mu = rng.uniform(0.1, 0.6, k)
    q, _, _ = constructed(W.toarray(), mu, dims, rng)
    pb = ConeContactProblem(W, q, mu, dims)
    assert sp.issparse(pb.W)
    for name in EXACT:
        check_exact(make_cone_solver(name).solve(pb), pb)


@pytest.mark.parametrize("name", ["local", "nsgs", "newton", "tresca", "auto"])
def test_refined_solutions_report_their_modes(name):
    """A polished solver returns the modes of its refined impulse (callers need not refine again)."""
    rng = np.random.default_rng(8)
    dims = [2] if name == "local" else [2, 1, 2, 2]
    k = len(dims)
    n = k + sum(dims)
    W, mu = spd(rng, n), rng.uniform(0.2, 0.8, k)
    q, p, modes = constructed(W, mu, dims, rng)
    pb = ConeContactProblem(W, q, mu, dims)
    sol = make_cone_solver(name).solve(pb)
    check_exact(sol, pb)
    assert sol.modes is not None and np.array_equal(sol.modes, np.asarray(pb.modes(sol.p)))
    assert np.array_equal(sol.modes, modes)
    # the loop's refinement of an already refined impulse changes nothing beyond rounding
    np.testing.assert_allclose(pb.refine(sol.p), sol.p, atol=1e-14 * max(pb.scale, np.max(np.abs(p))))
    if name == "local":
        raw = make_cone_solver("local", polish=False).solve(pb)
        assert raw.modes is None and raw.status == 0
