"""Spatial contacts in the event integrator: the system at a state, the phase accelerations, and
the acceleration- and velocity-level disk problems that decide the modes at events.

A closed contact j (gap 0, normal velocity 0) sticks (U_j = 0, friction f_j an unknown of the
disk |f_j| <= mu_j N_j) or slides in a direction d_j (|d_j| = 1, f_j = -mu_j N_j d_j). With the
sliding contacts' friction folded into their normal column, ``D_j = H_N,j' - mu_j H_T,j' d_j``, the
contact accelerations are affine in the unknowns (the normal forces, the sticking contacts'
friction): a = W p + b, W = H_c S D, b = H_c qdd_free + Hdot_c v (S the inverse mass matrix with
the bilateral constraints eliminated).

- In a smooth phase the closed normals and the sticking tangents are held at zero acceleration:
  one small linear solve per evaluation (:meth:`SpatialModel.phase_accel`).
- At an event, the acceleration-level disk problem (:class:`AccelDisk`) is the Coulomb disk law
  with forces and accelerations in place of impulses and velocities, in the layout of
  :class:`lcp.contact.spatial_problem.ConeContactProblem`; a sliding contact keeps its direction and enters
  with friction 0 in the problem (its friction is in its normal column). A contact at rest may
  stick, open, or start to slide: it then slides along its tangential acceleration, a_T = lambda d
  with lambda > 0, and d is the new slip direction.

One closed contact is solved by enumerating every case (open, stick, and every slide direction:
the roots of the parallelism condition on the circle), so that no solution and several solutions
(Painleve) are detected. Several closed contacts are solved by nonsmooth Gauss-Seidel with the
exact local disk solve (:func:`lcp.contact.spatial_nsgs.cone_nsgs`), refined on the branch of its modes; one
solution, without a uniqueness check.
"""
from __future__ import annotations

import math

import numpy as np

from lcp.contact.problem import OPEN, SLIDE, SLIDE_NEG, SLIDE_POS, STICK
from lcp.events.model import ContactKinematics, accel_arrays

__all__ = ["AccelDisk", "DiskSolution", "Frame", "SpatialModel", "impact_impulse"]


class Frame:
    """What the contact equations need at one state: H (all rows), Hdot v, gaps, qdd_free and
    SH = S H' (accelerations produced by unit forces along each row of H); for moving contacts
    ``b`` = (dg/dt, ds/dt), the local velocities being u = H v + b (None: fixed contacts, b = 0)."""

    __slots__ = ("A", "H", "Hdv", "SH", "b", "gap", "qdd_free")

    def __init__(self, H, Hdv, gap, qdd_free, SH, A, b=None):
        self.H, self.Hdv, self.gap, self.qdd_free, self.SH, self.A = H, Hdv, gap, qdd_free, SH, A
        self.b = b

    def velocity(self, v, rows=None):
        """Local velocities u = H v + b of the rows ``rows`` of H (all rows for None)."""
        if rows is None:
            return self.H @ v if self.b is None else self.H @ v + self.b
        u = self.H[rows] @ v
        return u if self.b is None else u + self.b[rows]


class SpatialModel(ContactKinematics):
    """Evaluates a System with spatial contacts; constant parts are assembled once.

    Parameters
    ----------
    system : lcp.model.system.System

    Examples
    --------
    >>> import lcp
    >>> from lcp.events.spatial_modes import SpatialModel
    >>> sc = lcp.scenes.plane_slide()
    >>> model = SpatialModel(sc.system)
    >>> model.frame(0.0, sc.q0, sc.v0).qdd_free.tolist(), model.trows[0].tolist()
    ([0.0, 0.0, -9.81], [1, 2])
    """

    def __init__(self, system):
        self.sys = system
        n, m = system.n, system.n_contacts
        self.n, self.m, self.nb = n, m, system.n_bilateral
        self.init_kinematics(system)
        self.dims = system.tangent_dims.copy()
        off = system.tangent_offsets
        #: rows of H holding contact j's tangent directions
        self.trows = [np.arange(m + off[j], m + off[j + 1]) for j in range(m)]
        self.mu = system.mu.copy()
        self.e = system.e.copy()
        self.constant = bool(system.mass_is_constant and system.kinematics_is_constant)
        self.affine_force = bool(system.force_is_affine and not system.force_depends_on_t)
        if self.constant:
            z = np.zeros(n)
            A, F, G, zeta, H, _Hdv, gap = self._evaluate(0.0, z, z)
            self.A, self.H, self.G = A, H, G
            self.gap0 = gap
            self.HN = H[:m]
            K = self._kkt(A, G)
            inv = np.linalg.solve(K, np.eye(K.shape[0]))
            self.S = inv[:n, :n]
            self.zeta_acc = inv[:n, n:] @ (-zeta) if self.nb else np.zeros(n)
            self.SH = self.S @ H.T
            self.Hdv = np.zeros(H.shape[0])
            if self.affine_force:
                _, _, K0, C0, *_ = (np.asarray(x, dtype=float) for x in system.step_data_fn(0.0, z, z))
                self.F0 = F
                self.Kq, self.Cv = -K0.reshape(n, n), -C0.reshape(n, n)
                self.acc0 = self.S @ F + self.zeta_acc
                self.accq = self.S @ self.Kq
                self.accv = self.S @ self.Cv
                self.state_force = bool(system.force_depends_on_state)

    def _kkt(self, A, G):
        nb = self.nb
        return np.block([[A, G.T], [G, np.zeros((nb, nb))]]) if nb else A

    def _evaluate(self, t, q, v):
        n, nb = self.n, self.nb
        A, F, G, zeta, H, Hdv, gap = accel_arrays(self.sys, t, q, v)
        return (A.reshape(n, n), F.ravel(), G.reshape(nb, n), zeta.ravel(), H.reshape(-1, n), Hdv.ravel(),
                gap.ravel())

    def frame(self, t, q, v) -> Frame:
        """The contact data at (t, q, v)."""
        if self.constant:
            gap = self.gap0 + self.HN @ q if self.m else self.gap0
            if self.affine_force:
                qdd = self.acc0 + self.accq @ q + self.accv @ v if self.state_force else self.acc0
            else:
                F = np.array(self.sys.force_fn(t, q, v), dtype=float).ravel()
                qdd = self.S @ F + self.zeta_acc
            return Frame(self.H, self.Hdv, gap, qdd, self.SH, self.A)
        A, F, G, zeta, H, Hdv, gap = self._evaluate(t, q, v)
        n = self.n
        K = self._kkt(A, G)
        rhs = np.zeros((K.shape[0], H.shape[0] + 1))
        rhs[:n, :-1] = H.T
        rhs[:n, -1] = F
        if self.nb:
            rhs[n:, -1] = -zeta
        X = np.linalg.solve(K, rhs)[:n]
        b = self.sys.contact_rates(q, t) if self.moving else None
        return Frame(H, Hdv, gap, X[:, -1], X[:, :-1], A, b)

    # ------------------------------------------------------------------ smooth phases
    def columns(self, fr: Frame, idx, stick, dirs):
        """Unknowns of a phase (closed contacts ``idx``; ``stick[i]``; ``dirs[i]`` the sliding
        direction): (S D, constraint rows of H, slices of N and of each sticking f in x)."""
        SH, mu = fr.SH, self.mu
        cols, rows = [], []
        for i, j in enumerate(idx):
            c = SH[:, j]
            if not stick[i]:
                c = c - mu[j] * (SH[:, self.trows[j]] @ dirs[i])
            cols.append(c)
            rows.append(j)
        for i, j in enumerate(idx):
            if stick[i]:
                cols.extend(SH[:, r] for r in self.trows[j])
                rows.extend(self.trows[j].tolist())
        SD = np.column_stack(cols) if cols else np.zeros((self.n, 0))
        return SD, np.array(rows, dtype=int)

    def phase_accel(self, fr: Frame, idx, stick, dirs):
        """(qdd, N (closed), f (tangent rows of the sticking contacts), singular) of the phase's modes."""
        if not len(idx):
            return fr.qdd_free, np.zeros(0), np.zeros(0), False
        SD, rows = self.columns(fr, idx, stick, dirs)
        Hr = fr.H[rows]
        M = Hr @ SD
        rhs = -(Hr @ fr.qdd_free + fr.Hdv[rows])
        singular = False
        if self.kinematic and len(idx) > 1:
            # a rigid body's redundant contacts (four corners of a face): the least-norm forces
            x, _, rank, _ = np.linalg.lstsq(M, rhs, rcond=1e-10)
            singular = rank < M.shape[0]
        else:
            try:
                x = np.linalg.solve(M, rhs)
            except np.linalg.LinAlgError:
                x = np.linalg.lstsq(M, rhs, rcond=None)[0]
                singular = True
        qdd = fr.qdd_free + SD @ x
        if self.constant:
            # a flat contact at rest stays exactly at rest (a coordinate fixed by one row)
            for r, row in zip(rows.tolist(), Hr):
                nz = np.flatnonzero(row)
                if nz.size == 1:
                    qdd[nz[0]] = 0.0
        k = len(idx)
        return qdd, x[:k], x[k:], singular


_SCAN = []


def _scan_angles():
    """The 1441 angles of the scan for sliding directions from rest, with their cosines and sines
    (those of :func:`math.cos` and :func:`math.sin`, as in the scalar function), computed once."""
    if not _SCAN:
        ths = np.linspace(-math.pi, math.pi, 1441)
        _SCAN.append((ths, np.array([math.cos(t) for t in ths]), np.array([math.sin(t) for t in ths])))
    return _SCAN[0]


class DiskSolution:
    """One solution of the acceleration-level disk problem.

    ``modes``: per closed contact OPEN / STICK / SLIDE (or SLIDE_POS / SLIDE_NEG for a planar
    contact); ``dirs``: per closed contact the sliding direction (None unless sliding); ``p`` the
    unknowns (blocked: normals, then the tangent components contact by contact), ``qdd``.
    """

    def __init__(self, modes, dirs, p, qdd):
        self.modes, self.dirs, self.p, self.qdd = tuple(modes), list(dirs), p, qdd

    def __repr__(self):
        return f"DiskSolution(modes={self.modes}, dirs={self.dirs})"


def _slide_mode(d):
    if d.size == 1:
        return SLIDE_POS if d[0] > 0 else SLIDE_NEG
    return SLIDE


class AccelDisk:
    """The acceleration-level disk problem of the closed contacts ``idx`` at one state.

    ``dirs[i]`` is the sliding direction U/|U| of closed contact i, or None when it is at rest.
    W, b and mu' (0 for sliding contacts) are in the blocked layout of
    :class:`lcp.contact.spatial_problem.ConeContactProblem`.
    """

    def __init__(self, model: SpatialModel, fr: Frame, idx, dirs):
        self.model, self.fr = model, fr
        self.idx = idx = [int(j) for j in idx]
        self.dirs = dirs
        self.k = len(idx)
        mu = model.mu
        self.dims = np.array([model.dims[j] for j in idx], dtype=np.int64)
        trows = [model.trows[j] for j in idx]
        rows = idx + [r for tr in trows for r in tr.tolist()]
        self.rows = np.array(rows, dtype=int)
        cols = []
        for i, j in enumerate(idx):
            c = fr.SH[:, j]
            if dirs[i] is not None:
                c = c - mu[j] * (fr.SH[:, trows[i]] @ dirs[i])
            cols.append(c)
        for tr in trows:
            cols.extend(fr.SH[:, r] for r in tr)
        self.SD = np.column_stack(cols)
        Hr = fr.H[self.rows]
        self.W = Hr @ self.SD
        self.b = Hr @ fr.qdd_free + fr.Hdv[self.rows]
        self.mu = np.array([0.0 if dirs[i] is not None else mu[j] for i, j in enumerate(idx)])
        self.mu_true = mu[idx]
        self.toff = np.concatenate([[0], np.cumsum(self.dims)]).astype(int)
        self.scale_a = max(float(np.max(np.abs(self.b))), float(np.max(np.abs(fr.qdd_free))), 1e-300)

    def qdd(self, p):
        return self.fr.qdd_free + self.SD @ p

    def tangent(self, x, i):
        """Contact i's tangential part of a blocked vector."""
        k = self.k
        return x[k + self.toff[i]:k + self.toff[i + 1]]

    # --------------------------------------------------------------- solutions
    def solutions(self):
        """Every solution for one closed contact; one (NSGS) for several. List of DiskSolution."""
        if self.k == 1:
            return self._single()
        return self._nsgs()

    def _single(self):
        W, b, k = self.W, self.b, 1
        d_slide = self.dirs[0]
        scale = max(float(np.max(np.abs(b))) / max(abs(W[0, 0]), float(np.max(np.abs(W))), 1e-300), 1e-300)
        tol = 1e-11 * scale
        atol = 1e-11 * max(float(np.max(np.abs(b))), 1e-300)
        sols = []
        n = W.shape[0]
        if b[0] >= -atol:  # open
            sols.append(DiskSolution([OPEN], [None], np.zeros(n), self.qdd(np.zeros(n))))
        if d_slide is not None:  # sliding: friction folded in, normal complementarity only
            a = W[0, 0]
            if a != 0.0:
                N = -b[0] / a
                if N > tol:
                    p = np.zeros(n)
                    p[0] = N
                    sols.append(DiskSolution([_slide_mode(d_slide)], [d_slide], p, self.qdd(p)))
            return sols
        mu = self.mu[0]
        # stick: a = 0
        try:
            p = np.linalg.solve(W, -b)
        except np.linalg.LinAlgError:
            p = None
        if p is not None and p[0] > tol and np.linalg.norm(p[k:]) <= mu * p[0] + tol:
            sols.append(DiskSolution([STICK], [None], p, self.qdd(p)))
        if mu == 0.0:
            return sols
        for d in self._slide_directions():
            den = W[0, 0] - mu * (W[0, k:] @ d)
            if den == 0.0:
                continue
            N = -b[0] / den
            if not N > tol:
                continue
            p = np.concatenate([[N], -mu * N * d])
            aT = W[k:] @ p + b[k:]
            lam = float(aT @ d)
            # lambda > 0 without tolerance: at the friction bound the stick (within its
            # tolerance) and this slide are one motion, grouped by their accelerations
            if lam <= 0.0 or np.linalg.norm(aT - lam * d) > 1e-8 * max(abs(lam), atol):
                continue
            sols.append(DiskSolution([_slide_mode(d)], [d], p, self.qdd(p)))
        return sols

    def _slide_directions(self):
        """Unit directions d with a_T(d) parallel to d (candidates of sliding from rest)."""
        W, b, mu, k = self.W, self.b, self.mu[0], 1
        WNN, WNT, WTN, WTT = W[0, 0], W[0, k:], W[k:, 0], W[k:, k:]
        if self.dims[0] == 1:
            return [np.array([1.0]), np.array([-1.0])]

        # den(d) a_T(d) = -b_N (W_TN - mu W_TT d) + den(d) b_T, den = W_NN - mu W_NT.d
        def h(th):
            d = np.array([math.cos(th), math.sin(th)])
            den = WNN - mu * (WNT @ d)
            v = -b[0] * (WTN - mu * WTT @ d) + den * b[k:]
            return d[0] * v[1] - d[1] * v[0]

        from scipy.optimize import brentq

        ths, C, S = _scan_angles()
        # h over the scan at once (the operations of h, elementwise): the signs bracket the roots
        den = WNN - mu * (WNT[0] * C + WNT[1] * S)
        v0 = -b[0] * (WTN[0] - mu * (WTT[0, 0] * C + WTT[0, 1] * S)) + den * b[k]
        v1 = -b[0] * (WTN[1] - mu * (WTT[1, 0] * C + WTT[1, 1] * S)) + den * b[k + 1]
        vals = C * v1 - S * v0
        ref = abs(b[0]) * (np.max(np.abs(WTN)) + mu * np.max(np.abs(WTT))) + (abs(WNN) + mu * np.max(np.abs(WNT))) \
            * np.max(np.abs(b[k:]))
        if np.max(np.abs(vals)) <= 1e-13 * ref:
            # every direction is parallel (no tangential load, isotropic W): the checks of the
            # candidates decide (a block on a plane: lambda < 0 for all, it sticks)
            return [np.array([1.0, 0.0]), np.array([0.0, 1.0])]
        out = []
        for i in range(ths.size - 1):
            a, c = vals[i], vals[i + 1]
            if a == 0.0:
                th = ths[i]
            elif a * c < 0:
                th = brentq(h, ths[i], ths[i + 1], xtol=1e-16, rtol=1e-15, maxiter=200)
            else:
                continue
            out.append(np.array([math.cos(th), math.sin(th)]))
        return out

    def _nsgs(self):
        from lcp.contact.spatial_nsgs import ConeOperator, cone_nsgs
        from lcp.contact.spatial_problem import ConeContactProblem

        pb = ConeContactProblem(self.W, self.b, self.mu, self.dims)
        op = ConeOperator(pb)
        r, _, _res, _fails = cone_nsgs(op, pb.interleave(self.b), self.mu, tol=1e-14, max_sweeps=10000)
        p = pb.deinterleave(r)
        if not np.all(np.isfinite(p)):
            return []
        p = pb.refine(p)
        a = self.W @ p + self.b
        tol = 1e-9 * max(float(np.max(np.abs(p))), 1e-300)
        modes, dirs = [], []
        for i in range(self.k):
            if p[i] <= tol:
                modes.append(OPEN)
                dirs.append(None)
            elif self.dirs[i] is not None:
                modes.append(_slide_mode(self.dirs[i]))
                dirs.append(self.dirs[i])
            else:
                aT = self.tangent(a, i)
                na = float(np.linalg.norm(aT))
                if na <= 1e-9 * self.scale_a:
                    modes.append(STICK)
                    dirs.append(None)
                else:
                    modes.append(_slide_mode(aT / na))
                    dirs.append(aT / na)
        if pb.residual(p) > 1e-8 * max(pb.scale, float(np.max(np.abs(p)))):
            return []
        return [DiskSolution(modes, dirs, p, self.qdd(p))]


def group_motions(sols, scale):
    """Solutions with the same acceleration are one motion (ties at a mode boundary)."""
    groups = []
    for s in sols:
        for g in groups:
            if np.max(np.abs(g[0].qdd - s.qdd)) <= 1e-9 * scale:
                g.append(s)
                break
        else:
            groups.append([s])
    return groups


def impact_impulse(model: SpatialModel, fr: Frame, v, contacts, restitution: bool = True, delta_b: bool = False):
    """Velocity-level disk problem of ``contacts``: u+ = W P + H_c v (+ e u_N on the normals).

    With ``delta_b`` the free velocity is shifted by delta b, delta -> 0+ (the problem a vanishing
    Moreau-Jean step solves: excludes the trivial solution of the Painleve fallback), and the
    branch found is re-solved at delta = 0 (stick only: a vanishing slide impulse is no impulse).
    Returns (dv, P blocked, modes) or None when there is no solution.
    """
    idx = [int(j) for j in contacts]
    k = len(idx)
    rows = np.array(idx + [r for j in idx for r in model.trows[j].tolist()], dtype=int)
    Hc = fr.H[rows]
    SH = fr.SH[:, rows]
    W = Hc @ SH
    u = fr.velocity(v, rows)
    qv = u.copy()
    if restitution:
        # on the approaching contacts only (as in the planar impact law): a closed or separating
        # contact of a cascade's round must not be pulled back
        qv[:k] += model.e[idx] * np.minimum(u[:k], 0.0)
    mu = model.mu[idx]
    dims = model.dims[idx]
    q_solve = qv
    if delta_b:
        b = Hc @ fr.qdd_free + fr.Hdv[rows]
        umax, bmax = float(np.max(np.abs(qv))), float(np.max(np.abs(b)))
        if bmax == 0.0:
            return None
        q_solve = qv + (1e-8 * umax / bmax if umax > 0 else 1.0) * b
    if k == 1:
        from lcp.contact.spatial_problem import local_disk

        P, mode = local_disk(W, q_solve, float(mu[0]))
        if mode < 0 or not np.all(np.isfinite(P)):
            return None
        modes = [mode]
    else:
        from lcp.contact.spatial_nsgs import ConeOperator, cone_nsgs
        from lcp.contact.spatial_problem import ConeContactProblem

        pb = ConeContactProblem(W, q_solve, mu, dims)
        r, _, _res, _ = cone_nsgs(ConeOperator(pb), pb.interleave(q_solve), mu, tol=1e-14, max_sweeps=10000)
        P = pb.refine(pb.deinterleave(r))
        if not np.all(np.isfinite(P)) or pb.residual(P) > 1e-8 * max(pb.scale, float(np.max(np.abs(P)))):
            return None
        modes = list(pb.modes(P))
    if delta_b:
        if any(md != STICK for md in modes):
            return None
        try:
            P = np.linalg.solve(W, -qv)
        except np.linalg.LinAlgError:
            return None
        toff = np.concatenate([[0], np.cumsum(dims)]).astype(int)
        for i in range(k):
            pT = P[k + toff[i]:k + toff[i + 1]]
            if P[i] < 0 or np.linalg.norm(pT) > mu[i] * P[i] * (1 + 1e-12):
                return None
    return SH @ P, P, modes
