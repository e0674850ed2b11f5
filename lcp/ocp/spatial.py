"""Spatial contacts in the optimal-control transcription: the Coulomb disk as a complementarity.

A spatial contact (two tangent directions, :class:`lcp.model.system.Contact` with a 2-vector
tangent) has at every Moreau-Jean step a normal force N >= 0, a friction force f in the tangent
plane and the sliding velocity U = H_T v_{k+1}. The disk law (|f| <= mu N, f = -mu N U / |U| while
U != 0) is written with a sliding multiplier beta and the slack of the cone in squared form::

    U + beta f = 0,      0 <= beta  perp  s = mu^2 N^2 - |f|^2 >= 0,      0 <= N  perp  w_N >= 0,

with w_N = u_N + e min(u_N-, 0) as in the planar velocity law (:mod:`lcp.ocp.transcription`). At a
stick beta = 0, so U = 0 and f anywhere in the disk; at a slide s = 0 (f on the rim) and U = -beta f
opposes f, i.e. f = -mu N U / |U|. Every function is smooth (the squared norm has no kink at
f = 0), the pairs are relaxed by the same Scholtes homotopy as the planar pairs (beta s <= sigma,
N w_N <= sigma) and fixed by the polishing solve. A planar contact of the same system takes the
same form with a one-entry f. Limitation (by name in the docs): a contact carrying no force cannot
slide (f = 0 forces U = 0), so the velocity law must keep every contact loaded, as a body resting
on a plane under gravity does.

:class:`SpatialTranscription` builds the NLP for the velocity law (every contact closed at every
step), uniform or free steps, the constant or linear hold, fixed or free final time; the gap law
and the affine hold are refused by name (:func:`check_spatial`). With free steps, the cross
complementarity of FESD (as in :mod:`lcp.ocp.transcription`) puts every switch on a node:
0 <= beta_{k-1} perp D_k = mu^2 N_k N_{k-1} - f_k . f_{k-1} >= 0 (D_k >= 0 by Cauchy-Schwarz within
the disks, zero only with both frictions on their rims and parallel), so a contact sliding at node k
keeps its friction on the rim, in the same direction, over step k (it can stop only at a node), and
N_k perp w_N,{k-1}. Not yet: a start that slides (v0 with U != 0) is not tied to step 0's friction
direction. Its ``diagnose_law`` is the
disk law's residual (:meth:`lcp.contact.spatial_problem.ConeContactProblem.residual`) on each step's
velocity-level problem, recomputed in NumPy. Imports the planar transcription (its bookkeeping and
step function) and the contact layer; it must not import the solve, the problem or the studies.
"""
from __future__ import annotations

import time

import casadi as ca
import numpy as np

from lcp.contact.spatial_problem import ConeContactProblem
from lcp.ocp.transcription import Transcription, grid_variables, step_terms, terminal_terms

__all__ = ["SpatialTranscription", "check_spatial"]

#: the pairs of a spatial contact (multiplier, slack), both >= 0
SPATIAL_PAIRS = (("pN", "wN"), ("beta", "s"))


def check_spatial(system, contact_law: str, hold: str, steps: str) -> None:
    """Refuse, by name, what the spatial transcription does not model."""
    if not system.is_spatial:
        return
    name = system.contacts[int(np.flatnonzero(system.tangent_dims == 2)[0])].name
    if contact_law != "velocity":
        raise ValueError(f"contact {name!r} is spatial: the transcription models spatial contacts with the "
                         f"velocity law only (every contact closed), got contact_law={contact_law!r}; give "
                         "contact_law='velocity' (a contact that starts open needs the gap law, planar only)")
    if hold not in ("constant", "linear"):
        raise ValueError(f"contact {name!r} is spatial: hold must be 'constant' or 'linear', got {hold!r}")
    if steps not in ("uniform", "free"):
        raise ValueError(f"contact {name!r} is spatial: steps must be 'uniform' or 'free', got {steps!r}")


class SpatialTranscription(Transcription):
    """The NLP of an :class:`~lcp.ocp.OptimalControlProblem` whose system has spatial contacts.

    Same attributes as :class:`~lcp.ocp.transcription.Transcription`; ``ix`` has, per step, the
    blocks ``pN``, ``wN``, ``beta``, ``s`` (m entries) and ``f`` (the tangent entries, contact by
    contact, as the rows of H).
    """

    def __init__(self, pb):
        t_start = time.perf_counter()
        self.pb = pb
        self.step = self._step_function()
        sys = pb.system
        self.kin = ca.Function("kin", [sys.t_sym, sys.q_sym], [sys.mass_expr, sys.H_expr,
                                                               ca.jacobian(sys.constraints_expr, sys.q_sym)])
        self.gap_scale = pb.theta * pb.T / pb.N
        self.gap_law = self.restitution = False
        #: the cross complementarity of free steps (module docstring)
        self.cross = pb.steps == "free"
        self._x, self._lbx, self._ubx, self._nx = [], [], [], 0
        self._g, self._lbg, self._ubg = [], [], []
        self.ix = {}
        self._build()
        self.build_time = time.perf_counter() - t_start

    def _build(self):
        pb = self.pb
        sys, N, th = pb.system, pb.N, pb.theta
        m, nb, nt = sys.n_contacts, sys.n_bilateral, sys.n_tangent
        mu, e = ca.DM(sys.mu), ca.DM(sys.e)
        off = sys.tangent_offsets
        sigma, q0p, v0p, Tv, z, hs, us, qs, vs, tk = grid_variables(self)
        J, sizes, prev = ca.SX(0), {}, None
        for k in range(N):
            t0, h = tk[k], hs[k]
            ua, ub = self.control_pair(us, k)
            qa, qb, va, vb = qs[k], qs[k + 1], vs[k], vs[k + 1]
            blk = {nm: self._var(f"{nm}{k}", m, 0.0, np.inf, key=nm) for a_w in SPATIAL_PAIRS for nm in a_w}
            f = self._var(f"f{k}", nt, -np.inf, np.inf, key="f")
            lamb = self._var(f"lb{k}", nb, -np.inf, np.inf, key="lb")
            Wh, r, H, G, phi_t1, _, _, _ = self.step(t0, h, qa, va, ua, 0.5 * (ua + ub), ub - ua)
            pN, pT = h * blk["pN"], h * f
            dyn = ca.mtimes(Wh, vb - va) - r - ca.mtimes(H.T, ca.vertcat(pN, pT))
            if nb:
                dyn = dyn - ca.mtimes(G.T, lamb)
                self._constrain(ca.mtimes(G, vb) + phi_t1, 0.0, 0.0)
            self._constrain(dyn, 0.0, 0.0)
            self._constrain(qb - qa - h * ((1 - th) * va + th * vb), 0.0, 0.0)
            uN, U = ca.mtimes(H[:m, :], vb), ca.mtimes(H[m:, :], vb)
            self._constrain(blk["wN"] - (uN + e * ca.fmin(ca.mtimes(H[:m, :], va), 0)), 0.0, 0.0)
            for j in range(m):
                rows = slice(int(off[j]), int(off[j + 1]))
                fj = f[rows]
                self._constrain(U[rows] + blk["beta"][j] * fj, 0.0, 0.0)
                self._constrain(blk["s"][j] - (mu[j] ** 2 * blk["pN"][j] ** 2 - ca.sumsqr(fj)), 0.0, 0.0)
            a = ca.vertcat(*[blk[x] for x, _ in SPATIAL_PAIRS])
            w = ca.vertcat(*[blk[y] for _, y in SPATIAL_PAIRS])
            if self.cross and prev is not None:
                a, w = ca.vertcat(a, self._cross(k, blk, f, prev, mu, off)), ca.vertcat(w, prev["beta"])
                a, w = ca.vertcat(a, blk["pN"]), ca.vertcat(w, prev["wN"])
            self._constrain(a * w - sigma, -np.inf, 0.0)  # Scholtes
            prev = {**blk, "f": f}
            st = pb.make_step(k, t0, h, qa, qb, va, vb, ua, ub, pN, pT)
            J = step_terms(self, J, st, us, k, h, ua, ub, z, sigma, sizes)
        J = terminal_terms(self, J, Tv, qs, vs, z)
        self.nlp = {"x": ca.vertcat(*self._x), "f": J, "g": ca.vertcat(*self._g), "p": ca.vertcat(sigma, q0p, v0p)}
        self.ix = {key: np.array(val) for key, val in self.ix.items()}
        self.lbx, self.ubx = np.concatenate(self._lbx), np.concatenate(self._ubx)
        self.lbg, self.ubg = np.concatenate(self._lbg), np.concatenate(self._ubg)
        del self._x, self._g, self._lbx, self._ubx, self._lbg, self._ubg, self._nx

    def _cross(self, k, blk, f, prev, mu, off):
        """The slack D_k = mu^2 N_k N_{k-1} - f_k . f_{k-1} >= 0 per contact (a variable ``D``), whose
        pair with beta_{k-1} keeps a contact sliding at node k on the rim in step k, its friction in
        the direction of step k - 1's."""
        m = self.pb.system.n_contacts
        D = self._var(f"D{k}", m, 0.0, np.inf, key="D")
        for j in range(m):
            rows = slice(int(off[j]), int(off[j + 1]))
            self._constrain(D[j] - (mu[j] ** 2 * blk["pN"][j] * prev["pN"][j] - ca.dot(f[rows], prev["f"][rows])),
                            0.0, 0.0)
        return D

    # ------------------------------------------------------------------ numbers out of x
    def unpack(self, x):
        """(T, steps, q, v, u, p_N (N, m), p_T (N, n_tangent)) of a vector of NLP variables."""
        pb, ix = self.pb, self.ix
        N, n, m, nt = pb.N, pb.system.n, pb.system.n_contacts, pb.system.n_tangent
        T = float(x[ix["T"]].ravel()[0]) if pb.free_time else pb.T
        steps = x[ix["h"]].ravel() if pb.steps == "free" else np.full(N, T / N)
        q = np.vstack([pb.q0] + [x[i] for i in ix["q"]]).reshape(N + 1, n)
        v = np.vstack([pb.v0] + [x[i] for i in ix["v"]]).reshape(N + 1, n)
        u = np.vstack([x[i] for i in ix["u"]]).reshape(-1, pb.nu)
        pN = steps[:, None] * x[ix["pN"]].reshape(N, m)
        pT = steps[:, None] * x[ix["f"]].reshape(N, nt)
        return T, steps, q, v, u, pN, pT

    def impulses(self, x):
        """No impulses at the nodes under the velocity law."""
        N = self.pb.N
        return np.zeros((N, 0)), np.zeros((N, 0))

    def x0_law(self, x0, gs, steps) -> None:
        """Fill the contact variables of ``x0`` (in place) from a guess's impulses and velocities."""
        pb, ix = self.pb, self.ix
        sys = pb.system
        m, off, mu = sys.n_contacts, sys.tangent_offsets, sys.mu
        prev = None
        for k in range(pb.N):
            H = sys.contact_jacobian(gs.q[k])
            uN, U = H[:m] @ gs.v[k + 1], H[m:] @ gs.v[k + 1]
            pN, f = np.maximum(gs.p_N[k], 0.0) / steps[k], np.asarray(gs.p_T[k], dtype=float) / steps[k]
            x0[ix["pN"][k]] = pN
            x0[ix["wN"][k]] = np.maximum(uN + sys.e * np.minimum(H[:m] @ gs.v[k], 0.0), 0.0)
            x0[ix["f"][k]] = f
            for j in range(m):
                fj, Uj = f[off[j]:off[j + 1]], U[off[j]:off[j + 1]]
                x0[ix["s"][k][j]] = max(mu[j] ** 2 * pN[j] ** 2 - float(fj @ fj), 0.0)
                x0[ix["beta"][k][j]] = float(np.linalg.norm(Uj)) / max(mu[j] * pN[j], 1e-9)
                if self.cross and prev is not None:
                    fp = prev[1][off[j]:off[j + 1]]
                    x0[ix["D"][k - 1][j]] = max(mu[j] ** 2 * pN[j] * prev[0][j] - float(fj @ fp), 0.0)
            prev = (pN, f)

    def diagnose_law(self, x) -> dict:
        """The disk law's residual on each step's velocity-level problem, the dynamics residual and
        the modes, recomputed in NumPy (the keys of :func:`lcp.ocp.complementarity.diagnose`)."""
        pb = self.pb
        sys = pb.system
        _, hs, q, v, u, pN, pT = self.unpack(x)
        N, n, m, nb = pb.N, sys.n, sys.n_contacts, sys.n_bilateral
        ua, ub = (u, u) if pb.hold == "constant" else (u[:-1], u[1:])
        tk = np.concatenate([[0.0], np.cumsum(hs)])[:-1]
        out = self.step.map(N)(tk[None, :], hs[None, :], q[:-1].T, v[:-1].T, ua.T, (0.5 * (ua + ub)).T, (ub - ua).T)

        def blocks(a, r, c):  # (r, c N) -> (N, r, c)
            return np.array(a, dtype=float).reshape(r, N, c).transpose(1, 0, 2)

        Wh, r, H = blocks(out[0], n, n), blocks(out[1], n, 1)[..., 0], blocks(out[2], m + sys.n_tangent, n)
        G, phi_t1 = blocks(out[3], nb, n), blocks(out[4], nb, 1)[..., 0]
        KKT = np.zeros((N, n + nb, n + nb))
        KKT[:, :n, :n], KKT[:, :n, n:], KKT[:, n:, :n] = Wh, G.transpose(0, 2, 1), G
        rhs = np.concatenate([r, -phi_t1 - np.einsum("kij,kj->ki", G, v[:-1])], axis=1)
        vfree = v[:-1] + np.linalg.solve(KKT, rhs[..., None])[:, :n, 0]
        Ht = np.concatenate([H.transpose(0, 2, 1), np.zeros((N, nb, H.shape[1]))], axis=1)
        SHt = np.linalg.solve(KKT, Ht)[:, :n]
        W = H @ SHt
        qf = np.einsum("kij,kj->ki", H, vfree)
        qf[:, :m] += sys.e * np.minimum(np.einsum("kij,kj->ki", H[:, :m], v[:-1]), 0.0)
        p = np.concatenate([pN, pT], axis=1)
        res, modes = 0.0, np.zeros((N, m), dtype=np.int8)
        for k in range(N):
            cp = ConeContactProblem(W[k], qf[k], sys.mu, sys.tangent_dims)
            res = max(res, cp.residual(p[k]))
            modes[k] = cp.modes(p[k], rtol=1e-6)
        vplus = vfree + np.einsum("kij,kj->ki", SHt, p)
        a = np.concatenate([x[self.ix[nm]].ravel() for nm, _ in SPATIAL_PAIRS])
        w = np.concatenate([x[self.ix[nm]].ravel() for _, nm in SPATIAL_PAIRS])
        cross = prod = 0.0
        for ia, iw in self._cross_pairs():
            cross = max(cross, float(np.max(np.abs(np.minimum(x[ia], x[iw])), initial=0.0)))
            prod = max(prod, float(np.max(x[ia] * x[iw], initial=0.0)))
        return {"residual": res, "dynamics": float(np.max(np.abs(vplus - v[1:]))), "modes": modes, "conflicts": 0,
                "max_product": max(float(np.max(a * w)), prod), "lcp": float(np.max(np.abs(np.minimum(a, w)))),
                "cross": cross}

    def _cross_pairs(self):
        """(index of a, index of w) of the cross pairs: D_k against beta_{k-1}, N_k against w_N,{k-1}."""
        if not self.cross or self.pb.N < 2:
            return []
        ix = self.ix
        return [(ix["D"].reshape(-1), ix["beta"][:-1].reshape(-1)),
                (ix["pN"][1:].reshape(-1), ix["wN"][:-1].reshape(-1))]

    def fixed_mode_bounds_law(self, x):
        """Bounds with the smaller member of each pair (N, w_N), (beta, s) at x fixed at zero."""
        lbx, ubx = self.lbx.copy(), self.ubx.copy()
        pairs = [(self.ix[a].reshape(-1), self.ix[w].reshape(-1)) for a, w in SPATIAL_PAIRS] + self._cross_pairs()
        for ia, iw in pairs:
            small = x[ia] <= x[iw]
            ubx[ia[small]] = 0.0
            ubx[iw[~small]] = 0.0
        return lbx, ubx
