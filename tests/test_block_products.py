"""The compiled set-up of independent bodies (lcp.numerics.block_products and the compressed-array paths).

- the operators S, S H', W, H, the constant free velocity and every array the compiled loop reads
  are the SciPy route's to the last bit, on bodies of one, two and three coordinates, numbered in
  order or permuted, with diagonal or full blocks (hypothesis over sizes and seeds);
- the SciPy matrices are built on first use only, and the Python loop sees the same operators;
- the contiguous-block search finds the graph search's blocks, or hands over to it;
- the compressed-array readers (CSR, CSC, interleaved W) equal the dense and SciPy routes.
"""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st

import lcp
from lcp.timestepping import assembly
from lcp.numerics import block_diagonal
from lcp.timestepping import compiled_loop
from lcp.numerics.jit import HAVE_NUMBA
from lcp.scenes import Scene
from lcp.model.system import Contact, System

pytestmark = pytest.mark.skipif(not HAVE_NUMBA, reason="the compiled route needs numba")


def _bodies(K, seed, size, diag=False, permute=False, damping=0.0):
    """K bodies of ``size`` >= 2 coordinates each (random SPD blocks, or their diagonals), one contact
    each (gap and tangent linear in the body's own coordinates), constant random forces."""
    rng = np.random.default_rng(seed)
    n = size * K
    q, v = ca.SX.sym("q", n), ca.SX.sym("v", n)
    blocks = []
    for _ in range(K):
        X = rng.normal(size=(size, size))
        B = X @ X.T + size * rng.uniform(0.1, 10) * np.eye(size)
        blocks.append(np.diag(np.diag(B)) if diag else B)
    perm = rng.permutation(n) if permute else np.arange(n)
    where = np.argsort(perm)  # the coordinate that holds row i of the unpermuted matrix
    mass = ca.SX(ca.DM(sp.csc_matrix(sp.block_diag(blocks).toarray()[np.ix_(perm, perm)])))
    force = ca.SX(rng.normal(size=n)) - damping * v
    contacts = []
    for i in range(K):
        own = [int(where[size * i + j]) for j in range(size)]
        a = rng.normal(size=size) + 0.5
        gap = sum(float(a[j]) * q[own[j]] for j in range(size))
        contacts.append(Contact(gap=gap, tangent=q[own[0]] - 0.7 * q[own[-1]], mu=0.3, name=f"c{i}"))
    v0 = rng.normal(size=n) * 0.1
    return Scene(System(q, v, mass, force, contacts=contacts), np.zeros(n), v0, 0.05, f"bodies_{K}_{size}")


def _both_routes(system, monkeypatch):
    z = np.zeros(system.n)
    system.check_state(z, z)
    compiled = assembly.StepAssembly(system, 1e-3, 0.5)
    with monkeypatch.context() as mp:
        mp.setattr(assembly, "_have_numba", lambda: False)
        scipy_route = assembly.StepAssembly(system, 1e-3, 0.5)
    return compiled, scipy_route


def _same_matrix(X, Y):
    X, Y = sp.csr_matrix(X), sp.csr_matrix(Y)
    X.sort_indices()
    Y.sort_indices()
    X.eliminate_zeros()
    Y.eliminate_zeros()
    return (X.shape == Y.shape and np.array_equal(X.indptr, Y.indptr) and np.array_equal(X.indices, Y.indices)
            and np.array_equal(X.data, Y.data))


@settings(max_examples=25, deadline=None)
@given(K=st.integers(100, 160), seed=st.integers(0, 2**31 - 1), size=st.sampled_from([2, 3]),
       diag=st.booleans(), permute=st.booleans())
def test_the_compiled_route_gives_scipys_operators_to_the_last_bit(K, seed, size, diag, permute):
    sc = _bodies(K, seed, size, diag, permute)
    mp = pytest.MonkeyPatch()
    try:
        compiled, scipy_route = _both_routes(sc.system, mp)
    finally:
        mp.undo()
    assert "arrays" in compiled.__dict__ and "arrays" not in scipy_route.__dict__
    assert "W" not in compiled.__dict__  # not built until asked for
    for name in ("S", "SHt", "W", "H"):
        assert _same_matrix(getattr(compiled, name), getattr(scipy_route, name)), name
    assert compiled.H[: compiled.m].shape == (compiled.m, compiled.n)
    np.testing.assert_array_equal(compiled.dv_const, scipy_route.dv_const)
    np.testing.assert_array_equal(compiled._solve(np.arange(sc.system.n, dtype=float)),
                                  scipy_route._solve(np.arange(sc.system.n, dtype=float)))
    # what the compiled loop reads: packed from arrays and from the SciPy matrices alike
    a, b = compiled_loop._pack_new(compiled), compiled_loop._pack_new(scipy_route)
    assert a[0] == b[0] and a[3] == b[3]
    for x, y in zip(a[1] + a[2], b[1] + b[2]):
        np.testing.assert_array_equal(x, y)


def test_springs_or_dampers_take_the_scipy_route_and_trajectories_agree(monkeypatch):
    damped = _bodies(110, 3, 2, damping=2.0)
    asm = assembly.StepAssembly(damped.system, 1e-3, 0.5)
    assert "arrays" not in asm.__dict__ and asm._lu is None  # W_h block diagonal, not the mass matrix
    sc = _bodies(110, 4, 2)
    res = lcp.simulate(sc, 0.05, h=1e-3)
    with monkeypatch.context() as mp:
        mp.setattr(assembly, "_have_numba", lambda: False)
        ref = lcp.simulate(_bodies(110, 4, 2), 0.05, h=1e-3)
    assert res.status == ref.status == 0 and res.solver == ref.solver
    np.testing.assert_array_equal(res.q, ref.q)
    np.testing.assert_array_equal(res.p_N, ref.p_N)
    python_loop = lcp.simulate(_bodies(110, 4, 2), 0.05, h=1e-3, fast=False)
    np.testing.assert_allclose(python_loop.q, res.q, rtol=0, atol=1e-13)


def test_a_singular_block_is_reported_by_name(monkeypatch):
    sc = _bodies(110, 5, 2)
    sc.system.check_state(np.zeros(sc.system.n), np.zeros(sc.system.n))
    idx, B = sc.system.mass_blocks[0]
    B[0] = 0.0  # the check's blocks, made singular behind its back: the assembly still refuses them
    with pytest.raises(FloatingPointError, match="singular"):
        assembly.StepAssembly(sc.system, 1e-3, 0.5)


@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 14), kind=st.integers(0, 2),
       permute=st.booleans(), max_size=st.sampled_from([1, 2, 32]))
def test_the_contiguous_search_agrees_with_the_graph_search(seed, n, kind, permute, max_size):
    rng = np.random.default_rng(seed)
    if kind == 0:  # consecutive blocks of one or two rows
        D, i = np.zeros((n, n)), 0
        while i < n:
            s = min(int(rng.integers(1, 3)), n - i)
            B = rng.normal(size=(s, s))
            D[i:i + s, i:i + s] = B + B.T
            i += s
    elif kind == 1:
        D = np.diag(rng.normal(size=n))
    else:
        D = rng.normal(size=(n, n)) * (rng.random((n, n)) < 0.2)
        D = D + D.T
    if permute:
        p = rng.permutation(n)
        D = D[np.ix_(p, p)]
    for A in (sp.csr_matrix(D), sp.csc_matrix(D)):
        fast = block_diagonal.diagonal_blocks(A, max_size)
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(block_diagonal, "_contiguous_blocks", lambda *a: None)
            graph = block_diagonal.diagonal_blocks(A, max_size)
        assert (fast is None) == (graph is None)
        for (i1, B1), (i2, B2) in zip(fast or [], graph or []):
            np.testing.assert_array_equal(i1, i2)
            np.testing.assert_array_equal(B1, B2)


@given(seed=st.integers(0, 2**31 - 1), rows=st.integers(1, 25), cols=st.integers(1, 25),
       density=st.floats(0, 1), unsorted=st.booleans())
def test_compressed_readers_equal_the_dense_route(seed, rows, cols, density, unsorted):
    rng = np.random.default_rng(seed)
    A = sp.random(rows, cols, density=density, format="csr", random_state=rng)
    A.data[rng.random(A.nnz) < 0.3] = 0.0  # explicit zeros are dropped
    if unsorted and A.nnz:
        A.indices = A.indices.copy()
        A.has_sorted_indices = False
    D = A.toarray()
    for reader in (compiled_loop._csr, compiled_loop._csc):
        for x, y in zip(reader(A), reader(D)):
            np.testing.assert_array_equal(x, y)
            assert x.dtype in (np.int64, np.float64)
    if rows == cols and rows % 2 == 0:
        m = rows // 2
        ref = compiled_loop._interleaved(D, m)
        for x, y in zip(compiled_loop._interleave_compiled(A.indptr.astype(np.int64), A.indices.astype(np.int64),
                                                           A.data, m), ref):
            np.testing.assert_array_equal(x, y)


def _spatial_blocks(K, seed):
    """K blocks on a floor (three coordinates each, spatial contacts), sliding in random directions:
    3K contact rows, the sparse assembly from K = 67."""
    rng = np.random.default_rng(seed)
    n = 3 * K
    q, v = ca.SX.sym("q", n), ca.SX.sym("v", n)
    masses = rng.uniform(0.5, 2.0, size=K)
    mass = ca.SX(ca.DM(sp.diags(np.repeat(masses, 3)).tocsc()))
    force = ca.SX(np.column_stack([np.zeros(K), np.zeros(K), -9.81 * masses]).ravel())
    contacts = [Contact(gap=q[3 * i + 2], tangent=ca.vertcat(q[3 * i], q[3 * i + 1]), mu=0.4, name=f"b{i}")
                for i in range(K)]
    v0 = np.zeros(n)
    v0[0::3], v0[1::3] = rng.normal(size=K), rng.normal(size=K)
    return Scene(System(q, v, mass, force, contacts=contacts), np.zeros(n), v0, 0.05, f"floor_{K}")


def test_spatial_contacts_on_the_compiled_route_keep_their_trajectory(monkeypatch):
    """The Python loop of spatial contacts reads the lazily built SciPy matrices: the same run as
    the SciPy route, and each block slides as alone (deceleration mu g along its velocity)."""
    sc = _spatial_blocks(80, 1)
    sc.system.check_state(sc.q0, sc.v0)  # finds the mass matrix's blocks, as simulate does first
    asm = assembly.StepAssembly(sc.system, 1e-3, 0.5)
    assert "arrays" in asm.__dict__
    res = lcp.simulate(sc, 0.05, h=1e-3)
    with monkeypatch.context() as mp:
        mp.setattr(assembly, "_have_numba", lambda: False)
        ref = lcp.simulate(_spatial_blocks(80, 1), 0.05, h=1e-3)
    assert res.status == ref.status == 0
    np.testing.assert_array_equal(res.q, ref.q)
    np.testing.assert_array_equal(res.v, ref.v)
    speed0 = np.hypot(sc.v0[0::3], sc.v0[1::3])
    speed = np.hypot(res.v[-1, 0::3], res.v[-1, 1::3])
    np.testing.assert_allclose(speed, np.maximum(speed0 - 0.4 * 9.81 * res.t[-1], 0.0), rtol=0, atol=1e-12)
    assert np.all(np.abs(res.q[:, 2::3]) < 1e-12)
