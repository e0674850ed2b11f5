"""The one-step frictional contact problem, and the Coulomb law (paper eq. 2.6) in one place.

Per Moreau-Jean step, the local velocities of the k active contacts are affine in their impulses,

    u = W p + q,    p = (p_N,1..p_N,k, p_T,1..p_T,k),   u = (u_N, u_T) in the same order,

with the Delassus operator W = H S H' (bilateral constraints eliminated in S) and q the free local
velocity (its normal part shifted by e u_N- for Newton restitution). The discrete Coulomb law per
contact j is

    0 <= p_N,j  perp  u_N,j >= 0,
    |p_T,j| <= mu_j p_N,j,    p_T,j = -mu_j p_N,j sign(u_T,j)  if u_T,j != 0.

In 2D this is exactly a linear complementarity problem (:meth:`ContactProblem.to_lcp`); it is not a
convex QP, because the friction law is non-associated (docs/numerical_methods.md).

Each contact's solution is in one of four modes (:data:`OPEN`, :data:`STICK`, :data:`SLIDE_POS`,
:data:`SLIDE_NEG`); once the modes are known the problem is linear (:meth:`solve_branch`).

This module holds :class:`ContactProblem`: the planar law's residual, checks, contact scales and
modes. What does not depend on the law is in :mod:`lcp.contact.friction_problem`, the branch
solves in :mod:`lcp.contact.planar_branches`, the mode codes in :mod:`lcp.contact.modes` and the
closed forms in :mod:`lcp.contact.planar_closed_form` (their names are re-exported here, where
they have always been imported from). Imports ``lcp.contact`` modules below it (the compiled
kernels of :mod:`lcp.contact.nsgs` when first needed) and :mod:`lcp.numerics`; it must not import
the solvers.
"""
from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np
from lcp.numerics.lazy import issparse
from lcp.contact.friction_problem import SPARSE_MIN_SIZE, FrictionContactProblem, stored_operator
from lcp.contact.law import COUPLING_FLOOR, SCALE_FLOOR
from lcp.contact.modes import MODE_NAMES, OPEN, SLIDE, SLIDE_NEG, SLIDE_POS, STICK, ContactMode, ModeArray
from lcp.contact.planar_branches import PlanarBranches
from lcp.contact.planar_closed_form import CASADI_OPS, NUMPY_OPS, PY_OPS, planar_enum, planar_refine

_EPS = float(np.finfo(float).eps)

__all__ = ["ContactMode", "ModeArray", "OPEN", "STICK", "SLIDE_POS", "SLIDE_NEG", "SLIDE", "MODE_NAMES", "ContactProblem",
           "planar_enum",
           "planar_refine", "PY_OPS", "NUMPY_OPS", "CASADI_OPS", "SPARSE_MIN_SIZE"]

_RESIDUAL_KERNELS = []


def _compiled_residual():
    """The compiled natural-map kernels of :mod:`lcp.contact.nsgs` when numba is installed, else None."""
    if not _RESIDUAL_KERNELS:
        try:
            from lcp.contact import nsgs

            _RESIDUAL_KERNELS.append((nsgs.residual_blocked_dense, nsgs.residual_blocked_csr,
                                      nsgs.checks_blocked_dense, nsgs.checks_blocked_csr,
                                      nsgs.contact_scales_blocked_csr)
                                     if nsgs.HAVE_NUMBA else None)
        except ImportError:  # pragma: no cover
            _RESIDUAL_KERNELS.append(None)
    return _RESIDUAL_KERNELS[0]


@dataclass
class ContactProblem(FrictionContactProblem, PlanarBranches):
    """The discrete Coulomb problem  u = W p + q  for k planar contacts.

    Find p such that, for every contact j, 0 <= p_N,j perp u_N,j >= 0, |p_T,j| <= mu_j p_N,j and
    p_T,j = -mu_j p_N,j sign(u_T,j) when u_T,j != 0.

    Parameters
    ----------
    W : ndarray, shape (2k, 2k)
        Delassus operator, symmetric positive semi-definite, ordered [normals, tangents].
    q : ndarray, shape (2k,)
        Free local velocity (normal part including the restitution shift e u_N-).
    mu : ndarray, shape (k,)
        Friction coefficients.
    key : hashable, optional
        Set by the caller when the same W recurs across steps (e.g. the active-contact indices of a
        system with constant W); solvers cache factorizations and OSQP workspaces on it.

    Examples
    --------
    A unit block pushed sideways at 2 m/s, pressed down at 1 m/s, friction 0.5: it slides.

    >>> import numpy as np
    >>> from lcp.contact.problem import ContactProblem, MODE_NAMES
    >>> pb = ContactProblem(np.eye(2), np.array([-1.0, 2.0]), np.array([0.5]))
    >>> p = pb.solve_branch([2]); p, MODE_NAMES[pb.modes(p)[0]], pb.residual(p)
    (array([ 1. , -0.5]), 'slide+', 0.0)
    """

    W: np.ndarray
    q: np.ndarray
    mu: np.ndarray
    key: object = None

    law = "planar"

    def __post_init__(self, rho=None):
        # sparse operators stay sparse (memory grows with nnz); tiny ones are cheaper dense
        self.W = stored_operator(self.W)
        self.q = np.asarray(self.q, dtype=float)
        self.mu = np.atleast_1d(np.asarray(self.mu, dtype=float))
        self.k = k = self.mu.size
        self.n = 2 * k
        if self.W.shape != (2 * k, 2 * k) or self.q.shape != (2 * k,):
            n = self.q.shape[0] if self.q.ndim == 1 else -1
            if n >= 0 and n % 2 == 0 and self.W.shape == (n, n):
                # W and q agree on n // 2 contacts: it is mu that does not
                raise ValueError(f"mu must hold one friction coefficient per contact: W {self.W.shape} and "
                                 f"q {self.q.shape} are for {n // 2} contacts, got mu of shape "
                                 f"{self.mu.shape}")
            raise ValueError(f"W must be ({2 * k}, {2 * k}) and q ({2 * k},) for {k} contacts, "
                             f"got {self.W.shape} and {self.q.shape}")
        if self.mu.ndim != 1:
            raise ValueError(f"mu must be a vector, one friction coefficient per contact, got shape {self.mu.shape}")
        if rho is None:
            d = self.W.diagonal() if issparse(self.W) else np.diag(self.W)
            # natural-map weights rho = 1/W_ii make the residual an impulse; guard zero diagonals
            rho = np.where(d > 0, 1.0 / np.where(d > 0, d, 1.0), 1.0)
        self.rho = rho
        self._rho_list = rho.tolist()
        # W's derived data (branch factorizations, |W|, the sweeps' operator), shared by with_q copies
        self._cache = {}
        self._set_scale()

    # ----------------------------------------------------------------- the Coulomb law
    def residual(self, p: np.ndarray) -> float:
        """Coulomb-law residual of p (impulse units), independent of any solver's own flags.

        The natural map: max over contacts of |min(p_N, rho_N u_N)| and
        |p_T - proj_[-mu p_N+, mu p_N+](p_T - rho_T u_T)|, with rho = 1/diag(W). It is zero exactly
        at solutions of the discrete Coulomb law (2.6).
        """
        if self.k == 0:
            return 0.0
        k = self.k
        if k == 1:  # the same natural map in floats: NumPy calls on 2-vectors cost more than the math
            (W00, W01), (W10, W11) = self.W.tolist()
            qN, qT = self.q.tolist()
            pN, pT = p.tolist()
            rhoN, rhoT = self.rho.tolist()
            uN, uT = W00 * pN + W01 * pT + qN, W10 * pN + W11 * pT + qT
            s = float(self.mu[0]) * max(pN, 0.0)
            rT = pT - min(max(pT - rhoT * uT, -s), s)
            return max(abs(min(pN, rhoN * uN)), abs(rT))
        fast = _compiled_residual()
        if fast is not None and p.dtype == np.float64 and np.all(np.isfinite(p)):
            # the same natural map, compiled: NumPy's per-call overhead dominates at small k
            if issparse(self.W):
                W = self.W
                return float(fast[1](W.indptr, W.indices, W.data, self.q, self.mu, self.rho, p))
            return float(fast[0](self.W, self.q, self.mu, self.rho, p))
        return float(np.max(self._residual_terms(p)))

    def _residual_terms(self, p: np.ndarray) -> np.ndarray:
        """Each contact's natural-map residual, max(|r_N|, |r_T|) (NumPy)."""
        k = self.k
        u = self.velocity(p)
        pN, pT = p[:k], p[k:]
        rN = np.minimum(pN, self.rho[:k] * u[:k])
        s = self.mu * np.maximum(pN, 0.0)
        rT = pT - np.clip(pT - self.rho[k:] * u[k:], -s, s)
        return np.maximum(np.abs(rN), np.abs(rT))

    def _scale_one(self, pN: float, pT: float) -> float:
        """:meth:`contact_scales` of a single contact, in floats."""
        (W00, W01), (W10, W11) = self.W.tolist()
        qN, qT = self.q.tolist()
        rhoN, rhoT = self.rho.tolist()
        return max(abs(qN) * rhoN, abs(qT) * rhoT, abs(pN), abs(pT),
                   COUPLING_FLOOR * rhoN * (abs(W00 * pN) + abs(W01 * pT)),
                   COUPLING_FLOOR * rhoT * (abs(W10 * pN) + abs(W11 * pT)), SCALE_FLOOR * self.scale)

    def error(self, p: np.ndarray) -> float:
        """Siconos-normalised natural-map error of p (:func:`lcp.contact.law.natural_map_error`).

        Computed from (W, q, mu, p) alone, in the units Siconos uses (no 1/W_ii weights), so a
        contact whose impulse is small beside the problem's impulse scale is still measured
        against the impulses actually there. NaN if p is not finite.
        """
        if self.k == 1 and p.shape == (2,):  # floats: NumPy calls on 2-vectors cost more than the math
            (W00, W01), (W10, W11) = self.W.tolist()
            qN, qT = self.q.tolist()
            rN, rT = p.tolist()
            if not (math.isfinite(rN) and math.isfinite(rT)):
                return float("nan")
            mu = float(self.mu[0])
            uN, uT = W00 * rN + W01 * rT + qN, W10 * rN + W11 * rT + qT
            zN, zT = rN - uN - mu * abs(uT), rT - uT
            aT = abs(zT)
            if aT <= mu * zN and zN >= 0.0:  # zN >= 0: mu = 0 would accept zN < 0 with zT = 0
                pN, pT = zN, zT
            elif mu * aT <= -zN:
                pN = pT = 0.0
            else:
                pN = (zN + mu * aT) / (1.0 + mu * mu)
                pT = math.copysign(mu * pN, zT)
            err = math.hypot(rN - pN, rT - pT)
            scale = max(math.hypot(rN, rT), math.hypot(uN, uT), math.hypot(qN, qT))
            return err / scale if scale > _EPS else err
        return super().error(p)

    def contact_scales(self, p: np.ndarray) -> np.ndarray:
        """Impulse scale of each contact: the largest of its impulses in p and of the impulses that
        would cancel its own free velocity (|q| / W_ii).

        Mode thresholds and the contact-by-contact acceptance are relative to these, so that a
        light body's contacts beside a heavy body's (masses 1e8 apart, say) are resolved to as
        many digits as the heavy ones: a threshold on the largest scale alone would leave them
        none.
        """
        k = self.k
        fast = _compiled_residual() if issparse(self.W) else None
        if fast is not None and p.dtype == np.float64:  # one pass, no |W| copy or SciPy call
            W = self.W
            return fast[4](W.indptr, W.indices, W.data, self.q, self.rho, p, SCALE_FLOOR * self.scale)
        aq = np.abs(self.q) * self.rho
        ap = np.abs(p)
        # at least a fraction of the terms the contact's velocity is summed from: a contact with no
        # impulse and no free velocity of its own is measured against their rounding
        ac = COUPLING_FLOOR * self.rho * (self._abs_W() @ ap)
        s = np.maximum(np.maximum(aq, ap), ac)
        return np.maximum(np.maximum(s[:k], s[k:]), SCALE_FLOOR * self.scale)

    def checks(self, p: np.ndarray) -> tuple[float, float, float]:
        """(:meth:`residual`, :meth:`relative_residual`, :meth:`error`) of p, in one pass over W
        when numba is installed (the sums in another order: equal to rounding)."""
        if self.k == 1 and p.shape == (2,):  # floats, as in residual() and error()
            res, err = self.residual(p), self.error(p)
            if not res > 0.0:
                return res, res, err
            return res, res / self._scale_one(*p.tolist()), err
        fast = _compiled_residual() if self.k > 1 else None
        if fast is not None and p.dtype == np.float64 and p.shape == (2 * self.k,) and np.all(np.isfinite(p)):
            floor = SCALE_FLOOR * self.scale
            if issparse(self.W):
                W = self.W
                out = fast[3](W.indptr, W.indices, W.data, self.q, self.mu, self.rho, p, floor)
            else:
                out = fast[2](self.W, self.q, self.mu, self.rho, p, floor)
            return float(out[0]), float(out[1]), float(out[2])
        return self.residual(p), self.relative_residual(p), self.error(p)

    def relative_residual(self, p: np.ndarray) -> float:
        """max over contacts of the natural-map residual (:meth:`residual`'s terms) divided by the
        contact's own impulse scale (:meth:`contact_scales`); NaN if p is not finite."""
        k = self.k
        if k == 0:
            return 0.0
        if not np.all(np.isfinite(p)):
            return float("nan")
        return float(np.max(self._residual_terms(p) / self.contact_scales(p)))

    def stop_measure(self, p: np.ndarray) -> float:
        """The iterative solvers' stopping measure: max(:meth:`residual`, scale *
        :meth:`relative_residual`). Below ``tol_rel * scale`` it says that the residual meets
        tol_rel on the problem's scale and every contact meets it on its own."""
        res, rel, _ = self.checks(p)
        return max(res, self.scale * rel)

    def modes(self, p: np.ndarray, rtol: float = 1e-9) -> np.ndarray:
        """Mode of each contact in the solution p (OPEN, STICK, SLIDE_POS, SLIDE_NEG), with
        thresholds rtol times each contact's own scale (:meth:`contact_scales`)."""
        k = self.k
        if k == 1:  # floats, as in residual()
            (W10, W11) = self.W[1].tolist()
            pN, pT = p.tolist()
            tol_p = rtol * self._scale_one(pN, pT)
            uT = (W10 * pN + W11 * pT + float(self.q[1])) * float(self.rho[1])
            mode = OPEN if pN <= tol_p else (SLIDE_POS if uT > tol_p else (SLIDE_NEG if uT < -tol_p else STICK))
            return np.array([mode], dtype=np.int8)
        tol_p = rtol * self.contact_scales(p)
        u = self.velocity(p)
        out = np.full(k, STICK, dtype=np.int8)
        uT = u[k:] * self.rho[k:]  # impulse units, comparable with tol_p
        out[uT > tol_p] = SLIDE_POS
        out[uT < -tol_p] = SLIDE_NEG
        out[p[:k] <= tol_p] = OPEN
        return out

    def _build_operator(self):
        from lcp.contact.nsgs import InterleavedOperator

        return InterleavedOperator(self.W)
