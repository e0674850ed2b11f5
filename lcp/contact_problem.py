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
"""
from __future__ import annotations

from dataclasses import dataclass
import enum
import math

import numpy as np
from ._imports import issparse
from ._imports import sparse as sp
from .friction_contact import COUPLING_FLOOR, SCALE_FLOOR

_EPS = float(np.finfo(float).eps)

__all__ = ["ContactMode", "ModeArray", "OPEN", "STICK", "SLIDE_POS", "SLIDE_NEG", "SLIDE", "MODE_NAMES", "ContactProblem",
           "planar_enum",
           "planar_refine", "PY_OPS", "NUMPY_OPS", "CASADI_OPS", "SPARSE_MIN_SIZE"]

class ContactMode(enum.IntEnum):
    """Mode of a contact in a step; the values are the integers stored in ``SimulationResult.modes``
    (so ``mode == 1`` and ``mode == ContactMode.STICK`` agree). INACTIVE (-1) marks a contact that
    took no part in the step (its gap stayed open)."""

    INACTIVE = -1
    OPEN = 0
    STICK = 1
    SLIDE_POS = 2
    SLIDE_NEG = 3
    #: a spatial contact sliding in its tangent plane (direction given by the velocity)
    SLIDE = 4


OPEN, STICK, SLIDE_POS, SLIDE_NEG = ContactMode.OPEN, ContactMode.STICK, ContactMode.SLIDE_POS, ContactMode.SLIDE_NEG
SLIDE = ContactMode.SLIDE
#: a scipy.sparse W with at most this many rows is stored dense (2 x 2 blocks gain nothing from sparsity)
SPARSE_MIN_SIZE = 8
MODE_NAMES = {OPEN: "open", STICK: "stick", SLIDE_POS: "slide+", SLIDE_NEG: "slide-", SLIDE: "slide"}


class ModeArray(np.ndarray):
    """An int8 array of contact modes that prints the :class:`ContactMode` names.

    It is an ordinary NumPy array otherwise (comparisons with integers or ``ContactMode`` members
    work as before); ``names`` gives the names as a string array.

    Examples
    --------
    >>> import numpy as np
    >>> from lcp.contact_problem import ModeArray, STICK
    >>> md = ModeArray.of(np.array([[1, -1], [2, 0]], dtype=np.int8)); md
    ModeArray([[STICK, INACTIVE],
               [SLIDE_POS, OPEN]])
    >>> bool(md[0, 0] == STICK), md.names[1].tolist()
    (True, ['SLIDE_POS', 'OPEN'])
    """

    @classmethod
    def of(cls, modes) -> "ModeArray":
        return np.asarray(modes, dtype=np.int8).view(cls)

    @property
    def names(self) -> np.ndarray:
        """The mode names, same shape."""
        lut = np.array([m.name for m in sorted(ContactMode)])  # index = value + 1
        return lut[np.asarray(self, dtype=int) + 1]

    def __array_wrap__(self, obj, context=None, return_scalar=False):
        # results of arithmetic or comparisons are plain arrays (a bool mask is not a mode)
        out = np.asarray(obj)
        return out[()] if return_scalar else out

    def _named(self) -> bool:
        return self.dtype == np.int8 and bool(np.all((self >= -1) & (self <= 4)))

    def __repr__(self):
        if not self._named():
            return np.ndarray.__repr__(np.asarray(self))
        text = np.array2string(np.asarray(self), separator=", ", prefix="ModeArray(", formatter=_MODE_FORMAT)
        return f"ModeArray({text})"

    def __str__(self):
        return np.array2string(np.asarray(self), formatter=_MODE_FORMAT) if self._named() else str(np.asarray(self))


_MODE_FORMAT = {"int": lambda x: ContactMode(int(x)).name}


class _Ops:
    """The few operations :func:`planar_enum` needs, for one number type."""

    def __init__(self, where, maximum, minimum):
        self.where, self.maximum, self.minimum = where, maximum, minimum


#: plain Python floats (the per-step solver), NumPy arrays (many scenes at once), CasADi SX (compiled steps)
PY_OPS = _Ops(lambda c, a, b: a if c else b, max, min)
NUMPY_OPS = _Ops(np.where, np.maximum, np.minimum)


def _casadi_ops():
    import casadi as ca

    return _Ops(ca.if_else, ca.fmax, ca.fmin)


class _LazyCasadiOps:
    def __getattr__(self, name):
        ops = _casadi_ops()
        return getattr(ops, name)


CASADI_OPS = _LazyCasadiOps()


def planar_enum(W00, W01, W10, W11, qN, qT, mu, ops=PY_OPS, rtol: float = 1e-12):
    """Closed-form solution of the discrete Coulomb problem of one planar contact.

    u = W p + q with p = (p_N, p_T): the four cases are tried in the order open (p = 0, q_N >= 0),
    stick (u = 0), slide+ (u_T > 0, p_T = -mu p_N), slide- (u_T < 0, p_T = mu p_N), and the first
    admissible one is returned. A sliding case whose normal coefficient W_NN -+ mu W_NT is not
    positive is the Painleve branch and is never admissible with p_N >= 0 pressing.

    Written once for every number type: ``ops`` selects plain floats (:data:`PY_OPS`), NumPy
    arrays elementwise (:data:`NUMPY_OPS`) or CasADi SX (:data:`CASADI_OPS`, for compiled steps).

    Returns
    -------
    pN, pT : impulses (NaN where no case is admissible)
    mode : OPEN, STICK, SLIDE_POS, SLIDE_NEG, or -1 where no case is admissible
    n_distinct : number of admissible cases whose impulses differ from the returned one by more
        than 1e-9 of the problem's scale, plus one (so > 1 flags several solutions)
    """
    where, fmax = ops.where, ops.maximum
    scale = fmax(fmax(abs(qN) / W00, abs(qT) / W11), 1e-300)
    tol = rtol * scale
    open_ok = (qN / W00) >= -tol
    det = W00 * W11 - W01 * W10
    det_ok = det > 0
    dets = where(det_ok, det, 1.0)
    pN_st = (-qN * W11 + qT * W01) / dets
    pT_st = (-qT * W00 + qN * W10) / dets
    st_ok = det_ok * (pN_st >= -tol) * (abs(pT_st) <= mu * pN_st + tol)
    a_p = W00 - mu * W01
    ok_p = a_p > 0
    pN_p = -qN / where(ok_p, a_p, 1.0)
    uT_p = (W10 - mu * W11) * pN_p + qT
    sp_ok = ok_p * (pN_p >= -tol) * ((uT_p / W11) > -tol)
    a_m = W00 + mu * W01
    ok_m = a_m > 0
    pN_m = -qN / where(ok_m, a_m, 1.0)
    uT_m = (W10 + mu * W11) * pN_m + qT
    sm_ok = ok_m * (pN_m >= -tol) * ((uT_m / W11) < tol)
    nan = float("nan")
    pN = where(open_ok, 0.0, where(st_ok, pN_st, where(sp_ok, pN_p, where(sm_ok, pN_m, nan))))
    pT = where(open_ok, 0.0, where(st_ok, pT_st, where(sp_ok, -mu * pN_p, where(sm_ok, mu * pN_m, nan))))
    mode = where(open_ok, OPEN, where(st_ok, STICK, where(sp_ok, SLIDE_POS, where(sm_ok, SLIDE_NEG, -1))))
    far = 1e-9 * scale

    def differs(ok, a, b):
        return ok * ((abs(a - pN) + abs(b - pT)) > far)

    n_distinct = (1 + differs(open_ok, 0.0, 0.0) + differs(st_ok, pN_st, pT_st)
                  + differs(sp_ok, pN_p, -mu * pN_p) + differs(sm_ok, pN_m, mu * pN_m))
    return pN, pT, mode, n_distinct


def planar_refine(W00, W01, W10, W11, rN, rT, mu, mode, ops=PY_OPS):
    """One step of iterative refinement of a planar contact solution on its branch.

    Given the local velocity residual (rN, rT) of the post-step velocity (what should be zero:
    rN for a closed contact, rT for a sticking one), return the impulse correction (dpN, dpT) that
    cancels it on the same branch (the sliding relation p_T = -+mu p_N is kept). With an
    ill-conditioned mass matrix the first solve leaves rounding of order cond(W) eps in the
    velocities, which would let a stuck block creep and a pressed one sink; one refinement
    removes it. Same number-type genericity as :func:`planar_enum`.
    """
    where = ops.where
    det = W00 * W11 - W01 * W10
    dets = where(det != 0, det, 1.0)
    st_N = (-rN * W11 + rT * W01) / dets
    st_T = (-rT * W00 + rN * W10) / dets
    a_p = W00 - mu * W01
    a_m = W00 + mu * W01
    sp_N = -rN / where(a_p != 0, a_p, 1.0)
    sm_N = -rN / where(a_m != 0, a_m, 1.0)
    dpN = where(mode == STICK, st_N, where(mode == SLIDE_POS, sp_N, where(mode == SLIDE_NEG, sm_N, 0.0)))
    dpT = where(mode == STICK, st_T, where(mode == SLIDE_POS, -mu * sp_N, where(mode == SLIDE_NEG, mu * sm_N, 0.0)))
    return dpN, dpT


_RESIDUAL_KERNELS = []


def _compiled_residual():
    """The compiled natural-map kernels of :mod:`lcp.nsgs` when numba is installed, else None."""
    if not _RESIDUAL_KERNELS:
        try:
            from . import nsgs

            _RESIDUAL_KERNELS.append((nsgs.residual_blocked_dense, nsgs.residual_blocked_csr,
                                      nsgs.checks_blocked_dense, nsgs.checks_blocked_csr,
                                      nsgs.contact_scales_blocked_csr)
                                     if nsgs.HAVE_NUMBA else None)
        except ImportError:  # pragma: no cover
            _RESIDUAL_KERNELS.append(None)
    return _RESIDUAL_KERNELS[0]


@dataclass
class ContactProblem:
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
    >>> from lcp.contact_problem import ContactProblem, MODE_NAMES
    >>> pb = ContactProblem(np.eye(2), np.array([-1.0, 2.0]), np.array([0.5]))
    >>> p = pb.solve_branch([2]); p, MODE_NAMES[pb.modes(p)[0]], pb.residual(p)
    (array([ 1. , -0.5]), 'slide+', 0.0)
    """

    W: np.ndarray
    q: np.ndarray
    mu: np.ndarray
    key: object = None

    def __post_init__(self, rho=None):
        if issparse(self.W):
            # sparse operators stay sparse (memory grows with nnz); tiny ones are cheaper dense
            self.W = (self.W.toarray().astype(float) if self.W.shape[0] <= SPARSE_MIN_SIZE
                      else sp.csr_matrix(self.W, dtype=float))
            if issparse(self.W):
                self._branch_lus = {}  # modes -> SuperLU of the branch matrix (it depends on W only)
        else:
            self.W = np.asarray(self.W, dtype=float)
        self.q = np.asarray(self.q, dtype=float)
        self.mu = np.atleast_1d(np.asarray(self.mu, dtype=float))
        self.k = k = self.mu.size
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
        # impulse scale of this problem: the impulse that cancels the free velocity contact by contact
        self.scale = max(float(np.max(np.abs(self.q) * self.rho)) if k else 0.0, 1e-300)

    def with_q(self, q: np.ndarray) -> "ContactProblem":
        """The same operator with another free velocity (cheap: W's derived data is reused)."""
        new = object.__new__(ContactProblem)
        new.W, new.mu, new.key, new.k, new.rho = self.W, self.mu, self.key, self.k, self.rho
        new.q = q
        if "_branch_lus" in self.__dict__:  # sparse W: branch factorizations are shared too
            new._branch_lus = self._branch_lus
        if "_absW" in self.__dict__:
            new._absW = self._absW
        if self.k == 1:  # floats: cheaper than three NumPy calls on a 2-vector
            qN, qT = q.tolist()
            rN, rT = self.rho.tolist()
            new.scale = max(abs(qN) * rN, abs(qT) * rT, 1e-300)
        else:
            new.scale = max(float(np.max(np.abs(q) * self.rho)) if self.k else 0.0, 1e-300)
        return new

    # ----------------------------------------------------------------- the Coulomb law
    def velocity(self, p: np.ndarray) -> np.ndarray:
        """Local post-step velocity u = W p + q."""
        return self.W @ p + self.q

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
        """Siconos-normalised natural-map error of p (:func:`lcp.friction_contact.natural_map_error`).

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
            if aT <= mu * zN:
                pN, pT = zN, zT
            elif mu * aT <= -zN:
                pN = pT = 0.0
            else:
                pN = (zN + mu * aT) / (1.0 + mu * mu)
                pT = math.copysign(mu * pN, zT)
            err = math.hypot(rN - pN, rT - pT)
            scale = max(math.hypot(rN, rT), math.hypot(uN, uT), math.hypot(qN, qT))
            return err / scale if scale > _EPS else err
        from .friction_contact import natural_map_error

        return natural_map_error(self.W, self.q, self.mu, p)

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

    def _abs_W(self):
        if "_absW" not in self.__dict__:
            self._absW = abs(self.W) if issparse(self.W) else np.abs(self.W)
        return self._absW

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

    # ----------------------------------------------------------------- branches
    def solve_branch(self, modes) -> np.ndarray | None:
        """Solve the linear system of one branch (modes per contact); None if it is singular.

        open: p_N = p_T = 0; closed: u_N = 0; stick: u_T = 0; slide+: p_T = -mu p_N;
        slide-: p_T = +mu p_N. The result satisfies the Coulomb law iff :meth:`admissible`.
        """
        k = self.k
        if k == 1:  # one contact: the closed form, without assembling a 2 x 2 system
            return self._solve_branch_planar(int(modes[0]))
        if issparse(self.W):
            return self._solve_branch_sparse(np.asarray(modes))
        E, r = self.branch_system(modes)
        try:
            p = np.linalg.solve(E, r)
        except np.linalg.LinAlgError:
            return None
        if not np.all(np.isfinite(p)):
            return None
        return p

    def branch_system(self, modes) -> tuple[np.ndarray, np.ndarray]:
        """The linear system E p = r of one branch (see :meth:`solve_branch`); E is singular when
        the branch's forces are not unique (redundant contacts)."""
        k = self.k
        E = np.zeros((2 * k, 2 * k))
        r = np.zeros(2 * k)
        for j, md in enumerate(modes):
            if md == OPEN:
                E[j, j] = 1.0
                E[k + j, k + j] = 1.0
                continue
            E[j] = self.W[j]
            r[j] = -self.q[j]
            if md == STICK:
                E[k + j] = self.W[k + j]
                r[k + j] = -self.q[k + j]
            else:
                E[k + j, k + j] = 1.0
                E[k + j, j] = self.mu[j] if md == SLIDE_POS else -self.mu[j]
        return E, r

    def _solve_branch_sparse(self, modes: np.ndarray) -> np.ndarray | None:
        return _sparse_branch_solve(self, modes)

    def _solve_branch_planar(self, mode: int) -> np.ndarray | None:
        (W00, W01), (W10, W11) = self.W.tolist()
        qN, qT = self.q.tolist()
        mu = float(self.mu[0])
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
    modes (shared by :meth:`with_q` copies): time stepping refines on the same branch step
    after step.
    """
    from scipy.sparse.linalg import splu

    k, W = self.k, self.W
    closed = modes != OPEN
    stick = modes == STICK
    from_W = np.concatenate([closed, stick])
    cache = self.__dict__.setdefault("_branch_lus", {})
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
