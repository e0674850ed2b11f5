"""The planar law in closed form, written once for every number type: one contact's Coulomb problem
(:func:`planar_enum`) and one step of iterative refinement on its branch (:func:`planar_refine`).

``ops`` selects plain floats (:data:`PY_OPS`), NumPy arrays elementwise (:data:`NUMPY_OPS`) or
CasADi SX (:data:`CASADI_OPS`, for compiled steps). Imports :mod:`lcp.contact.modes` and NumPy
(CasADi when its operations are first used); it must not import the problem classes or solvers.
"""
from __future__ import annotations

import numpy as np

from lcp.contact.modes import OPEN, SLIDE_NEG, SLIDE_POS, STICK

__all__ = ["CASADI_OPS", "NUMPY_OPS", "PY_OPS", "planar_enum", "planar_refine"]


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

