"""The spatial one-step friction-contact problem: Coulomb's disk, contact by contact.

Per Moreau-Jean step the local velocities of k active contacts are affine in their impulses,
u = W p + q. Contact j has a normal and d_j in {1, 2} tangent directions; with a 2-D tangent the
discrete Coulomb law is the friction disk

    0 <= p_N,j  perp  u_N,j >= 0,   |p_T,j| <= mu_j p_N,j,
    p_T,j = -mu_j p_N,j u_T,j / |u_T,j|   if u_T,j != 0,

a second-order cone complementarity problem that is not associated (it is not the KKT system of
a convex program). With De Saxce's modified velocity u~ = (u_N + mu |u_T|, u_T) it reads
K ∋ p ⊥ u~ ∈ K* with K = {|p_T| <= mu p_N}. A planar contact (d_j = 1) is the same law with a 1-D
tangent, so mixed systems are one problem.

Layout ("blocked"): p = (p_N,1 .. p_N,k, then the tangent components contact by contact:
p_T,1 (d_1 entries), p_T,2, ...); the same for u and q. The contact-by-contact ("interleaved")
order of FCLib and Siconos, (r_N,1, r_T,1.., r_N,2, ...), is reached by :attr:`perm`.

Solvers are in :mod:`lcp.contact.spatial_solvers`; the exact local solve of one contact is :func:`local_disk`.
"""
from __future__ import annotations

import math

import numpy as np

from lcp.numerics.lazy import issparse
from lcp.numerics.lazy import sparse as sp
from lcp.contact.problem import OPEN, SLIDE, SLIDE_NEG, SLIDE_POS, SPARSE_MIN_SIZE, STICK

# the mode codes as plain ints: IntEnum members in NumPy comparisons cost an enum lookup each
_OPEN, _STICK, _SLIDE_POS, _SLIDE_NEG, _SLIDE = int(OPEN), int(STICK), int(SLIDE_POS), int(SLIDE_NEG), int(SLIDE)

__all__ = ["ConeContactProblem", "cone_layout", "local_disk"]

#: a sparse operator with at most this many rows gets dense Newton/refinement matrices (LAPACK beats SuperLU there)
DENSE_JACOBIAN_MAX = 96


def cone_layout(dims) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Offsets of a layout with tangent dimensions ``dims``: (toff, start, perm).

    ``toff[j]``: first tangent entry of contact j within the tangent part (blocked order, add k);
    ``start[j]``: row of contact j's normal in the interleaved order; ``perm``: x_interleaved =
    x_blocked[perm].

    Examples
    --------
    >>> from lcp.contact.spatial_problem import cone_layout
    >>> cone_layout([2, 1])[2]
    array([0, 2, 3, 1, 4])
    """
    dims = np.asarray(dims, dtype=np.int64)
    k = dims.size
    toff = np.zeros(k, dtype=np.int64)
    toff[1:] = np.cumsum(dims)[:-1]
    start = toff + np.arange(k, dtype=np.int64)
    perm = np.empty(k + int(dims.sum()), dtype=np.int64)
    perm[start] = np.arange(k)
    for m in range(2):
        has = dims > m
        perm[start[has] + 1 + m] = k + toff[has] + m
    return toff, start, perm


_RESIDUAL_KERNELS: list = []


def _kernels():
    """:mod:`lcp.contact.spatial_nsgs` when numba is installed (compiled residuals), else None."""
    if not _RESIDUAL_KERNELS:
        try:
            from lcp.contact import spatial_nsgs as cone_nsgs

            _RESIDUAL_KERNELS.append(cone_nsgs if cone_nsgs.HAVE_NUMBA else None)
        except ImportError:  # pragma: no cover
            _RESIDUAL_KERNELS.append(None)
    return _RESIDUAL_KERNELS[0]


class ConeContactProblem:
    """The discrete Coulomb problem u = W p + q for k contacts of tangent dimension 1 or 2.

    Parameters
    ----------
    W : ndarray or scipy.sparse matrix, shape (n, n), n = k + sum(dims)
        Delassus operator in blocked order (normals, then tangents contact by contact). A sparse W
        above :data:`lcp.contact.problem.SPARSE_MIN_SIZE` rows stays sparse (CSR).
    q : ndarray, shape (n,)
        Free local velocity (normal part including the restitution shift).
    mu : ndarray, shape (k,)
        Friction coefficients, finite and >= 0.
    dims : array of int, shape (k,)
        Tangent dimension of each contact, 1 (planar) or 2 (spatial).
    key : hashable, optional
        Set by the caller when the same W recurs across steps; solvers cache operators, warm
        starts and conic workspaces on it.

    Examples
    --------
    A unit block on a plane, pressed at 1 m/s and pushed at (0.6, 0.8) m/s, friction 0.5: it
    slides, and the friction impulse opposes the sliding velocity.

    >>> import numpy as np
    >>> from lcp.contact.spatial_problem import ConeContactProblem
    >>> pb = ConeContactProblem(np.eye(3), np.array([-1.0, 0.6, 0.8]), [0.5], [2])
    >>> p = np.array([1.0, -0.3, -0.4]); pb.residual(p), pb.modes(p).names.tolist()
    (0.0, ['SLIDE'])
    """

    def __init__(self, W, q, mu, dims, key=None):
        mu = np.atleast_1d(np.asarray(mu, dtype=float))
        if mu.ndim != 1:
            raise ValueError(f"mu must be one-dimensional, got shape {mu.shape}")
        if not np.all(np.isfinite(mu)) or (mu.size and mu.min() < 0):
            raise ValueError(f"mu must be finite and >= 0, got {mu}")
        dims_a = np.atleast_1d(np.asarray(dims))
        if dims_a.shape != mu.shape:
            raise ValueError(f"dims must have shape {mu.shape} (one entry per contact), got {dims_a.shape}")
        if dims_a.size and (not np.all(np.isin(dims_a, (1, 2)))):
            raise ValueError(f"dims must be 1 or 2 for every contact, got {dims_a}")
        k = mu.size
        self.mu, self.k, self.key = mu, k, key
        self.dims = dims_a.astype(np.int64)
        n = k + int(self.dims.sum())
        self.n = n
        if issparse(W):
            if W.shape != (n, n):
                raise ValueError(f"W must be ({n}, {n}) for dims {self.dims.tolist()}, got {W.shape}")
            W = W.toarray().astype(float) if n <= SPARSE_MIN_SIZE else sp.csr_matrix(W, dtype=float)
            if issparse(W):
                W.sort_indices()
        else:
            W = np.asarray(W, dtype=float)
            if W.shape != (n, n):
                raise ValueError(f"W must be ({n}, {n}) for dims {self.dims.tolist()}, got {W.shape}")
        data = W.data if issparse(W) else W
        if not np.all(np.isfinite(data)):
            raise ValueError("W must be finite")
        q = np.asarray(q, dtype=float)
        if q.shape != (n,):
            raise ValueError(f"q must have shape ({n},), got {q.shape}")
        if not np.all(np.isfinite(q)):
            raise ValueError("q must be finite")
        self.W, self.q = W, q
        self._sparse = issparse(W)
        self.toff, self.start, self.perm = cone_layout(self.dims)
        # (k, 3) rows of each contact's (N, T0, T1) in the blocked order, -1 where d_j = 1
        R = np.full((k, 3), -1, dtype=np.int64)
        R[:, 0] = np.arange(k)
        R[:, 1] = k + self.toff
        R[self.dims == 2, 2] = k + self.toff[self.dims == 2] + 1
        self.R = R
        self._valid = R >= 0
        self._Rc = np.where(self._valid, R, 0)
        diag = W.diagonal() if issparse(W) else np.diag(W)
        dN = diag[:k]
        dT = diag[self._Rc[:, 1:]] * self._valid[:, 1:]
        dTm = dT.max(axis=1) if k else np.zeros(0)
        # natural-map weights: impulse units; one tangential weight per contact keeps the disk a disk
        self.rhoN = np.where(dN > 0, 1.0 / np.where(dN > 0, dN, 1.0), 1.0)
        self.rhoT = np.where(dTm > 0, 1.0 / np.where(dTm > 0, dTm, 1.0), 1.0)
        rho = np.empty(n)
        rho[:k] = self.rhoN
        rho[k:] = np.repeat(self.rhoT, self.dims)
        self.rho = rho
        self._rho_list = rho.tolist()
        self._cache: dict = {}
        self._set_scale()

    def _set_scale(self):
        # impulse scale: the impulse that cancels the free velocity contact by contact
        if 0 < self.n <= 8:  # floats: cheaper than three NumPy calls on a few numbers (the same products)
            self.scale = max(max([abs(a) * b for a, b in zip(self.q.tolist(), self._rho_list)]), 1e-300)
        else:
            self.scale = max(float(np.max(np.abs(self.q) * self.rho)) if self.k else 0.0, 1e-300)

    def with_q(self, q) -> ConeContactProblem:
        """The same operator with another free velocity (cheap: W's derived data is shared)."""
        q = np.asarray(q, dtype=float)
        if q.shape != (self.n,):
            raise ValueError(f"q must have shape ({self.n},), got {q.shape}")
        new = object.__new__(ConeContactProblem)
        new.__dict__.update(self.__dict__)
        new.q = q
        new._set_scale()
        return new

    # ----------------------------------------------------------------- layout
    @property
    def tangent_slices(self) -> list[slice]:
        """Slice of each contact's tangential impulse in the blocked vector."""
        return [slice(self.k + int(o), self.k + int(o) + int(d)) for o, d in zip(self.toff, self.dims)]

    def interleave(self, x) -> np.ndarray:
        """A blocked vector in contact-by-contact order."""
        return np.asarray(x)[self.perm]

    def deinterleave(self, r) -> np.ndarray:
        """A contact-by-contact vector in blocked order."""
        x = np.empty(self.n, dtype=np.result_type(np.asarray(r).dtype, float))
        x[self.perm] = r
        return x

    def to_interleaved(self):
        """(W, q, mu, dims) in contact-by-contact order (FCLib / Siconos fc3d layout)."""
        perm = self.perm
        W = self.W[perm][:, perm] if issparse(self.W) else self.W[np.ix_(perm, perm)]
        return W, self.q[perm], self.mu.copy(), self.dims.copy()

    @classmethod
    def from_interleaved(cls, W, q, mu, dims, key=None) -> ConeContactProblem:
        """The problem given in contact-by-contact order (W, q interleaved), stored blocked."""
        perm = cone_layout(np.atleast_1d(np.asarray(dims)))[2]
        inv = np.argsort(perm)
        q = np.asarray(q, dtype=float)
        if q.shape != perm.shape:
            raise ValueError(f"q must have shape {perm.shape}, got {q.shape}")
        if issparse(W):
            if W.shape != (perm.size, perm.size):
                raise ValueError(f"W must be ({perm.size}, {perm.size}), got {W.shape}")
            Wb = sp.csr_matrix(W)[inv][:, inv]
        else:
            W = np.asarray(W, dtype=float)
            if W.shape != (perm.size, perm.size):
                raise ValueError(f"W must be ({perm.size}, {perm.size}), got {W.shape}")
            Wb = W[np.ix_(inv, inv)]
        return cls(Wb, q[inv], mu, dims, key)

    def _gather(self, x) -> np.ndarray:
        """(k, 3) per-contact (N, T0, T1) values of a blocked vector, 0 in the padding."""
        return x[self._Rc] * self._valid

    def _scatter(self, X) -> np.ndarray:
        x = np.empty(self.n)
        x[self.R[self._valid]] = X[self._valid]
        return x

    # ----------------------------------------------------------------- the Coulomb law
    def velocity(self, p) -> np.ndarray:
        """Local post-step velocity u = W p + q."""
        return self.W @ p + self.q

    def residual(self, p) -> float:
        """Coulomb-law residual of p (impulse units), independent of any solver.

        Per contact the natural map max(|min(p_N, rho_N u_N)|, |p_T - proj_D(p_T - rho_T u_T)|)
        with D the disk (interval for d = 1) of radius mu max(p_N, 0), rho_N = 1/W_NN and
        rho_T = 1/max diag W_TT; the maximum over contacts. Zero exactly at solutions; for planar
        contacts it is :meth:`lcp.contact.problem.ContactProblem.residual`'s measure.
        """
        if self.k == 0:
            return 0.0
        p = np.asarray(p, dtype=float)
        ker = _kernels()
        if ker is not None and math.isfinite(p.sum()):  # one reduction: NaN/inf propagate into the sum
            if self._sparse:
                W = self.W
                return float(ker.residual_blocked_csr(W.indptr, W.indices, W.data, self.q, self.mu, self.dims,
                                                      self.toff, self.rhoN, self.rhoT, p))
            return float(ker.residual_blocked_dense(self.W, self.q, self.mu, self.dims, self.toff,
                                                    self.rhoN, self.rhoT, p))
        P, U = self._gather(p), self._gather(self.velocity(p))
        rN = np.minimum(P[:, 0], self.rhoN * U[:, 0])
        s = self.mu * np.maximum(P[:, 0], 0.0)
        z = P[:, 1:] - self.rhoT[:, None] * U[:, 1:]
        nz = np.hypot(z[:, 0], z[:, 1])
        f = np.where(nz > s, s / np.where(nz > 0, nz, 1.0), 1.0)
        rT = P[:, 1:] - z * f[:, None]
        res = np.maximum(np.abs(rN), np.hypot(rT[:, 0], rT[:, 1]))
        return float(np.max(res)) if np.all(np.isfinite(res)) else float("nan")

    def error(self, p) -> float:
        """Siconos-normalised natural-map error (:func:`lcp.contact.law.natural_map_error`)."""
        from lcp.contact.law import natural_map_error

        return natural_map_error(self.W, self.q, self.mu, p, dims=self.dims)

    def modes(self, p, rtol: float = 1e-9) -> np.ndarray:
        """Mode of each contact: OPEN, STICK, SLIDE (d = 2) or SLIDE_POS / SLIDE_NEG (d = 1)."""
        from lcp.contact.problem import ModeArray

        return ModeArray.of(self._modes(np.asarray(p, dtype=float), rtol))

    def _modes(self, p, rtol: float = 1e-9) -> np.ndarray:
        """:meth:`modes` as a plain int8 array (the codes of :class:`lcp.contact.problem.ContactMode`)."""
        ker = _kernels()
        if ker is not None:
            u = self.W @ p + self.q
            return ker.modes_blocked(p, u, self.dims, self.toff, self.rhoT, self.scale, rtol)
        tol = rtol * max(self.scale, float(np.max(np.abs(p))) if self.n else 0.0)
        P, U = self._gather(p), self._gather(self.velocity(p))
        uT = U[:, 1:] * self.rhoT[:, None]  # impulse units
        out = np.full(self.k, _STICK, dtype=np.int8)
        planar = self.dims == 1
        out[planar & (uT[:, 0] > tol)] = _SLIDE_POS
        out[planar & (uT[:, 0] < -tol)] = _SLIDE_NEG
        out[~planar & (np.hypot(uT[:, 0], uT[:, 1]) > tol)] = _SLIDE
        out[P[:, 0] <= tol] = _OPEN
        return out

    # ----------------------------------------------------------------- linearisations
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
        ker = _kernels()
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

    def _dense_W(self) -> np.ndarray:
        """W as a dense array (kept: small sparse operators factorize faster dense)."""
        if not self._sparse:
            return self.W
        Wd = self._cache.get("dense_W")
        if Wd is None:
            Wd = self._cache["dense_W"] = self.W.toarray()
        return Wd

    def operator(self):
        """The contact-by-contact operator of the sweeps (:class:`lcp.contact.spatial_nsgs.ConeOperator`),
        built once and shared by :meth:`with_q` copies."""
        op = self._cache.get("operator")
        if op is None:
            from lcp.contact.spatial_nsgs import ConeOperator

            op = self._cache["operator"] = ConeOperator(self)
        return op

    def solve_linear(self, J, rhs):
        """J x = rhs (dense or sparse; a singular dense J gets its least-squares solution); None if
        no finite solution is found."""
        try:
            if issparse(J):
                from scipy.sparse.linalg import splu

                x = splu(J).solve(rhs)
            else:
                x = np.linalg.solve(J, rhs)
        except (np.linalg.LinAlgError, RuntimeError):
            x = None
        if (x is None or not np.all(np.isfinite(x))) and not issparse(J):
            # redundant contacts make J singular: the least-squares (minimum-norm) step
            try:
                x = np.linalg.lstsq(J, rhs, rcond=None)[0]
            except np.linalg.LinAlgError:
                return None
        return x if x is not None and np.all(np.isfinite(x)) else None

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
        ker = _kernels()
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

def local_disk(W, q, mu: float, guess=None, compiled: bool = True):
    """Exact solution of one contact's Coulomb problem u = W p + q (W 3 x 3 for a disk, 2 x 2 planar).

    Cases tried in the order open (q_N >= 0), stick (u = 0 with p in the disk), slide (p_T =
    -mu p_N d, u_N = 0, u_T = lambda d with lambda > 0 and W_NN - mu W_NT.d > 0); the sliding
    direction is found by Newton in its angle, and by all roots of the quartic in exp(i t) when
    that fails (:mod:`lcp.contact.spatial_nsgs`).

    Parameters
    ----------
    W : array_like, shape (3, 3) or (2, 2)
    q : array_like, shape (3,) or (2,)
    mu : float
        Friction coefficient (>= 0).
    guess : array_like, shape (2,), optional
        A guess of the sliding direction d.
    compiled : bool
        Use the numba kernel when installed (False: the plain-Python function, for tests).

    Returns
    -------
    p : ndarray
        The impulse (NaN when no case is admissible: a Painleve-type problem).
    mode : int
        OPEN, STICK, SLIDE (d = 2) or SLIDE_POS / SLIDE_NEG (d = 1); -1 when none is admissible.

    Examples
    --------
    >>> import numpy as np
    >>> from lcp.contact.spatial_problem import local_disk
    >>> p, mode = local_disk(np.eye(3), np.array([-1.0, 0.0, 2.0]), 0.5); p, int(mode)
    (array([ 1. ,  0. , -0.5]), 4)
    """
    from lcp.contact import spatial_nsgs as cone_nsgs
    from lcp.contact.nsgs import local_planar

    W = np.asarray(W, dtype=float)
    q = np.asarray(q, dtype=float)
    if W.shape not in ((3, 3), (2, 2)):
        raise ValueError(f"W must be 3 x 3 (disk) or 2 x 2 (planar), got shape {W.shape}")
    if q.shape != (W.shape[0],):
        raise ValueError(f"q must have shape ({W.shape[0]},), got {q.shape}")
    mu = float(mu)
    if not (np.isfinite(mu) and mu >= 0):
        raise ValueError(f"mu must be finite and >= 0, got {mu!r}")
    if not (np.all(np.isfinite(W)) and np.all(np.isfinite(q))):
        raise ValueError("W and q must be finite")
    if W.shape == (2, 2):
        fn = local_planar if compiled else getattr(local_planar, "py_func", local_planar)
        pN, pT, mode = fn(W[0, 0], W[0, 1], W[1, 0], W[1, 1], q[0], q[1], mu)
        return np.array([pN, pT]), int(mode)
    g = (0.0, 0.0) if guess is None else tuple(float(x) for x in guess)
    fn = cone_nsgs.local_disk3 if compiled else getattr(cone_nsgs.local_disk3, "py_func", cone_nsgs.local_disk3)
    pN, pT0, pT1, mode, _ = fn(np.ascontiguousarray(W), q[0], q[1], q[2], mu, g[0], g[1])
    return np.array([pN, pT0, pT1]), int(mode)
