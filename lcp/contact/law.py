"""Frictional contact problems of any size: the contact-by-contact layout, the independent error
measure, and the checks made before any solve.

:class:`~lcp.contact.problem.ContactProblem` orders impulses by kind, ``p = (p_N,1..p_N,k,
p_T,1..p_T,k)``; iterative solvers and the problem files of the community (FCLib, Siconos) order
them contact by contact, ``r = (r_N,1, r_T,1, r_N,2, r_T,2, ...)``. :func:`interleave` maps one
order to the other. :func:`natural_map_error` is the error every solver result reports,
computed from (W, q, mu, r) alone:

    u = W r + q,   u~_j = (u_N,j + mu_j |u_T,j|, u_T,j)   (the modified velocity),
    err = || r - proj_K(r - u~) ||_2 / max(||r||_2, ||u||_2, ||q||_2),

with K the product of the planar Coulomb cones {|r_T| <= mu r_N}. It is zero exactly at the
solutions of the discrete Coulomb law, and it is normalised as Siconos normalises its fc2d error
(by the largest of the norms of r, u and q, unless all are below machine epsilon), so that the
numbers compare directly with that library's.
"""
from __future__ import annotations

import numpy as np

from lcp.numerics.lazy import issparse
from lcp.numerics.lazy import sparse as sp

#: floor of a contact's impulse scale (:meth:`lcp.contact.problem.ContactProblem.contact_scales`), as
#: a fraction of rho times the terms its velocity is summed from (the row of |W| |p|): a contact with
#: (almost) no impulse and no free velocity of its own is measured against the rounding of those
#: terms, not against nothing
COUPLING_FLOOR = 1e-2
#: and as a fraction of the problem's impulse scale: contacts 1e12 below it (a body 1e12 times
#: lighter than the heaviest) are still solved on their own scale, while a contact that carries
#: nothing and feels only the 1e-30 impulses of its neighbours is not asked for more than that
SCALE_FLOOR = 1e-12

__all__ = ["COUPLING_FLOOR", "SCALE_FLOOR", "ProblemCheck", "blocked", "check_problem", "interleave", "natural_map_error"]


def interleave(k: int) -> np.ndarray:
    """Permutation ``perm`` with ``x_interleaved = x_blocked[perm]`` for k planar contacts.

    Examples
    --------
    >>> from lcp.contact.law import interleave
    >>> interleave(3)
    array([0, 3, 1, 4, 2, 5])
    """
    perm = np.empty(2 * k, dtype=np.int64)
    perm[0::2] = np.arange(k)
    perm[1::2] = k + np.arange(k)
    return perm


def blocked(k: int) -> np.ndarray:
    """Inverse of :func:`interleave`: ``x_blocked = x_interleaved[blocked(k)]``."""
    return np.argsort(interleave(k))


def planar_cone_projection(zN, zT, mu):
    """Projection of (zN, zT) onto {|r_T| <= mu r_N}, contact by contact (arrays)."""
    aT = np.abs(zT)
    # zN >= 0 too: with mu = 0 the test aT <= mu zN alone holds for any zN < 0 when zT = 0
    inside = (aT <= mu * zN) & (zN >= 0)
    polar = mu * aT <= -zN  # in the polar cone: projects to the apex
    rN = (zN + mu * aT) / (1.0 + mu * mu)
    pN = np.where(inside, zN, np.where(polar, 0.0, rN))
    pT = np.where(inside, zT, np.where(polar, 0.0, mu * rN * np.sign(zT)))
    return pN, pT


def natural_map_error(W, q, mu, r, order: str = "blocked", dims=None) -> float:
    """The normalised natural-map error of impulses r for the problem u = W r + q.

    Parameters
    ----------
    W : ndarray or scipy.sparse matrix, shape (2k, 2k)
    q : ndarray, shape (2k,)
    mu : ndarray, shape (k,)
    r : ndarray, shape (2k,)
    order : {"blocked", "interleaved"}
        ``"blocked"``: (p_N..., p_T...) as :class:`~lcp.contact.problem.ContactProblem`;
        ``"interleaved"``: (r_N,1, r_T,1, ...) as the problem files.
    dims : array of int, shape (k,), optional
        Tangent dimension of each contact (1 or 2; :class:`~lcp.contact.spatial_problem.ConeContactProblem`'s
        layout, W, q and r of size k + sum(dims)). None: every contact planar. A 2-D tangent's cone
        is the disk cone {|r_T| <= mu r_N}, projected onto in closed form.

    Returns
    -------
    float
        ||r - proj_K(r - u~)|| / max(||r||, ||u||, ||q||) (see the module docstring); NaN if r
        is not finite.

    Examples
    --------
    >>> import numpy as np
    >>> from lcp.contact.law import natural_map_error
    >>> natural_map_error(np.eye(2), np.array([-1.0, 2.0]), np.array([0.5]), np.array([1.0, -0.5]))
    0.0
    """
    mu = np.atleast_1d(np.asarray(mu, dtype=float))
    k = mu.size
    r = np.asarray(r, dtype=float)
    q = np.asarray(q, dtype=float)
    if dims is not None:
        return _cone_natural_map_error(W, q, mu, r, order, dims)
    if r.shape != (2 * k,) or q.shape != (2 * k,):
        raise ValueError(f"r and q must have shape ({2 * k},), got {r.shape} and {q.shape}")
    if order not in ("blocked", "interleaved"):
        raise ValueError(f"order must be 'blocked' or 'interleaved', got {order!r}")
    if not np.all(np.isfinite(r)):
        return float("nan")
    u = W @ r + q
    if order == "blocked":
        rN, rT, uN, uT = r[:k], r[k:], u[:k], u[k:]
    else:
        rN, rT, uN, uT = r[0::2], r[1::2], u[0::2], u[1::2]
    # r - proj_K(r - u~), u~ = (u_N + mu |u_T|, u_T)
    pN, pT = planar_cone_projection(rN - uN - mu * np.abs(uT), rT - uT, mu)
    err = float(np.sqrt(np.sum((rN - pN) ** 2) + np.sum((rT - pT) ** 2)))
    scale = max(float(np.linalg.norm(r)), float(np.linalg.norm(u)), float(np.linalg.norm(q)))
    return err / scale if scale > np.finfo(float).eps else err


def _disk_cone_projection(zN, zT, mu):
    """Projection of (zN, zT) onto {|r_T| <= mu r_N}, zT of shape (k, 2) (rows padded with 0)."""
    aT = np.hypot(zT[:, 0], zT[:, 1])
    inside = (aT <= mu * zN) & (zN >= 0)  # zN >= 0: see planar_cone_projection
    polar = mu * aT <= -zN
    rN = (zN + mu * aT) / (1.0 + mu * mu)
    f = np.where(inside | polar, 0.0, mu * rN / np.where(aT > 0, aT, 1.0))
    pN = np.where(inside, zN, np.where(polar, 0.0, rN))
    pT = np.where(inside[:, None], zT, zT * f[:, None])
    return pN, pT


def _cone_natural_map_error(W, q, mu, r, order, dims):
    """natural_map_error for contacts of tangent dimension 1 or 2 (the disk cone)."""
    dims = np.atleast_1d(np.asarray(dims))
    k = mu.size
    if dims.shape != (k,) or not np.all(np.isin(dims, (1, 2))):
        raise ValueError(f"dims must hold 1 or 2 for each of the {k} contacts, got {dims}")
    n = k + int(dims.sum())
    if r.shape != (n,) or q.shape != (n,):
        raise ValueError(f"r and q must have shape ({n},), got {r.shape} and {q.shape}")
    if order not in ("blocked", "interleaved"):
        raise ValueError(f"order must be 'blocked' or 'interleaved', got {order!r}")
    if not np.all(np.isfinite(r)):
        return float("nan")
    u = W @ r + q
    toff = np.concatenate([[0], np.cumsum(dims)[:-1]]).astype(int)
    if order == "blocked":
        iN, iT0 = np.arange(k), k + toff
    else:
        iN = toff + np.arange(k)
        iT0 = iN + 1
    two = dims == 2
    iT1 = np.where(two, iT0 + 1, 0)

    def split(x):
        xT = np.zeros((k, 2))
        xT[:, 0] = x[iT0]
        xT[:, 1] = np.where(two, x[iT1], 0.0)
        return x[iN], xT

    rN, rT = split(r)
    uN, uT = split(u)
    # r - proj_K(r - u~), u~ = (u_N + mu |u_T|, u_T)
    pN, pT = _disk_cone_projection(rN - uN - mu * np.hypot(uT[:, 0], uT[:, 1]), rT - uT, mu)
    err = float(np.sqrt(np.sum((rN - pN) ** 2) + np.sum((rT - pT) ** 2)))
    scale = max(float(np.linalg.norm(r)), float(np.linalg.norm(u)), float(np.linalg.norm(q)))
    return err / scale if scale > np.finfo(float).eps else err


class ProblemCheck:
    """What :func:`check_problem` found: ``errors`` make a problem unsolvable, ``warnings`` do not.

    Attributes
    ----------
    errors, warnings : list of str
    symmetry : float
        max |W - W'| / max |W|.
    min_eigenvalue : float or None
        Smallest eigenvalue of (W + W')/2 relative to max |W| (None where W is too large for a
        dense eigenvalue computation; then only necessary conditions are checked).
    """

    def __init__(self):
        self.errors: list[str] = []
        self.warnings: list[str] = []
        self.symmetry = 0.0
        self.min_eigenvalue = None

    @property
    def ok(self) -> bool:
        return not self.errors

    def __repr__(self):
        return f"ProblemCheck(errors={self.errors}, warnings={self.warnings})"


def check_problem(W, q, mu, name: str = "problem", sym_tol: float = 1e-5, psd_tol: float = 1e-9,
                  dense_limit: int = 4096, dims=None) -> ProblemCheck:
    """Check a local problem (W, q, mu) before any solve.

    Sizes that disagree, negative or non-finite mu, non-finite entries of W or q are errors;
    an unsymmetric W (beyond ``sym_tol`` relative: files written with 6 digits are not exactly
    symmetric) and a W that is not positive semi-definite (smallest eigenvalue of its symmetric
    part below ``-psd_tol`` relative, computed densely up to ``dense_limit`` rows; above that,
    negative diagonal entries and 2 x 2 minors) are warnings. ``dims`` (tangent dimension 1 or 2
    per contact, None: all planar) sets the expected size k + sum(dims).

    Examples
    --------
    >>> import numpy as np
    >>> from lcp.contact.law import check_problem
    >>> check_problem(np.eye(2), np.zeros(2), [-0.1]).errors
    ['problem: friction coefficients must be >= 0 (min -0.1)']
    """
    out = ProblemCheck()
    mu = np.atleast_1d(np.asarray(mu, dtype=float))
    q = np.asarray(q, dtype=float)
    k = mu.size
    shape = W.shape if hasattr(W, "shape") else np.shape(W)
    n = 2 * k
    if dims is not None:
        dims = np.atleast_1d(np.asarray(dims))
        if dims.shape != (k,) or not np.all(np.isin(dims, (1, 2))):
            out.errors.append(f"{name}: dims must hold 1 or 2 for each of the {k} contacts, got {dims}")
            return out
        n = k + int(dims.sum())
    if shape != (n, n) or q.shape != (n,):
        out.errors.append(f"{name}: sizes disagree: {k} friction coefficients need W ({n}, {n}) "
                          f"and q ({n},), got W {shape} and q {q.shape}")
        return out
    if not np.all(np.isfinite(mu)):
        out.errors.append(f"{name}: friction coefficients must be finite")
    elif k and mu.min() < 0:
        out.errors.append(f"{name}: friction coefficients must be >= 0 (min {mu.min():.3g})")
    data = W.data if issparse(W) else np.asarray(W)
    if not np.all(np.isfinite(data)):
        out.errors.append(f"{name}: W has non-finite entries")
    if not np.all(np.isfinite(q)):
        out.errors.append(f"{name}: q has non-finite entries")
    if out.errors or k == 0:
        return out
    Wabs = float(abs(W).max()) if data.size else 0.0
    if Wabs == 0.0:
        out.warnings.append(f"{name}: W is zero")
        return out
    asym = W - W.T
    out.symmetry = float(abs(asym).max()) / Wabs if (asym.nnz if issparse(asym) else True) else 0.0
    if out.symmetry > sym_tol:
        out.warnings.append(f"{name}: W is not symmetric (max |W - W'| / max |W| = {out.symmetry:.3g})")
    diag = W.diagonal() if issparse(W) else np.diag(W)
    if np.any(diag < -psd_tol * Wabs):
        out.warnings.append(f"{name}: W has negative diagonal entries: not positive semi-definite")
    if n <= dense_limit:
        Wd = W.toarray() if issparse(W) else np.asarray(W, dtype=float)
        lam = float(np.linalg.eigvalsh(0.5 * (Wd + Wd.T))[0]) / Wabs
        out.min_eigenvalue = lam
        if lam < -psd_tol:
            out.warnings.append(f"{name}: W is not positive semi-definite (smallest eigenvalue "
                                f"{lam:.3g} of max |W|)")
    else:
        Wc = sp.coo_matrix(W)
        dpos = np.maximum(diag, 0.0)
        bad = Wc.data ** 2 > dpos[Wc.row] * dpos[Wc.col] * (1 + 1e-6) + (psd_tol * Wabs) ** 2
        if np.any(bad):
            out.warnings.append(f"{name}: W has {int(bad.sum())} entries with W_ij^2 > W_ii W_jj: "
                                "not positive semi-definite")
    return out
