"""Finishing a stalled planar friction solve exactly: fix the settled contacts, pivot on the rest.

Iterative solvers (NSGS, semismooth Newton) can stall a few digits short on problems whose W is
nearly singular: many redundant contacts, and a W stored with few significant digits that is
slightly indefinite. Typically almost every contact's mode (open, stick, slide+, slide-) is
already right at the stalled point; what is left is a small combinatorial core of contacts
around the near-null space of W, on which the iteration cycles.

:func:`core_pivot_solve` splits the contacts into a fixed set S and a free core F:

1. the modes of the start are read off the natural map (the Alart-Curnier piece of
   :mod:`lcp.contact.newton`), their branch's linear system is solved, and the contacts violating their
   mode's inequalities seed F;
2. with the modes of S fixed, their branch equations E_SS p_S + E_SF p_F = r_S are linear, so
   p_S = a + X p_F with a = E_SS^-1 r_S, X = -E_SS^-1 E_SF (a sparse LU of E_SS), and the core is
   the planar Coulomb problem u_F = M p_F + q'_F with the Schur complement M = W_FF + W_FS X and
   q'_F = q_F + W_FS a;
3. the core is solved exactly by Lemke's method on its LCP form
   (:meth:`ContactProblem.to_lcp <lcp.contact.problem.ContactProblem.to_lcp>`);
4. the contacts of S whose Coulomb law the assembled impulses violate join F, and 2-3 repeat. When
   Lemke ends on a ray (the core's fixed surroundings admit no solution) or E_SS is singular, F
   grows by its neighbours in W's contact graph instead.

The loop ends when the normalised natural-map error
(:func:`~lcp.contact.law.natural_map_error`) of the assembled impulses is below the
tolerance, or F outgrows ``max_core`` (dense Lemke costs O((4 |F|)^2) per pivot). Memory is that of
the sparse LU of E_SS plus O(n_b |S|) for a block of n_b Schur columns and O(|F|^2) for the core.

Lemke's method is a finite algorithm, but on a matrix that is not copositive-plus (a rounded,
indefinite W) a ray does not prove that the core has no solution; F then grows and Lemke tries a
larger core, and a failure is reported, never hidden.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lcp.numerics.lazy import sparse as sp
from lcp.contact.problem import OPEN, SLIDE_NEG, SLIDE_POS, STICK, ContactProblem
from lcp.contact.law import planar_cone_projection, natural_map_error
from lcp.contact.lemke import lemke
from lcp.contact.newton import alart_curnier

__all__ = ["CorePivotResult", "contact_errors", "core_pivot_solve", "natural_modes"]

#: columns of the Schur complement computed per block (bounds the dense work array to 2 |S| x this)
SCHUR_BLOCK = 64


@dataclass
class CorePivotResult:
    """What :func:`core_pivot_solve` returns.

    Attributes
    ----------
    p : ndarray, shape (2k,)
        Impulses (normals first); the best point found when ``status`` is not 0.
    status : int
        0: normalised natural-map error <= ``error_tol``; -1: not reached (see ``message``).
    message : str
    error : float
        Normalised natural-map error of ``p``, recomputed by
        :func:`~lcp.contact.law.natural_map_error`.
    core : ndarray of int
        The free contacts of the last round.
    rounds : int
        Core solves (Lemke calls).
    pivots : int
        Lemke pivots over all rounds.
    modes : ndarray of int8
        Modes of the fixed contacts' branch in the last round (free contacts: their Lemke modes).
    """

    p: np.ndarray
    status: int
    message: str
    error: float
    core: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    rounds: int = 0
    pivots: int = 0
    modes: np.ndarray | None = None

    @property
    def success(self) -> bool:
        return self.status == 0


def natural_modes(pb: ContactProblem, p: np.ndarray) -> np.ndarray:
    """Contact modes of the natural-map piece at p (the semismooth Newton's classification).

    With z = p - rho u (rho = 1/diag W): closed where z_N > 0, sticking where |z_T| < mu z_N,
    otherwise sliding against z_T. Unlike :meth:`ContactProblem.modes` it needs no tolerance.

    Examples
    --------
    >>> import numpy as np
    >>> from lcp.contact.problem import ContactProblem, MODE_NAMES
    >>> from lcp.contact.core_pivot import natural_modes
    >>> pb = ContactProblem(np.eye(2), np.array([-1.0, 2.0]), np.array([0.5]))
    >>> [MODE_NAMES[m] for m in natural_modes(pb, np.zeros(2))]
    ['slide+']
    """
    _, _, closed, stick, sgn = alart_curnier(pb.W, pb.q, pb.mu, pb.rho, np.asarray(p, dtype=float))
    modes = np.full(pb.k, OPEN, dtype=np.int8)
    modes[closed] = STICK
    slide = closed & ~stick
    # z_T < 0: the projection puts p_T at -mu z_N, the sliding branch p_T = -mu p_N
    modes[slide & (sgn <= 0)] = SLIDE_POS
    modes[slide & (sgn > 0)] = SLIDE_NEG
    return modes


def contact_errors(W, q, mu, p) -> tuple[np.ndarray, float]:
    """Per-contact terms of :func:`~lcp.contact.law.natural_map_error` and its normaliser.

    Returns (e, scale): e_j = |r_j - proj_K(r_j - u~_j)| (Euclidean in (N, T)) so that
    ``natural_map_error = ||e|| / scale``, scale = max(||p||, ||u||, ||q||).

    Examples
    --------
    >>> import numpy as np
    >>> from lcp.contact.core_pivot import contact_errors
    >>> e, s = contact_errors(np.eye(2), np.array([-1.0, 2.0]), np.array([0.5]), np.zeros(2))
    >>> e.round(3), round(s, 3)
    (array([0.894]), 2.236)
    """
    mu = np.atleast_1d(np.asarray(mu, dtype=float))
    k = mu.size
    u = W @ p + q
    rN, rT, uN, uT = p[:k], p[k:], u[:k], u[k:]
    pN, pT = planar_cone_projection(rN - uN - mu * np.abs(uT), rT - uT, mu)
    e = np.hypot(rN - pN, rT - pT)
    scale = max(float(np.linalg.norm(p)), float(np.linalg.norm(u)), float(np.linalg.norm(q)))
    return e, scale


def _branch_matrix(W, q, mu, modes):
    """Sparse branch system E p = r of :meth:`ContactProblem.solve_branch` (rows in p's order)."""
    k = mu.size
    closed = modes != OPEN
    stick = modes == STICK
    from_W = np.concatenate([closed, stick])
    eye_rows = np.flatnonzero(~from_W)
    sj = np.flatnonzero(closed & ~stick)  # sliding: p_T -+ mu p_N = 0
    sgn = np.where(modes[sj] == SLIDE_POS, 1.0, -1.0)
    E = (sp.diags(from_W.astype(float)) @ W
         + sp.csr_matrix((np.concatenate([np.ones(eye_rows.size), sgn * mu[sj]]),
                          (np.concatenate([eye_rows, k + sj]), np.concatenate([eye_rows, sj]))),
                         shape=(2 * k, 2 * k)))
    return sp.csr_matrix(E), -np.where(from_W, q, 0.0), from_W


def _factor(E, from_W):
    """Sparse LU of a branch matrix, returned with the matrix it factorizes.

    Exactly redundant closed contacts (identical rows of W) make the branch singular: their impulses
    are not unique. Then the rows taken from W get a compliance 1e-13 max|W| on their diagonal,
    which picks one split of the impulses and moves u by about 1e-13 |W| |p|, far below any
    error target (the result is checked against the unshifted problem anyway).
    """
    from scipy.sparse.linalg import splu

    E = sp.csc_matrix(E)
    try:
        return splu(E), E
    except RuntimeError:
        shift = 1e-13 * max(float(abs(E).max()) if E.nnz else 0.0, 1e-300)
        E = sp.csc_matrix(E + sp.diags(shift * from_W.astype(float)))
        return splu(E), E  # still singular: RuntimeError, the caller grows the core


def _contact_graph(W, k):
    """Contacts coupled through W (any of the four blocks), as a CSR pattern."""
    A = abs(W)
    A = A[:k] + A[k:]
    return sp.csr_matrix(A[:, :k] + A[:, k:])


def _lu_solve(lu, E, b):
    """LU solve with one step of iterative refinement (E nearly singular on redundant contacts)."""
    x = lu.solve(b)
    return x + lu.solve(b - E @ x)


def _lcp_modes(z, kf):
    """Branch modes of the core from an LCP solution of ``to_lcp`` (z = (p_N, beta+, beta-, lambda))."""
    tol = 1e-13 * max(1.0, float(np.max(np.abs(z)))) if z.size else 0.0
    pN, bp, bm, lam = z[:kf], z[kf:2 * kf], z[2 * kf:3 * kf], z[3 * kf:]
    m = np.full(kf, STICK, dtype=np.int8)
    slide = lam > tol
    m[slide & (bp >= bm)] = SLIDE_NEG  # u_T = -lambda < 0, p_T = +mu p_N
    m[slide & (bp < bm)] = SLIDE_POS
    m[pN <= tol] = OPEN
    return m


class _Core:
    """The core problem for fixed modes of S: Schur complement, Lemke, and the assembled impulses."""

    def __init__(self, W, q, mu, modes, F):
        k = mu.size
        self.F = F = np.sort(F)
        S = np.setdiff1d(np.arange(k), F)
        self.iF, self.iS = np.concatenate([F, k + F]), np.concatenate([S, k + S])
        E, r, from_W = _branch_matrix(W, q, mu, modes)
        E_S = E[self.iS]
        self.E_SF = sp.csc_matrix(E_S[:, self.iF])
        self.r_S = r[self.iS]
        self.lu = self.E_SS = None
        if S.size:  # RuntimeError: singular, the caller grows F
            self.lu, self.E_SS = _factor(E_S[:, self.iS], from_W[self.iS])
        W_F = sp.csr_matrix(W[self.iF])
        W_FS = W_F[:, self.iS]
        M = W_F[:, self.iF].toarray()
        qF = q[self.iF].copy()
        if S.size:
            self.a = _lu_solve(self.lu, self.E_SS, self.r_S)
            qF += W_FS @ self.a
            nF = self.iF.size
            for c0 in range(0, nF, SCHUR_BLOCK):
                c1 = min(c0 + SCHUR_BLOCK, nF)
                rhs = self.E_SF[:, c0:c1].toarray()
                if np.any(rhs):
                    M[:, c0:c1] -= W_FS @ self.lu.solve(rhs)
        self.problem = ContactProblem(M, qF, mu[F])

    def solve(self):
        Ml, bl = self.problem.to_lcp()
        return lemke(Ml, bl)

    def assemble(self, pF, k):
        p = np.empty(2 * k)
        p[self.iF] = pF
        if self.lu is not None:
            p[self.iS] = _lu_solve(self.lu, self.E_SS, self.r_S - self.E_SF @ pF)
        return p


def core_pivot_solve(pb: ContactProblem, p0=None, error_tol: float = 1e-10, max_core: int = 300,
                     max_rounds: int = 60) -> CorePivotResult:
    """Solve a planar friction problem exactly from a near-solution: fixed modes plus a Lemke core.

    See the module docstring for the method. Meant as the last resort after an iterative solver
    stalls; from a poor start (or none) the core grows to the whole problem, which is dense Lemke.

    Parameters
    ----------
    pb : ContactProblem
        W dense or sparse (kept sparse), any k.
    p0 : ndarray, shape (2k,), optional
        The stalled point (default zeros).
    error_tol : float
        Target of the normalised natural-map error (:func:`~lcp.contact.law.natural_map_error`).
    max_core : int
        Largest number of free contacts (the dense core LCP has 4 |F| unknowns).
    max_rounds : int
        Largest number of core solves.

    Returns
    -------
    CorePivotResult
        ``status`` 0 when the error is <= ``error_tol``; otherwise -1, the best impulses found and
        the reason in ``message``.

    Examples
    --------
    Two coincident (redundant) contacts of a block pressed down and pushed sideways, W rounded to
    three digits so that it is slightly indefinite:

    >>> import numpy as np
    >>> from lcp.contact.problem import ContactProblem
    >>> from lcp.contact.core_pivot import core_pivot_solve
    >>> from lcp.contact.law import natural_map_error
    >>> H = np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0], [0.0, 1.0]])  # rows u_N1, u_N2, u_T1, u_T2
    >>> W = np.round(H @ np.diag([1.0, 3.0]) @ H.T + 1e-4 * np.eye(4), 3)
    >>> pb = ContactProblem(W, np.array([-1.0, -1.0, 0.4, 0.4]), np.array([0.5, 0.5]))
    >>> out = core_pivot_solve(pb)
    >>> out.status, natural_map_error(pb.W, pb.q, pb.mu, out.p) <= 1e-10
    (0, True)
    """
    if not (np.isfinite(error_tol) and error_tol > 0):
        raise ValueError(f"error_tol must be finite and > 0, got {error_tol!r}")
    if int(max_core) < 1 or int(max_rounds) < 1:
        raise ValueError(f"max_core and max_rounds must be >= 1, got {max_core!r} and {max_rounds!r}")
    k = pb.k
    W = sp.csr_matrix(pb.W)
    q, mu = pb.q, pb.mu
    p0 = np.zeros(2 * k) if p0 is None else np.asarray(p0, dtype=float)
    if p0.shape != (2 * k,) or not np.all(np.isfinite(p0)):
        raise ValueError(f"p0 must be a finite array of shape ({2 * k},)")
    absW = abs(W)
    eps = np.finfo(float).eps

    def violators(p):
        """Contacts whose law p violates beyond what rounding of u = W p + q explains, and the error."""
        e, scale = contact_errors(pb.W, q, mu, p)
        rnd = 64 * eps * (absW @ np.abs(p) + np.abs(q))
        # ||e over the rest|| <= sqrt(k) thr = error_tol scale / 10: the rest cannot spoil the target
        thr = np.maximum(0.1 * error_tol * scale / np.sqrt(max(k, 1)), np.maximum(rnd[:k], rnd[k:]))
        return np.flatnonzero(e > thr), natural_map_error(pb.W, q, mu, p)

    best_p, best_err = p0, natural_map_error(pb.W, q, mu, p0)
    modes = natural_modes(pb, p0)
    E, r, from_W = _branch_matrix(W, q, mu, modes)
    try:
        p_b = _lu_solve(*_factor(E, from_W), r)
        if not np.all(np.isfinite(p_b)):
            raise RuntimeError("non-finite branch solution")
        F, err_b = violators(p_b)
        if err_b < best_err:
            best_p, best_err = p_b, err_b
    except RuntimeError:  # a singular branch (redundant contacts in it): seed from the start instead
        F, _ = violators(p0)
    if best_err <= error_tol:
        return CorePivotResult(best_p, 0, "solved by the start's branch", best_err, modes=modes)
    if F.size == 0:  # the error sits in rounding everywhere: let the worst contact be the core
        F = np.array([int(np.argmax(contact_errors(pb.W, q, mu, best_p)[0]))])
    graph = _contact_graph(W, k)

    def grow(F):
        """F and its neighbours in W's contact graph; every contact when that adds none."""
        grown = np.union1d(F, graph[F].indices)
        return grown if grown.size > F.size else np.arange(k)

    pivots = rounds = 0
    msg = f"round limit {max_rounds} reached"
    while rounds < max_rounds:
        if F.size > max_core:
            msg = f"the core outgrew max_core = {max_core} contacts ({F.size})"
            break
        try:
            core = _Core(W, q, mu, modes, F)
        except RuntimeError:  # E_SS singular: the fixed contacts alone are redundant (never when S is empty)
            F = grow(F)
            continue
        res = core.solve()
        rounds += 1
        pivots += res.pivots
        if res.status != 0:
            if F.size == k:
                msg = f"Lemke on the whole problem ({k} contacts): {res.message}"
                break
            F = grow(F)
            continue
        F = core.F
        p = core.assemble(core.problem.from_lcp(res.z), k)
        if not np.all(np.isfinite(p)):
            msg = "non-finite impulses from the core"
            break
        bad, err = violators(p)
        modes = modes.copy()
        modes[F] = _lcp_modes(res.z, F.size)
        if err < best_err:
            best_p, best_err = p, err
        if err <= error_tol:
            return CorePivotResult(p, 0, f"solved: core of {F.size} contacts, {rounds} Lemke solves",
                                   err, F, rounds, pivots, modes)
        new = np.setdiff1d(bad, F)
        if new.size == 0:
            # the fixed contacts are fine: the core's own accuracy falls short; the full branch
            # of the modes found is the sharper solve
            try:
                E, r, from_W = _branch_matrix(W, q, mu, modes)
                p_b = _lu_solve(*_factor(E, from_W), r)
                err_b = natural_map_error(pb.W, q, mu, p_b)
            except RuntimeError:
                err_b = np.inf
            if err_b <= error_tol:
                return CorePivotResult(p_b, 0, f"solved: core of {F.size} contacts, {rounds} Lemke solves, "
                                       "full branch polish", err_b, F, rounds, pivots, modes)
            if err_b < best_err:
                best_p, best_err = p_b, err_b
            # a larger core leaves less to the Schur complement (inaccurate when E_SS is nearly
            # singular); at the whole problem it is plain Lemke
            new = np.setdiff1d(grow(F), F)
            if new.size == 0:
                msg = f"core of {F.size} contacts solved, but the error {err:.3g} stays above {error_tol:.3g}"
                break
        F = np.union1d(F, new)
    return CorePivotResult(best_p, -1, msg, best_err, F, rounds, pivots, modes)
