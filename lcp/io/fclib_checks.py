"""Validation of friction-contact problem files for :mod:`lcp.io.fclib`: structure before data.

A problem file is untrusted input. Its declared sizes, pointers and indices are checked with NumPy
against each other and against what the file actually holds *before* any array is allocated from
them or any SciPy matrix is built (SciPy's conversions trust their index arrays: a negative row
index of a CSC matrix crashed the interpreter in its conversion to CSR). Every failure is a
``ValueError`` naming the file, the dataset (HDF5) or line (``.dat``) and what is wrong.

Value checks (:func:`check_values`), made by the readers unless they are called with
``check=False``:

- every entry of W, q (or M, H, f, w) finite; every friction coefficient finite and >= 0;
- W symmetric: ``max |W_ij - W_ji| <= SYM_TOL max |W_ij|`` with :data:`SYM_TOL` = 1e-2 (files of
  Siconos's own test collection reach 1.3e-3: ``Capsules-i125-1213``; a tighter warning stays
  in :meth:`lcp.io.fclib.ContactFile.check`);
- W positive semi-definite: ``(W + W')/2 + PSD_TOL ||W||_inf I`` positive definite, with
  :data:`PSD_TOL` = 1e-5, i.e. no eigenvalue of the symmetric part below ``-1e-5 ||W||_inf``
  (``||W||_inf`` the largest absolute row sum). A PSD matrix printed with 6 significant digits, as
  Siconos's fc2d files are, moves its eigenvalues by at most ``5e-6 ||W||_inf``; the collection's
  granular files reach -1.5e-7 of it. The test is a sparse LDL' factorization
  (:func:`shifted_pivots`), a cost near one factorization of W, not an eigenvalue decomposition.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

#: relative asymmetry max |W - W'| / max |W| above which a file's W is rejected
SYM_TOL = 1e-2
#: W is rejected when (W + W')/2 + PSD_TOL ||W||_inf I is not positive definite
PSD_TOL = 1e-5
#: the largest ratio of a deflate-compressed HDF5 dataset's size to its stored size (zlib's limit)
DEFLATE_RATIO = 1032


class FileError(ValueError):
    """A malformed problem file (its message names the file and the place)."""


def fail(path, where, what):
    raise FileError(f"{path}: {where}: {what}")


# --------------------------------------------------------------------------- matrices
def shifted_pivots(S, shift: float) -> int:
    """Number of non-positive pivots of an LDL' factorization of ``S + shift I`` (S symmetric).

    SuperLU factors in its symmetric mode with a fill-reducing symmetric ordering and diagonal
    pivots only (``diag_pivot_thresh=0``), so the factorization is P'(S + shift I)P = L D L' and,
    by Sylvester's law of inertia, the count of pivots <= 0 is 0 exactly when S + shift I is
    positive definite. A zero diagonal pivot forces SuperLU to exchange rows (then the matrix is not
    positive definite either): reported as 1, as is an exactly singular factorization.

    Examples
    --------
    >>> import numpy as np, scipy.sparse as sp
    >>> from lcp.io.fclib_checks import shifted_pivots
    >>> shifted_pivots(sp.csr_matrix(np.diag([2.0, 0.0, -1.0])), 1e-9)
    1
    >>> shifted_pivots(sp.csr_matrix(np.diag([2.0, 0.0, 1.0])), 1e-9)
    0
    """
    from scipy.sparse.linalg import splu

    n = S.shape[0]
    if n == 0:
        return 0
    A = sp.csc_matrix(S + shift * sp.identity(n, format="csc"))
    try:
        lu = splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))
    except RuntimeError:  # exactly singular
        return 1
    if not np.array_equal(lu.perm_r, lu.perm_c):
        return max(1, int(np.sum(lu.U.diagonal() <= 0)))
    return int(np.sum(lu.U.diagonal() <= 0))


def symmetry_and_psd(W, sym_tol: float = SYM_TOL, psd_tol: float = PSD_TOL, scale: str = "inf"):
    """(relative asymmetry, pivots <= 0 of the shifted LDL') of a sparse W; see the module doc.

    ``scale``: the shift is ``psd_tol`` times ``||W||_inf`` ("inf") or times ``max |W_ij|`` ("max").
    """
    W = sp.csr_matrix(W)
    if W.nnz == 0:
        return 0.0, 0
    absmax = float(abs(W).max())
    if absmax == 0.0:
        return 0.0, 0
    asym = W - W.T
    rel = float(abs(asym).max()) / absmax if asym.nnz else 0.0
    norm = float(np.max(np.asarray(abs(W).sum(axis=1)))) if scale == "inf" else absmax
    return rel, shifted_pivots(0.5 * (W + W.T), psd_tol * norm)


def check_values(path, W, q, mu, where_W="W", where_q="q", where_mu="mu", reduced=False):
    """Finite W and q, finite mu >= 0, W symmetric and PSD to :data:`SYM_TOL`, :data:`PSD_TOL`."""
    W = sp.csr_matrix(W)
    if not np.all(np.isfinite(W.data)):
        Wc = W.tocoo()
        bad = np.flatnonzero(~np.isfinite(Wc.data))[0]
        fail(path, where_W, f"non-finite entry W[{Wc.row[bad]}, {Wc.col[bad]}] = {Wc.data[bad]}")
    finite_vector(path, where_q, q, "q")
    mu = np.asarray(mu)
    bad = np.flatnonzero(~(np.isfinite(mu) & (mu >= 0)))
    if bad.size:
        fail(path, where_mu, f"friction coefficients must be >= 0 and finite: mu[{bad[0]}] = {mu[bad[0]]} "
                             f"(contact {bad[0]}, {bad.size} such)")
    rel, neg = symmetry_and_psd(W)
    what = "W = H' M^-1 H (reduced from M and H)" if reduced else "W"
    if rel > SYM_TOL:
        fail(path, where_W, f"{what} is not symmetric: max |W - W'| / max |W| = {rel:.3g} > {SYM_TOL:g}")
    if neg:
        fail(path, where_W, f"{what} is not positive semi-definite: (W + W')/2 + {PSD_TOL:g} ||W||_inf I has "
                            f"{neg} non-positive pivot(s) in its LDL' factorization (an eigenvalue below "
                            f"-{PSD_TOL:g} ||W||_inf)")


def finite_vector(path, where, x, name):
    x = np.asarray(x)
    if not np.all(np.isfinite(x)):
        bad = np.flatnonzero(~np.isfinite(x))[0]
        fail(path, where, f"non-finite entry {name}[{bad}] = {x[bad]}")


def compressed_matrix(path, where, kind, m, n, ptr, idx, val, check=True):
    """A CSR/CSC matrix from index arrays validated first (int64 NumPy arrays, values float).

    ``ptr`` must have ``outer + 1`` entries, start at 0 and never decrease; its last entry may not
    exceed the stored indices or values; every index lies in ``[0, inner)``. Duplicate entries are
    summed (as CSparse's routines treat them).
    """
    outer, inner = (n, m) if kind == "csc" else (m, n)
    if ptr.size != outer + 1:
        fail(path, where, f"{kind.upper()} pointers have {ptr.size} entries for {outer} "
                          f"{'columns' if kind == 'csc' else 'rows'} (expected {outer + 1})")
    if ptr[0] != 0:
        fail(path, where, f"{kind.upper()} pointers must start at 0, got {ptr[0]}")
    dec = np.flatnonzero(np.diff(ptr) < 0)
    if dec.size:
        fail(path, where, f"{kind.upper()} pointers decrease at {dec[0]} ({ptr[dec[0]]} then {ptr[dec[0] + 1]})")
    nnz = int(ptr[-1])
    if nnz > idx.size or nnz > val.size:
        fail(path, where, f"pointers declare {nnz} entries but only {idx.size} indices and {val.size} values "
                          "are stored")
    idx, val = idx[:nnz], val[:nnz]
    index_range(path, where, idx, inner, "row" if kind == "csc" else "column")
    if check and not np.all(np.isfinite(val)):
        bad = np.flatnonzero(~np.isfinite(val))[0]
        fail(path, where, f"non-finite value {val[bad]} at entry {bad}")
    cls = sp.csc_matrix if kind == "csc" else sp.csr_matrix
    mat = sp.csr_matrix(cls((val.astype(float), idx, ptr), shape=(m, n)))
    mat.sum_duplicates()
    return mat


def triplet_matrix(path, where, m, n, rows, cols, val, check=True):
    """A matrix from triplets (duplicates summed) whose indices are validated first."""
    index_range(path, where, rows, m, "row")
    index_range(path, where, cols, n, "column")
    if check and not np.all(np.isfinite(val)):
        bad = np.flatnonzero(~np.isfinite(val))[0]
        fail(path, where, f"non-finite value {val[bad]} at entry {bad} (row {rows[bad]}, column {cols[bad]})")
    return sp.csr_matrix(sp.coo_matrix((np.asarray(val, float), (rows, cols)), shape=(m, n)))


def index_range(path, where, idx, size, what):
    if idx.size == 0:
        return
    lo, hi = int(idx.min()), int(idx.max())
    if lo < 0:
        j = int(np.argmax(idx < 0))
        fail(path, where, f"negative {what} index {idx[j]} at entry {j}")
    if hi >= size:
        j = int(np.argmax(idx >= size))
        fail(path, where, f"{what} index {idx[j]} at entry {j} out of range (size {size})")


# --------------------------------------------------------------------------- HDF5 datasets
def h5_array(grp, key, path, what, integer: bool, file_size: int, scalar: bool = False):
    """One dataset of an FCLib group, validated before it is read.

    Numeric (integer where ``integer``), one-dimensional (or a single value where ``scalar``), held
    in the file (no virtual or external storage) and no larger than the file can hold: its declared
    size may not exceed the file's size, or :data:`DEFLATE_RATIO` times its stored size when it is
    compressed. Returns an int64 or float64 array.
    """
    where = f"{grp.name.rstrip('/')}/{key}"
    try:
        ds = grp[key]
    except KeyError:
        raise FileError(f"{path}: {what}: missing dataset {where}") from None
    except (OSError, RuntimeError, TypeError, ValueError) as exc:
        fail(path, where, f"cannot open: {exc}")
    if not hasattr(ds, "dtype") or not hasattr(ds, "shape"):
        fail(path, where, f"expected a dataset, found a {type(ds).__name__}")
    try:
        dt, shape = ds.dtype, ds.shape
        virtual, external = ds.is_virtual, ds.external
        filtered = bool(ds.compression) or bool(getattr(ds, "_filters", None))
        stored = ds.id.get_storage_size()
    except (OSError, RuntimeError, TypeError, ValueError, KeyError) as exc:
        fail(path, where, f"cannot read its header: {exc}")
    kinds = "iu" if integer else "iuf"
    if dt.kind not in kinds or dt.fields is not None or dt.subdtype is not None:
        fail(path, where, f"expected {'integers' if integer else 'numbers'}, found dtype {dt}")
    if shape is None:
        fail(path, where, "empty dataspace (no data)")
    if scalar and int(np.prod(shape, dtype=object)) != 1:
        fail(path, where, f"must hold one value, has shape {shape}")
    if not scalar and len(shape) != 1:
        fail(path, where, f"must be one-dimensional, has shape {shape}")
    if virtual or external:
        fail(path, where, "refers to data outside the file (virtual or external storage)")
    size = int(np.prod(shape, dtype=object))
    declared = size * dt.itemsize
    limit = DEFLATE_RATIO * stored + 64 if filtered else file_size
    if declared > limit:
        fail(path, where, f"declares {size} entries ({declared} bytes) but the file holds {file_size} bytes "
                          f"({stored} stored for this dataset)")
    try:
        raw = np.asarray(ds[()]).reshape(-1)
    except (OSError, RuntimeError, TypeError, ValueError, KeyError, MemoryError) as exc:
        fail(path, where, f"cannot read the data: {exc}")
    if raw.size != size:
        fail(path, where, f"holds {raw.size} entries, declares {size}")
    if integer:
        if raw.dtype.kind == "u" and raw.size and raw.max() > np.iinfo(np.int64).max:
            fail(path, where, f"integer {raw.max()} out of range")
        return raw.astype(np.int64)
    return raw.astype(float)


def h5_int(grp, key, path, what, file_size, low=None):
    x = h5_array(grp, key, path, what, True, file_size, scalar=True)
    v = int(x[0])
    if low is not None and v < low:
        fail(path, f"{grp.name.rstrip('/')}/{key}", f"must be >= {low}, got {v}")
    return v


def h5_matrix(grp, path, file_size, shape, check=True):
    """An FCLib matrix group (``m``, ``n``, ``nz``, ``nzmax``, ``p``, ``i``, ``x``) of the expected
    ``shape`` (from the vectors already read): sizes first, then the index arrays, then the matrix."""
    g = grp.name.rstrip("/")
    what = g
    m = h5_int(grp, "m", path, what, file_size, low=0)
    n = h5_int(grp, "n", path, what, file_size, low=0)
    if (m, n) != tuple(shape):
        fail(path, f"{g}/m, {g}/n", f"declare a {m} x {n} matrix, the vectors need {shape[0]} x {shape[1]}")
    nz = h5_int(grp, "nz", path, what, file_size)
    if nz < -2:
        fail(path, f"{g}/nz", f"unknown storage nz = {nz} (>= 0 triplets, -1 CSC, -2 CSR)")
    nzmax = h5_int(grp, "nzmax", path, what, file_size, low=0) if "nzmax" in grp else None
    p = h5_array(grp, "p", path, what, True, file_size)
    i = h5_array(grp, "i", path, what, True, file_size)
    x = h5_array(grp, "x", path, what, False, file_size)
    if nz >= 0:  # triplet, CSparse convention: i rows, p columns
        if min(p.size, i.size, x.size) < nz:
            fail(path, g, f"{nz} triplets declared but p, i, x hold {p.size}, {i.size}, {x.size} entries")
        if nzmax is not None and nzmax < nz:
            fail(path, f"{g}/nzmax", f"nzmax {nzmax} < nz {nz}")
        return triplet_matrix(path, g, m, n, i[:nz], p[:nz], x[:nz], check)
    kind = "csc" if nz == -1 else "csr"
    mat = compressed_matrix(path, g, kind, m, n, p, i, x, check)
    if nzmax is not None and nzmax < p[-1]:
        fail(path, f"{g}/nzmax", f"nzmax {nzmax} < the {p[-1]} entries its pointers declare")
    return mat
