"""The checks of a start: the mass matrix (symmetric positive definite) and the contact rows (independent).

:meth:`System.check_state <lcp.model.system.System.check_state>` runs these tests on a start;
they work on the nonzeros CasADi gives (a sparse mass matrix of independent bodies is tested
block by block, never formed dense). Imports :mod:`lcp.numerics` only (the System is passed in).
"""
from __future__ import annotations

import numpy as np

from lcp.numerics.casadi_eval import evaluate_into

__all__ = ["check_contact_rows", "check_dense_mass", "check_sparse_mass", "check_definite", "dense_mass", "mass_ccs_values",
           "null_space", "sparse_mass"]


def check_dense_mass(system, q0, t0) -> None:
    """The test of :meth:`System.check_state <lcp.model.system.System.check_state>` on the dense mass matrix (on the constraint manifold)."""
    A = dense_mass(system, q0, t0)
    if not np.all(np.isfinite(A)):
        raise ValueError("mass matrix is not finite at q0")
    if np.max(np.abs(A - A.T)) > 1e-12 * max(1.0, np.max(np.abs(A))):
        raise ValueError("mass matrix must be symmetric")
    if system.n_bilateral:
        _, G, _ = (np.array(x, dtype=float) for x in system.constraints_fn(t0, q0))
        Z = null_space(G.reshape(system.n_bilateral, system.n))
        A = Z.T @ A @ Z
    As = 0.5 * (A + A.T)
    check_definite([As] if A.size else [], As.shape[0],
                    1e-14 * max(1.0, float(np.max(np.sum(np.abs(As), axis=1), initial=0.0))))

def check_sparse_mass(system, q0, t0) -> None:
    """The test of :meth:`System.check_state <lcp.model.system.System.check_state>` for a sparse mass matrix without bilateral constraints,
    on its nonzeros: where A is block diagonal (up to a permutation) with small blocks, its
    eigenvalues (n <= 200) are those of the blocks and the Cholesky factorization of A - s I
    (larger n) is that of each block (batched), so the dense matrix is never formed and the
    verdicts are the dense test's; otherwise the dense test. A constant mass matrix keeps its
    blocks (``System.mass_blocks``): the sparse assembly inverts them instead of finding them again.
    Everything is read from CasADi's compressed arrays (no SciPy matrix unless the blocks are
    large): on a fresh system the conversions would cost more than the test."""
    from lcp.numerics.block_diagonal import compressed_diagonal_blocks

    n = system.n
    data, row, colind = mass_ccs_values(system, q0, t0)
    if not np.all(np.isfinite(data)):
        raise ValueError("mass matrix is not finite at q0")
    scale = max(1.0, float(np.max(np.abs(data), initial=0.0)))
    # symmetry on the nonzeros: CCS order sorts the keys col * n + row, so each entry's mirror
    # (row * n + col) is found by bisection; a missing mirror is a zero
    col = np.repeat(np.arange(n), np.diff(colind))
    row64 = row.astype(np.int64)  # row * n in int32 would overflow past 46340 coordinates
    keys = col * n + row64
    mkeys = row64 * n + col
    at = np.minimum(np.searchsorted(keys, mkeys), keys.size - 1)
    mirror = np.where(keys[at] == mkeys, data[at], 0.0)
    if np.max(np.abs(data - mirror), initial=0.0) > 1e-12 * scale:
        raise ValueError("mass matrix must be symmetric")
    shift = 1e-14 * max(1.0, float(np.max(np.bincount(row, np.abs(data), minlength=n), initial=0.0)))
    blocks = compressed_diagonal_blocks(n, colind, row, data, True)
    if blocks is None:
        from scipy.sparse import csc_matrix

        A = csc_matrix((data, row, colind), shape=(n, n))
        As = 0.5 * (A + A.T)
        check_definite([As.toarray()], n, shift)
        return
    check_definite([0.5 * (B + B.transpose(0, 2, 1)) for _, B in blocks], n, shift)
    if system.mass_is_constant:
        system.mass_blocks = blocks

def dense_mass(system, q, t) -> np.ndarray:
    """:meth:`System.mass <lcp.model.system.System.mass>` for a validated q, evaluated into NumPy buffers (the check of a fresh small
    system pays CasADi's matrix conversion otherwise)."""
    n = system.n
    sparsity = system.mass_fn.sparsity_out(0)
    data = np.empty(sparsity.nnz())
    evaluate_into(system.mass_fn, [np.array([float(t)]), np.asarray(q, dtype=float)], [data])
    flat = np.zeros(n * n)
    flat[np.array(sparsity.find(), dtype=np.int64)] = data  # column-major positions
    return np.ascontiguousarray(flat.reshape(n, n).T)

def sparse_mass(system, q, t: float = 0.0):
    """The mass matrix A(t, q) as a SciPy CSC matrix of its structural nonzeros (never dense)."""
    from scipy.sparse import csc_matrix

    data, row, colind = mass_ccs_values(system, q, t)
    return csc_matrix((data, row, colind), shape=(system.n, system.n))


def mass_ccs_values(system, q, t):
    """(nonzeros, row indices, column pointers) of A(t, q), CasADi's CCS arrays (int32 indices)."""
    sparsity = system.mass_fn.sparsity_out(0)
    if "_mass_ccs" not in system.__dict__:
        colind, row = sparsity.get_ccs()
        system._mass_ccs = (np.array(row, dtype=np.int32), np.array(colind, dtype=np.int32))
    data = np.empty(sparsity.nnz())
    evaluate_into(system.mass_fn, [np.array([float(t)]), np.asarray(q, dtype=float)], [data])
    row, colind = system._mass_ccs
    return data, row, colind


def check_definite(blocks, size: int, shift: float) -> None:
    """The positive-definiteness test of a symmetric mass matrix of ``size`` rows given as diagonal
    ``blocks`` (arrays (..., k, k); the whole matrix as one block, or none when it is empty), or
    ValueError. Up to 200 rows: the eigenvalues, all above 1e-14 of the largest. Larger: a Cholesky
    factorization of each block minus ``shift`` I, which succeeds iff every eigenvalue exceeds the
    shift; with the shift above 1e-14 of the largest eigenvalue (the infinity norm bounds it) that
    is the same test at a tenth of the cost (seconds for thousands of coordinates)."""
    if size <= 200:
        eigs = [np.linalg.eigvalsh(B) for B in blocks]  # ascending along the last axis
        low = min((float(e[..., 0].min()) for e in eigs if e.size), default=1.0)
        high = max((max(-float(e[..., 0].min()), float(e[..., -1].max())) for e in eigs if e.size), default=1.0)
        if low <= 1e-14 * max(1.0, high):
            eig = np.sort(np.concatenate([e.ravel() for e in eigs]))
            raise ValueError("mass matrix is singular or not positive definite (on the constraint manifold) "
                             f"at q0: eigenvalues {eig}")
        return
    for B in blocks:
        try:
            np.linalg.cholesky(B - shift * np.eye(B.shape[-1]))
        except np.linalg.LinAlgError:
            raise ValueError("mass matrix is singular or not positive definite (on the constraint manifold) "
                             f"at q0: an eigenvalue is below {shift:.3g}") from None


def null_space(G: np.ndarray) -> np.ndarray:
    """Orthonormal basis of the null space of G (for the bilateral constraints)."""
    if G.shape[0] == 0:
        return np.eye(G.shape[1])
    u, s, vt = np.linalg.svd(G)
    rank = int(np.sum(s > 1e-12 * max(1.0, s.max())))
    if rank < G.shape[0]:
        raise ValueError("bilateral constraints are redundant (their Jacobian G is rank deficient)")
    return vt[rank:].T


def check_contact_rows(system, q) -> None:
    """The tangent rows of each contact must be independent of each other and of its normal."""
    H = system.contact_jacobian(q)
    m, off = system.n_contacts, system.tangent_offsets
    for j, c in enumerate(system.contacts):
        rows = H[np.r_[j, m + off[j]:m + off[j + 1]]]
        s = np.linalg.svd(rows, compute_uv=False)
        if not np.all(np.isfinite(s)):
            raise ValueError(f"contact {c.name!r}: its Jacobian rows are not finite at q = {q}")
        if s[-1] <= 1e-10 * max(s[0], 1e-300):
            which = "normal" if s[0] == 0 else ("tangent rows" if rows.shape[0] > 2 else "tangent row")
            raise ValueError(f"contact {c.name!r}: its {which} must be independent of each other and of "
                             f"the normal (the rows [H_N; H_T] are rank deficient, singular values {s})")
    system.contact_rows_checked = True
