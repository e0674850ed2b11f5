"""Friction-contact problem files: FCLib's HDF5 format and Siconos's ``.dat`` text format.

Both store a planar (``spacedim`` 2) or spatial (``spacedim`` 3) problem contact by contact,
``r = (r_N,1, r_T,1, ...)`` (one tangent entry per planar contact, two per spatial one), in one of
two forms:

- local: u = W r + q, Coulomb's law between r and u (W of size d k, d the dimension);
- global: M v = H r + f, u = H' v + w (FCLib's names; Siconos writes q for f and b for w), reduced
  here to the local form W = H' M^-1 H, q = H' M^-1 f + w with a sparse factorization of M.

:func:`read_problem` returns a :class:`ContactFile` whose ``dim`` is the file's dimension and whose
:meth:`ContactFile.problem` is a :class:`~lcp.contact_problem.ContactProblem` for a planar file or a
:class:`~lcp.cone_problem.ConeContactProblem` (the Coulomb disk) for a spatial one, impulses
ordered normals first, the package's order (:func:`lcp.friction_contact.interleave` and
:attr:`ConeContactProblem.perm <lcp.cone_problem.ConeContactProblem>` map between the two).
Matrices stay sparse.

Siconos ``.dat`` layout (whitespace-separated): dimension, number of contacts, then the matrix
(storage 0 dense column-major, 1 sparse-block, 2 CSparse triplet/CSC/CSR), then q and mu for the
local form (:func:`write_dat` writes d x d blocks for sparse-block storage); for the global form
M, H, then q, b and mu. FCLib HDF5 layout: groups ``/fclib_local`` (``spacedim``, ``W``,
``vectors/q``, ``vectors/mu``, optional ``info``) or ``/fclib_global`` (``spacedim``, ``M``, ``H``,
``vectors/f``, ``vectors/w``, ``vectors/mu``); each matrix has ``m``, ``n``, ``nz`` (triplet
count, -1 CSC, -2 CSR), ``nzmax``, ``p``, ``i``, ``x`` as CSparse stores them.

A malformed or truncated file raises ``ValueError`` naming the file and where reading stopped
(line of a ``.dat`` file, dataset of an HDF5 file); :meth:`ContactFile.check` reports sizes that
disagree, negative or non-finite friction coefficients, non-finite entries (with the first one's
place) and an unsymmetric or indefinite W before any solve.

Examples
--------
>>> import numpy as np, tempfile, os
>>> from lcp.fclib import ContactFile, read_problem, write_hdf5
>>> W = np.array([[2.0, 0.5], [0.5, 1.0]])
>>> cf = ContactFile(W=W, q=np.array([-1.0, 0.3]), mu=np.array([0.4]))
>>> path = os.path.join(tempfile.mkdtemp(), "one.hdf5")
>>> write_hdf5(path, cf)
>>> back = read_problem(path)
>>> np.allclose(back.W.toarray(), W), back.form, back.n_contacts, back.dim
(True, 'local', 1, 2)

A spatial contact (dimension 3): a unit block pressed at 1 m/s and pushed sideways at 2 m/s,
friction 0.5, read back as the Coulomb-disk problem and solved.

>>> from lcp.cone_solvers import make_cone_solver
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

from .cone_problem import ConeContactProblem
from .contact_problem import ContactProblem
from .friction_contact import blocked, check_problem

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
    M, H, f, w : global data when ``form == "global"`` (else None)
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
        >>> from lcp.fclib import ContactFile
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
        return _from_global(M, H, f, w, mu, name or "problem", "", dim)

    @property
    def n_contacts(self) -> int:
        return self.mu.size

    @property
    def dims(self) -> np.ndarray:
        """Tangent dimension of each contact (``dim - 1``), the layout of a ConeContactProblem."""
        return np.full(self.n_contacts, self.dim - 1, dtype=np.int64)

    def check(self):
        """Sizes, signs, finiteness, symmetry and PSD-ness (:func:`lcp.friction_contact.check_problem`).

        A non-finite entry of W or q is reported with the place of the first one (file order).
        """
        name = self.name or "problem"
        rep = check_problem(self.W, self.q, self.mu, name=name, dims=None if self.dim == 2 else self.dims)
        for i, msg in enumerate(rep.errors):
            if msg == f"{name}: W has non-finite entries":
                Wc = sp.coo_matrix(self.W)
                bad = np.flatnonzero(~np.isfinite(Wc.data))[0]
                rep.errors[i] = f"{msg} (first: W[{Wc.row[bad]}, {Wc.col[bad]}] = {Wc.data[bad]})"
            elif msg == f"{name}: q has non-finite entries":
                bad = np.flatnonzero(~np.isfinite(self.q))[0]
                rep.errors[i] = f"{msg} (first: q[{bad}] = {self.q[bad]})"
            elif msg.startswith(f"{name}: friction coefficients must be"):
                bad = np.flatnonzero(~(self.mu >= 0))[0]  # NaN included
                rep.errors[i] = f"{msg} (first: mu[{bad}] = {self.mu[bad]}, contact {bad})"
        return rep

    def problem(self, check: bool = True) -> ContactProblem | ConeContactProblem:
        """The problem in the package's order (normals first); raises ValueError on errors.

        A planar file gives a :class:`ContactProblem`, a spatial one a
        :class:`~lcp.cone_problem.ConeContactProblem` (every contact with a 2-D tangent).
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
    """Whitespace tokens of a text file, with the line of each, for error messages."""

    def __init__(self, path, text):
        self.path = path
        self.lines = text.splitlines()
        self.line, self.words, self.pos = 0, [], 0

    def _fill(self):
        while self.pos >= len(self.words):
            if self.line >= len(self.lines):
                raise ValueError(f"{self.path}: file ends early (line {self.line}): truncated")
            self.words = self.lines[self.line].split()
            self.line += 1
            self.pos = 0

    def word(self, what):
        try:
            self._fill()
        except ValueError as exc:
            raise ValueError(f"{exc} while reading {what}") from None
        w = self.words[self.pos]
        self.pos += 1
        return w

    def int(self, what, low=0):
        w = self.word(what)
        try:
            v = int(w)
        except ValueError:
            raise ValueError(f"{self.path}: line {self.line}: expected an integer for {what}, got {w!r}") from None
        if v < low:
            raise ValueError(f"{self.path}: line {self.line}: {what} must be >= {low}, got {v}")
        return v

    def float(self, what):
        w = self.word(what)
        try:
            return float(w)
        except ValueError:
            raise ValueError(f"{self.path}: line {self.line}: expected a number for {what}, got {w!r}") from None

    def floats(self, n, what):
        out = np.empty(n)
        for i in range(n):
            out[i] = self.float(f"{what}[{i}]")
        return out

    def rest_of_line(self):
        """The unread words of the current line, then move to the next line."""
        words = self.words[self.pos:]
        self.words, self.pos = [], 0
        return words

    def next_line(self, what):
        if self.line >= len(self.lines):
            raise ValueError(f"{self.path}: file ends early (line {self.line}) while reading {what}: truncated")
        s = self.lines[self.line]
        self.line += 1
        self.words, self.pos = [], 0
        return s


def _read_matrix(tk: _Tokens, what: str):
    storage = tk.int(f"{what} storage type")
    n0 = tk.int(f"{what} rows")
    n1 = tk.int(f"{what} columns")
    if storage == 0:
        r0, r1 = tk.int(f"{what} rows (dense)"), tk.int(f"{what} columns (dense)")
        if (r0, r1) != (n0, n1):
            raise ValueError(f"{tk.path}: line {tk.line}: {what} sizes disagree ({n0}x{n1} then {r0}x{r1})")
        vals = tk.floats(n0 * n1, f"{what} entries")
        return sp.csr_matrix(vals.reshape(n1, n0).T), "dense"  # column-major
    if storage == 1:
        return _read_sbm(tk, what, n0, n1), "sparse-block"
    if storage == 2:
        return _read_csparse(tk, what, n0, n1)
    raise ValueError(f"{tk.path}: line {tk.line}: unknown storage type {storage} for {what}")


def _read_sbm(tk, what, n0, n1):
    nb = tk.int(f"{what} number of blocks")
    if nb == 0:
        return sp.csr_matrix((n0, n1))
    b0, b1 = tk.int(f"{what} block rows"), tk.int(f"{what} block columns")
    s0 = np.array([tk.int(f"{what} row block sizes") for _ in range(b0)])
    s1 = np.array([tk.int(f"{what} column block sizes") for _ in range(b1)])
    if (b0 and s0[-1] != n0) or (b1 and s1[-1] != n1) or np.any(np.diff(s0) <= 0) or np.any(np.diff(s1) <= 0):
        raise ValueError(f"{tk.path}: line {tk.line}: {what} block sizes disagree with its {n0}x{n1} size")
    f1, f2 = tk.int(f"{what} filled1"), tk.int(f"{what} filled2")
    if f1 != b0 + 1 or f2 != nb:
        raise ValueError(f"{tk.path}: line {tk.line}: {what} block index sizes disagree ({f1}, {f2})")
    rowptr = np.array([tk.int(f"{what} block row pointers") for _ in range(f1)])
    colidx = np.array([tk.int(f"{what} block column indices") for _ in range(f2)])
    if rowptr[-1] != nb or np.any(np.diff(rowptr) < 0) or np.any(colidx >= b1):
        raise ValueError(f"{tk.path}: line {tk.line}: {what} block indices out of range")
    start0 = np.concatenate([[0], s0[:-1]])
    start1 = np.concatenate([[0], s1[:-1]])
    rows, cols, vals = [], [], []
    for bi in range(b0):
        for blk in range(rowptr[bi], rowptr[bi + 1]):
            bj = colidx[blk]
            num = tk.int(f"{what} block number")
            if num != blk:
                raise ValueError(f"{tk.path}: line {tk.line}: {what} block {blk} is numbered {num}")
            nr, nc = s0[bi] - start0[bi], s1[bj] - start1[bj]
            v = tk.floats(nr * nc, f"{what} block {blk}")
            rows.append(start0[bi] + np.tile(np.arange(nr), nc))  # column-major blocks
            cols.append(start1[bj] + np.repeat(np.arange(nc), nr))
            vals.append(v)
    if not rows:
        return sp.csr_matrix((n0, n1))
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n0, n1))


def _read_csparse(tk, what, n0, n1):
    tk.int(f"{what} sparse origin")
    tk.rest_of_line()
    head = tk.next_line(f"{what} CSparse banner")
    if "CSparse" not in head:
        raise ValueError(f"{tk.path}: line {tk.line}: expected the CSparse banner for {what}, got {head[:40]!r}")
    desc = tk.next_line(f"{what} CSparse header").split()
    kind = "triplet" if desc[:1] == ["triplet:"] else ("csr" if desc[:1] == ["csr:"] else "csc")
    size = desc[1] if kind != "csc" else desc[0]
    try:
        m, n = (int(x) for x in size.rstrip(",").split("-by-"))
        nnz = int(desc[desc.index("nnz:") + 1].rstrip(","))
    except (ValueError, IndexError):
        raise ValueError(f"{tk.path}: line {tk.line}: cannot read the CSparse header of {what}: "
                         f"{' '.join(desc)!r}") from None
    if (m, n) != (n0, n1):
        raise ValueError(f"{tk.path}: line {tk.line}: {what} sizes disagree ({n0}x{n1} then {m}x{n})")
    if kind == "triplet":
        rows, cols, vals = np.empty(nnz, int), np.empty(nnz, int), np.empty(nnz)
        for p in range(nnz):
            rows[p] = tk.int(f"{what} entry {p} row")
            cols[p] = tk.int(f"{what} entry {p} column")
            if tk.word(f"{what} entry {p}") != ":":
                raise ValueError(f"{tk.path}: line {tk.line}: malformed triplet entry {p} of {what}")
            vals[p] = tk.float(f"{what} entry {p} value")
        if nnz and (rows.max() >= m or cols.max() >= n):
            raise ValueError(f"{tk.path}: line {tk.line}: {what} entry index out of range")
        return sp.csr_matrix((vals, (rows, cols)), shape=(m, n)), "csparse-triplet"
    outer = n if kind == "csc" else m
    ptr = np.zeros(outer + 1, int)
    idx, vals = [], []
    for j in range(outer):
        words = tk.next_line(f"{what} {'column' if kind == 'csc' else 'row'} {j}").split()
        try:  # "col j : locations a to b"
            a, b = int(words[4]), int(words[6])
        except (ValueError, IndexError):
            raise ValueError(f"{tk.path}: line {tk.line}: malformed CSparse column header of {what}") from None
        ptr[j], ptr[j + 1] = a, b + 1
        for _ in range(a, b + 1):
            words = tk.next_line(f"{what} entries").split()
            try:
                idx.append(int(words[0]))
                vals.append(float(words[2]))
            except (ValueError, IndexError):
                raise ValueError(f"{tk.path}: line {tk.line}: malformed CSparse entry of {what}") from None
    cls = sp.csc_matrix if kind == "csc" else sp.csr_matrix
    try:
        mat = cls((np.array(vals), np.array(idx, dtype=int), ptr), shape=(m, n))
        mat.check_format(full_check=True)
    except ValueError as exc:
        raise ValueError(f"{tk.path}: {what}: inconsistent CSparse data: {exc}") from None
    return sp.csr_matrix(mat), kind


def read_dat(path: str | os.PathLike) -> ContactFile:
    """Read a Siconos ``.dat`` friction-contact problem (local or global form, dimension 2 or 3);
    see the module doc.

    The form is the one the file's content implies: a second matrix after the first one makes it
    global; otherwise the first matrix must be square of size d k (local).
    """
    path = os.fspath(path)
    name = os.path.basename(path)
    try:
        with open(path) as fh:
            text = fh.read()
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a text file") from None
    tk = _Tokens(path, text)
    dim = tk.int("dimension", low=1)
    if dim not in DIMENSIONS:
        raise ValueError(f"{path}: line 1: only planar and spatial problems (dimension 2 or 3) are supported, "
                         f"got {dim}")
    k = tk.int("number of contacts")
    n = dim * k
    A, storage = _read_matrix(tk, "first matrix")
    if not _global_follows(tk, A):
        if A.shape != (n, n):
            raise ValueError(f"{path}: line {tk.line}: sizes disagree: W is {A.shape[0]}x{A.shape[1]} for {k} "
                             f"contacts of dimension {dim} (expected {n}x{n})")
        q = tk.floats(n, "q")
        mu = tk.floats(k, "mu")
        return ContactFile(A, q, mu, "local", name=name, storage=storage, dim=dim)
    M = A
    H, _ = _read_matrix(tk, "H")
    nv = M.shape[0]
    if M.shape != (nv, nv) or H.shape != (nv, n):
        raise ValueError(f"{path}: line {tk.line}: global sizes disagree: M {M.shape}, H {H.shape} "
                         f"for {k} contacts of dimension {dim}")
    f = tk.floats(nv, "q (global)")
    w = tk.floats(n, "b")
    mu = tk.floats(k, "mu")
    return _from_global(M, H, f, w, mu, name, storage, dim)


def _global_follows(tk, A):
    """Whether another matrix follows the first one (the global form): peek at the next tokens."""
    save = (tk.line, list(tk.words), tk.pos)
    try:
        first = tk.word("next")
        # a matrix header is an integer storage type 0-2 followed by two integer sizes;
        # q starts with a float written with a decimal point or exponent
        if first not in ("0", "1", "2"):
            return False
        int(tk.word("next"))
        int(tk.word("next"))
        return True
    except ValueError:
        return False
    finally:
        tk.line, tk.words, tk.pos = save


def _from_global(M, H, f, w, mu, name, storage, dim=2):
    from scipy.sparse.linalg import splu

    n = dim * mu.size
    # non-finite data would reach W only as a NaN of the reduction: name its place in the file
    for what, x in (("M", M), ("H", H), ("q (global)", f), ("b", w)):
        data = x.tocoo() if sp.issparse(x) else np.asarray(x)
        vals = data.data if sp.issparse(x) else data
        if not np.all(np.isfinite(vals)):
            bad = np.flatnonzero(~np.isfinite(vals))[0]
            where = f"[{data.row[bad]}, {data.col[bad]}]" if sp.issparse(x) else f"[{bad}]"
            raise ValueError(f"{name}: {what} has non-finite entries (first: {what}{where} = {vals[bad]})")
    M = sp.csc_matrix(M)
    try:
        lu = splu(M)
    except RuntimeError as exc:
        raise ValueError(f"{name}: the global mass matrix M is singular: {exc}") from None
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
    lines.extend(" ".join(f"{x:.17g}" for x in v) + "\n" for v in vectors)
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
        lines.append(f"2\n{n0}\n{n1}\n1\nCSparse Version 3.1.9 (written by lcp.fclib)\n"
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
def _h5_read(grp, key, path, what, dtype=float):
    """One dataset of an FCLib group; a missing or unreadable one names the file and the dataset."""
    where = f"{grp.name.rstrip('/')}/{key}"
    try:
        return np.asarray(grp[key][()], dtype=dtype).ravel()
    except KeyError:
        raise ValueError(f"{path}: {what}: missing dataset {where}") from None
    except (OSError, TypeError, ValueError) as exc:  # a truncated or corrupt file fails here
        raise ValueError(f"{path}: {what}: cannot read dataset {where}: {exc}") from None


def _h5_int(grp, key, path, what):
    x = _h5_read(grp, key, path, what, dtype=np.int64)
    if x.size != 1:
        raise ValueError(f"{path}: {what}: {grp.name.rstrip('/')}/{key} must hold one integer, got {x.size}")
    return int(x[0])


def _h5_matrix(grp, what, path):
    m, n, nz = (_h5_int(grp, key, path, what) for key in ("m", "n", "nz"))
    p, i = _h5_read(grp, "p", path, what, np.int64), _h5_read(grp, "i", path, what, np.int64)
    x = _h5_read(grp, "x", path, what)
    try:
        if nz >= 0:  # triplet, CSparse convention: i rows, p columns
            mat = sp.coo_matrix((x[:nz], (i[:nz], p[:nz])), shape=(m, n))
        elif nz == -1:
            mat = sp.csc_matrix((x[:p[-1]], i[:p[-1]], p), shape=(m, n))
        elif nz == -2:
            mat = sp.csr_matrix((x[:p[-1]], i[:p[-1]], p), shape=(m, n))
        else:
            raise ValueError(f"unknown storage nz = {nz}")
        mat = sp.csr_matrix(mat)
        mat.check_format(full_check=True)
    except (ValueError, IndexError) as exc:
        raise ValueError(f"{path}: {what}: inconsistent sparse data: {exc}") from None
    return mat


def _h5py():
    try:
        import h5py
    except ImportError:  # pragma: no cover - h5py is in the "fclib" extra
        raise ImportError("FCLib HDF5 files need h5py: pip install lcp-lem[fclib]") from None
    return h5py


def read_hdf5(path: str | os.PathLike) -> ContactFile:
    """Read an FCLib HDF5 problem (``/fclib_local`` or ``/fclib_global``, ``spacedim`` 2 or 3)."""
    h5py = _h5py()

    path = os.fspath(path)
    name = os.path.basename(path)
    try:
        fh = h5py.File(path, "r")
    except OSError as exc:
        raise ValueError(f"{path}: not a readable HDF5 file: {exc}") from None
    with fh:
        try:
            form = "local" if "fclib_local" in fh else ("global" if "fclib_global" in fh else None)
        except (OSError, RuntimeError) as exc:
            raise ValueError(f"{path}: cannot read the root group: {exc}") from None
        if form is None:
            raise ValueError(f"{path}: neither /fclib_local nor /fclib_global found")
        try:
            g = fh[f"fclib_{form}"]
            dim = _h5_int(g, "spacedim", path, "dimension")
            if dim not in DIMENSIONS:
                raise ValueError(f"{path}: /fclib_{form}/spacedim: only planar and spatial problems "
                                 f"(spacedim 2 or 3) are supported, got {dim}")
            if form == "local":
                if "R" in g or "V" in g:
                    raise ValueError(f"{path}: mixed problems (V, R) are not supported")
                W = _h5_matrix(_h5_group(g, "W", path), "/fclib_local/W", path)
                q = _h5_read(g, "vectors/q", path, "q")
                mu = _h5_read(g, "vectors/mu", path, "mu")
                if q.size != W.shape[0] or W.shape[0] != W.shape[1] or dim * mu.size != q.size:
                    raise ValueError(f"{path}: sizes disagree: W {W.shape}, q {q.shape}, mu {mu.shape} "
                                     f"(spacedim {dim})")
                return ContactFile(W, q, mu, "local", name=name, storage="fclib", dim=dim)
            if "G" in g:
                raise ValueError(f"{path}: global problems with bilateral constraints (G) are not supported")
            M = _h5_matrix(_h5_group(g, "M", path), "/fclib_global/M", path)
            H = _h5_matrix(_h5_group(g, "H", path), "/fclib_global/H", path)
            f, w = _h5_read(g, "vectors/f", path, "f"), _h5_read(g, "vectors/w", path, "w")
            mu = _h5_read(g, "vectors/mu", path, "mu")
            if M.shape != (f.size, f.size) or H.shape != (f.size, w.size) or w.size != dim * mu.size:
                raise ValueError(f"{path}: global sizes disagree: M {M.shape}, H {H.shape}, f {f.shape}, "
                                 f"w {w.shape}, mu {mu.shape} (spacedim {dim})")
            return _from_global(M, H, f, w, mu, name, "fclib", dim)
        except (OSError, RuntimeError) as exc:  # HDF5 trouble below the datasets' level
            raise ValueError(f"{path}: /fclib_{form}: cannot read: {exc}") from None


def _h5_group(g, key, path):
    try:
        return g[key]
    except KeyError:
        raise ValueError(f"{path}: missing FCLib item {g.name}/{key}") from None


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
        info["description"] = np.bytes_(f"{cf.n_contacts} {kind} contacts, written by lcp.fclib")


def read_problem(path: str | os.PathLike) -> ContactFile:
    """Read a problem file by its content: HDF5 (FCLib) or Siconos ``.dat`` text."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise ValueError(f"{path}: no such file")
    with open(path, "rb") as fh:
        magic = fh.read(8)
    if magic == b"\x89HDF\r\n\x1a\n":
        return read_hdf5(path)
    return read_dat(path)
