r"""The truncated LEM moment system ``V' = A_N(t) V`` of a field about a centre.

For the displacement ``w = y - c`` the moments ``v_gamma = w**gamma`` obey

.. math::  v_gamma' = \sum_j \gamma_j \sum_\mu a_{j\mu}(t)\, v_{\gamma - e_j + \mu},

(the paper's (3.5)); :func:`moment_system` keeps the moments of degree ``<= N`` that the outputs
depend on. The *structure* of the system (which moments are kept, where each Taylor term lands in
the sparse matrix) depends only on which Taylor coefficients are non-zero, not on their values:
:class:`MomentStructure` holds it and is cached, so re-centred expansions of the same field at the
same degree (restarts, shooting trials) only refill the values.
"""
from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .fields import Expansion, as_field
from .jets import index_powers, monomial_space
from .validation import check_int, check_outputs, finite_vector, is_exact_number

__all__ = [
    "MomentStructure",
    "MomentSystem",
    "Placement",
    "build_system",
    "clear_structure_cache",
    "moment_structure",
    "moment_system",
]


@dataclass
class MomentSystem:
    r"""The truncated LEM system ``V' = (A + sum_i a_i(t) A_i) V`` for ``v_gamma = w**gamma``.

    Attributes
    ----------
    A : scipy.sparse.csr_matrix, shape (dimension, dimension)
        Constant part of the moment matrix (float; for exact fields see :attr:`triplets`).
    varying : list of (callable, csr_matrix)
        Time-varying parts ``a_i(t) A_i`` (empty for constant coefficients).
    exponents : ndarray of int, shape (dimension, n)
        The multi-index gamma of each kept moment (sorted by code).
    degree : int
        Truncation degree N (maximum total degree of the kept moments).
    outputs : ndarray of int
        Positions of the degree-1 moments ``w_i`` of the output components.
    constant_index : int or None
        Position of ``v_0 = 1`` when it is needed (``f(centre) != 0``).
    triplets : tuple (rows, cols, values) or None
        The entries with exact (``Fraction``) values when the field is rational.
    n_vars : int
        Number of moment variables (n, or n + 1 when t is a state).
    """

    A: sp.csr_matrix
    varying: list
    exponents: np.ndarray
    degree: int
    outputs: np.ndarray
    constant_index: int | None
    triplets: tuple | None
    n_vars: int
    codes: np.ndarray
    pw: np.ndarray

    @property
    def dimension(self) -> int:
        return int(self.exponents.shape[0])

    @property
    def nnz(self) -> int:
        return int(self.A.nnz + sum(B.nnz for _, B in self.varying))

    def index(self, gamma) -> int:
        """Position of moment gamma (ValueError if it is not kept)."""
        g = np.asarray(gamma, dtype=np.int64)
        if g.shape != (self.n_vars,) or g.sum() > self.degree or np.any(g < 0):
            raise ValueError(f"gamma {tuple(gamma)} is not a moment of this system")
        code = int(g @ self.pw)
        i = int(np.searchsorted(self.codes, code))
        if i >= self.codes.size or self.codes[i] != code:
            raise ValueError(f"moment {tuple(gamma)} is not kept (no output depends on it)")
        return i

    def initial_moments(self, w0) -> np.ndarray:
        """V(0) = w0**gamma for the kept moments."""
        w0 = np.asarray(w0, dtype=float)
        return np.prod(w0[None, :] ** self.exponents, axis=1)


def _targets(G: np.ndarray, comp: np.ndarray, exps: np.ndarray, N: int, chunk: int = 2_000_000):
    """All (row, column multi-index, term) with row gamma in G: gamma - e_j + mu, degree <= N."""
    rows_out, cols_out, terms_out = [], [], []
    n = G.shape[1]
    for j in np.unique(comp):
        tj = np.flatnonzero(comp == j)
        rj = np.flatnonzero(G[:, j] >= 1)
        if rj.size == 0 or tj.size == 0:
            continue
        base = G[rj].copy()
        base[:, j] -= 1
        bdeg = base.sum(axis=1)
        mus = exps[tj]
        mdeg = mus.sum(axis=1)
        step = max(1, chunk // max(1, tj.size * n))
        for s in range(0, rj.size, step):
            sl = slice(s, s + step)
            mask = (bdeg[sl, None] + mdeg[None, :]) <= N
            r_idx, t_idx = np.nonzero(mask)
            rows_out.append(rj[sl][r_idx])
            cols_out.append(base[sl][r_idx] + mus[t_idx])
            terms_out.append(tj[t_idx])
    if not rows_out:
        return (np.zeros(0, np.int64), np.zeros((0, n), np.int64), np.zeros(0, np.int64))
    return np.concatenate(rows_out), np.vstack(cols_out), np.concatenate(terms_out)


@dataclass
class Placement:
    """Where the Taylor terms of one coefficient group land in the CSR moment matrix.

    Term ``terms[i]`` with multiplicity ``mult[i]`` (the gamma_j of the row) contributes to the
    stored entry ``pos[i]`` of the matrix whose pattern is ``(indptr, indices)``; several terms
    may share an entry, so values are summed.
    """

    rows: np.ndarray
    cidx: np.ndarray
    terms: np.ndarray
    mult: np.ndarray
    indptr: np.ndarray
    indices: np.ndarray
    pos: np.ndarray

    def matrix(self, vals, dim: int) -> sp.csr_matrix:
        """The moment matrix for the coefficient values ``vals`` (one per Taylor term)."""
        v = self.mult * np.asarray(vals, dtype=float)[self.terms]
        data = np.bincount(self.pos, weights=v, minlength=self.indices.size)
        return sp.csr_matrix((data, self.indices, self.indptr), shape=(dim, dim))

    def exact_triplets(self, vals) -> tuple:
        """(rows, cols, values) with the values kept as exact numbers (Fractions)."""
        v = np.empty(self.terms.size, dtype=object)
        v[:] = [int(m) * vals[t] for m, t in zip(self.mult.tolist(), self.terms.tolist())]
        return self.rows, self.cidx, v


@dataclass
class MomentStructure:
    """The kept moments of a truncated system and the placement of every Taylor term.

    It depends on the field only through which Taylor coefficients are non-zero (their component
    and exponent), on the degree and on the outputs, never on the coefficient values: re-centred
    expansions of one field (restarts, shooting trials) share it, and :func:`moment_structure`
    caches it.
    """

    codes: np.ndarray
    exponents: np.ndarray
    pw: np.ndarray
    degree: int
    n_vars: int
    outputs: np.ndarray
    constant_index: int | None
    placements: list

    @property
    def dimension(self) -> int:
        return int(self.codes.size)


_STRUCTURES: OrderedDict = OrderedDict()
_STRUCTURE_CACHE_SIZE = 256


def clear_structure_cache() -> None:
    """Forget every cached :class:`MomentStructure` (the next builds start from scratch)."""
    _STRUCTURES.clear()


def moment_structure(exp: Expansion, N: int, out_components, prune: bool,
                     max_dimension: int) -> MomentStructure:
    """The (cached) :class:`MomentStructure` of an expansion's sparsity pattern at degree N.

    Examples
    --------
    Two centres of Troesch's field with non-zero sinh and cosh terms share one structure:

    >>> import numpy as np
    >>> from lem.fields import AnalyticField
    >>> f = AnalyticField(lambda t, y: [y[1], 5 * np.sinh(5 * y[0])], 2)
    >>> a = moment_structure(f.expansion(0.0, [0.1, 0.2], 8), 8, (0, 1), True, 10**6)
    >>> b = moment_structure(f.expansion(0.0, [0.3, 0.7], 8), 8, (0, 1), True, 10**6)
    >>> a is b, a.dimension
    (True, 45)
    """
    groups = [(exp.comp, exp.exps)] + [(c, e) for _, c, e, _ in exp.varying]
    key = (exp.n, N, tuple(out_components), prune, bool(prune or exp.has_constant),
           tuple((np.ascontiguousarray(c, np.int64).tobytes(),
                  np.ascontiguousarray(e, np.int64).tobytes()) for c, e in groups))
    S = _STRUCTURES.get(key)
    if S is None:
        S = _new_structure(exp.n, groups, N, out_components, prune, exp.has_constant, max_dimension)
        _STRUCTURES[key] = S
        if len(_STRUCTURES) > _STRUCTURE_CACHE_SIZE:
            _STRUCTURES.popitem(last=False)
    else:
        _STRUCTURES.move_to_end(key)
    if S.dimension > max_dimension:
        raise ValueError(f"the moment system exceeds max_dimension={max_dimension} "
                         f"(degree {N}, {exp.n} variables)")
    return S


def _kept_moments(n, groups, N, out_components, prune, has_constant, max_dimension):
    pw = index_powers(n, N)
    all_comp = np.concatenate([c for c, _ in groups])
    all_exps = np.vstack([e for _, e in groups])
    pattern = np.unique(np.column_stack([all_comp, all_exps]), axis=0) if all_comp.size else \
        np.zeros((0, n + 1), np.int64)
    pat_comp, pat_exps = pattern[:, 0], pattern[:, 1:]
    if not prune:
        allm = monomial_space(n, N)
        keep = allm.deg >= (0 if has_constant else 1)
        if int(keep.sum()) > max_dimension:
            raise ValueError(f"the moment system exceeds max_dimension={max_dimension} "
                             f"(degree {N}, {n} variables)")
        return pw, allm.codes[keep], allm.exps[keep]
    eye = np.eye(n, dtype=np.int64)
    known = np.unique(eye[list(out_components)] @ pw)
    frontier = eye[list(out_components)]
    while frontier.shape[0]:
        _, cols, _ = _targets(frontier, pat_comp, pat_exps, N)
        if cols.shape[0] == 0:
            break
        ccodes, first = np.unique(cols @ pw, return_index=True)
        new = ~np.isin(ccodes, known)
        frontier = cols[first[new]]
        known = np.union1d(known, ccodes[new])
        if known.size > max_dimension:
            raise ValueError(f"the moment system exceeds max_dimension={max_dimension} "
                             f"(degree {N}, {n} variables)")
    codes = np.sort(known)
    exps_R = np.zeros((codes.size, n), dtype=np.int64)
    rem = codes.copy()
    for i in range(n):
        exps_R[:, i] = rem % (N + 1)
        rem //= (N + 1)
    return pw, codes, exps_R


def _new_structure(n, groups, N, out_components, prune, has_constant, max_dimension):
    pw, codes, exps_R = _kept_moments(n, groups, N, out_components, prune, has_constant,
                                      max_dimension)
    dim = codes.size
    placements = []
    for comp, exps in groups:
        rows, cols, terms = _targets(exps_R, comp, exps, N)
        ccodes = cols @ pw
        cidx = np.searchsorted(codes, ccodes)
        if cidx.size and (np.any(cidx >= dim) or np.any(codes[np.minimum(cidx, dim - 1)] != ccodes)):
            raise AssertionError("moment closure violated")  # pragma: no cover - internal invariant
        mult = exps_R[rows, comp[terms]]
        entries, pos = np.unique(rows * dim + cidx, return_inverse=True)
        indptr = np.searchsorted(entries // max(dim, 1), np.arange(dim + 1)).astype(np.int32)
        indices = (entries % max(dim, 1)).astype(np.int32)
        placements.append(Placement(rows, cidx, terms, mult, indptr, indices, pos.ravel()))
    eye = np.eye(n, dtype=np.int64)
    outputs = np.searchsorted(codes, eye[list(out_components)] @ pw)
    const = int(np.searchsorted(codes, 0)) if codes.size and codes[0] == 0 else None
    return MomentStructure(codes, exps_R, pw, N, n, outputs, const, placements)


def build_system(exp: Expansion, N: int, out_components, prune: bool, max_dimension: int,
                 exact: bool = False) -> MomentSystem:
    """The degree-N moment system of an expansion: cached structure, values filled in."""
    st = moment_structure(exp, N, out_components, prune, max_dimension)
    dim = st.dimension
    first = st.placements[0]
    A = first.matrix(exp.vals, dim)
    triplets = first.exact_triplets(exp.vals) if exact else None
    varying = [(a, pl.matrix(v, dim)) for (a, _, _, v), pl in zip(exp.varying, st.placements[1:])]
    return MomentSystem(A, varying, st.exponents, N, st.outputs, st.constant_index, triplets,
                        n_vars=st.n_vars, codes=st.codes, pw=st.pw)


def moment_system(fun, degree: int, *, centre=None, t: float = 0.0, outputs=None, prune: bool = True,
                  n: int | None = None, max_dimension: int = 200_000) -> MomentSystem:
    """Build the truncated LEM moment system of ``fun`` at an expansion centre.

    Parameters
    ----------
    fun : PolynomialField, AnalyticField, list of dicts, or callable ``fun(t, y)``
        The vector field (a callable needs ``n``).
    degree : int
        Truncation degree N >= 1 (also the degree of f's Taylor polynomial).
    centre : array_like, optional
        Expansion centre c (default: the origin, as in the paper).
    t : float
        Time at which time-dependent coefficients are expanded.
    outputs : sequence of int, optional
        Components whose degree-1 moments must be exact outputs (default all); only the moments
        they depend on are kept when ``prune`` is true.
    prune : bool
        Keep only the moments the outputs need (default) or every moment up to degree N.

    Returns
    -------
    MomentSystem

    Examples
    --------
    y'' = tanh y keeps only odd-degree moments (tanh is odd), as in the paper's (3.17):

    >>> import numpy as np
    >>> S = moment_system(lambda t, y: [y[1], np.tanh(y[0])], 5, n=2)
    >>> S.dimension, sorted(set(S.exponents.sum(axis=1).tolist()))
    (12, [1, 3, 5])
    """
    check_int("degree", degree, 1)
    f = as_field(fun, n)
    c = [0] * f.n if centre is None else finite_vector("centre", centre, f.n, allow_exact=True)
    outs = check_outputs(outputs, f.n)
    exp = f.expansion(t, list(c), degree)
    exact = bool(getattr(f, "exact", False)) and all(is_exact_number(x) for x in c)
    return build_system(exp, degree, outs, prune, max_dimension, exact=exact)
