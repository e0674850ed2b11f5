"""The spatial (disk) contact problem: exact local solutions, the residual, layouts, refinement."""
import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given
from hypothesis import strategies as st

from lcp.contact import disk_branches
from lcp.contact.spatial_problem import ConeContactProblem, cone_layout, local_disk
from lcp.contact.problem import OPEN, SLIDE, SLIDE_NEG, SLIDE_POS, STICK, ContactProblem
from lcp.contact.law import check_problem, natural_map_error


def spd(rng, n, cond=10.0):
    """A random symmetric positive-definite matrix with eigenvalues in [1, cond]."""
    Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    return (Q * rng.uniform(1.0, cond, n)) @ Q.T


def constructed(W, mu, dims, rng, modes=None):
    """q and an exact solution p (blocked) of u = W p + q, with the modes drawn (or given).

    p and u are chosen to satisfy the disk law contact by contact; q = u - W p.
    """
    dims = np.asarray(dims)
    k = dims.size
    toff, _, _ = cone_layout(dims)
    n = k + int(dims.sum())
    p, u = np.zeros(n), np.zeros(n)
    if modes is None:
        modes = rng.integers(0, 3, k)  # 0 open, 1 stick, 2 slide
    out = np.zeros(k, dtype=np.int8)
    for j in range(k):
        d = dims[j]
        t = slice(k + toff[j], k + toff[j] + d)
        if modes[j] == 0:
            u[j] = rng.uniform(0.1, 1.0)
            u[t] = rng.normal(size=d)
            out[j] = OPEN
            continue
        pN = rng.uniform(0.2, 2.0)
        p[j] = pN
        if modes[j] == 1 or mu[j] == 0:
            direction = rng.normal(size=d)
            p[t] = mu[j] * pN * rng.uniform(0, 0.9) * direction / np.linalg.norm(direction)
            out[j] = STICK
        else:
            direction = rng.normal(size=d)
            direction /= np.linalg.norm(direction)
            lam = rng.uniform(0.1, 1.0)
            u[t] = lam * direction
            p[t] = -mu[j] * pN * direction
            out[j] = SLIDE if d == 2 else (SLIDE_POS if direction[0] > 0 else SLIDE_NEG)
    return u - W @ p, p, out


# ----------------------------------------------------------------- one block on a plane
@given(m=st.floats(0.1, 10.0), wT=st.floats(0.1, 10.0), qN=st.floats(-5.0, 5.0).filter(lambda x: abs(x) > 1e-9),
       qx=st.floats(-5.0, 5.0), qy=st.floats(-5.0, 5.0), mu=st.floats(0.0, 2.0))
def test_block_on_plane_closed_form(m, wT, qN, qx, qy, mu):
    """W = diag(1/m, wT, wT): open if q_N >= 0, stick if |q_T|/wT <= mu p_N, else slide against q_T."""
    W = np.diag([1.0 / m, wT, wT])
    q = np.array([qN, qx, qy])
    p, mode = local_disk(W, q, mu)
    qT = np.hypot(qx, qy)
    if qN >= 0:
        assert mode == OPEN and np.all(p == 0)
        return
    pN = -qN * m
    assert p[0] == pytest.approx(pN, rel=1e-14)
    margin = 1e-12 * (pN + qT / wT)  # within round-off of the disk's edge either answer is right
    if qT / wT <= mu * pN - margin:
        assert mode == STICK
        np.testing.assert_allclose(p[1:], -q[1:] / wT, rtol=1e-14, atol=1e-300)
    elif qT / wT > mu * pN + margin:
        assert mode == SLIDE
        np.testing.assert_allclose(p[1:], -mu * pN * q[1:] / qT, rtol=1e-13, atol=1e-14 * mu * pN)
    pb = ConeContactProblem(W, q, [mu], [2])
    assert pb.residual(p) <= 1e-14 * max(pb.scale, np.max(np.abs(p)))


def test_block_on_plane_examples():
    W = np.eye(3)
    p, mode = local_disk(W, np.array([-1.0, 0.0, 2.0]), 0.5)
    assert mode == SLIDE and np.array_equal(p, [1.0, 0.0, -0.5])  # exact, not only to round-off
    p, mode = local_disk(W, np.array([-1.0, 0.3, 0.4]), 0.5)
    assert mode == STICK and np.array_equal(p, [1.0, -0.3, -0.4])
    p, mode = local_disk(W, np.array([0.5, 3.0, 0.4]), 0.5)
    assert mode == OPEN and np.array_equal(p, np.zeros(3))
    p, mode = local_disk(W, np.array([-1.0, 3.0, 0.0]), 0.0)  # frictionless
    assert mode == SLIDE and np.array_equal(p, [1.0, 0.0, 0.0])


@given(seed=st.integers(0, 2**32 - 1), mu=st.floats(0.0, 0.3), mode=st.sampled_from([0, 1, 2]))
def test_coupled_local_constructed(seed, mu, mode):
    """A coupled 3 x 3 W (close to identity, small mu: unique solution) with a constructed answer,
    including a known sliding direction."""
    rng = np.random.default_rng(seed)
    E = rng.normal(size=(3, 3)) * 0.1
    W = np.eye(3) + 0.5 * (E + E.T)
    q, p_exact, modes = constructed(W, np.array([mu]), [2], rng, [mode])
    p, md = local_disk(W, q, mu)
    np.testing.assert_allclose(p, p_exact, rtol=1e-12, atol=1e-12 * np.max(np.abs(p_exact)) + 1e-15)
    pb = ConeContactProblem(W, q, [mu], [2])
    assert pb.residual(p) <= 1e-13 * max(pb.scale, np.max(np.abs(p)))
    if mu > 0 and md != OPEN:
        assert md == modes[0]


@given(seed=st.integers(0, 2**32 - 1), mu=st.floats(0.0, 3.0), cond=st.floats(1.0, 1e4))
def test_local_disk_random_spd(seed, mu, cond):
    """Any SPD block has a solution; the local solve finds one to round-off (compiled and plain)."""
    rng = np.random.default_rng(seed)
    W = spd(rng, 3, cond)
    q = rng.normal(size=3)
    pb = ConeContactProblem(W, q, [mu], [2])
    for compiled in (True, False):
        p, md = local_disk(W, q, mu, compiled=compiled)
        assert md >= 0
        assert pb.residual(p) <= 1e-11 * max(pb.scale, np.max(np.abs(p)))


def test_local_planar_block():
    p, md = local_disk(np.eye(2), np.array([-1.0, 2.0]), 0.5)
    assert md == SLIDE_POS and np.array_equal(p, [1.0, -0.5])


@given(seed=st.integers(0, 2**32 - 1), mu=st.floats(0.5, 3.0))
def test_painleve_blocks_report_failure(seed, mu):
    """Indefinite blocks (Painleve-type): either no case (mode -1, NaN) or a true solution."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(3, 3))
    W = 0.5 * (A + A.T)
    W[0, 0] = abs(W[0, 0]) + 0.1
    q = rng.normal(size=3)
    q[0] = -abs(q[0]) - 0.1
    p, md = local_disk(W, q, mu)
    if md < 0:
        assert np.all(np.isnan(p))
    else:
        pb = ConeContactProblem(W, q, [mu], [2])
        assert pb.residual(p) <= 1e-10 * max(pb.scale, np.max(np.abs(p)))


def test_painleve_no_solution():
    """A case with no solution at all, and it is said (no wrong answer).

    W = [[1, 1, 0], [1, 1, 0], [0, 0, 1]], q = (-1, 1, 0), mu = 1. Open: q_N < 0. Stick: the
    (N, T0) rows p_N + p_T0 = 1 and = -1 disagree. Slide d = (c, s): a = 1 - c > 0, p_N = 1/(1 - c),
    u_T = (2, -s/(1 - c)); u_T parallel to d needs s = 0, so d = (-1, 0), against u_T = (2, 0).
    """
    W = np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    q = np.array([-1.0, 1.0, 0.0])
    for compiled in (True, False):
        p, md = local_disk(W, q, 1.0, compiled=compiled)
        assert md == -1 and np.all(np.isnan(p))


# ----------------------------------------------------------------- the problem object
def test_validation_names_argument():
    W, q = np.eye(3), np.zeros(3)
    with pytest.raises(ValueError, match="mu"):
        ConeContactProblem(W, q, [-0.1], [2])
    with pytest.raises(ValueError, match="mu"):
        ConeContactProblem(W, q, [np.inf], [2])
    with pytest.raises(ValueError, match="dims"):
        ConeContactProblem(W, q, [0.1], [3])
    with pytest.raises(ValueError, match="dims"):
        ConeContactProblem(W, q, [0.1], [2, 1])
    with pytest.raises(ValueError, match="W"):
        ConeContactProblem(np.eye(4), q, [0.1], [2])
    with pytest.raises(ValueError, match="q"):
        ConeContactProblem(W, np.zeros(2), [0.1], [2])
    with pytest.raises(ValueError, match="W"):
        ConeContactProblem(sp.identity(9, format="csr"), np.zeros(9), [0.1, 0.1, 0.1], [2, 2, 1])
    with pytest.raises(ValueError, match="q"):
        ConeContactProblem(W, [np.nan, 0, 0], [0.1], [2])
    with pytest.raises(ValueError, match="W"):
        local_disk(np.eye(4), np.zeros(4), 0.1)
    with pytest.raises(ValueError, match="mu"):
        local_disk(np.eye(3), np.zeros(3), -1.0)


dims_st = st.lists(st.sampled_from([1, 2]), min_size=1, max_size=12)


@given(dims=dims_st, seed=st.integers(0, 2**32 - 1))
def test_interleaved_round_trip(dims, seed):
    rng = np.random.default_rng(seed)
    k = len(dims)
    n = k + sum(dims)
    W, q, mu = spd(rng, n), rng.normal(size=n), rng.uniform(0, 1, k)
    pb = ConeContactProblem(W, q, mu, dims)
    Wi, qi, mui, di = pb.to_interleaved()
    # contact j's rows are contiguous: normal first, then its tangents
    for j in range(k):
        s = pb.start[j]
        assert qi[s] == q[j]
        np.testing.assert_array_equal(qi[s + 1:s + 1 + dims[j]], q[pb.tangent_slices[j]])
    back = ConeContactProblem.from_interleaved(Wi, qi, mui, di)
    assert np.array_equal(back.W, pb.W) and np.array_equal(back.q, pb.q)
    x = rng.normal(size=n)
    assert np.array_equal(pb.deinterleave(pb.interleave(x)), x)
    back_s = ConeContactProblem.from_interleaved(sp.csr_matrix(Wi), qi, mui, di)
    p = rng.normal(size=n)
    assert back_s.residual(p) == pytest.approx(pb.residual(p), rel=1e-12)
    assert natural_map_error(Wi, qi, mu, pb.interleave(p), order="interleaved", dims=dims) == \
        pytest.approx(pb.error(p), rel=1e-12)


@given(dims=dims_st, seed=st.integers(0, 2**32 - 1), mu_max=st.floats(0.0, 2.0))
def test_residual_zero_at_constructed_solutions(dims, seed, mu_max):
    rng = np.random.default_rng(seed)
    k = len(dims)
    n = k + sum(dims)
    W, mu = spd(rng, n), rng.uniform(0, mu_max, k)
    q, p, modes = constructed(W, mu, dims, rng)
    pb = ConeContactProblem(W, q, mu, dims)
    tol = 1e-13 * max(pb.scale, np.max(np.abs(p)))
    assert pb.residual(p) <= tol
    assert pb.error(p) <= 1e-13
    md = pb.modes(p)
    keep = mu > 0  # a frictionless stick is a slide with zero velocity
    assert np.array_equal(md[keep], modes[keep])
    # a wrong impulse is seen by the residual and by the error alike
    p_bad = p.copy()
    p_bad[rng.integers(n)] += 0.1
    assert pb.residual(p_bad) > 1e-3 and pb.error(p_bad) > 1e-4


@given(dims=dims_st, seed=st.integers(0, 2**32 - 1))
def test_residual_paths_agree(dims, seed):
    """Compiled dense, compiled CSR and the NumPy fallback compute the same natural map."""
    rng = np.random.default_rng(seed)
    k = len(dims)
    n = k + sum(dims)
    W, q, mu = spd(rng, n), rng.normal(size=n), rng.uniform(0, 1, k)
    p = rng.normal(size=n)
    dense = ConeContactProblem(W, q, mu, dims)
    sparse = ConeContactProblem(sp.csr_matrix(W), q, mu, dims)
    r = dense.residual(p)
    assert sparse.residual(p) == pytest.approx(r, rel=1e-12)
    saved = disk_branches.COMPILED_KERNELS[:]
    try:
        disk_branches.COMPILED_KERNELS[:] = [None]
        assert dense.residual(p) == pytest.approx(r, rel=1e-12)
    finally:
        disk_branches.COMPILED_KERNELS[:] = saved


@given(k=st.integers(1, 10), seed=st.integers(0, 2**32 - 1))
def test_planar_dims_match_contact_problem(k, seed):
    """All dims 1: the residual, modes and error are ContactProblem's (same layout)."""
    rng = np.random.default_rng(seed)
    W, q, mu, p = spd(rng, 2 * k), rng.normal(size=2 * k), rng.uniform(0, 1, k), rng.normal(size=2 * k)
    a, b = ContactProblem(W, q, mu), ConeContactProblem(W, q, mu, np.ones(k, dtype=int))
    assert b.residual(p) == pytest.approx(a.residual(p), rel=1e-14)
    assert np.array_equal(np.asarray(b.modes(p)), a.modes(p))
    assert b.error(p) == pytest.approx(natural_map_error(W, q, mu, p), rel=1e-12)
    assert natural_map_error(W, q, mu, p) == natural_map_error(W, q, mu, p, dims=None)


def test_check_problem_dims():
    W, q = np.eye(5), np.zeros(5)
    assert check_problem(W, q, [0.1, 0.2], dims=[2, 1]).ok
    assert not check_problem(W, q, [0.1, 0.2]).ok
    assert "dims" in check_problem(W, q, [0.1, 0.2], dims=[3, 0]).errors[0]


@given(dims=dims_st, seed=st.integers(0, 2**32 - 1), sparse=st.booleans())
def test_refine_restores_branch(dims, seed, sparse):
    """A perturbed solution is corrected on its branch: open contacts 0, stuck contacts' velocity
    zero to rounding, sliding ones back on the disk edge."""
    rng = np.random.default_rng(seed)
    k = len(dims)
    n = k + sum(dims)
    W, mu = spd(rng, n), rng.uniform(0.1, 1.0, k)
    q, p, modes = constructed(W, mu, dims, rng)
    pb = ConeContactProblem(sp.csr_matrix(W) if sparse else W, q, mu, dims)
    p_noisy = p + 1e-11 * rng.normal(size=n) * np.where(np.arange(n) < k, p[:k].max(), 1.0)
    p_noisy[:k][modes == OPEN] = 0.0
    p_noisy[k:][np.repeat(modes == OPEN, dims)] = 0.0
    assert np.array_equal(np.asarray(pb.modes(p_noisy)), modes)
    pr = pb.refine(p_noisy)
    scale = max(pb.scale, np.max(np.abs(p)))
    assert pb.residual(pr) <= 1e-14 * scale
    np.testing.assert_allclose(pr, p, atol=1e-12 * scale)
    u = pb.velocity(pr)
    for j in np.flatnonzero(modes == STICK):
        assert np.max(np.abs(u[pb.tangent_slices[j]])) <= 1e-14 * np.max(np.abs(q))


def test_with_q_shares_operator():
    rng = np.random.default_rng(3)
    W = spd(rng, 8)
    pb = ConeContactProblem(W, rng.normal(size=8), [0.3, 0.5, 0.2], [2, 2, 1], key="a")
    q2 = rng.normal(size=8)
    pb2 = pb.with_q(q2)
    assert pb2.W is pb.W and pb2.key == "a" and np.array_equal(pb2.q, q2)
    fresh = ConeContactProblem(W, q2, [0.3, 0.5, 0.2], [2, 2, 1])
    p = rng.normal(size=8)
    assert pb2.residual(p) == fresh.residual(p) and pb2.scale == fresh.scale


def test_sparse_kept_sparse_above_small_size():
    W = sp.identity(12, format="csr")
    pb = ConeContactProblem(W, np.zeros(12), np.full(4, 0.5), [2, 2, 2, 2])
    assert sp.issparse(pb.W)
    small = ConeContactProblem(sp.identity(3, format="csr"), np.zeros(3), [0.5], [2])
    assert isinstance(small.W, np.ndarray)


@given(dims=dims_st, seed=st.integers(0, 2**32 - 1), sparse=st.booleans())
def test_compiled_refinement_matches_numpy(dims, seed, sparse):
    """refine_modes (one compiled call) = the NumPy refinement followed by modes, to rounding."""
    rng = np.random.default_rng(seed)
    k = len(dims)
    n = k + sum(dims)
    W, mu = spd(rng, n), rng.uniform(0.1, 1.0, k)
    q, p, modes = constructed(W, mu, dims, rng)
    pb = ConeContactProblem(sp.csr_matrix(W) if sparse else W, q, mu, dims)
    p_noisy = p + 1e-11 * rng.normal(size=n)
    p_noisy[:k][modes == OPEN] = 0.0
    pr, md = pb.refine_modes(p_noisy)
    ref = pb._refine_numpy(p_noisy, 3)
    scale = max(pb.scale, np.max(np.abs(p)))
    np.testing.assert_allclose(pr, ref, atol=1e-14 * scale)
    assert md.dtype == np.int8 and np.array_equal(md, np.asarray(pb.modes(pr)))
    assert np.array_equal(pb.refine_modes(p_noisy, iterations=0)[1], np.asarray(pb.modes(p_noisy)))


@given(dims=st.lists(st.sampled_from([1, 2]), min_size=1, max_size=40), seed=st.integers(0, 2**32 - 1))
def test_newton_system_matches_blocks(dims, seed):
    """The compiled Alart-Curnier (Phi, J), dense and sparse (CSR assembly above the dense limit),
    equal alart_curnier's blocks assembled by jacobian."""
    rng = np.random.default_rng(seed)
    k = len(dims)
    n = k + sum(dims)
    W = spd(rng, n)
    W[np.abs(W) < 0.3] = 0.0  # some sparsity
    W = W @ W.T + np.eye(n)
    q, mu, p = rng.normal(size=n), rng.uniform(0, 1, k), rng.normal(size=n)
    for Wx in (W, sp.csr_matrix(W)):
        pb = ConeContactProblem(Wx, q, mu, dims)
        phi, J = pb.newton_system(p)
        phi0, A, B = pb.alart_curnier(p)
        J0 = pb.jacobian(A, B)
        dense = lambda M: M.toarray() if sp.issparse(M) else M
        np.testing.assert_allclose(phi, phi0, rtol=1e-13, atol=1e-13 * np.max(np.abs(phi0)))
        np.testing.assert_allclose(dense(J), dense(J0), rtol=1e-13, atol=1e-13 * np.max(np.abs(W)))
        assert np.array_equal(pb.newton_system(p, jacobian=False)[0], phi)


def test_compiled_refinement_large_sparse():
    """Above the dense limit the refinement keeps the sparse NumPy path (same answer as dense)."""
    rng = np.random.default_rng(5)
    dims = [2] * 40
    n = 40 + 80
    L = sp.diags([np.full(n, 2.5), np.full(n - 1, -0.6), np.full(n - 1, -0.6)], [0, -1, 1], format="csr")
    W = (L @ L.T).tocsr()
    mu = rng.uniform(0.1, 0.6, 40)
    q, p, modes = constructed(W.toarray(), mu, dims, rng)
    a = ConeContactProblem(W, q, mu, dims)
    b = ConeContactProblem(W.toarray(), q, mu, dims)
    p_noisy = p + 1e-11 * rng.normal(size=n)
    p_noisy[:40][modes == OPEN] = 0.0
    pa, ma = a.refine_modes(p_noisy)
    pb_, mb = b.refine_modes(p_noisy)
    np.testing.assert_allclose(pa, pb_, atol=1e-13 * max(a.scale, np.max(np.abs(p))))
    assert np.array_equal(ma, mb) and np.array_equal(ma, modes)


@given(seed=st.integers(0, 2**32 - 1))
def test_solve3_matches_lapack(seed):
    from lcp.contact.kernels import _solve3

    rng = np.random.default_rng(seed)
    W = spd(rng, 3, cond=100.0) + rng.normal(size=(3, 3)) * 0.1
    b = rng.normal(size=3)
    x = np.linalg.solve(W, b)
    for fn in (_solve3, getattr(_solve3, "py_func", _solve3)):
        x0, x1, x2, ok = fn(W, *b)
        assert ok
        np.testing.assert_allclose([x0, x1, x2], x, rtol=1e-10, atol=1e-12 * np.max(np.abs(x)))
    assert not _solve3(np.ones((3, 3)), 1.0, 2.0, 3.0)[3]
