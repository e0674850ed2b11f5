"""The core-pivot finish (lcp.contact.core_pivot): fixed settled modes, Lemke on the rest.

Checked by the independent natural-map error, against brute-force enumeration of all branches on
small problems, and on problems with redundant contacts whose W is rounded to a few significant
digits (slightly indefinite, as W stored in text files is).
"""
import itertools
import os

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given
from hypothesis import strategies as st

from lcp.contact.problem import OPEN, SLIDE_NEG, SLIDE_POS, STICK, ContactProblem
from lcp.contact.core_pivot import contact_errors, core_pivot_solve, natural_modes
from lcp.contact.law import natural_map_error
from lcp.contact.lemke import lemke

TOL = 1e-10


def round_significant(A, digits):
    """A rounded to ``digits`` significant digits entrywise (as a %g text file stores it)."""
    A = np.asarray(A, dtype=float)
    out = A.copy()
    nz = A != 0
    f = 10.0 ** (digits - 1 - np.floor(np.log10(np.abs(A[nz]))))
    out[nz] = np.round(A[nz] * f) / f
    return out


def disc_chain(n, seed, digits=None, mu=0.5, duplicates=3):
    """n discs in a line: each touches its right neighbour, every other one the ground, so W has
    about as many rows as the discs have degrees of freedom; ``duplicates`` contacts are doubled
    (exactly redundant). W = H M^-1 H' with the generalized velocities (x, y, theta) of each disc,
    optionally rounded to ``digits`` significant digits; q = H v for a random v pressing down."""
    rng = np.random.default_rng(seed)
    nd = 3 * n
    rows = []

    def contact(a, b, normal):
        nrm = np.asarray(normal, float) / np.linalg.norm(normal)
        tan = np.array([-nrm[1], nrm[0]])
        hN, hT = np.zeros(nd), np.zeros(nd)
        for body, sign in ((a, 1.0), (b, -1.0)):
            if body is not None:
                hN[3 * body:3 * body + 2] = sign * nrm
                hT[3 * body:3 * body + 2] = sign * tan
                hT[3 * body + 2] = rng.uniform(0.5, 1.0)  # radius: the contact point moves with omega
        rows.append((hN, hT))

    for i in range(n):
        if i % 2 == 0:
            contact(i, None, (rng.uniform(-0.3, 0.3), 1.0))
        if i + 1 < n:
            contact(i, i + 1, (-1.0, rng.uniform(-0.5, 0.5)))
    for i in rng.choice(len(rows), min(duplicates, len(rows)), replace=False):
        rows.append((rows[i][0].copy(), rows[i][1].copy()))
    H = np.array([r[0] for r in rows] + [r[1] for r in rows])
    minv = np.repeat(rng.uniform(0.5, 2.0, n), 3) * np.tile([1.0, 1.0, 2.0], n)
    W = H @ np.diag(minv) @ H.T
    if digits:
        W = round_significant(W, digits)
    v = rng.normal(size=nd)
    v[1::3] -= 2.0
    return ContactProblem(sp.csr_matrix(W), H @ v, np.full(len(rows), mu))


def planted(pb, seed, degenerate=0.0):
    """The same W and mu with q chosen so that a random p* (random modes) solves the problem exactly:
    a solution is known to exist even when W is rounded and indefinite. A share ``degenerate`` of
    the contacts sits on a mode boundary (p_N = u_N = 0, or a stick on the cone's edge), where
    iterative solvers stall."""
    rng = np.random.default_rng(seed)
    k, mu = pb.k, pb.mu
    modes = rng.choice([OPEN, STICK, SLIDE_POS, SLIDE_NEG], size=k, p=[0.3, 0.4, 0.15, 0.15])
    pN = np.where(modes == OPEN, 0.0, rng.uniform(0.1, 1.0, k))
    pT = np.where(modes == STICK, rng.uniform(-0.9, 0.9, k) * mu * pN,
                  np.where(modes == SLIDE_POS, -mu * pN, np.where(modes == SLIDE_NEG, mu * pN, 0.0)))
    uN = np.where(modes == OPEN, rng.uniform(0.1, 1.0, k), 0.0)
    uT = np.where(modes == SLIDE_POS, 1.0, np.where(modes == SLIDE_NEG, -1.0, 0.0)) * rng.uniform(0.1, 1.0, k)
    uT = np.where(modes == OPEN, rng.normal(size=k), uT)
    edge = rng.random(k) < degenerate
    uN[edge & (modes == OPEN)] = 0.0  # grazing: open and closed at once
    pT[edge & (modes == STICK)] = mu[edge & (modes == STICK)] * pN[edge & (modes == STICK)]  # stick-slip
    uT[edge & (modes != OPEN)] = 0.0
    p = np.concatenate([pN, pT])
    return ContactProblem(pb.W, np.concatenate([uN, uT]) - pb.W @ p, mu), p


def random_pd(k, seed, mu):
    """A positive definite W (no redundancy) and any q: small problems for the enumeration."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(2 * k, 2 * k))
    return ContactProblem(A @ A.T + 0.5 * np.eye(2 * k), rng.normal(size=2 * k), np.full(k, mu))


def enumerate_solutions(pb):
    """Every admissible branch solution, by trying all 4^k mode combinations."""
    sols = []
    for modes in itertools.product((OPEN, STICK, SLIDE_POS, SLIDE_NEG), repeat=pb.k):
        p = pb.solve_branch(np.array(modes, dtype=np.int8))
        if p is not None and pb.admissible(p, modes, rtol=1e-9):
            sols.append(p)
    return sols


# ------------------------------------------------------------------------------- helpers
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(1, 6))
def test_contact_errors_add_up_to_the_natural_map_error(seed, k):
    rng = np.random.default_rng(seed)
    pb = random_pd(k, seed, rng.uniform(0.0, 1.0))
    p = rng.normal(size=2 * k)
    e, scale = contact_errors(pb.W, pb.q, pb.mu, p)
    assert e.shape == (k,) and np.all(e >= 0)
    assert np.isclose(np.linalg.norm(e) / scale, natural_map_error(pb.W, pb.q, pb.mu, p), rtol=1e-12)


@given(seed=st.integers(0, 2**32 - 1), k=st.integers(1, 3))
def test_natural_modes_of_a_solution_give_its_branch(seed, k):
    pb = random_pd(k, seed, 0.4)
    for p in enumerate_solutions(pb):
        # the branch named by the natural map at a solution reproduces that solution
        p_b = pb.solve_branch(natural_modes(pb, p))
        assert p_b is not None and np.allclose(p_b, p, atol=1e-9 * max(1.0, np.abs(p).max()))


# ------------------------------------------------------------------------------- exactness
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(1, 3), mu=st.floats(0.0, 1.5))
def test_matches_brute_force_enumeration(seed, k, mu):
    pb = random_pd(k, seed, mu)
    sols = enumerate_solutions(pb)
    out = core_pivot_solve(pb)
    if out.success:
        assert natural_map_error(pb.W, pb.q, pb.mu, out.p) <= TOL
        scale = max(1.0, np.abs(out.p).max())
        assert any(np.allclose(out.p, s, atol=1e-8 * scale) for s in sols)
    else:
        # a failure must be a Lemke ray on the whole problem, and Lemke alone must agree
        assert "Lemke on the whole problem" in out.message and out.core.size == k
        assert lemke(*pb.to_lcp()).status != 0


@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 6), mu=st.floats(0.1, 1.0))
def test_redundant_contacts_exact_W(seed, n, mu):
    """Redundant (doubled) contacts, W = H M^-1 H' exact: singular but positive semi-definite, and a
    solution exists; from no start at all the core grows to whatever it needs."""
    pb = disc_chain(n, seed, mu=mu)
    out = core_pivot_solve(pb, max_core=200)
    assert out.success, out.message
    assert natural_map_error(pb.W, pb.q, pb.mu, out.p) <= TOL
    assert out.error == pytest.approx(natural_map_error(pb.W, pb.q, pb.mu, out.p), rel=1e-9, abs=1e-300)


@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 8), digits=st.sampled_from([4, 6, 8]))
def test_rounded_W_is_sound_and_never_worse_than_the_start(seed, n, digits):
    """W rounded to a few digits may be indefinite and the problem may have no solution: whatever
    happens, status 0 means the error target is met, and the result is never worse than the start."""
    pb = disc_chain(n, seed, digits=digits)
    rng = np.random.default_rng(seed)
    p0 = np.abs(rng.normal(size=2 * pb.k)) * 1e-2
    out = core_pivot_solve(pb, p0, max_core=200)
    err = natural_map_error(pb.W, pb.q, pb.mu, out.p)
    assert err == pytest.approx(out.error, rel=1e-9, abs=1e-300)
    assert err <= natural_map_error(pb.W, pb.q, pb.mu, p0)
    assert (err <= TOL) == out.success


@pytest.mark.parametrize("seed", range(6))
def test_stalled_start_needs_only_a_small_core(seed):
    """A near-solution of a problem with many contacts on mode boundaries (what an iterative solver
    leaves after a stall): the settled contacts stay fixed and the core stays a small part."""
    pb, p_star = planted(disc_chain(40, seed, digits=6), seed, degenerate=0.3)
    rng = np.random.default_rng(seed)
    p0 = p_star + 1e-7 * rng.normal(size=p_star.size)
    out = core_pivot_solve(pb, p0)
    assert out.success, out.message
    assert natural_map_error(pb.W, pb.q, pb.mu, out.p) <= TOL
    assert out.core.size <= pb.k // 4


@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 6), digits=st.sampled_from([4, 6]))
def test_planted_solution_of_rounded_W_is_found(seed, n, digits):
    """Rounded, indefinite W with redundant contacts, q chosen so that a solution exists."""
    pb, _ = planted(disc_chain(n, seed, digits=digits), seed)
    out = core_pivot_solve(pb, max_core=200)
    assert out.success, out.message
    assert natural_map_error(pb.W, pb.q, pb.mu, out.p) <= TOL


def test_start_on_the_right_branch_needs_no_pivoting():
    pb, p_star = planted(disc_chain(10, 3, digits=6), 3)
    out = core_pivot_solve(pb, p_star * (1 + 1e-9))
    assert out.success and out.rounds == 0 and out.core.size == 0


def test_no_contacts():
    pb = ContactProblem(np.zeros((0, 0)), np.zeros(0), np.zeros(0))
    out = core_pivot_solve(pb)
    assert out.success and out.p.shape == (0,)


# ------------------------------------------------------------------------------- reporting
def test_core_limit_is_reported_with_the_best_point():
    pb = disc_chain(12, 1, digits=6)
    p0 = np.zeros(2 * pb.k)
    out = core_pivot_solve(pb, p0, max_core=1)
    assert out.status == -1 and "max_core" in out.message
    assert out.error <= natural_map_error(pb.W, pb.q, pb.mu, p0)


def test_a_problem_without_solution_is_reported():
    # one contact whose normal coefficient is negative: pressing makes it penetrate faster
    pb = ContactProblem(np.array([[-1.0, 0.0], [0.0, 1.0]]), np.array([-1.0, 0.0]), np.array([0.5]))
    out = core_pivot_solve(pb)
    assert out.status == -1 and "ray" in out.message
    assert out.error > TOL


@pytest.mark.parametrize("kwargs, name", [({"error_tol": 0.0}, "error_tol"), ({"error_tol": np.nan}, "error_tol"),
                                          ({"max_core": 0}, "max_core"), ({"p0": np.zeros(3)}, "p0"),
                                          ({"p0": np.full(4, np.nan)}, "p0")])
def test_bad_input(kwargs, name):
    pb = random_pd(2, 0, 0.5)
    with pytest.raises(ValueError, match=name):
        core_pivot_solve(pb, **kwargs)


# ------------------------------------------------------------------------------- real files
FILES = {"LCP_FC2D_GRANULAR_2020": 2020, "LCP_FC2D_GRANULAR_7002": 7002}


@pytest.mark.slow
@pytest.mark.parametrize("var", sorted(FILES))
def test_granular_file_after_stall(var):
    """Siconos's fc2d granular-flow problems (W printed with 6 digits, indefinite): from the point
    where NSGS + Newton stall, the core pivot reaches the error target. The file's path is given by
    the environment variable named in the parameter."""
    path = os.environ.get(var)
    if not path or not os.path.exists(path):
        pytest.skip(f"set {var} to the problem file's path")
    from lcp.fclib import read_problem
    from lcp.contact.solvers import make_solver

    pb = read_problem(path).problem(check=False)
    assert pb.k == FILES[var]
    start = make_solver("newton", error_tol=TOL).solve(pb).p
    out = core_pivot_solve(pb, start, error_tol=TOL)
    assert out.success, out.message
    assert natural_map_error(pb.W, pb.q, pb.mu, out.p) <= TOL
    assert out.core.size < pb.k // 10
