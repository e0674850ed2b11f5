"""Block-diagonal structure of a sparse matrix: bodies coupled by nothing but their contacts.

The mass matrix of K independent bodies, and the iteration matrix W_h of the theta-method built
from it, are block diagonal up to a permutation of the coordinates. Their positive-definiteness test
and their inverse then reduce to small dense blocks, batched by size (one LAPACK call per size).
The blocks are gathered from the nonzeros in O(nnz) NumPy operations, without SciPy's fancy
indexing, whose fixed cost (a fraction of a millisecond per call) dominated the set-up of a few
hundred contacts.
"""
from __future__ import annotations

import numpy as np

from lcp.numerics.lazy import sparse as sp

__all__ = ["BLOCK_MAX", "block_inverse", "block_inverse_arrays", "compressed_diagonal_blocks", "diagonal_blocks"]

#: largest diagonal block handled densely
BLOCK_MAX = 32


def diagonal_blocks(A, max_size: int = BLOCK_MAX):
    """The diagonal blocks of a sparse square matrix, grouped by size, or None.

    The blocks are the connected components of A's graph (an entry (i, j) joins i and j). Returns
    None when a component has more than ``max_size`` rows, else a list of ``(idx, B)`` per block
    size s: ``idx`` (n_blocks, s) the rows of each block in increasing order, ``B`` (n_blocks, s, s)
    the blocks, ``B[b] == A[idx[b]][:, idx[b]]``.

    Parameters
    ----------
    A : scipy.sparse matrix, shape (n, n)
    max_size : int

    Examples
    --------
    >>> import numpy as np, scipy.sparse as sp
    >>> from lcp.numerics.block_diagonal import diagonal_blocks
    >>> A = sp.csr_matrix(np.array([[2.0, 0, 1], [0, 3, 0], [1, 0, 4]]))
    >>> [(idx.tolist(), B.tolist()) for idx, B in diagonal_blocks(A)]
    [([[1]], [[[3.0]]]), ([[0, 2]], [[[2.0, 1.0], [1.0, 4.0]]])]
    """
    if A.format == "csc":  # read as the CSR arrays of A', without a conversion
        return compressed_diagonal_blocks(A.shape[0], A.indptr, A.indices, A.data, True, max_size)
    A = A.tocsr()
    return compressed_diagonal_blocks(A.shape[0], A.indptr, A.indices, A.data, False, max_size)


def compressed_diagonal_blocks(n, ptr, inner, vals, by_columns: bool, max_size: int = BLOCK_MAX):
    """:func:`diagonal_blocks` of the n x n matrix given by its compressed arrays: CSC (column
    pointers, row indices) when ``by_columns``, else CSR. A fresh system's check passes CasADi's
    arrays here directly: a SciPy matrix built only to be read costs more than the search."""
    if n == 0:
        return []
    rows = np.repeat(np.arange(n), np.diff(ptr))
    cols = inner
    if by_columns:
        rows, cols = cols, rows
    found = _contiguous_blocks(n, rows, cols, max_size)
    if found is not None and found[1].min() == found[1].max():
        # consecutive blocks of one size s (bodies of s coordinates each): block r // s, place r % s
        s = int(found[1][0])
        B = np.zeros((n // s, s, s))
        np.add.at(B, (rows // s, rows % s, cols % s), vals)  # duplicates add up, as in A's value
        return [(np.arange(n).reshape(-1, s), B)]
    if found is None:
        found = _components(n, ptr, inner, vals, max_size)
        if found is None:
            return None
    label, sizes, order = found
    starts = np.concatenate([[0], np.cumsum(sizes)])
    pos = np.empty(n, dtype=np.int64)
    pos[order] = np.arange(n) - np.repeat(starts[:-1], sizes)  # place of each row in its block
    out = []
    size_of_entry = sizes[label[rows]]
    for size in np.unique(sizes).tolist():
        comps = np.flatnonzero(sizes == size)
        slot = np.empty(sizes.size, dtype=np.int64)
        slot[comps] = np.arange(comps.size)  # the place of each component among blocks of this size
        idx = order[starts[comps][:, None] + np.arange(size)[None, :]]
        B = np.zeros((comps.size, size, size))
        sel = size_of_entry == size
        r = rows[sel]
        # duplicates (an unsummed COO-born matrix) add up, as in A's value
        np.add.at(B, (slot[label[r]], pos[r], pos[cols[sel]]), vals[sel])
        out.append((idx, B))
    return out


def _contiguous_blocks(n, rows, cols, max_size):
    """(label, sizes, order) when the components of A's graph are intervals of consecutive rows
    (the usual numbering: each body's coordinates together), found in O(nnz) without a graph
    search (bodies of one or two coordinates: particles, the reduced Jean-Pratt system); else None.
    Each interval closes where no entry of its rows reaches beyond it; the labels are then checked
    on every entry, so an entry that joins two intervals sends the caller to the graph search."""
    if rows.size == 0:
        return None
    reach = np.arange(n)
    np.maximum.at(reach, rows, cols)
    np.maximum.at(reach, cols, rows)
    reach = np.maximum.accumulate(reach)
    ends = reach == np.arange(n)
    label = np.cumsum(ends) - ends  # the interval of each row
    if not np.array_equal(label[rows], label[cols]):
        return None
    sizes = np.bincount(label)
    # an interval of two rows is linked by the entry that opened it; a longer one may hold several
    # components (a zero pattern inside it), whose blocks the graph search finds
    if sizes.max() > min(2, max_size):
        return None
    return label, sizes, np.arange(n)


def _components(n, ptr, inner, vals, max_size):
    """(label, sizes, order) of the connected components of A's graph, or None past max_size."""
    from scipy.sparse.csgraph import connected_components

    graph = sp.csr_matrix((vals, inner, ptr), shape=(n, n))  # A or A': the same components
    n_comp, label = connected_components(graph, directed=False)
    sizes = np.bincount(label, minlength=n_comp)
    if sizes.max() > max_size:
        return None
    return label, sizes, np.argsort(label, kind="stable")  # the members of each block, block by block, increasing


def block_inverse(A, blocks=None):
    """A^-1 as a sparse matrix when A is block diagonal (up to a permutation) with blocks of at most
    :data:`BLOCK_MAX` rows, else None.

    Parameters
    ----------
    A : scipy.sparse matrix, shape (n, n), or None
        None when ``blocks`` are given (every row is in one of them).
    blocks : list, optional
        A's :func:`diagonal_blocks`, when the caller has them already.

    Examples
    --------
    >>> import numpy as np, scipy.sparse as sp
    >>> from lcp.numerics.block_diagonal import block_inverse
    >>> A = sp.csr_matrix(np.array([[2.0, 0, 1], [0, 4, 0], [1, 0, 1]]))
    >>> np.allclose(block_inverse(A) @ A.toarray(), np.eye(3))
    True
    """
    n = A.shape[0] if A is not None else sum(idx.size for idx, _ in blocks)
    if blocks is None:
        blocks = diagonal_blocks(A)
    if not blocks:
        return None
    data, indices, indptr = block_inverse_arrays(blocks, n)
    return sp.csr_matrix((data, indices, indptr), shape=(n, n))


def block_inverse_arrays(blocks, n: int):
    """The CSR arrays (data, indices, indptr) of the inverse of the n x n block-diagonal matrix of
    ``blocks`` (:func:`diagonal_blocks`' list); LinAlgError for a singular block."""
    # CSR arrays directly: each row of a block holds that block's columns, in increasing order
    # (idx is increasing within a block), so no COO sort is needed
    indptr = np.zeros(n + 1, dtype=np.int64)
    indices = np.empty(sum(idx.size * idx.shape[1] for idx, _ in blocks), dtype=np.int64)
    data = np.empty(indices.size)
    row_len = np.zeros(n, dtype=np.int64)
    for idx, _ in blocks:
        row_len[idx.ravel()] = idx.shape[1]
    np.cumsum(row_len, out=indptr[1:])
    for idx, B in blocks:
        size = idx.shape[1]
        at = indptr[idx.ravel()][:, None] + np.arange(size)[None, :]  # (n_blocks * size, size) slots
        indices[at] = np.repeat(idx, size, axis=0)
        data[at] = np.linalg.inv(B).reshape(-1, size)
    return data, indices, indptr
