"""The branches of the planar law: once each contact's mode is known the problem is linear.

:class:`PlanarBranches` is the part of :class:`lcp.contact.problem.ContactProblem` that works mode
by mode: the linear system of one branch (open, stick, slide+, slide-) and its solution, dense,
sparse (factorizations kept per modes) or in closed form for one contact; whether a branch
solution is admissible; the active-set correction of a guess of the modes; and the equivalent
LCP (Stewart-Trinkle form) and its impulses.

A mixin of the problem class (it reads ``W``, ``q``, ``mu``, ``k``, ``rho``, ``_cache`` and calls
``velocity`` and ``contact_scales``). Imports :mod:`lcp.contact.modes`, NumPy and SciPy: it must
not import the problem module or any solver.
"""
from __future__ import annotations

import numpy as np

from lcp.contact.modes import OPEN, SLIDE_NEG, SLIDE_POS, STICK
from lcp.numerics.lazy import issparse
from lcp.numerics.lazy import sparse as sp

__all__ = ["PlanarBranches", "branch_system", "dense_branch_solution"]


class PlanarBranches:
    """Branch solves, admissibility, active-set refinement and the LCP form of a planar problem."""

    def solve_branch(self, modes) -> np.ndarray | None:
        """Solve the linear system of one branch (modes per contact); None if it is singular.

        open: p_N = p_T = 0; closed: u_N = 0; stick: u_T = 0; slide+: p_T = -mu p_N;
        slide-: p_T = +mu p_N. The result satisfies the Coulomb law iff :meth:`admissible`.
        """
        if issparse(self.W) and self.k > 1:
            return self._solve_branch_sparse(np.asarray(modes))
        return dense_branch_solution(self.W, self.q, self.mu, modes)

    def branch_system(self, modes) -> tuple[np.ndarray, np.ndarray]:
        """The linear system E p = r of one branch (see :meth:`solve_branch`); E is singular when
        the branch's forces are not unique (redundant contacts)."""
        return branch_system(self.W, self.q, self.mu, modes)

    def _solve_branch_sparse(self, modes: np.ndarray) -> np.ndarray | None:
        return _sparse_branch_solve(self, modes)

    def admissible(self, p: np.ndarray, modes, rtol: float = 1e-11) -> bool:
        """Whether a branch solution p satisfies the inequalities of its modes (within rtol * scale)."""
        k = self.k
        # plain floats: this runs once or more per step, on a handful of numbers
        pl = p.tolist()
        u = self.velocity(p).tolist()
        rho, mu = self.rho.tolist(), self.mu.tolist()
        # contact by contact (contact_scales): a light contact's inequalities are not waved
        # through on a heavy contact's scale
        tols = (rtol * self.contact_scales(p)).tolist()
        for j, md in enumerate(modes):
            pN, pT = pl[j], pl[k + j]
            tol = tols[j]
            if md == OPEN:
                if u[j] * rho[j] < -tol:
                    return False
                continue
            if pN < -tol:
                return False
            uT = u[k + j] * rho[k + j]
            if md == STICK and abs(pT) > mu[j] * pN + tol:
                return False
            if md == SLIDE_POS and uT < -tol:
                return False
            if md == SLIDE_NEG and uT > tol:
                return False
        return True

    def refine_branch(self, modes, max_changes: int | None = None):
        """Starting from a guess of the modes, correct them until the branch solution is admissible.

        A primal active-set iteration on the four modes: a closed contact pulling (p_N < 0)
        opens; an open contact penetrating (u_N < 0) closes; a stick outside the cone slides
        against its impulse; a slide whose velocity has the wrong sign sticks. Returns
        (p, modes) or (None, modes) when no admissible branch is reached within ``max_changes``
        corrections (default 2k + 2) or a cycle appears.
        """
        k = self.k
        modes = np.array(modes, dtype=np.int8)
        seen = set()
        for _ in range((2 * k + 2) if max_changes is None else max_changes):
            key = modes.tobytes()
            if key in seen:
                break
            seen.add(key)
            p = self.solve_branch(modes)
            if p is None:
                break
            if self.admissible(p, modes):
                return p, modes
            u = self.velocity(p)
            tols = 1e-11 * self.contact_scales(p)
            new = modes.copy()
            for j in range(k):
                pN, pT, uT = p[j], p[k + j], u[k + j] * self.rho[k + j]
                tol = tols[j]
                if modes[j] == OPEN:
                    if u[j] * self.rho[j] < -tol:
                        new[j] = STICK
                elif pN < -tol:
                    new[j] = OPEN
                elif modes[j] == STICK and abs(pT) > self.mu[j] * pN + tol:
                    new[j] = SLIDE_POS if pT < 0 else SLIDE_NEG
                elif (modes[j] == SLIDE_POS and uT < -tol) or (modes[j] == SLIDE_NEG and uT > tol):
                    new[j] = STICK
            modes = new
        return None, modes

    # ----------------------------------------------------------------- LCP form
    def to_lcp(self) -> tuple[np.ndarray, np.ndarray]:
        """The equivalent LCP(M, b): 0 <= z perp M z + b >= 0, z = (p_N, beta+, beta-, lambda).

        p_T = beta+ - beta-; the rows are u_N, u_T + lambda, -u_T + lambda, mu p_N - beta+ - beta-
        (Stewart-Trinkle / Anitescu-Potra form with the two tangent directions +-t).
        """
        return _lcp_form(self)

    def from_lcp(self, z: np.ndarray) -> np.ndarray:
        """Impulses p from an LCP solution z of :meth:`to_lcp`."""
        k = self.k
        return np.concatenate([z[:k], z[k:2 * k] - z[2 * k:3 * k]])


def _sparse_branch_solve(self, modes: np.ndarray) -> np.ndarray | None:
    """ContactProblem.solve_branch for a sparse W: the same rows, assembled and factorized sparsely.

    The branch matrix depends on W, mu and the modes only, so its factorization is kept per
    modes (in the problem's cache, shared by :meth:`with_q` copies): time stepping refines on the same branch step
    after step.
    """
    from scipy.sparse.linalg import splu

    k, W = self.k, self.W
    closed = modes != OPEN
    stick = modes == STICK
    from_W = np.concatenate([closed, stick])
    cache = self._cache.setdefault("branch_lus", {})
    key = modes.astype(np.int8).tobytes()
    lu = cache.get(key)
    if lu is None:
        j = np.arange(k)
        slide = closed & ~stick
        # rows taken from W: u_N of closed contacts, u_T of sticking ones; identity rows otherwise
        eye_rows = np.flatnonzero(~from_W)
        sj = j[slide]  # p_T + -mu p_N = 0 on sliding contacts: the p_N column of their rows
        sgn = np.where(modes[slide] == SLIDE_POS, 1.0, -1.0)
        E = (sp.diags(from_W.astype(float)) @ W
             + sp.csr_matrix((np.concatenate([np.ones(eye_rows.size), sgn * self.mu[sj]]),
                              (np.concatenate([eye_rows, k + sj]), np.concatenate([eye_rows, sj]))),
                             shape=(2 * k, 2 * k))).tocsc()
        try:
            lu = splu(E)
        except RuntimeError:  # exactly singular: the branch's impulses are not unique
            lu = False
        if len(cache) > 64:
            cache.clear()
        cache[key] = lu
    if lu is False:
        return None
    p = lu.solve(-np.where(from_W, self.q, 0.0))
    if not np.all(np.isfinite(p)):
        return None
    return p


def _lcp_form(self) -> tuple[np.ndarray, np.ndarray]:
    """ContactProblem.to_lcp: the equivalent LCP(M, b): 0 <= z perp M z + b >= 0, z = (p_N, beta+, beta-, lambda).

    p_T = beta+ - beta-; the rows are u_N, u_T + lambda, -u_T + lambda, mu p_N - beta+ - beta-
    (Stewart-Trinkle / Anitescu-Potra form with the two tangent directions +-t).
    """
    k = self.k
    W = self.W.toarray() if issparse(self.W) else self.W
    WN, WT = W[:k], W[k:]  # rows of u_N and u_T in p = (p_N, p_T)
    I = np.eye(k)
    M = np.zeros((4 * k, 4 * k))
    M[:k, :k], M[:k, k:2 * k], M[:k, 2 * k:3 * k] = WN[:, :k], WN[:, k:], -WN[:, k:]
    M[k:2 * k, :k], M[k:2 * k, k:2 * k], M[k:2 * k, 2 * k:3 * k] = WT[:, :k], WT[:, k:], -WT[:, k:]
    M[2 * k:3 * k, :3 * k] = -M[k:2 * k, :3 * k]
    M[k:2 * k, 3 * k:] = I
    M[2 * k:3 * k, 3 * k:] = I
    M[3 * k:, :k] = np.diag(self.mu)
    M[3 * k:, k:2 * k] = -I
    M[3 * k:, 2 * k:3 * k] = -I
    b = np.concatenate([self.q[:k], self.q[k:], -self.q[k:], np.zeros(k)])
    return M, b


def dense_branch_solution(W, q, mu, modes) -> np.ndarray | None:
    """:meth:`PlanarBranches.solve_branch` of the dense problem (W, q, mu): None if the branch is
    singular. Also called without a problem object, by the event integrator's smooth phases
    (:class:`lcp.events.modes.PhaseBranch`), whose branch is the same at every state."""
    if len(modes) == 1:  # one contact: the closed form, without assembling a 2 x 2 system
        return _planar_branch(W, q, mu, int(modes[0]))
    E, r = branch_system(W, q, mu, modes)
    try:
        p = np.linalg.solve(E, r)
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(p)):
        return None
    return p


def branch_system(W, q, mu, modes) -> tuple[np.ndarray, np.ndarray]:
    """The linear system E p = r of one branch of the problem (W, q, mu) (see
    :meth:`PlanarBranches.solve_branch`)."""
    k = len(modes)
    E = np.zeros((2 * k, 2 * k))
    r = np.zeros(2 * k)
    for j, md in enumerate(modes):
        if md == OPEN:
            E[j, j] = 1.0
            E[k + j, k + j] = 1.0
            continue
        E[j] = W[j]
        r[j] = -q[j]
        if md == STICK:
            E[k + j] = W[k + j]
            r[k + j] = -q[k + j]
        else:
            E[k + j, k + j] = 1.0
            E[k + j, j] = mu[j] if md == SLIDE_POS else -mu[j]
    return E, r


def _planar_branch(W, q, mu, mode: int) -> np.ndarray | None:
    (W00, W01), (W10, W11) = W.tolist()
    qN, qT = q.tolist()
    mu = float(mu[0])
    if mode == OPEN:
        return np.zeros(2)
    if mode == STICK:
        det = W00 * W11 - W01 * W10
        if det == 0.0:
            return None
        return np.array([(-qN * W11 + qT * W01) / det, (-qT * W00 + qN * W10) / det])
    sgn = 1.0 if mode == SLIDE_POS else -1.0
    a = W00 - sgn * mu * W01
    if a == 0.0:
        return None
    pN = -qN / a
    return np.array([pN, -sgn * mu * pN])
