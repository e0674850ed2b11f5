"""Compiled kernels of the spatial (Coulomb disk) contact problem: the exact local solve of one
contact, the natural-map residual and the nonsmooth Gauss-Seidel sweep.

A contact j has a normal and d_j in {1, 2} tangent directions. Its local problem, the others held
fixed, is u = W_jj r + q (W_jj of size 1 + d_j); :func:`local_disk` solves it exactly for d = 2
(the planar case is :func:`lcp.contact.nsgs.local_planar`):

- open: q_N >= 0, r = 0;
- stick: u = 0 (a 3 x 3 solve), accepted when the impulse is in the disk |r_T| <= mu r_N;
- slide: r_T = -mu r_N d with |d| = 1 and u_N = 0, u_T = lambda d, lambda > 0. With d = (cos t,
  sin t), u_N = 0 gives r_N = -q_N / a(t), a(t) = W_NN - mu W_NT.d (a <= 0 is the Painleve branch,
  never admissible), and a(t) u_T = v(t) = v0 + V d is affine in d. Parallelism d x v(t) = 0 is a
  trigonometric polynomial of degree 2 in t: at most four roots, found as the roots of a quartic
  in z = exp(i t) (companion matrix) and polished by Newton in t. A Newton solve from the
  direction of the stick impulse is tried first; the enumeration runs only if it fails.

The residual is the natural map of :meth:`lcp.contact.spatial_problem.ConeContactProblem.residual`
(impulse units, rho_N = 1/W_NN, rho_T = 1/max diag W_TT per contact).

Everything is compiled with numba when it is installed; otherwise the same functions run as
plain Python (correct, slow). :data:`HAVE_NUMBA` says which.
"""
from __future__ import annotations

import math

import numpy as np

from lcp.numerics.jit import HAVE_NUMBA, njit
from lcp.contact.kernels import contact_residual, local_planar, row_dot

__all__ = [
    "HAVE_NUMBA",
    "ConeOperator",
    "cone_nsgs",
    "cone_nsgs_sweeps",
    "disk_residual",
    "local_disk3",
    "residual_blocked_csr",
    "residual_blocked_dense",
    "residual_interleaved",
]

#: local outcome codes (as lcp.contact.problem's modes; -1: no case admissible)
_OPEN, _STICK, _SLIDE = 0, 1, 4


@njit(cache=True)
def disk_residual(pN, pT0, pT1, uN, uT0, uT1, mu, rhoN, rhoT):
    """Natural map of one disk contact: max(|min(p_N, rho_N u_N)|, |p_T - proj_D(p_T - rho_T u_T)|),
    D the disk of radius mu max(p_N, 0)."""
    s = mu * max(pN, 0.0)
    z0 = pT0 - rhoT * uT0
    z1 = pT1 - rhoT * uT1
    nz = math.hypot(z0, z1)
    if nz > s:
        f = s / nz
        z0 *= f
        z1 *= f
    return max(abs(min(pN, rhoN * uN)), math.hypot(pT0 - z0, pT1 - z1))


@njit(cache=True)
def _solve3(W, b0, b1, b2):
    """x with W x = b (3 x 3, Gaussian elimination with partial pivoting); ok False if singular.

    Scalars only (no heap allocation: this runs once per contact and sweep)."""
    a00, a01, a02 = W[0, 0], W[0, 1], W[0, 2]
    a10, a11, a12 = W[1, 0], W[1, 1], W[1, 2]
    a20, a21, a22 = W[2, 0], W[2, 1], W[2, 2]
    big = max(abs(a00), abs(a01), abs(a02), abs(a10), abs(a11), abs(a12), abs(a20), abs(a21), abs(a22))
    if big == 0.0:
        return 0.0, 0.0, 0.0, False
    small = 1e-14 * big
    # column 0: pivot row first
    if abs(a10) > abs(a00) and abs(a10) >= abs(a20):
        a00, a01, a02, b0, a10, a11, a12, b1 = a10, a11, a12, b1, a00, a01, a02, b0
    elif abs(a20) > abs(a00) and abs(a20) > abs(a10):
        a00, a01, a02, b0, a20, a21, a22, b2 = a20, a21, a22, b2, a00, a01, a02, b0
    if abs(a00) <= small:
        return 0.0, 0.0, 0.0, False
    f = a10 / a00
    a11 -= f * a01
    a12 -= f * a02
    b1 -= f * b0
    f = a20 / a00
    a21 -= f * a01
    a22 -= f * a02
    b2 -= f * b0
    # column 1
    if abs(a21) > abs(a11):
        a11, a12, b1, a21, a22, b2 = a21, a22, b2, a11, a12, b1
    if abs(a11) <= small:
        return 0.0, 0.0, 0.0, False
    f = a21 / a11
    a22 -= f * a12
    b2 -= f * b1
    if abs(a22) <= small:
        return 0.0, 0.0, 0.0, False
    x2 = b2 / a22
    x1 = (b1 - a12 * x2) / a11
    x0 = (b0 - a01 * x1 - a02 * x2) / a00
    return x0, x1, x2, True


@njit(cache=True)
def _par(c, s, v0x, v0y, V00, V01, V10, V11):
    """h = d x v and dh/dt for d = (c, s) = (cos t, sin t), v = v0 + V d."""
    vx = v0x + V00 * c + V01 * s
    vy = v0y + V10 * c + V11 * s
    h = c * vy - s * vx
    dh = -s * vy - c * vx + c * (-V10 * s + V11 * c) - s * (-V00 * s + V01 * c)
    return h, dh


@njit(cache=True)
def _polish(c, s, v0x, v0y, V00, V01, V10, V11):
    """Newton on h(t) = 0 from the unit vector (c, s), rotating it; steps limited to 0.5 (a
    double root converges linearly). A direction where h is exactly zero is returned unchanged;
    the iteration stops once a tiny step no longer shrinks (the rounding floor of h)."""
    nrm = math.hypot(c, s)
    c /= nrm
    s /= nrm
    prev = np.inf
    for _ in range(60):
        h, dh = _par(c, s, v0x, v0y, V00, V01, V10, V11)
        if h == 0.0 or dh == 0.0:
            break
        step = -h / dh
        if step > 0.5:
            step = 0.5
        elif step < -0.5:
            step = -0.5
        if abs(step) < 1e-12 and abs(step) >= prev:
            break  # no longer shrinking: h is at its rounding floor (further steps only dither)
        prev = abs(step)
        # rotate by atan(step) (= step + O(step^3): still Newton's quadratic convergence) with one
        # square root instead of a cosine and a sine
        w = 1.0 / math.sqrt(1.0 + step * step)
        c, s = (c - s * step) * w, (s + c * step) * w
        if abs(step) <= 1e-16:
            break
    return c, s


@njit(cache=True)
def _slide_at(c, s, W, qN, qT0, qT1, mu, rhoN, rhoT):
    """Impulse and local residual of the sliding candidate with direction d = (c, s) (residual inf
    when a(d) <= 0 or the tangential velocity points the wrong way)."""
    a = W[0, 0] - mu * (W[0, 1] * c + W[0, 2] * s)
    if not a > 0.0:
        return 0.0, 0.0, 0.0, np.inf
    pN = -qN / a
    pT0 = -mu * pN * c
    pT1 = -mu * pN * s
    uN = W[0, 0] * pN + W[0, 1] * pT0 + W[0, 2] * pT1 + qN
    uT0 = W[1, 0] * pN + W[1, 1] * pT0 + W[1, 2] * pT1 + qT0
    uT1 = W[2, 0] * pN + W[2, 1] * pT0 + W[2, 2] * pT1 + qT1
    if uT0 * c + uT1 * s < 0.0 and math.hypot(uT0, uT1) * rhoT > 1e-13 * pN:
        return 0.0, 0.0, 0.0, np.inf
    return pN, pT0, pT1, disk_residual(pN, pT0, pT1, uN, uT0, uT1, mu, rhoN, rhoT)


@njit(cache=True)
def local_disk3(W, qN, qT0, qT1, mu, g0, g1):
    """Exact solution of one disk contact u = W r + q (W 3 x 3, order N, T0, T1).

    (g0, g1) is a guess of the sliding direction d (e.g. the last tangential impulse negated;
    (0, 0) for none). Returns (pN, pT0, pT1, mode, residual): mode 0 open, 1 stick, 4 slide,
    -1 when no case is admissible (a Painleve-type block: NaN impulses). ``residual`` is the local
    natural map of the returned impulse.
    """
    WNN = W[0, 0]
    if not WNN > 0.0:
        return np.nan, np.nan, np.nan, -1, np.inf
    wT = max(W[1, 1], W[2, 2])
    rhoN = 1.0 / WNN
    rhoT = 1.0 / wT if wT > 0.0 else 1.0
    scale = max(abs(qN) * rhoN, math.hypot(qT0, qT1) * rhoT, 1e-300)
    tol = 1e-13 * scale
    if qN * rhoN >= -tol:
        return 0.0, 0.0, 0.0, _OPEN, 0.0
    if mu == 0.0:
        # no friction: the normal impulse alone; the contact slides unless u_T vanishes
        pN = -qN * rhoN
        uT0 = W[1, 0] * pN + qT0
        uT1 = W[2, 0] * pN + qT1
        md = _STICK if math.hypot(uT0, uT1) * rhoT <= tol else _SLIDE
        return pN, 0.0, 0.0, md, abs(W[0, 0] * pN + qN) * rhoN
    x0, x1, x2, ok = _solve3(W, -qN, -qT0, -qT1)
    if ok and x0 >= -tol and math.hypot(x1, x2) <= mu * x0 + tol:
        return x0, x1, x2, _STICK, 0.0
    # sliding: a(t) u_T = v0 + V d
    v0x = -qN * W[1, 0] + WNN * qT0
    v0y = -qN * W[2, 0] + WNN * qT1
    V00 = mu * (qN * W[1, 1] - qT0 * W[0, 1])
    V01 = mu * (qN * W[1, 2] - qT0 * W[0, 2])
    V10 = mu * (qN * W[2, 1] - qT1 * W[0, 1])
    V11 = mu * (qN * W[2, 2] - qT1 * W[0, 2])
    accept = 1e-12 * scale
    if ok and math.hypot(x1, x2) > 0.0:
        c0, s0 = -x1, -x2
    elif g0 != 0.0 or g1 != 0.0:
        c0, s0 = g0, g1
    elif v0x != 0.0 or v0y != 0.0:
        c0, s0 = v0x, v0y
    else:
        c0, s0 = 1.0, 0.0
    c, s = _polish(c0, s0, v0x, v0y, V00, V01, V10, V11)
    pN, pT0, pT1, res = _slide_at(c, s, W, qN, qT0, qT1, mu, rhoN, rhoT)
    if res <= accept:
        return pN, pT0, pT1, _SLIDE, res
    # every root of h: z^2 h(t) with z = exp(i t) is a quartic in z
    a0 = 0.5 * (V10 - V01)
    a1 = v0y
    b1 = -v0x
    a2 = 0.5 * (V10 + V01)
    b2 = 0.5 * (V11 - V00)
    coef = np.empty(5, dtype=np.complex128)  # highest degree first
    coef[0] = 0.5 * complex(a2, -b2)
    coef[1] = 0.5 * complex(a1, -b1)
    coef[2] = complex(a0, 0.0)
    coef[3] = 0.5 * complex(a1, b1)
    coef[4] = 0.5 * complex(a2, b2)
    cmax = 0.0
    for i in range(5):
        cmax = max(cmax, abs(coef[i]))
    best = (np.nan, np.nan, np.nan, np.inf)
    if cmax > 0.0:
        lo = 0
        while lo < 4 and abs(coef[lo]) <= 1e-15 * cmax:
            lo += 1
        hi = 4
        while hi > lo and abs(coef[hi]) <= 1e-15 * cmax:
            hi -= 1  # a zero constant term is a root z = 0, off the unit circle
        deg = hi - lo
        if deg >= 1:
            C = np.zeros((deg, deg), dtype=np.complex128)
            for j in range(deg):
                C[0, j] = -coef[lo + 1 + j] / coef[lo]
            for i in range(1, deg):
                C[i, i - 1] = 1.0
            roots = np.linalg.eigvals(C)
            for i in range(deg):
                z = roots[i]
                if not (abs(z) > 0.0 and np.isfinite(z.real) and np.isfinite(z.imag)):
                    continue
                c, s = _polish(z.real, z.imag, v0x, v0y, V00, V01, V10, V11)
                cand = _slide_at(c, s, W, qN, qT0, qT1, mu, rhoN, rhoT)
                if cand[3] < best[3]:
                    best = cand
    if best[3] <= accept:
        return best[0], best[1], best[2], _SLIDE, best[3]
    # no admissible sliding direction: maybe a stick at the cone's edge missed by the tolerance
    if ok and x0 >= -tol:
        sN = max(x0, 0.0)
        uN = W[0, 0] * x0 + W[0, 1] * x1 + W[0, 2] * x2 + qN
        uT0 = W[1, 0] * x0 + W[1, 1] * x1 + W[1, 2] * x2 + qT0
        uT1 = W[2, 0] * x0 + W[2, 1] * x1 + W[2, 2] * x2 + qT1
        r = disk_residual(sN, x1, x2, uN, uT0, uT1, mu, rhoN, rhoT)
        if r <= accept:
            return x0, x1, x2, _STICK, r
    return np.nan, np.nan, np.nan, -1, np.inf


# ----------------------------------------------------------------- residual kernels
@njit(cache=True)
def residual_blocked_csr(indptr, indices, data, q, mu, dims, toff, rhoN, rhoT, p):
    """ConeContactProblem.residual for a CSR W in blocked order (normals, then tangents)."""
    k = mu.size
    res = 0.0
    for j in range(k):
        uN = q[j] + row_dot(indptr, indices, data, p, j)
        t0 = k + toff[j]
        uT0 = q[t0] + row_dot(indptr, indices, data, p, t0)
        if dims[j] == 1:
            r = contact_residual(p[j], p[t0], uN, uT0, mu[j], rhoN[j], rhoT[j])
        else:
            uT1 = q[t0 + 1] + row_dot(indptr, indices, data, p, t0 + 1)
            r = disk_residual(p[j], p[t0], p[t0 + 1], uN, uT0, uT1, mu[j], rhoN[j], rhoT[j])
        res = max(res, r)
    return res


@njit(cache=True)
def _dense_row_dot(W, x, i):
    s = 0.0
    for m in range(x.size):
        s += W[i, m] * x[m]
    return s


@njit(cache=True)
def residual_blocked_dense(W, q, mu, dims, toff, rhoN, rhoT, p):
    """ConeContactProblem.residual for a dense W in blocked order."""
    k = mu.size
    res = 0.0
    for j in range(k):
        uN = q[j] + _dense_row_dot(W, p, j)
        t0 = k + toff[j]
        uT0 = q[t0] + _dense_row_dot(W, p, t0)
        if dims[j] == 1:
            r = contact_residual(p[j], p[t0], uN, uT0, mu[j], rhoN[j], rhoT[j])
        else:
            uT1 = q[t0 + 1] + _dense_row_dot(W, p, t0 + 1)
            r = disk_residual(p[j], p[t0], p[t0 + 1], uN, uT0, uT1, mu[j], rhoN[j], rhoT[j])
        res = max(res, r)
    return res


@njit(cache=True)
def residual_interleaved(indptr, indices, data, q, mu, dims, start, rhoN, rhoT, r):
    """The same natural map in contact-by-contact order (start[j]: row of contact j's normal)."""
    k = mu.size
    res = 0.0
    for j in range(k):
        i0 = start[j]
        uN = q[i0] + row_dot(indptr, indices, data, r, i0)
        uT0 = q[i0 + 1] + row_dot(indptr, indices, data, r, i0 + 1)
        if dims[j] == 1:
            e = contact_residual(r[i0], r[i0 + 1], uN, uT0, mu[j], rhoN[j], rhoT[j])
        else:
            uT1 = q[i0 + 2] + row_dot(indptr, indices, data, r, i0 + 2)
            e = disk_residual(r[i0], r[i0 + 1], r[i0 + 2], uN, uT0, uT1, mu[j], rhoN[j], rhoT[j])
        res = max(res, e)
    return res


# ----------------------------------------------------------------- NSGS
@njit(cache=True)
def cone_nsgs_sweeps(indptr, indices, data, blocks, q, mu, dims, start, rhoN, rhoT, r, tol, max_sweeps):
    """Sweep until the natural-map residual is <= tol; returns (sweeps, residual, local failures).

    ``blocks[j]`` is contact j's diagonal block (3 x 3, padded for d = 1); ``r`` (contact-by-contact
    order) is updated in place. The residual is evaluated only when a sweep's largest change falls
    below ``tol``.
    """
    k = mu.size
    res = np.inf
    fails = 0
    sweep = 0
    ql = np.zeros(3)
    for sweep in range(1, max_sweeps + 1):
        change = 0.0
        fails = 0
        for j in range(k):
            i0 = start[j]
            d = dims[j]
            B = blocks[j]
            for a in range(d + 1):
                s = q[i0 + a] + row_dot(indptr, indices, data, r, i0 + a)
                for b in range(d + 1):
                    s -= B[a, b] * r[i0 + b]
                ql[a] = s
            if B[0, 0] <= 0.0:  # a contact that no impulse moves: leave it
                fails += 1
                continue
            if d == 1:
                pN, pT, mode = local_planar(B[0, 0], B[0, 1], B[1, 0], B[1, 1], ql[0], ql[1], mu[j])
                pT1 = 0.0
            else:
                pN, pT, pT1, mode, _ = local_disk3(B, ql[0], ql[1], ql[2], mu[j], -r[i0 + 1], -r[i0 + 2])
            if mode < 0:
                # no admissible local case (a Painleve-type block): one projected natural-map step
                fails += 1
                uN = ql[0]
                uT0 = ql[1]
                uT1 = ql[2] if d == 2 else 0.0
                for b in range(d + 1):
                    uN += B[0, b] * r[i0 + b]
                    uT0 += B[1, b] * r[i0 + b]
                    if d == 2:
                        uT1 += B[2, b] * r[i0 + b]
                pN = max(r[i0] - rhoN[j] * uN, 0.0)
                pT = r[i0 + 1] - rhoT[j] * uT0
                pT1 = (r[i0 + 2] - rhoT[j] * uT1) if d == 2 else 0.0
                nz = math.hypot(pT, pT1)
                lim = mu[j] * pN
                if nz > lim:
                    pT *= lim / nz
                    pT1 *= lim / nz
            change = max(change, abs(pN - r[i0]), abs(pT - r[i0 + 1]))
            r[i0] = pN
            r[i0 + 1] = pT
            if d == 2:
                change = max(change, abs(pT1 - r[i0 + 2]))
                r[i0 + 2] = pT1
        if change <= tol:
            res = residual_interleaved(indptr, indices, data, q, mu, dims, start, rhoN, rhoT, r)
            if res <= tol:
                return sweep, res, fails
    res = residual_interleaved(indptr, indices, data, q, mu, dims, start, rhoN, rhoT, r)
    return sweep, res, fails


class ConeOperator:
    """W in contact-by-contact CSR order with its diagonal blocks, built once per operator.

    Parameters
    ----------
    problem : ConeContactProblem
        Supplies W (blocked), dims, the permutation to contact-by-contact order and the weights.
    """

    def __init__(self, problem):
        import scipy.sparse as sp

        perm = problem.perm
        W = problem.W
        Wi = sp.csr_matrix(W)[perm][:, perm] if sp.issparse(W) else sp.csr_matrix(np.asarray(W)[np.ix_(perm, perm)])
        Wi.sort_indices()
        self.k, self.n, self.perm = problem.k, problem.n, perm
        self.dims, self.start = problem.dims, problem.start
        self.indptr = Wi.indptr.astype(np.int64)
        self.indices = Wi.indices.astype(np.int64)
        self.data = Wi.data.astype(float)
        self.nnz = Wi.nnz
        k = problem.k
        # diagonal blocks: the entries whose row and column belong to the same contact
        owner = np.repeat(np.arange(k), problem.dims + 1)
        local = np.arange(problem.n) - problem.start[owner]
        C = Wi.tocoo()
        same = owner[C.row] == owner[C.col]
        self.blocks = np.zeros((k, 3, 3))
        self.blocks[owner[C.row[same]], local[C.row[same]], local[C.col[same]]] = C.data[same]
        self.rhoN, self.rhoT = problem.rhoN, problem.rhoT

    def fits(self, problem) -> bool:
        """Whether this operator can be the one of ``problem`` (a warm start kept on its key)."""
        return self.n == problem.n and np.array_equal(self.dims, problem.dims)

    def sweeps(self, q, mu, r0, tol, max_sweeps, compiled=True, rel_scale=0.0):
        """:func:`cone_nsgs` on this operator (its stopping measure is the residual: ``rel_scale``
        must be 0)."""
        if rel_scale != 0.0:
            raise ValueError("the disk-law sweeps stop on the natural-map residual only (rel_scale = 0)")
        return cone_nsgs(self, q, mu, r0, tol, max_sweeps, compiled)


def cone_nsgs(op: ConeOperator, q, mu, r0=None, tol: float = 1e-12, max_sweeps: int = 10000,
              compiled: bool = True):
    """Run NSGS on a :class:`ConeOperator` (vectors in contact-by-contact order).

    Returns (r, sweeps, residual, local_failures).
    """
    r = np.zeros(op.n) if r0 is None else np.array(r0, dtype=float)
    fn = cone_nsgs_sweeps if compiled else getattr(cone_nsgs_sweeps, "py_func", cone_nsgs_sweeps)
    sweeps, res, fails = fn(op.indptr, op.indices, op.data, op.blocks, np.asarray(q, dtype=float),
                            np.asarray(mu, dtype=float), op.dims, op.start, op.rhoN, op.rhoT, r,
                            float(tol), int(max_sweeps))
    return r, int(sweeps), float(res), int(fails)


# ----------------------------------------------------------------- branch refinement, modes, Newton
# Blocked layout throughout (normals 0..k-1, then tangents contact by contact from k + toff[j]).
# Mode codes as lcp.contact.problem: 0 open, 1 stick, 2 slide+, 3 slide-, 4 slide (d = 2).
@njit(cache=True)
def velocity_dense(W, q, p):
    """u = q + W p, row by row in the order of :func:`residual_blocked_dense`."""
    n = q.size
    u = np.empty(n)
    for i in range(n):
        u[i] = q[i] + _dense_row_dot(W, p, i)
    return u


@njit(cache=True)
def velocity_csr(indptr, indices, data, q, p):
    """u = q + W p for a CSR W, row by row in the order of :func:`residual_blocked_csr`."""
    n = q.size
    u = np.empty(n)
    for i in range(n):
        u[i] = q[i] + row_dot(indptr, indices, data, p, i)
    return u


@njit(cache=True)
def _absmax(x):
    """max |x_i|; NaN when an entry is NaN (as NumPy's max)."""
    m = 0.0
    for i in range(x.size):
        a = abs(x[i])
        if not a <= m:
            m = a
    return m


@njit(cache=True)
def modes_blocked(p, u, dims, toff, rhoT, scale, rtol):
    """Mode of each contact (ConeContactProblem.modes) from p and u = W p + q."""
    k = dims.size
    tol = rtol * max(scale, _absmax(p)) if p.size else rtol * scale
    out = np.empty(k, dtype=np.int8)
    for j in range(k):
        t0 = k + toff[j]
        uT0 = u[t0] * rhoT[j]
        md = 1
        if dims[j] == 1:
            if uT0 > tol:
                md = 2
            elif uT0 < -tol:
                md = 3
        elif math.hypot(uT0, u[t0 + 1] * rhoT[j]) > tol:
            md = 4
        if p[j] <= tol:
            md = 0
        out[j] = md
    return out


@njit(cache=True)
def _branch_dense(W, mu, dims, toff, modes, x, u, F, J):
    """Branch equations F of ``modes`` at x (u = W x + q) and J = dF/dx (dense, overwritten)."""
    k = dims.size
    n = x.size
    J[:, :] = 0.0
    for j in range(k):
        t0 = k + toff[j]
        d = dims[j]
        md = modes[j]
        if md == 0:  # open: p = 0
            F[j] = x[j]
            J[j, j] = 1.0
            for a in range(d):
                F[t0 + a] = x[t0 + a]
                J[t0 + a, t0 + a] = 1.0
            continue
        F[j] = u[j]  # closed: u_N = 0
        for m in range(n):
            J[j, m] = W[j, m]
        if md == 1:  # stick: u_T = 0
            for a in range(d):
                F[t0 + a] = u[t0 + a]
                for m in range(n):
                    J[t0 + a, m] = W[t0 + a, m]
        elif md == 2 or md == 3:  # slide+-: p_T +- mu p_N = 0
            sgn = 1.0 if md == 2 else -1.0
            F[t0] = x[t0] + mu[j] * x[j] * sgn
            J[t0, t0] = 1.0
            J[t0, j] = mu[j] * sgn
        elif md == 4:  # slide: p_T + mu p_N u_T / |u_T| = 0
            nu = math.hypot(u[t0], u[t0 + 1])
            if not nu > 0.0:
                nu = 1.0
            n0 = u[t0] / nu
            n1 = u[t0 + 1] / nu
            c = mu[j] * x[j] / nu
            F[t0] = x[t0] + mu[j] * x[j] * n0
            F[t0 + 1] = x[t0 + 1] + mu[j] * x[j] * n1
            g00 = c * (1.0 - n0 * n0)
            g01 = c * (0.0 - n0 * n1)
            g11 = c * (1.0 - n1 * n1)
            for m in range(n):
                J[t0, m] = g00 * W[t0, m] + g01 * W[t0 + 1, m]
                J[t0 + 1, m] = g01 * W[t0, m] + g11 * W[t0 + 1, m]
            J[t0, t0] += 1.0
            J[t0 + 1, t0 + 1] += 1.0
            J[t0, j] += mu[j] * n0
            J[t0 + 1, j] += mu[j] * n1


@njit(cache=True)
def solve_dense(J, rhs):
    """J x = rhs by LU; a singular J (redundant contacts) gets its least-squares solution.
    Returns (x, ok): ok False when no finite solution is found."""
    n = rhs.size
    x = np.empty(n)
    ok = True
    try:
        x = np.linalg.solve(J, rhs)
    except Exception:  # noqa: BLE001 - numba raises LinAlgError for an exactly singular pivot
        ok = False
    if ok:
        for i in range(n):
            if not np.isfinite(x[i]):
                ok = False
                break
    if not ok:
        ok = True
        try:
            x = np.linalg.lstsq(J, rhs, rcond=2.220446049250313e-16 * n)[0]
        except Exception:  # noqa: BLE001
            ok = False
        if ok:
            for i in range(n):
                if not np.isfinite(x[i]):
                    ok = False
                    break
    return x, ok


@njit(cache=True)
def refine_dense(W, q, mu, dims, toff, rhoN, rhoT, scale, p, iterations, rtol):
    """ConeContactProblem.refine followed by its modes, in one call (dense W, blocked order).

    Newton on the equations of the branch of p's modes; a step is kept while it lowers the branch
    equations without raising the Coulomb residual. Returns (p refined, modes of the result).
    """
    n = p.size
    u = velocity_dense(W, q, p)
    modes = modes_blocked(p, u, dims, toff, rhoT, scale, rtol)
    if iterations <= 0:
        return p, modes
    r0 = residual_blocked_dense(W, q, mu, dims, toff, rhoN, rhoT, p)
    r_ok = max(r0, 1e-15 * max(scale, _absmax(p)))
    best = p
    F = np.empty(n)
    J = np.empty((n, n))
    _branch_dense(W, mu, dims, toff, modes, p, u, F, J)
    f_best = _absmax(F)
    x = p
    changed = False
    for _ in range(iterations):
        if f_best == 0.0:
            break
        dx, ok = solve_dense(J, -F)
        if not ok:
            break
        x = x + dx
        ux = velocity_dense(W, q, x)
        _branch_dense(W, mu, dims, toff, modes, x, ux, F, J)
        fx = _absmax(F)
        if not fx < f_best:
            break
        if residual_blocked_dense(W, q, mu, dims, toff, rhoN, rhoT, x) <= r_ok:
            best, f_best = x, fx
            changed = True
    if changed:
        modes = modes_blocked(best, velocity_dense(W, q, best), dims, toff, rhoT, scale, rtol)
    return best, modes


@njit(cache=True)
def _ac_contact(pN, pT0, pT1, uN, uT0, uT1, mu, rhoN, rhoT, A, B):
    """Alart-Curnier function of one contact and its blocks A, B (3 x 3, N T0 T1; overwritten)."""
    zN = pN - rhoN * uN
    closed = zN > 0.0
    s = mu * max(zN, 0.0)
    z0 = pT0 - rhoT * uT0
    z1 = pT1 - rhoT * uT1
    nz = math.hypot(z0, z1)
    interior = closed and nz < s
    proj_on = (not interior) and nz > 0.0
    nzs = nz if nz > 0.0 else 1.0
    n0 = z0 / nzs
    n1 = z1 / nzs
    if interior:
        f = 1.0
    elif nz > 0.0:
        f = min(s / nzs, 1.0)
    else:
        f = 0.0
    phiN = pN - max(zN, 0.0)
    phi0 = pT0 - z0 * f
    phi1 = pT1 - z1 * f
    if interior:
        G00, G01, G11 = 1.0, 0.0, 1.0
    elif proj_on:
        c = s / nzs
        G00, G01, G11 = c * (1.0 - n0 * n0), c * (0.0 - n0 * n1), c * (1.0 - n1 * n1)
    else:
        G00, G01, G11 = 0.0, 0.0, 0.0
    gm = mu if (closed and proj_on) else 0.0
    g0 = n0 * gm
    g1 = n1 * gm
    A[0, 0] = 0.0 if closed else 1.0
    A[0, 1] = 0.0
    A[0, 2] = 0.0
    B[0, 0] = rhoN if closed else 0.0
    B[0, 1] = 0.0
    B[0, 2] = 0.0
    A[1, 0], A[1, 1], A[1, 2] = -g0, 1.0 - G00, 0.0 - G01
    A[2, 0], A[2, 1], A[2, 2] = -g1, 0.0 - G01, 1.0 - G11
    B[1, 0], B[1, 1], B[1, 2] = rhoN * g0, rhoT * G00, rhoT * G01
    B[2, 0], B[2, 1], B[2, 2] = rhoN * g1, rhoT * G01, rhoT * G11
    return phiN, phi0, phi1


@njit(cache=True)
def alart_curnier_phi(u, mu, dims, toff, rhoN, rhoT, p):
    """The Alart-Curnier function Phi(p) (blocked) from p and u = W p + q."""
    k = dims.size
    phi = np.empty(p.size)
    A = np.empty((3, 3))
    B = np.empty((3, 3))
    for j in range(k):
        t0 = k + toff[j]
        two = dims[j] == 2
        pN, pT0, pT1 = p[j], p[t0], p[t0 + 1] if two else 0.0
        f0, f1, f2 = _ac_contact(pN, pT0, pT1, u[j], u[t0], u[t0 + 1] if two else 0.0,
                                 mu[j], rhoN[j], rhoT[j], A, B)
        phi[j] = f0
        phi[t0] = f1
        if two:
            phi[t0 + 1] = f2
    return phi


@njit(cache=True)
def alart_curnier_dense(W, u, mu, dims, toff, rhoN, rhoT, p):
    """(Phi, J) of the Alart-Curnier function at p: J = A + B W dense, blocked order."""
    k = dims.size
    n = p.size
    phi = np.empty(n)
    J = np.zeros((n, n))
    A = np.empty((3, 3))
    B = np.empty((3, 3))
    rows = np.empty(3, dtype=np.int64)
    for j in range(k):
        t0 = k + toff[j]
        d = dims[j]
        two = d == 2
        f0, f1, f2 = _ac_contact(p[j], p[t0], p[t0 + 1] if two else 0.0, u[j], u[t0], u[t0 + 1] if two else 0.0,
                                 mu[j], rhoN[j], rhoT[j], A, B)
        phi[j] = f0
        phi[t0] = f1
        if two:
            phi[t0 + 1] = f2
        rows[0], rows[1], rows[2] = j, t0, t0 + 1
        for a in range(d + 1):
            ra = rows[a]
            for b in range(d + 1):
                rb = rows[b]
                J[ra, rb] += A[a, b]
                bab = B[a, b]
                if bab != 0.0:
                    for m in range(n):
                        J[ra, m] += bab * W[rb, m]
    return phi, J


@njit(cache=True)
def alart_curnier_csr(indptr, indices, data, u, mu, dims, toff, rhoN, rhoT, p):
    """(Phi, rows, cols, vals) of the Alart-Curnier function at p: J = A + B W as COO triplets
    (duplicates to be summed), W in blocked CSR."""
    k = dims.size
    n = p.size
    phi = np.empty(n)
    cap = 9 * k
    for j in range(k):
        t0 = k + toff[j]
        w = (indptr[j + 1] - indptr[j]) + (indptr[t0 + 1] - indptr[t0])
        if dims[j] == 2:
            w += indptr[t0 + 2] - indptr[t0 + 1]
        cap += (dims[j] + 1) * w
    ri = np.empty(cap, dtype=np.int64)
    ci = np.empty(cap, dtype=np.int64)
    vv = np.empty(cap)
    A = np.empty((3, 3))
    B = np.empty((3, 3))
    rows = np.empty(3, dtype=np.int64)
    m = 0
    for j in range(k):
        t0 = k + toff[j]
        d = dims[j]
        two = d == 2
        f0, f1, f2 = _ac_contact(p[j], p[t0], p[t0 + 1] if two else 0.0, u[j], u[t0], u[t0 + 1] if two else 0.0,
                                 mu[j], rhoN[j], rhoT[j], A, B)
        phi[j] = f0
        phi[t0] = f1
        if two:
            phi[t0 + 1] = f2
        rows[0], rows[1], rows[2] = j, t0, t0 + 1
        for a in range(d + 1):
            ra = rows[a]
            for b in range(d + 1):
                rb = rows[b]
                ri[m] = ra
                ci[m] = rb
                vv[m] = A[a, b]
                m += 1
                bab = B[a, b]
                if bab != 0.0:
                    for e in range(indptr[rb], indptr[rb + 1]):
                        ri[m] = ra
                        ci[m] = indices[e]
                        vv[m] = bab * data[e]
                        m += 1
    return phi, ri[:m], ci[:m], vv[:m]
