"""Friction-contact problem files: FCLib's HDF5 format and Siconos's ``.dat`` text format.

Both store a planar (``spacedim`` 2) or spatial (``spacedim`` 3) problem contact by contact,
``r = (r_N,1, r_T,1, ...)`` (one tangent entry per planar contact, two per spatial one), in one of
two forms:

- local: u = W r + q, Coulomb's law between r and u (W of size d k, d the dimension);
- global: M v = H r + f, u = H' v + w (FCLib's names; Siconos writes q for f and b for w), reduced
  here to the local form W = H' M^-1 H, q = H' M^-1 f + w with a sparse factorization of M.

:func:`read_problem` returns a :class:`ContactFile` whose ``dim`` is the file's dimension and whose
:meth:`ContactFile.problem` is a :class:`~lcp.contact.problem.ContactProblem` for a planar file or a
:class:`~lcp.contact.spatial_problem.ConeContactProblem` (the Coulomb disk) for a spatial one, impulses
ordered normals first, the package's order (:func:`lcp.contact.law.interleave` and
:attr:`ConeContactProblem.perm <lcp.contact.spatial_problem.ConeContactProblem>` map between the two).
Matrices stay sparse.

Siconos ``.dat`` layout (whitespace-separated): dimension, number of contacts, then the matrix
(storage 0 dense column-major, 1 sparse-block, 2 CSparse triplet/CSC/CSR), then q and mu for the
local form (:func:`write_dat` writes d x d blocks for sparse-block storage); for the global form
M, H, then q, b and mu. FCLib HDF5 layout: groups ``/fclib_local`` (``spacedim``, ``W``,
``vectors/q``, ``vectors/mu``, optional ``info``) or ``/fclib_global`` (``spacedim``, ``M``, ``H``,
``vectors/f``, ``vectors/w``, ``vectors/mu``); each matrix has ``m``, ``n``, ``nz`` (triplet
count, -1 CSC, -2 CSR), ``nzmax``, ``p``, ``i``, ``x`` as CSparse stores them.

The readers validate before they convert or allocate (:mod:`lcp.io.fclib_checks`): dtypes (numbers;
integers for sizes and indices), shapes, every declared size against the data present and the
file's size, CSR/CSC pointers (from 0, never decreasing, within the stored entries), indices
within range; then, unless called with ``check=False``, the values: finite data, finite mu >= 0,
W symmetric (to :data:`~lcp.io.fclib_checks.SYM_TOL` = 1e-2 of max |W|) and positive semi-definite
(no eigenvalue below -:data:`~lcp.io.fclib_checks.PSD_TOL` ||W||_inf = -1e-5 ||W||_inf, by a sparse
LDL' factorization). A malformed, truncated or invalid file raises ``ValueError`` naming the file,
the place (line of a ``.dat`` file, dataset of an HDF5 file) and what is wrong;
:meth:`ContactFile.check` reports sizes that disagree, negative or non-finite friction
coefficients, non-finite entries (with the first one's place) and an unsymmetric or indefinite W
(warnings at the tighter tolerances 1e-5 and 1e-9 of max |W|) before any solve.

:func:`write_dat` writes every number so that it reads back to the same double (``%.17e``,
``%.17g``, ``repr``), vectors never as bare integers; the reader tells the local form from the
global one by the count of numbers after the first matrix (exactly d k + k for q and mu, plus the
closing integer some Siconos files carry), so files of whole numbers round-trip too.

Examples
--------
>>> import numpy as np, tempfile, os
>>> from lcp.io.fclib import ContactFile, read_problem, write_hdf5
>>> W = np.array([[2.0, 0.5], [0.5, 1.0]])
>>> cf = ContactFile(W=W, q=np.array([-1.0, 0.3]), mu=np.array([0.4]))
>>> path = os.path.join(tempfile.mkdtemp(), "one.hdf5")
>>> write_hdf5(path, cf)
>>> back = read_problem(path)
>>> np.allclose(back.W.toarray(), W), back.form, back.n_contacts, back.dim
(True, 'local', 1, 2)

A spatial contact (dimension 3): a unit block pressed at 1 m/s and pushed sideways at 2 m/s,
friction 0.5, read back as the Coulomb-disk problem and solved.

>>> from lcp.contact.spatial_solvers import make_cone_solver
>>> cf3 = ContactFile(np.eye(3), np.array([-1.0, 0.0, 2.0]), [0.5], dim=3)
>>> path3 = os.path.join(tempfile.mkdtemp(), "one3.dat")
>>> write_dat(path3, cf3, storage="sparse-block")
>>> pb = read_problem(path3).problem(); type(pb).__name__
'ConeContactProblem'
>>> make_cone_solver("auto").solve(pb).p
array([ 1. ,  0. , -0.5])
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from lcp.io import fclib_checks as _checks
from lcp.contact.spatial_problem import ConeContactProblem
from lcp.contact.problem import ContactProblem
from lcp.contact.law import blocked, check_problem

#: dimensions (``spacedim``) the files may have: planar and spatial contacts
DIMENSIONS = (2, 3)

__all__ = ["ContactFile", "read_dat", "read_hdf5", "read_problem", "write_dat", "write_hdf5"]


@dataclass
class ContactFile:
    """A friction-contact problem as stored in a file (contact-by-contact order).

    Attributes
    ----------
    W : scipy.sparse matrix, shape (d k, d k)
        Local Delassus operator (the reduced one for a global problem).
    q : ndarray, shape (d k,)
    mu : ndarray, shape (k,)
    form : {"local", "global"}
    M : scipy.sparse matrix or None
        Global data (when ``form == "global"``, else None): the mass matrix ...
    H : scipy.sparse matrix or None
        ... the contact matrix ...
    f : ndarray or None
        ... the force vector ...
    w : ndarray or None
        ... and the contact offset, of M v = H r + f, u = H' v + w.
    name : str
    storage : str
        How the file stored its matrix ("dense", "sparse-block", "csparse-triplet", "csc", ...).
    dim : {2, 3}
        The file's dimension (``spacedim``): 2 planar contacts (one tangent direction), 3 spatial
        contacts (two).
    """

    W: object
    q: np.ndarray
    mu: np.ndarray
    form: str = "local"
    M: object = None
    H: object = None
    f: np.ndarray | None = None
    w: np.ndarray | None = None
    name: str = ""
    storage: str = ""
    info: dict = field(default_factory=dict)
    dim: int = 2

    def __post_init__(self):
        if self.dim not in DIMENSIONS:
            raise ValueError(f"dim must be 2 (planar) or 3 (spatial), got {self.dim!r}")
        self.dim = int(self.dim)
        self.W = sp.csr_matrix(self.W, dtype=float)
        self.q = np.asarray(self.q, dtype=float)
        self.mu = np.atleast_1d(np.asarray(self.mu, dtype=float))

    @classmethod
    def from_global(cls, M, H, f, w, mu, dim: int = 2, name: str = "") -> ContactFile:
        """A global-form problem (M v = H r + f, u = H' v + w) with its reduced local form.

        Examples
        --------
        >>> import numpy as np
        >>> from lcp.io.fclib import ContactFile
        >>> cf = ContactFile.from_global(2 * np.eye(3), np.eye(3), np.zeros(3), np.array([-1.0, 0, 0]), [0.5], dim=3)
        >>> cf.W.toarray().diagonal(), cf.form
        (array([0.5, 0.5, 0.5]), 'global')
        """
        if dim not in DIMENSIONS:
            raise ValueError(f"dim must be 2 (planar) or 3 (spatial), got {dim!r}")
        M, H = sp.csr_matrix(M, dtype=float), sp.csr_matrix(H, dtype=float)
        f, w = np.asarray(f, dtype=float), np.asarray(w, dtype=float)
        mu = np.atleast_1d(np.asarray(mu, dtype=float))
        nv = f.size
        if M.shape != (nv, nv) or H.shape != (nv, dim * mu.size) or w.shape != (dim * mu.size,):
            raise ValueError(f"global sizes disagree: M {M.shape}, H {H.shape}, f {f.shape}, w {w.shape} for "
                             f"{mu.size} contacts of dimension {dim}")
        return _from_global(M, H, f, w, mu, name or "problem", "", dim, check=False)

    @property
    def n_contacts(self) -> int:
        return self.mu.size

    @property
    def dims(self) -> np.ndarray:
        """Tangent dimension of each contact (``dim - 1``), the layout of a ConeContactProblem."""
        return np.full(self.n_contacts, self.dim - 1, dtype=np.int64)

    def check(self):
        """Sizes, signs, finiteness, symmetry and PSD-ness (:func:`lcp.contact.law.check_problem`).

        A non-finite entry of W or q is reported with the place of the first one (file order). W not
        positive semi-definite is a warning when (W + W')/2 + 1e-9 max |W| I has a non-positive
        pivot in a sparse LDL' factorization (:func:`lcp.io.fclib_checks.shifted_pivots`; the
        tolerance of ``check_problem``'s dense eigenvalue test, at the cost of one factorization).
        """
        name = self.name or "problem"
        # psd_tol=inf, dense_limit=0: no dense eigenvalue decomposition there, the PSD test is below
        rep = check_problem(self.W, self.q, self.mu, name=name, dims=None if self.dim == 2 else self.dims,
                            psd_tol=np.inf, dense_limit=0)
        for i, msg in enumerate(rep.errors):
            if msg == f"{name}: W has non-finite entries":
                Wc = sp.coo_matrix(self.W)
                bad = np.flatnonzero(~np.isfinite(Wc.data))[0]
                rep.errors[i] = f"{msg} (first: W[{Wc.row[bad]}, {Wc.col[bad]}] = {Wc.data[bad]})"
            elif msg == f"{name}: q has non-finite entries":
                bad = np.flatnonzero(~np.isfinite(self.q))[0]
                rep.errors[i] = f"{msg} (first: q[{bad}] = {self.q[bad]})"
            elif msg.startswith(f"{name}: friction coefficients must be"):
                bad = np.flatnonzero(~(np.isfinite(self.mu) & (self.mu >= 0)))[0]  # NaN and inf included
                rep.errors[i] = f"{msg} (first: mu[{bad}] = {self.mu[bad]}, contact {bad})"
        if not rep.errors and self.W.nnz:
            _, neg = _checks.symmetry_and_psd(self.W, psd_tol=1e-9, scale="max")
            if neg:
                rep.warnings.append(f"{name}: W is not positive semi-definite ((W + W')/2 + 1e-9 max |W| I has "
                                    f"{neg} non-positive pivot(s) in its LDL' factorization)")
        return rep

    def problem(self, check: bool = True) -> ContactProblem | ConeContactProblem:
        """The problem in the package's order (normals first); raises ValueError on errors.

        A planar file gives a :class:`ContactProblem`, a spatial one a
        :class:`~lcp.contact.spatial_problem.ConeContactProblem` (every contact with a 2-D tangent).
        """
        if check:
            rep = self.check()
            if rep.errors:
                raise ValueError("; ".join(rep.errors))
        if self.dim == 3:
            return ConeContactProblem.from_interleaved(self.W, self.q, self.mu, self.dims)
        k = self.n_contacts
        back = blocked(k)
        return ContactProblem(self.W[back][:, back], self.q[back], self.mu)


# --------------------------------------------------------------------------- text (.dat)
class _Tokens:
    """Whitespace tokens of a text file, with the line of each, for error messages, and the count of
    tokens left (declared sizes are checked against it before anything is allocated)."""

    def __init__(self, path, text):
        self.path = path
        self.lines = text.splitlines()
        self.split = [ln.split() for ln in self.lines]
        # after[i]: tokens on lines i, i + 1, ...
        self.after = np.concatenate([np.cumsum([len(w) for w in self.split][::-1])[::-1], [0]]).astype(np.int64)
        self.line, self.words, self.pos = 0, [], 0

    def remaining(self) -> int:
        """Tokens not yet read."""
        return len(self.words) - self.pos + int(self.after[self.line])

    def last_word(self):
        """The file's last token (None for a file without tokens)."""
        for words in reversed(self.split):
            if words:
                return words[-1]
        return None

    def need(self, count, what):
        """Fail unless ``count`` more tokens are left: a declared size the file cannot hold."""
        left = self.remaining()
        if count > left:
            raise _checks.FileError(f"{self.path}: line {self.line}: {what} needs {count} more numbers but the "
                                    f"file holds only {left}: truncated or a wrong size")

    def _fill(self):
        while self.pos >= len(self.words):
            if self.line >= len(self.lines):
                raise ValueError(f"{self.path}: file ends early (line {self.line}): truncated")
            self.words = self.split[self.line]
            self.line += 1
            self.pos = 0

    def word(self, what):
        try:
            self._fill()
        except ValueError as exc:
            raise _checks.FileError(f"{exc} while reading {what}") from None
        w = self.words[self.pos]
        self.pos += 1
        return w

    def int(self, what, low=0):
        w = self.word(what)
        try:
            v = int(w)
        except ValueError:
            raise _checks.FileError(f"{self.path}: line {self.line}: expected an integer for {what}, "
                                    f"got {w!r}") from None
        if v < low:
            raise _checks.FileError(f"{self.path}: line {self.line}: {what} must be >= {low}, got {v}")
        return v

    def float(self, what):
        w = self.word(what)
        try:
            return float(w)
        except ValueError:
            raise _checks.FileError(f"{self.path}: line {self.line}: expected a number for {what}, got {w!r}") from None

    def floats(self, n, what):
        self.need(n, what)
        out = np.empty(n)
        for i in range(n):
            out[i] = self.float(f"{what}[{i}]")
        return out

    def ints(self, n, what, low=0):
        self.need(n, what)
        return np.array([self.int(what, low) for _ in range(n)], dtype=np.int64)

    def rest_of_line(self):
        """The unread words of the current line, then move to the next line."""
        words = self.words[self.pos:]
        self.words, self.pos = [], 0
        return words

    def next_line(self, what):
        if self.line >= len(self.lines):
            raise _checks.FileError(f"{self.path}: file ends early (line {self.line}) while reading {what}: truncated")
        s = self.lines[self.line]
        self.line += 1
        self.words, self.pos = [], 0
        return s


def _read_matrix(tk: _Tokens, what: str, check: bool = True):
    storage = tk.int(f"{what} storage type")
    n0 = tk.int(f"{what} rows")
    n1 = tk.int(f"{what} columns")
    # every size of a problem's matrix is the length of a vector that follows it in the file
    tk.need(max(n0, n1), f"{what} of size {n0}x{n1} (a vector of that length follows it)")
    if storage == 0:
        r0, r1 = tk.int(f"{what} rows (dense)"), tk.int(f"{what} columns (dense)")
        if (r0, r1) != (n0, n1):
            raise _checks.FileError(f"{tk.path}: line {tk.line}: {what} sizes disagree ({n0}x{n1} then {r0}x{r1})")
        A = tk.floats(n0 * n1, f"{what} entries").reshape(n1, n0).T  # column-major
        # keep -0.0 entries: the written file is read back bit for bit
        rows, cols = np.nonzero((A != 0) | np.signbit(A))
        return sp.csr_matrix((A[rows, cols], (rows, cols)), shape=(n0, n1)), "dense"
    if storage == 1:
        return _read_sbm(tk, what, n0, n1), "sparse-block"
    if storage == 2:
        return _read_csparse(tk, what, n0, n1, check)
    raise _checks.FileError(f"{tk.path}: line {tk.line}: unknown storage type {storage} for {what}")


def _read_sbm(tk, what, n0, n1):
    nb = tk.int(f"{what} number of blocks")
    if nb == 0:
        return sp.csr_matrix((n0, n1))
    tk.need(nb, f"{what} block count")
    b0, b1 = tk.int(f"{what} block rows"), tk.int(f"{what} block columns")
    s0 = tk.ints(b0, f"{what} row block sizes")
    s1 = tk.ints(b1, f"{what} column block sizes")
    if (not b0 or not b1 or s0[-1] != n0 or s1[-1] != n1 or s0[0] <= 0 or s1[0] <= 0 or np.any(np.diff(s0) <= 0)
            or np.any(np.diff(s1) <= 0)):
        raise _checks.FileError(f"{tk.path}: line {tk.line}: {what} block sizes disagree with its {n0}x{n1} size")
    f1, f2 = tk.int(f"{what} filled1"), tk.int(f"{what} filled2")
    if f1 != b0 + 1 or f2 != nb:
        raise _checks.FileError(f"{tk.path}: line {tk.line}: {what} block index sizes disagree ({f1}, {f2})")
    rowptr = tk.ints(f1, f"{what} block row pointers")
    colidx = tk.ints(f2, f"{what} block column indices")
    rowdiff = np.diff(rowptr)
    if rowptr[0] != 0 or rowptr[-1] != nb or np.any(rowdiff < 0) or np.any(colidx >= b1):
        raise _checks.FileError(f"{tk.path}: line {tk.line}: {what} block indices out of range or unordered")
    # block columns strictly increase within a block row (Siconos's sparse-block storage is sorted)
    same_row = np.repeat(np.arange(b0), rowdiff)
    if np.any((np.diff(colidx) <= 0) & (np.diff(same_row) == 0)):
        raise _checks.FileError(f"{tk.path}: line {tk.line}: {what} block column indices repeat or are unordered "
                                "within a block row")
    start0 = np.concatenate([[0], s0[:-1]])
    start1 = np.concatenate([[0], s1[:-1]])
    rows, cols, vals = [], [], []
    for bi in range(b0):
        for blk in range(rowptr[bi], rowptr[bi + 1]):
            bj = colidx[blk]
            num = tk.int(f"{what} block number")
            if num != blk:
                raise _checks.FileError(f"{tk.path}: line {tk.line}: {what} block {blk} is numbered {num}")
            nr, nc = s0[bi] - start0[bi], s1[bj] - start1[bj]
            v = tk.floats(nr * nc, f"{what} block {blk}")
            rows.append(start0[bi] + np.tile(np.arange(nr), nc))  # column-major blocks
            cols.append(start1[bj] + np.repeat(np.arange(nc), nr))
            vals.append(v)
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n0, n1))


def _read_csparse(tk, what, n0, n1, check=True):
    tk.int(f"{what} sparse origin")
    tk.rest_of_line()
    head = tk.next_line(f"{what} CSparse banner")
    if "CSparse" not in head:
        raise _checks.FileError(f"{tk.path}: line {tk.line}: expected the CSparse banner for {what}, got {head[:40]!r}")
    desc = tk.next_line(f"{what} CSparse header").split()
    kind = "triplet" if desc[:1] == ["triplet:"] else ("csr" if desc[:1] == ["csr:"] else "csc")
    try:
        size = desc[1] if kind != "csc" else desc[0]
        m, n = (int(x) for x in size.rstrip(",").split("-by-"))
        nnz = int(desc[desc.index("nnz:") + 1].rstrip(","))
    except (ValueError, IndexError):
        raise _checks.FileError(f"{tk.path}: line {tk.line}: cannot read the CSparse header of {what}: "
                                f"{' '.join(desc)!r}") from None
    if (m, n) != (n0, n1):
        raise _checks.FileError(f"{tk.path}: line {tk.line}: {what} sizes disagree ({n0}x{n1} then {m}x{n})")
    if nnz < 0:
        raise _checks.FileError(f"{tk.path}: line {tk.line}: {what}: negative entry count nnz = {nnz}")
    where = f"line {tk.line}: {what}"
    if kind == "triplet":
        tk.need(4 * nnz, f"{what}'s {nnz} triplets")
        rows, cols, vals = np.empty(nnz, np.int64), np.empty(nnz, np.int64), np.empty(nnz)
        for p in range(nnz):
            rows[p] = tk.int(f"{what} entry {p} row", low=-2 ** 62)
            cols[p] = tk.int(f"{what} entry {p} column", low=-2 ** 62)
            if tk.word(f"{what} entry {p}") != ":":
                raise _checks.FileError(f"{tk.path}: line {tk.line}: malformed triplet entry {p} of {what}")
            vals[p] = tk.float(f"{what} entry {p} value")
        # non-finite values are the value checks' (check=True) business, with the entry's place
        return _checks.triplet_matrix(tk.path, where, m, n, rows, cols, vals, check=False), "csparse-triplet"
    outer = n if kind == "csc" else m
    tk.need(nnz, f"{what}'s {nnz} entries")
    ptr = np.zeros(outer + 1, np.int64)
    idx, vals = [], []
    for j in range(outer):
        words = tk.next_line(f"{what} {'column' if kind == 'csc' else 'row'} {j}").split()
        try:  # "col j : locations a to b"
            a, b = int(words[4]), int(words[6])
        except (ValueError, IndexError):
            raise _checks.FileError(f"{tk.path}: line {tk.line}: malformed CSparse column header of {what}") from None
        if a != ptr[j] or b + 1 < a or b + 1 > nnz:
            raise _checks.FileError(f"{tk.path}: line {tk.line}: {what}: locations {a} to {b} do not continue "
                                    f"from {ptr[j]} within the {nnz} entries")
        ptr[j + 1] = b + 1
        for _ in range(a, b + 1):
            words = tk.next_line(f"{what} entries").split()
            try:
                idx.append(int(words[0]))
                vals.append(float(words[2]))
            except (ValueError, IndexError):
                raise _checks.FileError(f"{tk.path}: line {tk.line}: malformed CSparse entry of {what}") from None
    if ptr[-1] != nnz:
        raise _checks.FileError(f"{tk.path}: line {tk.line}: {what}: {ptr[-1]} entries listed, header says {nnz}")
    mat = _checks.compressed_matrix(tk.path, where, kind, m, n, ptr, np.array(idx, dtype=np.int64),
                                    np.array(vals, dtype=float), check=False)
    return mat, kind


def read_dat(path: str | os.PathLike, check: bool = True) -> ContactFile:
    """Read a Siconos ``.dat`` friction-contact problem (local or global form, dimension 2 or 3);
    see the module doc.

    The form is the one the file's content implies: the local form's W is followed by exactly
    d k + k numbers (q and mu); anything else after the first matrix must be the global form's H.
    ``check``: also the value checks of :mod:`lcp.io.fclib_checks` (finite data, mu >= 0, W symmetric
    and positive semi-definite); the structure (sizes, indices, numbers) is always checked.
    """
    path = os.fspath(path)
    name = os.path.basename(path)
    try:
        with open(path, encoding="utf-8") as fh:
            text = fh.read()
    except UnicodeDecodeError:
        raise _checks.FileError(f"{path}: not a text file (not UTF-8)") from None
    except OSError as exc:
        raise _checks.FileError(f"{path}: cannot read: {exc}") from None
    if not text.strip():
        raise _checks.FileError(f"{path}: empty file")
    tk = _Tokens(path, text)
    dim = tk.int("dimension", low=1)
    if dim not in DIMENSIONS:
        raise _checks.FileError(f"{path}: line 1: only planar and spatial problems (dimension 2 or 3) are "
                                f"supported, got {dim}")
    k = tk.int("number of contacts")
    n = dim * k
    tk.need(n + k, f"{k} contacts (q and mu)")
    A, storage = _read_matrix(tk, "first matrix", check)
    # files of Siconos's collection end with one more integer line after mu, which its readers ignore
    tail = 1 if _is_int(tk.last_word()) else 0
    if A.shape == (n, n) and tk.remaining() in (n + k, n + k + tail):
        local = True
    elif _global_follows(tk):
        local = False
    elif A.shape != (n, n):
        raise _checks.FileError(f"{path}: line {tk.line}: sizes disagree: W is {A.shape[0]}x{A.shape[1]} for {k} "
                                f"contacts of dimension {dim} (expected {n}x{n})")
    else:
        left = tk.remaining()
        if left < n + k:
            raise _checks.FileError(f"{path}: file ends early (line {tk.line}): q and mu need {n + k} numbers, "
                                    f"{left} left: truncated")
        raise _checks.FileError(f"{path}: line {tk.line}: q and mu need {n + k} numbers, the file holds {left} "
                                "more: unexpected words after mu (and no matrix H follows)")
    if local:
        q = tk.floats(n, "q")
        mu = tk.floats(k, "mu")
        _end(tk, tail)
        if check:
            _checks.check_values(path, A, q, mu, f"W (line {tk.line})", "q", "mu")
        return ContactFile(A, q, mu, "local", name=name, storage=storage, dim=dim)
    M = A
    H, _ = _read_matrix(tk, "H", check)
    nv = M.shape[0]
    if M.shape != (nv, nv) or H.shape != (nv, n):
        raise _checks.FileError(f"{path}: line {tk.line}: global sizes disagree: M {M.shape}, H {H.shape} "
                                f"for {k} contacts of dimension {dim}")
    tk.need(nv + n + k, "q (global), b and mu")
    f = tk.floats(nv, "q (global)")
    w = tk.floats(n, "b")
    mu = tk.floats(k, "mu")
    _end(tk, tail)
    return _from_global(M, H, f, w, mu, name, storage, dim, path=path, check=check)


def _is_int(word) -> bool:
    try:
        int(word)
    except (TypeError, ValueError):
        return False
    return True


def _end(tk, tail):
    """Nothing may follow mu but Siconos's closing integer (``tail`` 1 where the file has one)."""
    if tk.remaining() > tail:
        raise _checks.FileError(f"{tk.path}: line {tk.line}: {tk.remaining()} unexpected words after mu")


def _global_follows(tk):
    """Whether another matrix follows the first one (the global form): peek at the next tokens."""
    save = (tk.line, tk.words, tk.pos)
    try:
        # a matrix header is an integer storage type 0-2 followed by two integer sizes
        if tk.word("next") not in ("0", "1", "2"):
            return False
        int(tk.word("next"))
        int(tk.word("next"))
        return True
    except ValueError:
        return False
    finally:
        tk.line, tk.words, tk.pos = save


def _from_global(M, H, f, w, mu, name, storage, dim=2, path=None, check=True,
                 labels=("M", "H", "q (global)", "b", "mu")):
    from scipy.sparse.linalg import splu

    path = path or name
    # non-finite data would reach W only as a NaN of the reduction: name its place in the file
    for what, x in zip(labels, (M, H, f, w)):
        data = x.tocoo() if sp.issparse(x) else np.asarray(x)
        vals = data.data if sp.issparse(x) else data
        if not np.all(np.isfinite(vals)):
            bad = np.flatnonzero(~np.isfinite(vals))[0]
            where = f"[{data.row[bad]}, {data.col[bad]}]" if sp.issparse(x) else f"[{bad}]"
            raise _checks.FileError(f"{path}: {what} has non-finite entries (first: {what}{where} = {vals[bad]})")
    M = sp.csc_matrix(M)
    try:
        lu = splu(M)
    except RuntimeError as exc:
        raise _checks.FileError(f"{path}: the global mass matrix M is singular: {exc}") from None
    n = dim * mu.size
    Hd = sp.csc_matrix(H)
    # M^-1 H column block by column block keeps the dense intermediate small
    X = lu.solve(Hd.toarray()) if n <= 4096 else None
    if X is None:
        cols = []
        for a in range(0, n, 1024):
            cols.append(sp.csc_matrix(lu.solve(Hd[:, a:a + 1024].toarray())))
        MinvH = sp.hstack(cols).tocsr()
    else:
        MinvH = sp.csr_matrix(X)
    W = (Hd.T @ MinvH).tocsr()
    q = Hd.T @ lu.solve(np.asarray(f, dtype=float)) + w
    if check:
        _checks.check_values(path, W, q, mu, f"{labels[0]}, {labels[1]}", f"{labels[2]}, {labels[3]}", labels[4],
                             reduced=True)
    return ContactFile(W, q, mu, "global", M=sp.csr_matrix(M), H=sp.csr_matrix(H), f=f, w=w, name=name,
                       storage=storage, dim=dim)


def write_dat(path: str | os.PathLike, cf: ContactFile, storage: str = "csparse", form: str = "local",
              mass_blocks: int | None = None) -> None:
    """Write a problem in Siconos's ``.dat`` layout (the layout its ``newFromFile`` readers take).

    ``storage``: ``"csparse"`` (triplets), ``"sparse-block"`` (d x d blocks for W, the storage
    Siconos's fc2d/fc3d solvers take sparse) or ``"dense"`` (column-major). ``form``: ``"local"``
    (W, q, mu; also for a problem read in the global form) or ``"global"`` (M, H, f, w, mu). In
    sparse-block storage of the global form M's blocks are ``mass_blocks`` x ``mass_blocks`` (e.g.
    6 for rigid bodies in space: Siconos's global NSGS rejected a diagonal M stored in 1 x 1
    blocks), by default its finest diagonal blocks; H's block rows are M's, its block columns d wide.
    """
    if storage not in ("csparse", "sparse-block", "dense"):
        raise ValueError(f"storage must be 'csparse', 'sparse-block' or 'dense', got {storage!r}")
    if form not in ("local", "global"):
        raise ValueError(f"form must be 'local' or 'global', got {form!r}")
    if form == "global" and cf.M is None:
        raise ValueError("form='global' needs M, H, f and w")
    k, d = cf.n_contacts, cf.dim
    lines = [f"{d}\n{k}\n"]
    if form == "local":
        _write_dat_matrix(lines, cf.W, storage, d, d)
        vectors = (cf.q, cf.mu)
    else:
        nv = cf.M.shape[0]
        if mass_blocks is not None and (int(mass_blocks) != mass_blocks or mass_blocks < 1 or nv % mass_blocks):
            raise ValueError(f"mass_blocks must be a positive divisor of M's size {nv}, got {mass_blocks!r}")
        rows = None
        if storage == "sparse-block":
            rows = _diagonal_blocks(cf.M) if mass_blocks is None else np.arange(mass_blocks, nv + 1, int(mass_blocks))
        _write_dat_matrix(lines, cf.M, storage, rows, rows)
        _write_dat_matrix(lines, cf.H, storage, rows, d)
        vectors = (np.asarray(cf.f, float), np.asarray(cf.w, float), cf.mu)
    # repr: the shortest text that reads back to the same double, and never a bare integer ("0.0",
    # "3.0", "1e+16"), so that no q is mistaken for the header of a global form's second matrix
    lines.extend(" ".join(repr(float(x)) for x in v) + "\n" for v in vectors)
    with open(path, "w") as fh:
        fh.writelines(lines)


def _diagonal_blocks(A) -> np.ndarray:
    """Ends of the finest contiguous diagonal blocks of a square A (no entry couples two blocks)."""
    A = sp.coo_matrix(A)
    n = A.shape[0]
    # a block ends after row i when no entry joins a row/column <= i to one > i
    reach = np.arange(n)
    np.maximum.at(reach, np.minimum(A.row, A.col), np.maximum(A.row, A.col))
    ends = np.flatnonzero(np.maximum.accumulate(reach) == np.arange(n)) + 1
    return ends


def _write_dat_matrix(lines, A, storage, rows, cols):
    """Append one matrix in Siconos's NumericsMatrix text layout. ``rows``, ``cols``: block size
    (int) or block ends (array) of the sparse-block storage."""
    n0, n1 = A.shape
    if storage == "dense":
        lines.append(f"0\n{n0}\n{n1}\n{n0}\t{n1}\n")
        Ad = A.toarray()
        for j in range(n1):  # one column per line
            lines.append(" ".join(f"{x:.17e}" for x in Ad[:, j]) + "\n")
    elif storage == "sparse-block":
        lines.append(_sbm_text(A, rows, cols))
    else:
        Ac = sp.coo_matrix(A)
        lines.append(f"2\n{n0}\n{n1}\n1\nCSparse Version 3.1.9 (written by lcp.io.fclib)\n"
                     f"triplet: {n0}-by-{n1}, nzmax: {Ac.nnz} nnz: {Ac.nnz}\n")
        lines.extend(f"    {i} {j} : {x:.17g}\n" for i, j, x in zip(Ac.row, Ac.col, Ac.data))


def _sbm_text(A, rows, cols) -> str:
    """Sparse-block storage of A (blocks stored column-major, block rows in order)."""
    n0, n1 = A.shape
    ends0 = np.arange(rows, n0 + 1, rows) if np.isscalar(rows) else np.asarray(rows)
    ends1 = np.arange(cols, n1 + 1, cols) if np.isscalar(cols) else np.asarray(cols)
    if np.isscalar(rows) and np.isscalar(cols):
        B = sp.bsr_matrix(A, blocksize=(rows, cols))
        B.sort_indices()
        indptr, indices = B.indptr, B.indices
        blocks = [B.data[b].ravel(order="F") for b in range(indices.size)]
    else:
        Ac = sp.coo_matrix(A)
        start0, start1 = np.concatenate([[0], ends0[:-1]]), np.concatenate([[0], ends1[:-1]])
        bi, bj = np.searchsorted(ends0, Ac.row, side="right"), np.searchsorted(ends1, Ac.col, side="right")
        pairs = np.unique(np.stack([bi, bj], axis=1), axis=0).reshape(-1, 2)  # sorted by (row, column)
        indptr = np.searchsorted(pairs[:, 0], np.arange(ends0.size + 1))
        indices = pairs[:, 1]
        Ad = sp.csr_matrix(A)
        blocks = [Ad[start0[i]:ends0[i], start1[j]:ends1[j]].toarray().ravel(order="F") for i, j in pairs]
    nb = indices.size
    if nb == 0:  # Siconos writes the block count alone
        return f"1\n{n0}\n{n1}\n0\n"
    out = [(f"1\n{n0}\n{n1}\n{nb}\n{ends0.size}\n{ends1.size}\n{' '.join(map(str, ends0))}\n"
            f"{' '.join(map(str, ends1))}\n{ends0.size + 1}\n{nb}\n"),
           " ".join(map(str, indptr)) + "\n", " ".join(map(str, indices)) + "\n"]
    out.extend(f"{b}\n" + " ".join(f"{x:.17e}" for x in v) + "\n" for b, v in enumerate(blocks))
    return "".join(out)


# --------------------------------------------------------------------------- FCLib (HDF5)
def _h5py():
    try:
        import h5py
    except ImportError:  # pragma: no cover - h5py is in the "fclib" extra
        raise ImportError("FCLib HDF5 files need h5py: pip install lcp-lem[fclib]") from None
    return h5py


def read_hdf5(path: str | os.PathLike, check: bool = True) -> ContactFile:
    """Read an FCLib HDF5 problem (``/fclib_local`` or ``/fclib_global``, ``spacedim`` 2 or 3).

    Every dataset is checked before it is read (numeric, integer for sizes and indices, its declared
    size against the file's, :func:`lcp.io.fclib_checks.h5_array`), the vectors' sizes against each
    other, then each matrix's declared size against the vectors' and its pointers and indices
    before the matrix is built. ``check``: also the value checks (finite data, mu >= 0, W symmetric
    and positive semi-definite; :mod:`lcp.io.fclib_checks`).
    """
    h5py = _h5py()

    path = os.fspath(path)
    name = os.path.basename(path)
    try:
        size = os.path.getsize(path)
    except OSError as exc:
        raise _checks.FileError(f"{path}: cannot read: {exc}") from None
    if size == 0:
        raise _checks.FileError(f"{path}: empty file")
    try:
        fh = h5py.File(path, "r")
    except (OSError, RuntimeError, ValueError, KeyError) as exc:
        raise _checks.FileError(f"{path}: not a readable HDF5 file: {exc}") from None
    with fh:
        try:
            return _read_h5_groups(fh, path, name, size, check)
        except _checks.FileError:
            raise
        except (OSError, RuntimeError, KeyError, TypeError, ValueError, IndexError) as exc:
            # HDF5 trouble below the datasets' level (a corrupt B-tree, a truncated file)
            raise _checks.FileError(f"{path}: cannot read the FCLib groups: {type(exc).__name__}: {exc}") from None


def _read_h5_groups(fh, path, name, size, check):
    form = "local" if "fclib_local" in fh else ("global" if "fclib_global" in fh else None)
    if form is None:
        raise _checks.FileError(f"{path}: neither /fclib_local nor /fclib_global found")
    g = _h5_group(fh, f"fclib_{form}", path)
    dim = _checks.h5_int(g, "spacedim", path, "dimension", size)
    if dim not in DIMENSIONS:
        raise _checks.FileError(f"{path}: /fclib_{form}/spacedim: only planar and spatial problems "
                                f"(spacedim 2 or 3) are supported, got {dim}")
    vec = _h5_group(g, "vectors", path)
    mu = _checks.h5_array(vec, "mu", path, "mu", False, size)
    if form == "local":
        if "R" in g or "V" in g:
            raise _checks.FileError(f"{path}: mixed problems (V, R) are not supported")
        q = _checks.h5_array(vec, "q", path, "q", False, size)
        n = dim * mu.size
        if q.size != n:
            raise _checks.FileError(f"{path}: sizes disagree: q {q.shape}, mu {mu.shape} (spacedim {dim}: q "
                                    f"needs {n} entries)")
        W = _checks.h5_matrix(_h5_group(g, "W", path), path, size, (n, n), check)
        if check:
            _checks.check_values(path, W, q, mu, "/fclib_local/W", "/fclib_local/vectors/q",
                                 "/fclib_local/vectors/mu")
        return ContactFile(W, q, mu, "local", name=name, storage="fclib", dim=dim)
    if "G" in g:
        raise _checks.FileError(f"{path}: global problems with bilateral constraints (G) are not supported")
    f = _checks.h5_array(vec, "f", path, "f", False, size)
    w = _checks.h5_array(vec, "w", path, "w", False, size)
    if w.size != dim * mu.size:
        raise _checks.FileError(f"{path}: global sizes disagree: f {f.shape}, w {w.shape}, mu {mu.shape} "
                                f"(spacedim {dim})")
    M = _checks.h5_matrix(_h5_group(g, "M", path), path, size, (f.size, f.size), check)
    H = _checks.h5_matrix(_h5_group(g, "H", path), path, size, (f.size, w.size), check)
    return _from_global(M, H, f, w, mu, name, "fclib", dim, path=path, check=check,
                        labels=tuple(f"/fclib_global/{x}" for x in ("M", "H", "vectors/f", "vectors/w", "vectors/mu")))


def _h5_group(g, key, path):
    try:
        sub = g[key]
    except KeyError:
        raise _checks.FileError(f"{path}: missing FCLib item {g.name.rstrip('/')}/{key}") from None
    if not hasattr(sub, "keys"):
        raise _checks.FileError(f"{path}: {g.name.rstrip('/')}/{key}: expected a group, found a dataset")
    return sub


def _h5_write_matrix(g, A):
    A = sp.csc_matrix(A)
    A.sort_indices()
    g["m"], g["n"] = np.array([A.shape[0]], np.int32), np.array([A.shape[1]], np.int32)
    g["nz"], g["nzmax"] = np.array([-1], np.int32), np.array([A.nnz], np.int32)
    g["p"], g["i"], g["x"] = A.indptr.astype(np.int32), A.indices.astype(np.int32), A.data.astype(float)


def write_hdf5(path: str | os.PathLike, cf: ContactFile, form: str | None = None) -> None:
    """Write a problem in FCLib's HDF5 layout (CSC matrices); ``form`` defaults to the file's own."""
    h5py = _h5py()

    form = form or cf.form
    if form not in ("local", "global"):
        raise ValueError(f"form must be 'local' or 'global', got {form!r}")
    if form == "global" and cf.M is None:
        raise ValueError("form='global' needs M, H, f and w")
    with h5py.File(path, "w") as fh:
        g = fh.create_group(f"fclib_{form}")
        g["spacedim"] = np.array([cf.dim], np.int32)
        v = g.create_group("vectors")
        if form == "local":
            _h5_write_matrix(g.create_group("W"), cf.W)
            v["q"] = cf.q
        else:
            _h5_write_matrix(g.create_group("M"), cf.M)
            _h5_write_matrix(g.create_group("H"), cf.H)
            v["f"], v["w"] = np.asarray(cf.f, float), np.asarray(cf.w, float)
        v["mu"] = cf.mu
        info = g.create_group("info")
        # fixed-length ASCII strings, as FCLib's C library writes and reads them
        info["title"] = np.bytes_(cf.name or "problem")
        kind = "planar" if cf.dim == 2 else "spatial"
        info["description"] = np.bytes_(f"{cf.n_contacts} {kind} contacts, written by lcp.io.fclib")


def read_problem(path: str | os.PathLike, check: bool = True) -> ContactFile:
    """Read a problem file by its content: HDF5 (FCLib) or Siconos ``.dat`` text.

    ``check`` (default): the value checks too (:mod:`lcp.io.fclib_checks`: finite data, finite
    mu >= 0, W symmetric and positive semi-definite to stated tolerances), each failure a
    ``ValueError`` naming the file and the dataset; ``check=False`` keeps the structural checks only
    (what :meth:`ContactFile.check` then reports is the caller's).
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise _checks.FileError(f"{path}: no such file")
    with open(path, "rb") as fh:
        magic = fh.read(8)
    if magic == b"\x89HDF\r\n\x1a\n":
        return read_hdf5(path, check=check)
    return read_dat(path, check=check)
