"""Block-diagonal structure (lcp.numerics.block_diagonal) and the sparse assembly of independent bodies.

- the blocks gathered from the nonzeros put back together give the matrix, in every storage;
- the block inverse is the inverse (checked against the dense one);
- independent bodies skip SuperLU in the sparse assembly: the same trajectory as the dense
  assembly, with and without damping (which makes W_h differ from the mass matrix).
"""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given
from hypothesis import strategies as st

import lcp
from lcp.timestepping import assembly
from lcp.numerics.block_diagonal import block_inverse, diagonal_blocks
from lcp.scenes import Scene
from lcp.model.system import Contact, System


def _random_blocks(seed, sizes, symmetric):
    rng = np.random.default_rng(seed)
    n = int(sum(sizes))
    D = np.zeros((n, n))
    at = 0
    for s in sizes:
        B = rng.normal(size=(s, s))
        B = B @ B.T + s * np.eye(s) if symmetric else B + 2 * s * np.eye(s)
        D[at:at + s, at:at + s] = B
        at += s
    perm = rng.permutation(n)
    return D[np.ix_(perm, perm)]


@given(seed=st.integers(0, 2**31 - 1), sizes=st.lists(st.integers(1, 6), min_size=1, max_size=30),
       symmetric=st.booleans(), fmt=st.sampled_from(["csr", "csc", "coo"]))
def test_blocks_rebuild_the_matrix_and_invert_it(seed, sizes, symmetric, fmt):
    D = _random_blocks(seed, sizes, symmetric)
    A = sp.csr_matrix(D).asformat(fmt)
    blocks = diagonal_blocks(A)
    rebuilt = np.zeros_like(D)
    for idx, B in blocks:
        assert np.all(np.diff(idx, axis=1) > 0)  # rows of a block in increasing order
        for rows, b in zip(idx, B):
            rebuilt[np.ix_(rows, rows)] = b
    np.testing.assert_array_equal(rebuilt, D)
    assert sorted(idx.shape[1] for idx, B in blocks for _ in idx) == sorted(sizes)
    X = block_inverse(A).toarray()
    np.testing.assert_allclose(X, np.linalg.inv(D), rtol=1e-10, atol=1e-12 * np.abs(np.linalg.inv(D)).max())


def test_duplicate_entries_add_up_and_large_components_are_refused():
    A = sp.coo_matrix((np.array([1.0, 2.0, 5.0]), (np.array([0, 0, 1]), np.array([0, 0, 1]))), shape=(2, 2))
    (_, B), = diagonal_blocks(A.tocsc())
    assert B.ravel().tolist() == [3.0, 5.0]
    chain = sp.diags([np.ones(39), np.full(40, 3.0), np.ones(39)], [-1, 0, 1])  # one component of 40 rows
    assert diagonal_blocks(chain) is None and block_inverse(chain) is None
    assert diagonal_blocks(chain, max_size=40) is not None
    assert diagonal_blocks(sp.csr_matrix((0, 0))) == []


def _damped_copies(K, c):
    """K reduced Jean-Pratt systems (alpha = pi/4, R = 0.5) in one System, each with a dashpot c on
    its own sliding coordinate when c > 0 (W_h = A + h theta C, still block diagonal)."""
    n = 2 * K
    q, v = ca.SX.sym("q", n), ca.SX.sym("v", n)
    mass = ca.SX(ca.DM(sp.csc_matrix(sp.kron(sp.eye(K), np.array([[2.0, -1.0], [-1.0, 2.0]])))))
    force = ca.vertcat(*[x for i in range(K) for x in (-c * v[2 * i], ca.SX(-2 * 9.81))])
    contacts = [Contact(gap=q[2 * i + 1], tangent=q[2 * i], mu=0.5, name=f"P{i}") for i in range(K)]
    v0 = np.zeros(n)
    v0[0::2] = 1.0 + np.arange(K) / K
    return Scene(System(q, v, mass, force, contacts=contacts), np.zeros(n), v0, 0.3, f"copies_{K}")


@pytest.mark.parametrize("c", [0.0, 3.0])
def test_independent_bodies_skip_superlu_and_match_the_dense_assembly(c, monkeypatch):
    sc = _damped_copies(110, c)  # 220 contact rows: the sparse assembly
    asm = assembly.StepAssembly(sc.system, 1e-3, 0.5)
    assert asm.sparse and asm._lu is None  # the block inverse, no factorization
    sparse_run = lcp.simulate(sc, 0.3, h=1e-3)
    monkeypatch.setattr(assembly, "SPARSE_MIN_CONTACT_ROWS", 10**9)
    dense_run = lcp.simulate(_damped_copies(110, c), 0.3, h=1e-3)
    assert sparse_run.status == dense_run.status == 0
    np.testing.assert_allclose(sparse_run.q, dense_run.q, rtol=0, atol=1e-13)
    np.testing.assert_allclose(sparse_run.v, dense_run.v, rtol=0, atol=1e-12)
    assert np.all(np.abs(sparse_run.q[:, 1::2]) < 1e-12)  # no lift-off, no sinking
    if c == 0.0:
        # exact: each copy slides at x'' = -2 mu g / (2 - mu) (normal impulse 2g - x'') until it
        # stops, and the theta-method is exact on velocities under a constant force
        a = 2 * 0.5 * 9.81 / (2 - 0.5)
        v0 = sc.v0[0::2]
        np.testing.assert_allclose(sparse_run.v[-1, 0::2], np.maximum(v0 - a * sparse_run.t[-1], 0.0),
                                   rtol=0, atol=1e-12)
