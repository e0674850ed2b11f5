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

This module holds :class:`ConeContactProblem`: the layout, the disk law's residual and modes,
and :func:`local_disk`. What does not depend on the law is in :mod:`lcp.contact.friction_problem`,
the linearisations and branch refinement in :mod:`lcp.contact.disk_branches`. Imports
``lcp.contact`` modules below it (the compiled kernels when first needed) and :mod:`lcp.numerics`;
it must not import the solvers.
"""
from __future__ import annotations

import math

import numpy as np

from lcp.numerics.lazy import issparse
from lcp.numerics.lazy import sparse as sp
from lcp.contact.disk_branches import DENSE_JACOBIAN_MAX, DiskBranches, compiled_kernels
from lcp.contact.friction_problem import FrictionContactProblem, stored_operator
from lcp.contact.modes import OPEN, SLIDE, SLIDE_NEG, SLIDE_POS, STICK, ModeArray

# the mode codes as plain ints: IntEnum members in NumPy comparisons cost an enum lookup each
_OPEN, _STICK, _SLIDE_POS, _SLIDE_NEG, _SLIDE = int(OPEN), int(STICK), int(SLIDE_POS), int(SLIDE_NEG), int(SLIDE)

__all__ = ["ConeContactProblem", "DENSE_JACOBIAN_MAX", "cone_layout", "local_disk"]


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


class ConeContactProblem(FrictionContactProblem, DiskBranches):
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

    law = "disk"

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
        W = stored_operator(W)
        if W.shape != (n, n):
            raise ValueError(f"W must be ({n}, {n}) for dims {self.dims.tolist()}, got {W.shape}")
        if issparse(W):
            W.sort_indices()
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
        ker = compiled_kernels()
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

    def modes(self, p, rtol: float = 1e-9) -> np.ndarray:
        """Mode of each contact: OPEN, STICK, SLIDE (d = 2) or SLIDE_POS / SLIDE_NEG (d = 1)."""
        return ModeArray.of(self._modes(np.asarray(p, dtype=float), rtol))

    def _modes(self, p, rtol: float = 1e-9) -> np.ndarray:
        """:meth:`modes` as a plain int8 array (the codes of :class:`lcp.contact.problem.ContactMode`)."""
        ker = compiled_kernels()
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

    def _build_operator(self):
        from lcp.contact.spatial_nsgs import ConeOperator

        return ConeOperator(self)


def local_disk(W, q, mu: float, guess=None, compiled: bool = True):
    """Exact solution of one contact's Coulomb problem u = W p + q (W 3 x 3 for a disk, 2 x 2 planar).

    Cases tried in the order open (q_N >= 0), stick (u = 0 with p in the disk), slide (p_T =
    -mu p_N d, u_N = 0, u_T = lambda d with lambda > 0 and W_NN - mu W_NT.d > 0); the sliding
    direction is found by Newton in its angle, and by all roots of the quartic in exp(i t) when
    that fails (:func:`lcp.contact.kernels.local_disk3`).

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
    from lcp.contact.kernels import local_disk3, local_planar

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
    fn = local_disk3 if compiled else getattr(local_disk3, "py_func", local_disk3)
    pN, pT0, pT1, mode, _ = fn(np.ascontiguousarray(W), q[0], q[1], q[2], mu, g[0], g[1])
    return np.array([pN, pT0, pT1]), int(mode)
