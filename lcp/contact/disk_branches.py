"""The branches and linearisations of the disk law: what Newton and the branch refinement of a
:class:`lcp.contact.spatial_problem.ConeContactProblem` solve.

:class:`DiskBranches` holds the Alart-Curnier function and the blocks of its generalized
Jacobian (J = A + B W), the equations of one branch (open, stick, slide, slide+/-), the assembly
of J (dense or CSC) and the branch-wise refinement of a solution; :func:`compiled_kernels` gives
the numba kernels of :mod:`lcp.contact.spatial_nsgs` (None without numba: the NumPy paths here).

A mixin of the problem class (it reads ``W``, ``q``, ``mu``, ``dims``, ``toff``, ``R``, the
weights and ``_cache``, and calls ``residual``, ``velocity``, ``solve_linear`` and the layout
helpers). Imports :mod:`lcp.contact.modes`, NumPy and SciPy (the kernels module when first
needed): it must not import the problem module or any solver.
"""
from __future__ import annotations

import math

import numpy as np

from lcp.contact.modes import OPEN, SLIDE, SLIDE_NEG, SLIDE_POS, STICK
from lcp.numerics.lazy import issparse
from lcp.numerics.lazy import sparse as sp

__all__ = ["COMPILED_KERNELS", "DENSE_JACOBIAN_MAX", "DiskBranches", "compiled_kernels"]

# the mode codes as plain ints: IntEnum members in NumPy comparisons cost an enum lookup each
_OPEN, _STICK, _SLIDE_POS, _SLIDE_NEG, _SLIDE = int(OPEN), int(STICK), int(SLIDE_POS), int(SLIDE_NEG), int(SLIDE)

#: a sparse operator with at most this many rows gets dense Newton/refinement matrices (LAPACK beats SuperLU there)
DENSE_JACOBIAN_MAX = 96

#: the loaded kernels module, or None without numba (a test may set [None] to force the NumPy paths)
COMPILED_KERNELS: list = []


def compiled_kernels():
    """:mod:`lcp.contact.spatial_nsgs` when numba is installed (compiled residuals), else None."""
    if not COMPILED_KERNELS:
        try:
            from lcp.contact import spatial_nsgs as cone_nsgs

            COMPILED_KERNELS.append(cone_nsgs if cone_nsgs.HAVE_NUMBA else None)
        except ImportError:  # pragma: no cover
            COMPILED_KERNELS.append(None)
    return COMPILED_KERNELS[0]


class DiskBranches:
    """Alart-Curnier linearisation, branch equations and branch refinement of a disk-law problem."""

    def alart_curnier(self, p):
        """The Alart-Curnier function Phi(p) (blocked) and its piece's blocks (A, B), J = A + B W.

        Phi_N = p_N - max(0, z_N), Phi_T = p_T - proj_D(z_T), z = p - rho u, D the disk of radius
        mu max(z_N, 0). A and B are (k, 3, 3) per-contact blocks in (N, T0, T1) order.
        """
        k = self.k
        P, U = self._gather(p), self._gather(self.velocity(p))
        zN = P[:, 0] - self.rhoN * U[:, 0]
        closed = zN > 0
        s = self.mu * np.maximum(zN, 0.0)
        zT = P[:, 1:] - self.rhoT[:, None] * U[:, 1:]
        nz = np.hypot(zT[:, 0], zT[:, 1])
        interior = closed & (nz < s)
        proj_on = ~interior & (nz > 0)
        nzs = np.where(nz > 0, nz, 1.0)
        nrm = zT / nzs[:, None]
        f = np.where(interior, 1.0, np.where(nz > 0, np.minimum(s / nzs, 1.0), 0.0))
        Phi = np.zeros((k, 3))
        Phi[:, 0] = P[:, 0] - np.maximum(zN, 0.0)
        Phi[:, 1:] = P[:, 1:] - zT * f[:, None]
        eye = np.eye(2)
        G = np.where(interior[:, None, None], eye,
                     np.where(proj_on[:, None, None], (s / nzs)[:, None, None]
                              * (eye - nrm[:, :, None] * nrm[:, None, :]), 0.0))
        g = nrm * (self.mu * closed * proj_on)[:, None]
        A = np.zeros((k, 3, 3))
        B = np.zeros((k, 3, 3))
        A[:, 0, 0] = np.where(closed, 0.0, 1.0)
        B[:, 0, 0] = np.where(closed, self.rhoN, 0.0)
        A[:, 1:, 1:] = eye - G
        A[:, 1:, 0] = -g
        B[:, 1:, 1:] = self.rhoT[:, None, None] * G
        B[:, 1:, 0] = self.rhoN[:, None] * g
        return self._scatter(Phi), A, B

    def branch_equations(self, p, modes):
        """The equations of the branch ``modes`` at p and their Jacobian blocks (F, A, B).

        open: p = 0; closed: u_N = 0; stick: u_T = 0; slide (d = 2): p_T + mu p_N u_T/|u_T| = 0;
        slide+/- (d = 1): p_T +- mu p_N = 0. Newton on F (J = A + B W) keeps the branch.
        """
        k = self.k
        modes = np.asarray(modes, dtype=np.int64)
        P, U = self._gather(p), self._gather(self.velocity(p))
        F = np.zeros((k, 3))
        A = np.zeros((k, 3, 3))
        B = np.zeros((k, 3, 3))
        eye = np.eye(2)
        op = modes == _OPEN
        F[op] = P[op]
        A[op] = np.eye(3)
        cl = ~op
        F[cl, 0] = U[cl, 0]
        B[cl, 0, 0] = 1.0
        st = modes == _STICK
        F[st, 1:] = U[st, 1:]
        B[st, 1:, 1:] = eye
        sl1 = (modes == _SLIDE_POS) | (modes == _SLIDE_NEG)
        sgn = np.where(modes == _SLIDE_POS, 1.0, -1.0)
        F[sl1, 1] = P[sl1, 1] + self.mu[sl1] * P[sl1, 0] * sgn[sl1]
        A[sl1, 1:, 1:] = eye
        A[sl1, 1, 0] = self.mu[sl1] * sgn[sl1]
        sl = modes == _SLIDE
        if np.any(sl):
            uT = U[sl, 1:]
            nu = np.hypot(uT[:, 0], uT[:, 1])
            nu = np.where(nu > 0, nu, 1.0)
            nrm = uT / nu[:, None]
            mu, pN = self.mu[sl], P[sl, 0]
            F[sl, 1:] = P[sl, 1:] + (mu * pN)[:, None] * nrm
            A[sl, 1:, 1:] = eye
            A[sl, 1:, 0] = mu[:, None] * nrm
            B[sl, 1:, 1:] = (mu * pN / nu)[:, None, None] * (eye - nrm[:, :, None] * nrm[:, None, :])
        return self._scatter(F), A, B

    def jacobian(self, A, B):
        """J = A + B W from per-contact blocks: dense ndarray for a dense W, CSC for a sparse one."""
        R, V = self.R, self._valid
        if issparse(self.W) and self.n > DENSE_JACOBIAN_MAX:
            rows, cols, av, bv = [], [], [], []
            for a in range(3):
                for b in range(3):
                    ok = V[:, a] & V[:, b]
                    rows.append(R[ok, a])
                    cols.append(R[ok, b])
                    av.append(A[ok, a, b])
                    bv.append(B[ok, a, b])
            rows, cols = np.concatenate(rows), np.concatenate(cols)
            Am = sp.csr_matrix((np.concatenate(av), (rows, cols)), shape=(self.n, self.n))
            Bm = sp.csr_matrix((np.concatenate(bv), (rows, cols)), shape=(self.n, self.n))
            return (Am + Bm @ self.W).tocsc()
        J = np.zeros((self.n, self.n))
        W = self._dense_W()
        for a in range(3):
            ra = V[:, a]
            for b in range(3):
                ok = ra & V[:, b]
                J[R[ok, a], R[ok, b]] += A[ok, a, b]
                J[R[ok, a]] += B[ok, a, b][:, None] * W[R[ok, b]]
        return J

    def newton_system(self, p, jacobian: bool = True):
        """(Phi, J) of the Alart-Curnier function at p (:meth:`alart_curnier`, :meth:`jacobian`),
        compiled when numba is installed; J is None with ``jacobian=False`` (a line search needs
        Phi only)."""
        ker = compiled_kernels()
        p = np.asarray(p, dtype=float)
        if ker is None or not math.isfinite(p.sum()):
            phi, A, B = self.alart_curnier(p)
            return phi, (self.jacobian(A, B) if jacobian else None)
        sparse = self._sparse
        if sparse:
            W = self.W
            u = ker.velocity_csr(W.indptr, W.indices, W.data, self.q, p)
        else:
            u = ker.velocity_dense(self.W, self.q, p)
        if not jacobian:
            return ker.alart_curnier_phi(u, self.mu, self.dims, self.toff, self.rhoN, self.rhoT, p), None
        if not sparse or self.n <= DENSE_JACOBIAN_MAX:
            return ker.alart_curnier_dense(self._dense_W(), u, self.mu, self.dims, self.toff, self.rhoN,
                                           self.rhoT, p)
        W = self.W
        phi, r, c, v = ker.alart_curnier_csr(W.indptr, W.indices, W.data, u, self.mu, self.dims, self.toff,
                                             self.rhoN, self.rhoT, p)
        return phi, sp.csc_matrix((v, (r, c)), shape=(self.n, self.n))


    def refine(self, p, iterations: int = 3) -> np.ndarray:
        """Branch-wise exact correction of a solution p: Newton on the equations of its modes.

        Open contacts get p = 0; sticking ones the linear rows u_N = u_T = 0; sliding ones the
        sliding equations (:meth:`branch_equations`). Each step is kept only while it lowers the
        branch equations without raising the Coulomb residual, so a stuck contact's tangential
        velocity ends at rounding level of W p + q (it does not creep step after step). Returns
        the corrected impulse (p itself when nothing improves).
        """
        return self.refine_modes(p, iterations)[0]

    def refine_modes(self, p, iterations: int = 3) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`refine` and the modes of its result (int8 codes, as :meth:`modes`) in one pass.

        With numba installed and W dense or small (at most :data:`DENSE_JACOBIAN_MAX` rows) the
        whole refinement is one compiled call; ``iterations = 0`` gives (p, modes of p).
        """
        p = np.asarray(p, dtype=float)
        if self.k == 0:
            return p, np.zeros(0, dtype=np.int8)
        if not math.isfinite(p.sum()):
            return p, self._modes(p)
        ker = compiled_kernels()
        if ker is not None and (not self._sparse or self.n <= DENSE_JACOBIAN_MAX):
            return ker.refine_dense(self._dense_W(), self.q, self.mu, self.dims, self.toff, self.rhoN, self.rhoT,
                                    self.scale, p, int(iterations), 1e-9)
        best = self._refine_numpy(p, iterations)
        return best, self._modes(best)

    def _refine_numpy(self, p, iterations):
        modes = self._modes(p)
        r0 = self.residual(p)
        r_ok = max(r0, 1e-15 * max(self.scale, float(np.max(np.abs(p)))))
        best = p
        F, A, B = self.branch_equations(p, modes)
        f_best = float(np.max(np.abs(F)))
        x = p
        for _ in range(iterations):
            if f_best == 0.0:
                break
            dx = self.solve_linear(self.jacobian(A, B), -F)
            if dx is None:
                break
            x = x + dx
            F, A, B = self.branch_equations(x, modes)
            fx = float(np.max(np.abs(F)))
            if not fx < f_best:
                break
            if self.residual(x) <= r_ok:
                best, f_best = x, fx
        return best
