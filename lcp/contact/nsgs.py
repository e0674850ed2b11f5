"""Nonsmooth Gauss-Seidel (NSGS) for planar frictional contact, with exact local solves.

For u = W r + q (contact-by-contact order, W in CSR), one sweep visits the contacts in turn and
replaces contact j's impulse by the exact solution of its own one-contact Coulomb problem, the
others held fixed:

    u_j = W_jj r_j + q~_j,    q~_j = q_j + sum_{i != j} W_ji r_i,

solved in closed form by case analysis (open, stick, slide+, slide-, as
:func:`lcp.contact.problem.planar_enum`). Sweeps stop when the natural-map residual (the measure
of :meth:`lcp.contact.problem.ContactProblem.residual`, impulse units, rho = 1/W_ii) is below the
tolerance.

The small per-contact kernels (the local solve, a CSR row times a vector, one contact's natural
map) are inlined into their callers at numba's level: a call per contact would cost more than the
work. The sweep and the local solve are compiled with numba when it is installed (``pip install
lcp-lem[fast]``); otherwise the same functions run as plain Python, correct but slow (one
interpreted step per nonzero). :data:`HAVE_NUMBA` says which.

The local solve is the only place where the contact's dimension enters: a spatial (disk) contact
would add a 3 x 3 local solve beside :func:`local_planar` and dispatch on the block size.
"""
from __future__ import annotations

import math

import numpy as np

from lcp.contact.law import SCALE_FLOOR
from lcp.contact.kernels import contact_residual, contact_scale, local_planar, row_absdot, row_dot
from lcp.numerics.jit import HAVE_NUMBA, njit


__all__ = ["HAVE_NUMBA", "local_planar", "nsgs", "nsgs_sweeps", "residual_interleaved", "stop_measure_interleaved"]

@njit(cache=True)
def stop_measure_interleaved(indptr, indices, data, q, mu, rho, r, rel_scale):
    """max(residual, rel_scale * the largest contact residual relative to its own scale).

    With ``rel_scale`` the problem's impulse scale, ``measure <= 0.1 tol_rel scale`` holds when
    the residual meets the tolerance on the problem's scale and every contact meets it on its own
    (:func:`contact_scale`); 0 gives :func:`residual_interleaved`."""
    k = mu.size
    res = 0.0
    rel = 0.0
    for j in range(k):
        iN = 2 * j
        iT = iN + 1
        uN = q[iN] + row_dot(indptr, indices, data, r, iN)
        uT = q[iT] + row_dot(indptr, indices, data, r, iT)
        c = contact_residual(r[iN], r[iT], uN, uT, mu[j], rho[iN], rho[iT])
        res = max(res, c)
        if rel_scale > 0.0 and c > 0.0:
            sc = contact_scale(r[iN], r[iT], q[iN], q[iT], rho[iN], rho[iT],
                                row_absdot(indptr, indices, data, r, iN), row_absdot(indptr, indices, data, r, iT),
                                SCALE_FLOOR * rel_scale)
            rel = max(rel, c / sc)
    return max(res, rel_scale * rel)


@njit(cache=True)
def residual_interleaved(indptr, indices, data, q, mu, rho, r):
    """max over contacts of the natural-map residual (ContactProblem.residual's measure)."""
    return stop_measure_interleaved(indptr, indices, data, q, mu, rho, r, 0.0)


@njit(cache=True)
def nsgs_sweeps(indptr, indices, data, blocks, q, mu, rho, r, tol, max_sweeps, rel_scale=0.0):
    """Sweep until the stopping measure is <= tol; returns (sweeps, measure, local failures).

    The measure is :func:`stop_measure_interleaved` (the natural-map residual when ``rel_scale``
    is 0). ``blocks[j] = (W_NN, W_NT, W_TN, W_TT)`` of contact j; ``r`` is updated in place. The
    measure is evaluated only when a sweep's largest change falls below ``tol`` (it costs a sweep).
    """
    k = mu.size
    res = np.inf
    fails = 0
    sweep = 0
    for sweep in range(1, max_sweeps + 1):
        change = 0.0
        fails = 0
        for j in range(k):
            iN = 2 * j
            iT = iN + 1
            W00, W01, W10, W11 = blocks[j, 0], blocks[j, 1], blocks[j, 2], blocks[j, 3]
            rN, rT = r[iN], r[iT]
            qN = q[iN] + row_dot(indptr, indices, data, r, iN) - W00 * rN - W01 * rT
            qT = q[iT] + row_dot(indptr, indices, data, r, iT) - W10 * rN - W11 * rT
            if W00 <= 0.0:  # a contact that no impulse moves: leave it
                fails += 1
                continue
            pN, pT, mode = local_planar(W00, W01, W10, W11, qN, qT, mu[j])
            if mode < 0:
                # no closed-form case (a Painleve-type local block): one projected natural-map step
                fails += 1
                uN = W00 * rN + W01 * rT + qN
                uT = W10 * rN + W11 * rT + qT
                pN = max(rN - rho[iN] * uN, 0.0)
                s = mu[j] * pN
                pT = min(max(rT - rho[iT] * uT, -s), s)
            change = max(change, abs(pN - rN), abs(pT - rT))
            r[iN] = pN
            r[iT] = pT
        if change <= tol:
            res = stop_measure_interleaved(indptr, indices, data, q, mu, rho, r, rel_scale)
            if res <= tol:
                return sweep, res, fails
    res = stop_measure_interleaved(indptr, indices, data, q, mu, rho, r, rel_scale)
    return sweep, res, fails


class InterleavedOperator:
    """W in contact-by-contact CSR order with its diagonal 2 x 2 blocks and natural-map weights.

    Built once per operator (solvers cache it on :attr:`ContactProblem.key`).

    Parameters
    ----------
    W : ndarray or scipy.sparse matrix, shape (2k, 2k), blocked order (normals, tangents)
    """

    def __init__(self, W):
        import scipy.sparse as sp

        from lcp.contact.law import interleave

        n = W.shape[0]
        k = n // 2
        perm = interleave(k)
        Wi = sp.csr_matrix(W)[perm][:, perm] if sp.issparse(W) else sp.csr_matrix(np.asarray(W)[np.ix_(perm, perm)])
        Wi.sort_indices()
        self.k, self.perm = k, perm
        self.indptr = Wi.indptr.astype(np.int64)
        self.indices = Wi.indices.astype(np.int64)
        self.data = Wi.data.astype(float)
        d = Wi.diagonal()
        self.blocks = np.empty((k, 4))
        self.blocks[:, 0] = d[0::2]
        self.blocks[:, 3] = d[1::2]
        even = 2 * np.arange(k)
        self.blocks[:, 1] = np.asarray(Wi[even, even + 1]).ravel()
        self.blocks[:, 2] = np.asarray(Wi[even + 1, even]).ravel()
        self.rho = np.where(d > 0, 1.0 / np.where(d > 0, d, 1.0), 1.0)
        self.nnz = Wi.nnz

    def fits(self, problem) -> bool:
        """Whether this operator can be the one of ``problem`` (a warm start kept on its key)."""
        return self.k == problem.k

    def sweeps(self, q, mu, r0, tol, max_sweeps, compiled=True, rel_scale=0.0):
        """:func:`nsgs` on this operator."""
        return nsgs(self, q, mu, r0, tol, max_sweeps, compiled, rel_scale)


def nsgs(op: InterleavedOperator, q, mu, r0=None, tol: float = 1e-12, max_sweeps: int = 10000,
         compiled: bool = True, rel_scale: float = 0.0):
    """Run NSGS on an :class:`InterleavedOperator` (all vectors in contact-by-contact order).

    Stops when :func:`stop_measure_interleaved` (with ``rel_scale``; 0: the natural-map residual)
    is <= tol. Returns (r, sweeps, measure, local_failures): local_failures counts the contacts of
    the last sweep whose local problem had no closed-form case (a projected step was taken instead).
    """
    r = np.zeros(2 * op.k) if r0 is None else np.array(r0, dtype=float)
    # without numba every function is plain Python already; compiled=False asks for the
    # interpreted sweep explicitly (its helpers stay whatever is installed)
    fn = nsgs_sweeps if compiled else getattr(nsgs_sweeps, "py_func", nsgs_sweeps)
    sweeps, res, fails = fn(op.indptr, op.indices, op.data, op.blocks, np.asarray(q, dtype=float),
                            np.asarray(mu, dtype=float), op.rho, r, float(tol), int(max_sweeps), float(rel_scale))
    return r, int(sweeps), float(res), int(fails)


@njit(cache=True)
def residual_blocked_dense(W, q, mu, rho, p):
    """ContactProblem.residual's natural map for a dense W in blocked order (normals first)."""
    k = mu.size
    n = 2 * k
    res = 0.0
    for j in range(k):
        uN = q[j]
        uT = q[k + j]
        for i in range(n):
            uN += W[j, i] * p[i]
            uT += W[k + j, i] * p[i]
        res = max(res, contact_residual(p[j], p[k + j], uN, uT, mu[j], rho[j], rho[k + j]))
    return res


@njit(cache=True)
def residual_blocked_csr(indptr, indices, data, q, mu, rho, p):
    """ContactProblem.residual's natural map for a CSR W in blocked order (normals first)."""
    k = mu.size
    res = 0.0
    for j in range(k):
        uN = q[j] + row_dot(indptr, indices, data, p, j)
        uT = q[k + j] + row_dot(indptr, indices, data, p, k + j)
        res = max(res, contact_residual(p[j], p[k + j], uN, uT, mu[j], rho[j], rho[k + j]))
    return res


@njit(cache=True, inline="always")
def _contact_checks(pN, pT, uN, uT, qN, qT, mu, rhoN, rhoT, aN, aT, floor):
    """One contact's terms of ContactProblem.checks: (residual, relative residual, squared
    natural-map error of lcp.contact.law.natural_map_error)."""
    c = contact_residual(pN, pT, uN, uT, mu, rhoN, rhoT)
    rel = c / contact_scale(pN, pT, qN, qT, rhoN, rhoT, aN, aT, floor) if c > 0.0 else 0.0
    zN = pN - uN - mu * abs(uT)
    zT = pT - uT
    az = abs(zT)
    if az <= mu * zN and zN >= 0.0:  # zN >= 0: mu = 0 would accept any zN < 0 with zT = 0
        xN, xT = zN, zT
    elif mu * az <= -zN:
        xN, xT = 0.0, 0.0
    else:
        xN = (zN + mu * az) / (1.0 + mu * mu)
        xT = mu * xN if zT >= 0.0 else -mu * xN
    return c, rel, (pN - xN) ** 2 + (pT - xT) ** 2


@njit(cache=True)
def _checks_from_velocity(q, mu, rho, p, u, a, floor):
    """ContactProblem.checks from the local velocity u = W p + q and a = |W| |p| (blocked order)."""
    k = mu.size
    res = 0.0
    rel = 0.0
    e2 = 0.0
    nr = 0.0
    nu = 0.0
    nq = 0.0
    for j in range(k):
        c, r, e = _contact_checks(p[j], p[k + j], u[j], u[k + j], q[j], q[k + j], mu[j], rho[j], rho[k + j],
                                  a[j], a[k + j], floor)
        res = max(res, c)
        rel = max(rel, r)
        e2 += e
        nr += p[j] * p[j] + p[k + j] * p[k + j]
        nu += u[j] * u[j] + u[k + j] * u[k + j]
        nq += q[j] * q[j] + q[k + j] * q[k + j]
    scale = max(math.sqrt(nr), math.sqrt(nu), math.sqrt(nq))
    err = math.sqrt(e2)
    return res, rel, err / scale if scale > 2.220446049250313e-16 else err


@njit(cache=True)
def checks_blocked_csr(indptr, indices, data, q, mu, rho, p, floor):
    """(residual, relative residual, natural-map error) of p for a CSR W in blocked order, in one
    pass over W (ContactProblem.checks)."""
    n = q.size
    u = q.copy()
    a = np.zeros(n)
    for i in range(n):
        for t in range(indptr[i], indptr[i + 1]):
            x = data[t] * p[indices[t]]
            u[i] += x
            a[i] += abs(x)
    return _checks_from_velocity(q, mu, rho, p, u, a, floor)


@njit(cache=True)
def checks_blocked_dense(W, q, mu, rho, p, floor):
    """:func:`checks_blocked_csr` for a dense W."""
    n = q.size
    u = q.copy()
    a = np.zeros(n)
    for i in range(n):
        for c in range(n):
            x = W[i, c] * p[c]
            u[i] += x
            a[i] += abs(x)
    return _checks_from_velocity(q, mu, rho, p, u, a, floor)


@njit(cache=True)
def contact_scales_blocked_csr(indptr, indices, data, q, rho, p, floor):
    """ContactProblem.contact_scales for a CSR W in blocked order."""
    k = q.size // 2
    out = np.empty(k)
    for j in range(k):
        aN = row_absdot(indptr, indices, data, p, j)
        aT = row_absdot(indptr, indices, data, p, k + j)
        out[j] = contact_scale(p[j], p[k + j], q[j], q[k + j], rho[j], rho[k + j], aN, aT, floor)
    return out
