"""Compiled kernels of the spatial (Coulomb disk) contact problem: the exact local solve of one
contact, the natural-map residual and the nonsmooth Gauss-Seidel sweep.

A contact j has a normal and d_j in {1, 2} tangent directions. Its local problem, the others held
fixed, is u = W_jj r + q (W_jj of size 1 + d_j); :func:`lcp.contact.kernels.local_disk3` solves it
exactly for d = 2 (the planar case is its twin :func:`lcp.contact.kernels.local_planar`):

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
from lcp.contact.kernels import contact_residual, disk_residual, local_disk3, local_planar, row_dot

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
