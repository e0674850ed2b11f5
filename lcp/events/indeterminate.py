"""Redundant contacts: branches of the acceleration-level problem whose forces are not unique.

Two corners of a box on a floor, the four legs of a table, a block wedged between two walls: the
constraint rows of the closed contacts are linearly dependent, so the Delassus matrix W is only
positive semidefinite and a branch's linear system E p = r (:meth:`ContactProblem.branch_system`)
is singular. The motion is still unique (forces along the null space of E do no work), but the
forces form a polytope

    P = {p : E p = r, G p >= h},

with G p >= h the inequalities of the branch's modes (N >= 0, |f| <= mu N for a stick, the sign of
the sliding acceleration for a slip, a_N >= 0 for an open contact). This module

- solves such a branch: p = p0 + Z z, p0 the least-norm solution of E p = r (SVD) and Z a basis of
  the null space of E; the reported forces are the **least-norm admissible** ones, the projection
  of 0 onto P, found as a least-distance program by Lawson and Hanson's NNLS reduction
  (``scipy.optimize.nnls``), and checked against the Coulomb inequalities afterwards; the friction
  bounds of mu = 0 contacts (f = 0, two opposite rows of G) are held as equalities, as in the
  force margin below;
- measures how far P is from being empty, the **force margin**
  ``max {s : E p = r, G p >= h + s}`` (a linear program), whose zero crossing is the event that
  ends a phase of redundant contacts (onset of slip, or a contact unloading: tipping).

SciPy's optimizers are imported on first use only.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lcp.contact.problem import OPEN, SLIDE_NEG, SLIDE_POS, STICK

__all__ = ["BranchForces", "branch_forces", "admissibility_rows", "force_margin", "RANK_RTOL"]

#: relative singular-value threshold below which a branch is treated as singular
RANK_RTOL = 1e-10


@dataclass(eq=False)
class BranchForces:
    """Forces of one branch: ``p`` (admissible if ``admissible``), the null-space dimension
    ``nullity`` of its linear system (0: unique), and the pieces of the force set (p0, Z)."""

    p: np.ndarray
    nullity: int
    admissible: bool
    p0: np.ndarray
    Z: np.ndarray


def admissibility_rows(pb, modes) -> tuple[np.ndarray, np.ndarray, np.ndarray, list]:
    """Inequalities G p >= h equivalent to ``pb.admissible(p, modes)`` (without its tolerance), a
    mask of the rows that are friction bounds of a contact with mu = 0 (equalities in fact), and
    per row the event its violation means, (kind, contact index in the problem)."""
    k, W, q, mu = pb.k, pb.W, pb.q, pb.mu
    rows, rhs, zero_mu, labels = [], [], [], []

    def add(g, h, label, flag=False):
        rows.append(g)
        rhs.append(h)
        zero_mu.append(flag)
        labels.append((label, j))

    for j, md in enumerate(modes):
        if md == OPEN:
            add(W[j], -q[j], "impact")  # a_N >= 0
            continue
        e = np.zeros(2 * k)
        e[j] = 1.0
        add(e, 0.0, "lift-off")  # N >= 0
        if md == STICK:
            for sgn in (1.0, -1.0):
                g = mu[j] * e
                g[k + j] = -sgn
                add(g, 0.0, "slip", mu[j] == 0.0)  # mu N -+ f >= 0
        elif md in (SLIDE_POS, SLIDE_NEG):
            sgn = 1.0 if md == SLIDE_POS else -1.0
            add(sgn * W[k + j], -sgn * q[k + j], "stop")  # sign of the sliding acceleration
    if not rows:
        return np.zeros((0, 2 * k)), np.zeros(0), np.zeros(0, dtype=bool), []
    return np.array(rows), np.array(rhs), np.array(zero_mu), labels


def _null_split(E, r, info=None):
    """(p0, Z, consistent): least-norm solution of E p = r, null-space basis of E, and whether
    E p0 = r holds to rounding. ``info`` (a dict), if given, receives the numbers the rank and
    consistency decisions were made on (see :func:`branch_forces`)."""
    U, s, Vt = np.linalg.svd(E)
    smax = float(s[0]) if s.size else 0.0
    rank = int(np.sum(s > RANK_RTOL * max(smax, 1e-300)))
    Ur, Vr = U[:, :rank], Vt[:rank].T
    p0 = Vr @ ((Ur.T @ r) / s[:rank])
    Z = Vt[rank:].T
    res = float(np.max(np.abs(E @ p0 - r))) if r.size else 0.0
    scale = float(np.max(np.abs(r))) if r.size else 0.0
    scale = max(scale, smax * (float(np.max(np.abs(p0))) if p0.size else 0.0), 1e-300)
    if info is not None:
        info.update(s=s, smax=smax, res=res, r_max=float(np.max(np.abs(r))) if r.size else 0.0,
                    p0_max=float(np.max(np.abs(p0))) if p0.size else 0.0, consistent=res <= 1e-9 * scale)
    return p0, Z, res <= 1e-9 * scale


def _least_distance(B, c):
    """argmin ||z|| subject to B z >= c, or None if infeasible (Lawson & Hanson, LDP by NNLS)."""
    from scipy.optimize import nnls  # only for redundant contacts

    d = B.shape[1]
    Ematrix = np.vstack([B.T, c[None, :]])
    f = np.zeros(d + 1)
    f[d] = 1.0
    u, _ = nnls(Ematrix, f, maxiter=50 * (B.shape[0] + d + 1))
    res = Ematrix @ u - f
    if abs(res[d]) <= 1e-14 or np.linalg.norm(res) <= 1e-12:
        return None
    return -res[:d] / res[d]


def branch_forces(pb, check_modes, branch_modes, info: dict | None = None) -> BranchForces | None:
    """Forces of one branch of ``pb``: the unique solution when the branch is regular, the
    least-norm admissible one when it is singular; None if the branch's equations are
    inconsistent. ``check_modes`` and ``branch_modes`` are the modes for ``admissible`` and
    ``solve_branch`` (they differ for sliding contacts folded into the problem).

    ``info``, a dict if given, receives what the rank and consistency decisions were made on: the
    singular values ``s`` of the branch matrix and the largest ``smax``, the residual ``res`` of
    the least-norm solution, the largest right-hand side ``r_max`` and force ``p0_max``, and
    ``consistent``. The rank is cut at ``RANK_RTOL * smax`` and the branch is consistent when
    ``res <= 1e-9 * max(r_max, smax * p0_max)`` (:mod:`lcp.events.modes` checks with these that a
    sub-problem decides as the whole problem would)."""
    E, r = pb.branch_system(branch_modes)
    p0, Z, consistent = _null_split(E, r, info)
    if not consistent:
        return None
    if Z.shape[1] == 0:
        p = p0
        return BranchForces(p, 0, pb.admissible(p, check_modes), p0, Z)
    G, h, zero_mu, _ = admissibility_rows(pb, check_modes)
    slack = G @ p0 - h
    tol = 1e-12 * max(pb.scale, float(np.max(np.abs(p0))) if p0.size else 0.0)
    if slack.size == 0 or slack.min() >= -tol:
        p = p0  # p0 (orthogonal to the null space) is already the least-norm admissible point
    else:
        z = _least_distance_eq(G @ Z, -slack, zero_mu, tol)
        if z is None:
            return BranchForces(p0, Z.shape[1], False, p0, Z)
        p = p0 + Z @ z
    return BranchForces(p, Z.shape[1], pb.admissible(p, check_modes), p0, Z)


def _least_distance_eq(B, c, eq, tol):
    """argmin ||z|| subject to B z >= c on the rows not in ``eq`` and B z = c on the rows in
    ``eq`` (the friction bounds of mu = 0 contacts, written as two opposite inequalities), or
    None if infeasible.

    The equalities are not left to the inequality solver: two opposite rows whose right-hand
    sides are rounding (p0's friction force of a frictionless contact is 1e-17, not 0) make an
    empty strip for it, and the least-norm solution p0 (with N < 0) was kept. Here they restrict
    z to an affine subspace, z = z_e + Y w with z_e the least-norm solution (SVD, rank to
    RANK_RTOL: the rows of B have norm <= 1) and Y an orthonormal basis of the rest, so that
    ||z||^2 = ||z_e||^2 + ||w||^2 and the inequalities become a least-distance program in w.
    Equalities that are rounding on both sides (B's row and c below ``tol``) hold already.
    """
    z = _least_distance_rows(B, c, eq, tol)
    return None if z is None else _polish_ldp(B, c, eq, z, tol)


def _polish_ldp(B, c, eq, z, tol):
    """The least-distance point recomputed on its active face: NNLS meets the active rows to about
    1e-12 of the forces (N = -7e-11 of 87 N), which the Coulomb check on a light contact's own
    scale rejects. At the optimum z = B_A' lam (lam >= 0 on the inequalities) with B_A z = c_A, so
    z is the least-norm solution of the active rows: taken when it is feasible to rounding and
    its multipliers have the right signs, else z as it was."""
    slack = B @ z - c
    act = eq | (slack <= 1e4 * tol)
    if not act.any():
        return z
    BA, cA = B[act], c[act]
    zs = np.linalg.lstsq(BA, cA, rcond=RANK_RTOL)[0]
    lam = np.linalg.lstsq(BA.T, zs, rcond=RANK_RTOL)[0]
    sl = B @ zs - c
    if (np.all(sl[~eq] >= -tol) and np.all(np.abs(sl[eq]) <= tol)
            and np.all(lam[~eq[act]] >= -1e-9 * max(float(np.max(np.abs(lam))), 1e-300))):
        return zs
    return z


def _least_distance_rows(B, c, eq, tol):
    """:func:`_least_distance_eq` before its polish."""
    if not eq.any():
        return _least_distance(B, c)
    Be, ce = B[eq], c[eq]
    d = B.shape[1]
    U, s, Vt = np.linalg.svd(Be)
    rank = int(np.sum(s > RANK_RTOL))
    z_e = Vt[:rank].T @ ((U[:, :rank].T @ ce) / s[:rank])
    if np.max(np.abs(Be @ z_e - ce)) > tol:
        return None  # the equalities cannot hold: no admissible forces
    Y = Vt[rank:].T
    Bi, ci = B[~eq], c[~eq] - B[~eq] @ z_e
    if Y.shape[1] == 0 or Bi.shape[0] == 0:
        return z_e if np.all(ci <= tol) else None
    w = _least_distance(Bi @ Y, ci)
    if w is None:
        return None
    return z_e + Y @ w if d else z_e


def force_margin(pb, check_modes, branch_modes) -> tuple[float, np.ndarray, list]:
    """(margin, slack, labels): the largest s with E p = r and G p >= h + s (a linear program;
    negative when the branch has no admissible forces), the slack G p - h of each inequality at
    the optimum and the rows' labels (as in :func:`admissibility_rows`; friction rows of mu = 0
    contacts are held as equalities and excluded from s)."""
    E, r = pb.branch_system(branch_modes)
    p0, Z, _ = _null_split(E, r)
    G, h, zero_mu, labels = admissibility_rows(pb, check_modes)
    base = G @ p0 - h
    if G.shape[0] == 0:
        return np.inf, base, labels
    B = G @ Z
    free = ~zero_mu
    if Z.shape[1] == 0 or not B.any():
        return (float(base[free].min()) if free.any() else np.inf), base, labels
    from scipy.optimize import linprog  # only for redundant contacts

    d = Z.shape[1]
    # variables (z, s): maximise s subject to B z + base >= s on the free rows, B z + base = 0 on
    # the rows of frictionless sticks
    c = np.zeros(d + 1)
    c[d] = -1.0
    A_ub = np.hstack([-B[free], np.ones((int(free.sum()), 1))])
    b_ub = base[free]
    kw = {}
    if zero_mu.any():
        kw = {"A_eq": np.hstack([B[zero_mu], np.zeros((int(zero_mu.sum()), 1))]), "b_eq": -base[zero_mu]}
    scale = max(float(np.max(np.abs(base))), 1.0)
    res = linprog(c, A_ub=A_ub, b_ub=b_ub, bounds=[(None, None)] * d + [(None, scale)], method="highs",
                  options={"primal_feasibility_tolerance": 1e-10, "dual_feasibility_tolerance": 1e-10}, **kw)
    if res.status != 0:
        return -np.inf, base, labels
    z, s_opt = _polish(B, base, zero_mu, res.x[:d], float(res.x[d]), scale)
    return s_opt, B @ z + base, labels


def _polish(B, base, zero_mu, z, s, scale):
    """The LP vertex (z, s) recomputed exactly: HiGHS meets its constraints to its feasibility
    tolerance only, and the margin's zero is an event time. The rows active within that
    tolerance are few: each choice of d + 1 of them (with the equality rows) is solved, and the
    best vertex feasible to rounding is kept."""
    from itertools import combinations

    d = B.shape[1]
    slack = B @ z + base
    eq = [int(i) for i in np.flatnonzero(zero_mu)]
    cand = [int(i) for i in np.argsort(slack - s) if not zero_mu[i] and slack[i] - s <= 1e-6 * scale][:12]
    need = d + 1 - len(eq)
    if need < 0 or len(cand) < need:
        return z, s
    tol = 256 * np.finfo(float).eps * scale
    best = None
    free = ~zero_mu
    for pick in combinations(cand, need):
        rows = eq + list(pick)
        M = np.array([np.append(B[i], 0.0 if zero_mu[i] else -1.0) for i in rows])
        try:
            x = np.linalg.solve(M, -base[rows])
        except np.linalg.LinAlgError:
            continue
        zp, sp = x[:d], float(x[d])
        sl = B @ zp + base
        if not np.all(np.isfinite(x)) or np.any(sl[free] < sp - tol) or (eq and np.max(np.abs(sl[eq])) > tol):
            continue
        if best is None or sp > best[1]:
            best = (zp, sp)
    return best if best is not None and abs(best[1] - s) <= 1e-6 * scale else (z, s)
