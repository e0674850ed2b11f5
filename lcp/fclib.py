"""Friction-contact problem files: FCLib's HDF5 format and Siconos's ``.dat`` text format.

Both store a planar (``spacedim`` 2) problem contact by contact, ``r = (r_N,1, r_T,1, ...)``, in
one of two forms:

- local: u = W r + q, Coulomb's law between r and u (W of size 2k);
- global: M v = H r + f, u = H' v + w (FCLib's names; Siconos writes q for f and b for w), reduced
  here to the local form W = H' M^-1 H, q = H' M^-1 f + w with a sparse factorization of M.

:func:`read_problem` returns a :class:`ContactFile` whose :meth:`ContactFile.problem` is a
:class:`~lcp.contact_problem.ContactProblem` (impulses ordered normals first, the package's
order; :func:`lcp.friction_contact.interleave` maps between the two). Matrices stay sparse.

Siconos ``.dat`` layout (whitespace-separated): dimension, number of contacts, then the matrix
(storage 0 dense column-major, 1 sparse-block, 2 CSparse triplet/CSC/CSR), then q and mu for the
local form; for the global form M, H, then q, b and mu. FCLib HDF5 layout: groups ``/fclib_local``
(``spacedim``, ``W``, ``vectors/q``, ``vectors/mu``, optional ``info``) or ``/fclib_global``
(``M``, ``H``, ``vectors/f``, ``vectors/w``, ``vectors/mu``); each matrix has ``m``, ``n``,
``nz`` (triplet count, -1 CSC, -2 CSR), ``nzmax``, ``p``, ``i``, ``x`` as CSparse stores them.

A malformed or truncated file raises ``ValueError`` naming the file and where reading stopped.

Examples
--------
>>> import numpy as np, tempfile, os
>>> from lcp.fclib import ContactFile, read_problem, write_hdf5
>>> W = np.array([[2.0, 0.5], [0.5, 1.0]])
>>> cf = ContactFile(W=W, q=np.array([-1.0, 0.3]), mu=np.array([0.4]))
>>> path = os.path.join(tempfile.mkdtemp(), "one.hdf5")
>>> write_hdf5(path, cf)
>>> back = read_problem(path)
>>> np.allclose(back.W.toarray(), W), back.form, back.n_contacts
(True, 'local', 1)
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from .contact_problem import ContactProblem
from .friction_contact import blocked, check_problem

__all__ = ["ContactFile", "read_dat", "read_hdf5", "read_problem", "write_dat", "write_hdf5"]


@dataclass
class ContactFile:
    """A planar friction-contact problem as stored in a file (contact-by-contact order).

    Attributes
    ----------
    W : scipy.sparse matrix, shape (2k, 2k)
        Local Delassus operator (the reduced one for a global problem).
    q : ndarray, shape (2k,)
    mu : ndarray, shape (k,)
    form : {"local", "global"}
    M, H, f, w : global data when ``form == "global"`` (else None)
    name : str
    storage : str
        How the file stored its matrix ("dense", "sparse-block", "csparse-triplet", "csc", ...).
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

    def __post_init__(self):
        self.W = sp.csr_matrix(self.W, dtype=float)
        self.q = np.asarray(self.q, dtype=float)
        self.mu = np.atleast_1d(np.asarray(self.mu, dtype=float))

    @property
    def n_contacts(self) -> int:
        return self.mu.size

    def check(self):
        """Sizes, signs, finiteness, symmetry and PSD-ness (:func:`lcp.friction_contact.check_problem`)."""
        return check_problem(self.W, self.q, self.mu, name=self.name or "problem")

    def problem(self, check: bool = True) -> ContactProblem:
        """The problem as a :class:`ContactProblem` (normals first); raises ValueError on errors."""
        if check:
            rep = self.check()
            if rep.errors:
                raise ValueError("; ".join(rep.errors))
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
        raise ValueError(f"{tk.path}: line {tk.line}: cannot read the CSparse header of {what}: {' '.join(desc)!r}") from None
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


def read_dat(path) -> ContactFile:
    """Read a Siconos ``.dat`` friction-contact problem (local or global form); see the module doc.

    The form is the one the file's first matrix implies: square with 2k rows is local; otherwise
    (or when a second matrix follows) global.
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
    if dim != 2:
        raise ValueError(f"{path}: line 1: only planar problems (dimension 2) are supported, got {dim}")
    k = tk.int("number of contacts")
    A, storage = _read_matrix(tk, "first matrix")
    if A.shape == (2 * k, 2 * k) and not _global_follows(tk, A):
        q = tk.floats(2 * k, "q")
        mu = tk.floats(k, "mu")
        return ContactFile(A, q, mu, "local", name=name, storage=storage)
    M = A
    H, _ = _read_matrix(tk, "H")
    nv = M.shape[0]
    if M.shape != (nv, nv) or H.shape != (nv, 2 * k):
        raise ValueError(f"{path}: line {tk.line}: global sizes disagree: M {M.shape}, H {H.shape} "
                         f"for {k} contacts")
    f = tk.floats(nv, "q (global)")
    w = tk.floats(2 * k, "b")
    mu = tk.floats(k, "mu")
    return _from_global(M, H, f, w, mu, name, storage)


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


def _from_global(M, H, f, w, mu, name, storage):
    from scipy.sparse.linalg import splu

    k = mu.size
    M = sp.csc_matrix(M)
    try:
        lu = splu(M)
    except RuntimeError as exc:
        raise ValueError(f"{name}: the global mass matrix M is singular: {exc}") from None
    Hd = sp.csc_matrix(H)
    # M^-1 H column block by column block keeps the dense intermediate small
    X = lu.solve(Hd.toarray()) if 2 * k <= 4096 else None
    if X is None:
        cols = []
        for a in range(0, 2 * k, 1024):
            cols.append(sp.csc_matrix(lu.solve(Hd[:, a:a + 1024].toarray())))
        MinvH = sp.hstack(cols).tocsr()
    else:
        MinvH = sp.csr_matrix(X)
    W = (Hd.T @ MinvH).tocsr()
    q = Hd.T @ lu.solve(np.asarray(f, dtype=float)) + w
    return ContactFile(W, q, mu, "global", M=sp.csr_matrix(M), H=sp.csr_matrix(H), f=f, w=w, name=name,
                       storage=storage)


def write_dat(path, cf: ContactFile, storage: str = "csparse") -> None:
    """Write the local form of a problem in Siconos's ``.dat`` layout.

    ``storage``: ``"csparse"`` (triplets), ``"sparse-block"`` (2 x 2 blocks, the storage Siconos's
    fc2d solvers take sparse) or ``"dense"`` (column-major).
    """
    if storage not in ("csparse", "sparse-block", "dense"):
        raise ValueError(f"storage must be 'csparse', 'sparse-block' or 'dense', got {storage!r}")
    k = cf.n_contacts
    n = 2 * k
    lines = [f"2\n{k}\n"]
    if storage == "dense":
        lines.append(f"0\n{n}\n{n}\n{n}\t{n}\n")
        Wd = cf.W.toarray()
        for j in range(n):  # one column per line
            lines.append(" ".join(f"{x:.17e}" for x in Wd[:, j]) + "\n")
    elif storage == "sparse-block":
        B = sp.bsr_matrix(cf.W, blocksize=(2, 2))
        B.sort_indices()
        nb = B.indices.size
        sizes = " ".join(str(2 * (i + 1)) for i in range(k))
        lines.append(f"1\n{n}\n{n}\n{nb}\n{k}\n{k}\n{sizes}\n{sizes}\n{k + 1}\n{nb}\n")
        lines.append(" ".join(map(str, B.indptr)) + "\n")
        lines.append(" ".join(map(str, B.indices)) + "\n")
        for b in range(nb):
            lines.append(f"{b}\n" + " ".join(f"{x:.17e}" for x in B.data[b].ravel(order="F")) + "\n")
    else:
        W = sp.coo_matrix(cf.W)
        lines.append(f"2\n{n}\n{n}\n1\nCSparse Version 3.1.9 (written by lcp.fclib)\n"
                     f"triplet: {n}-by-{n}, nzmax: {W.nnz} nnz: {W.nnz}\n")
        lines.extend(f"    {i} {j} : {x:.17g}\n" for i, j, x in zip(W.row, W.col, W.data))
    lines.append(" ".join(f"{x:.17g}" for x in cf.q) + "\n")
    lines.append(" ".join(f"{x:.17g}" for x in cf.mu) + "\n")
    with open(path, "w") as fh:
        fh.writelines(lines)


# --------------------------------------------------------------------------- FCLib (HDF5)
def _h5_matrix(grp, what, path):
    try:
        m, n, nz = int(grp["m"][0]), int(grp["n"][0]), int(grp["nz"][0])
        p, i, x = np.asarray(grp["p"][:]), np.asarray(grp["i"][:]), np.asarray(grp["x"][:], dtype=float)
    except KeyError as exc:
        raise ValueError(f"{path}: {what}: missing dataset {exc}") from None
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


def read_hdf5(path) -> ContactFile:
    """Read an FCLib HDF5 problem (``/fclib_local`` or ``/fclib_global``, planar)."""
    h5py = _h5py()

    path = os.fspath(path)
    name = os.path.basename(path)
    try:
        fh = h5py.File(path, "r")
    except OSError as exc:
        raise ValueError(f"{path}: not a readable HDF5 file: {exc}") from None
    with fh:
        try:
            if "fclib_local" in fh:
                g = fh["fclib_local"]
                dim = int(g["spacedim"][0])
                if dim != 2:
                    raise ValueError(f"{path}: only planar problems (spacedim 2) are supported, got {dim}")
                W = _h5_matrix(g["W"], "/fclib_local/W", path)
                q, mu = np.asarray(g["vectors/q"][:], float), np.asarray(g["vectors/mu"][:], float)
                if "R" in g or "V" in g:
                    raise ValueError(f"{path}: mixed problems (V, R) are not supported")
                if q.size != W.shape[0] or 2 * mu.size != q.size:
                    raise ValueError(f"{path}: sizes disagree: W {W.shape}, q {q.shape}, mu {mu.shape}")
                return ContactFile(W, q, mu, "local", name=name, storage="fclib")
            if "fclib_global" in fh:
                g = fh["fclib_global"]
                dim = int(g["spacedim"][0])
                if dim != 2:
                    raise ValueError(f"{path}: only planar problems (spacedim 2) are supported, got {dim}")
                if "G" in g:
                    raise ValueError(f"{path}: global problems with bilateral constraints (G) are not supported")
                M = _h5_matrix(g["M"], "/fclib_global/M", path)
                H = _h5_matrix(g["H"], "/fclib_global/H", path)
                f, w = np.asarray(g["vectors/f"][:], float), np.asarray(g["vectors/w"][:], float)
                mu = np.asarray(g["vectors/mu"][:], float)
                if M.shape != (f.size, f.size) or H.shape != (f.size, w.size) or w.size != 2 * mu.size:
                    raise ValueError(f"{path}: global sizes disagree: M {M.shape}, H {H.shape}, f {f.shape}, "
                                     f"w {w.shape}, mu {mu.shape}")
                return _from_global(M, H, f, w, mu, name, "fclib")
        except KeyError as exc:
            raise ValueError(f"{path}: missing FCLib item {exc}") from None
    raise ValueError(f"{path}: neither /fclib_local nor /fclib_global found")


def _h5_write_matrix(g, A):
    A = sp.csc_matrix(A)
    A.sort_indices()
    g["m"], g["n"] = np.array([A.shape[0]], np.int32), np.array([A.shape[1]], np.int32)
    g["nz"], g["nzmax"] = np.array([-1], np.int32), np.array([A.nnz], np.int32)
    g["p"], g["i"], g["x"] = A.indptr.astype(np.int32), A.indices.astype(np.int32), A.data.astype(float)


def write_hdf5(path, cf: ContactFile, form: str | None = None) -> None:
    """Write a problem in FCLib's HDF5 layout (CSC matrices); ``form`` defaults to the file's own."""
    h5py = _h5py()

    form = form or cf.form
    if form not in ("local", "global"):
        raise ValueError(f"form must be 'local' or 'global', got {form!r}")
    if form == "global" and cf.M is None:
        raise ValueError("form='global' needs M, H, f and w")
    with h5py.File(path, "w") as fh:
        g = fh.create_group(f"fclib_{form}")
        g["spacedim"] = np.array([2], np.int32)
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
        info["description"] = np.bytes_(f"{cf.n_contacts} planar contacts, written by lcp.fclib")


def read_problem(path) -> ContactFile:
    """Read a problem file by its content: HDF5 (FCLib) or Siconos ``.dat`` text."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise ValueError(f"{path}: no such file")
    with open(path, "rb") as fh:
        magic = fh.read(8)
    if magic == b"\x89HDF\r\n\x1a\n":
        return read_hdf5(path)
    return read_dat(path)
