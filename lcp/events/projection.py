"""Projection of the state onto the active constraints after a phase.

A phase ends with the constraints of its modes satisfied up to integration drift and rounding. At
an event the state is corrected onto g_j = 0 for the closed contacts and the bilateral constraints,
and the velocity onto the closed contacts' normal (and sticking contacts' tangential) velocities
and the bilateral velocity constraints, each by the smallest correction in the mass metric. For a system with Newton-Euler kinematics
(qdot = T(q) v) the corrections are v-space vectors dx (the Jacobians map v) and move q by T(q) dx,
its unit quaternions renormalised after.
"""
from __future__ import annotations

import numpy as np

from lcp.events.model import coordinate_rows, mass_projection

__all__ = ["StateProjector"]


class StateProjector:
    """Mass-metric projections of one system (correction matrices kept per system when constant)."""

    def __init__(self, system, model):
        self.sys, self.model = system, model
        self.n, self.m = system.n, system.n_contacts

    def project(self, t, q, v, gap_rows, normal_rows, tangent_rows):
        """Snap q onto g_j = 0 (j in gap_rows) and the bilateral constraints, and v onto
        u_N,j = 0 (normal_rows), u_T,j = 0 (tangent_rows) and the bilateral velocity constraints,
        each by the smallest correction in the mass metric (it removes drift and rounding only).
        The rows are tuples of contact indices."""
        if self.model.constant:
            return self._constant(t, q, v, gap_rows, normal_rows, tangent_rows)
        n, m = self.n, self.m
        nb = self.sys.n_bilateral
        gap_rows = np.array(gap_rows, dtype=int)
        A = self.sys.mass(q, t)
        if gap_rows.size or nb:
            for _ in range(3):
                rows, res = [], []
                if nb:
                    phi, G, _ = (np.array(x, dtype=float) for x in self.sys.constraints_fn(t, q))
                    rows.append(G.reshape(nb, n))
                    res.append(phi.ravel())
                if gap_rows.size:
                    rows.append(self.model.jac(q, t)[gap_rows])
                    res.append(self.model.gaps(q, t)[gap_rows])
                J, r = np.vstack(rows), np.concatenate(res)
                if not np.any(r):
                    break
                # in v-space: q moves by T(q) dx (Newton-Euler kinematics), quaternions renormalised
                q = self.model.advance(t, q, -mass_projection(A, J, r))
        rows, res = [], []
        if nb:
            _, G, phi_t = (np.array(x, dtype=float) for x in self.sys.constraints_fn(t, q))
            G = G.reshape(nb, n)
            rows.append(G)
            res.append(G @ v + phi_t.ravel())
        vr = np.array(normal_rows + tuple(m + j for j in tangent_rows), dtype=int)
        if vr.size:
            H = self.model.jac(q, t)
            rows.append(H[vr])
            res.append(H[vr] @ v if not self.model.moving else (H @ v + self.sys.contact_rates(q, t))[vr])
        if rows:
            J, r = np.vstack(rows), np.concatenate(res)
            if np.any(r):
                v = v - mass_projection(A, J, r)
        return q, v

    def _constant(self, t, q, v, gap_rows, normal_rows, tangent_rows):
        """:meth:`project` for a constant system: one correction each (the constraints are
        affine), with the rows and correction matrices of each row set built once per system."""
        model, m = self.model, self.m
        nb = model.nb
        if gap_rows or nb:
            key = ("q", gap_rows)
            entry = model.proj_cache.get(key)
            if entry is None:
                rows = np.array(gap_rows, dtype=int)
                entry = model.proj_cache[key] = (rows, model.projector(key, [model.G, model.H[rows]]),
                                                 coordinate_rows(model.HN[rows], -model.gap0[rows]))
            rows, C, snap = entry
            res = []
            if nb:
                res.append(np.array(self.sys.constraints_fn(t, q)[0], dtype=float).ravel())
            if gap_rows:
                g = model.gaps(q)
                res.append(g if len(gap_rows) == g.size and gap_rows == model.all_contacts else g[rows])
            r = np.concatenate(res) if len(res) > 1 else res[0]
            if r.any():
                q = q - C @ r
            for i, val in snap:  # a flat contact: its gap exactly zero, not to rounding
                q[i] = val
        vr = normal_rows + tuple(m + j for j in tangent_rows)
        if nb or vr:
            key = ("v", vr)
            entry = model.proj_cache.get(key)
            if entry is None:
                Hv = model.H[np.array(vr, dtype=int)]
                entry = model.proj_cache[key] = (Hv, model.projector(key, [model.G, Hv]),
                                                 coordinate_rows(Hv, np.zeros(len(vr))))
            Hv, C, snap = entry
            if nb:
                r = np.concatenate([model.G @ v + model.phi_t, Hv @ v])
            else:
                r = Hv @ v
            if r.any():
                v = v - C @ r
            for i, val in snap:
                v[i] = val
        return q, v

