"""One Moreau-Jean step's contact solve on the active set (the Python loop's step).

Holds :class:`ContactStep` (the local problem from the active set's cached slices of the step's
operators, the restitution shift, the solve with its fallback, the branch refinement, planar or
spatial) and the fallback rule shared with the compiled loop (:func:`fallback_for`,
:func:`retry_with_fallback`, :func:`count_solve`). Imports :mod:`lcp.contact` only (it fills in the run's
:class:`~lcp.timestepping.outcome.RunNotes`, handed to it); never the loops, the path choice or
anything above :mod:`lcp.timestepping`.
"""
from __future__ import annotations

import math

import numpy as np

from lcp.contact.problem import STICK, ContactProblem
from lcp.contact.solvers import make_solver

__all__ = ["CONE_RTOL", "ContactStep", "count_solve", "fallback_for", "in_cones", "retry_with_fallback"]

#: tolerance of :func:`in_cones`, relative to the largest impulse
CONE_RTOL = 1e-12


def in_cones(p, mu, dims=None) -> bool:
    """Whether every contact's impulse in ``p`` (the k normal impulses, then ``dims[j]`` tangential
    components per contact; one each where ``dims`` is None: a planar problem) lies in its Coulomb cone: p_N >= 0 and |p_T| <= mu p_N, within
    :data:`CONE_RTOL` of the largest impulse. The compiled loops apply the same test.

    The refinement after a solve (the planar branch solve, the spatial all-stick correction)
    removes the rounding the solve leaves in the velocities. Where contacts are redundant (two
    pucks joined by a bar, a rod lying on both ends, both stuck) its matrix is singular to
    rounding and its solution has a null-space component: it only moves the split of the
    redundant impulses, which is harmless while every contact stays in its cone, but it moved a
    puck's friction impulse to 2.46 mu p_N under a "solved" residual (and a block's to 2.9 mu p_N
    after Lemke). A refined impulse outside a cone is therefore dropped for the solver's own.
    """
    k = len(mu) if dims is None else len(dims)
    tol = CONE_RTOL * float(np.max(np.abs(p), initial=0.0))
    off = k
    for j in range(k):
        pn = float(p[j])
        if pn < -tol:
            return False
        d = 1 if dims is None else int(dims[j])
        if d == 1:
            pt = abs(float(p[off]))
        else:
            a, b = float(p[off]), float(p[off + 1])
            pt = math.sqrt(a * a + b * b)
        off += d
        if pt > float(mu[j]) * pn + tol:
            return False
    return True


def fallback_for(solver, k: int):
    """The other exact solver that retries a step on which ``solver`` failed (k active contacts)."""
    if getattr(solver, "spatial", False):  # a disk-law solver (lcp.contact.spatial_solvers, already loaded)
        from lcp.contact.spatial_solvers import make_cone_solver

        return make_cone_solver("nsgs" if solver.name == "newton" else "newton")
    name = {"auto": "osqp", "enum": "lemke", "lemke": "enum" if k == 1 else "osqp",
            "osqp": "enum" if k == 1 else "lemke"}.get(solver.name, "lemke")
    return make_solver(name)


def count_solve(stats, sol):
    """Add one solve's iterations and OSQP solves to the run's counters ``stats``."""
    stats.iterations += sol.iterations
    stats.max_iterations = max(stats.max_iterations, sol.iterations)
    stats.qp_solves += sol.qp_solves


def retry_with_fallback(solver, pb, sol, k: int, fallback: bool, fallbacks: dict):
    """The retry of a one-step problem ``pb`` (k active contacts) on which ``solver`` failed with the
    solution ``sol``: where ``fallback`` is set, by :func:`fallback_for`'s solver (cached in
    ``fallbacks`` by k).

    Returns (solution, name of the fallback solver that succeeded or None, the failed solver's
    message or None); the solution is ``sol`` itself where no retry succeeded.
    """
    if fallback and sol.status != -3:  # -3: forced solver does not apply
        fb = fallbacks.setdefault(k, fallback_for(solver, k))
        if fb is not None:
            sol2 = fb.solve(pb)
            if sol2.success:
                return sol2, fb.name, sol.message
    return sol, None, None


class ContactStep:
    """The contact solve of one step on its active set (:meth:`solve`).

    Parameters
    ----------
    system : lcp.model.system.System
    asm : lcp.timestepping.assembly.StepAssembly
        The run's assembly (constant operators: the active sets' slices are cached).
    solver : OneStepSolver or ConeSolver
    fallback : bool
        MoreauJeanOptions.fallback.
    notes : lcp.timestepping.outcome.RunNotes
        The run's counters and notes, filled in by each solve.
    """

    def __init__(self, system, asm, solver, fallback: bool, notes):
        self.m = system.n_contacts
        self.mu, self.e = system.mu, system.e
        self.spatial = system.is_spatial
        self.system = system
        if self.spatial:  # the disk law: the cone problem, its tangent rows laid out contact by contact
            self.dims, self.toff = system.tangent_dims, system.tangent_offsets
        self.keyed = asm.matrices_constant  # constant W: solvers and this step may cache per active set
        self.cache = {}
        self.fallbacks = {}
        self.solver, self.fallback, self.notes = solver, fallback, notes

    def _explain_restitution(self, pb, qa, shift, active, sol):
        """After every solver failed on a step with a restitution shift: if the same step without
        it has a solution, say so in ``sol.message``. Opposed contacts without clearance (a slider
        in a guide) are the case: the drift of a q-dependent normal, O(h), makes one corner
        approach and its opposite separate, and u_N+ >= e |u_N-| on the one cannot hold while the
        other stays closed: the problem has no solution, and no tolerance would make one."""
        q0 = qa.copy()
        q0[: active.size] -= shift
        plain = self.solver.solve(pb.with_q(q0))
        if plain.success:
            names = ", ".join(repr(self.system.contacts[j].name) for j in active[shift != 0].tolist())
            sol.message = (f"{sol.message}. Without the Newton restitution of the approaching contact(s) "
                           f"{names} (u_N- down to {float(np.min(shift / self.e[active].clip(1e-300))):.3g}) "
                           "the step has a solution: their rebound cannot be met together with the other active "
                           "contacts (redundant contacts, e.g. opposed faces without clearance, whose "
                           "normal velocities sum to a constant)")

    def local(self, active, SHt, W, H):
        """(rows, H rows, S H' columns, restitution coefficients or None, problem template, tangent
        columns) of the active set, cached per active set when the operators are constant."""
        keyed = self.keyed
        key = active.tobytes()
        local = self.cache.get(key) if keyed else None
        if local is None:  # the active set's slices of the (constant) operators, built once
            ea = self.e[active]
            mu = self.mu
            if self.spatial:
                from lcp.contact.spatial_problem import ConeContactProblem

                toff = self.toff
                idx = self.system.contact_rows(active)
                cols = np.concatenate([np.arange(toff[j], toff[j + 1]) for j in active.tolist()])
                template = ConeContactProblem(W[np.ix_(idx, idx)], np.zeros(idx.size), mu[active], self.dims[active],
                                              key=tuple(active) if keyed else None)
            else:
                m = self.m
                idx = np.concatenate([active, m + active])
                cols = active
                template = ContactProblem(W[np.ix_(idx, idx)], np.zeros(idx.size), mu[active],
                                          key=tuple(active) if keyed else None)
            local = (idx, H[idx], SHt[:, idx], ea if np.any(ea) else None, template, cols)
            if keyed:
                self.cache[key] = local
        return local

    def solve(self, k, tk, active, v, vfree, dvf, SHt, W, H, uN_minus, b=None):
        """The contact solve of step k (time tk) on ``active``.

        ``b``, where given, is the moving contacts' b = (dg/dt, ds/dt) at the step's end (rows as in
        H): the local velocity is then u = H v+ + b, and the problem's free velocity gets + b.

        Returns (dv, p, modes, tangent columns of p, solution): the velocity increment with the
        impulses, the active contacts' impulses (normals, then tangents) and modes. ``dv`` is None
        when every solver failed (``solution.message`` says why).
        """
        local = self.cache.get(active.tobytes()) if self.keyed else None
        if local is None:
            local = self.local(active, SHt, W, H)
        idx, Ha, SHta, ea, template, cols = local
        qa = Ha @ vfree
        ba = None if b is None else b[idx]
        if ba is not None:
            qa = qa + ba
        if ea is not None:
            # Newton restitution u_N+ >= -e u_N- acts only on approaching contacts: with a
            # separating one (u_N- > 0) it would pull the body back and create energy
            shift = ea * np.minimum(uN_minus[active], 0.0)
            qa[: active.size] += shift
        pb = template.with_q(qa)
        notes = self.notes
        stats = notes.stats
        sol = self.solver.solve(pb)
        stats.solver_calls += 1
        count_solve(stats, sol)
        if not sol.success:
            sol, fb_name, why = retry_with_fallback(self.solver, pb, sol, active.size, self.fallback, self.fallbacks)
            if fb_name is not None:
                stats.fallbacks += 1
                if notes.first_fallback is None:
                    notes.first_fallback = (k, tk, why, fb_name)
            if not sol.success:
                if ea is not None and np.any(shift):
                    self._explain_restitution(pb, qa, shift, active, sol)
                return None, None, None, None, sol
        if sol.message.startswith("fallback"):
            stats.fallbacks += 1
        if sol.ambiguous and notes.first_ambiguous is None:
            notes.first_ambiguous = (k, tk)
        stats.ambiguous_steps += int(sol.ambiguous)
        if sol.status > 0:  # an approximation (the faceted disk): said in the message, never silent
            approx = notes.approx
            notes.approx = (approx[0] + 1, approx[1] or sol.message, max(approx[2], sol.residual))
        stats.max_residual = max(stats.max_residual, sol.residual)
        p = sol.p
        if self.spatial:
            # the branch refinement of the disk law (a stuck contact's velocity to the last bit):
            # done by the solver when it reports the modes of its refined impulse
            md = getattr(sol, "modes", None)
            if md is None:
                p, md = pb.refine_modes(p)
            dv = dvf + SHta @ p
            if md.size and np.all(md == STICK):
                # every contact stuck: one correction on the velocities themselves, as in the
                # planar branch (the refinement above works on W p + q, whose rounding in the
                # generalized velocities would leave a stuck body at 1e-19 m/s for some steps)
                r = Ha @ (v + dv)
                if ba is not None:
                    r = r + ba
                if ea is not None:
                    r[: active.size] += shift
                dp = pb.solve_linear(pb.W, -r)
                if dp is not None and in_cones(p + dp, pb.mu, pb.dims):
                    p = p + dp
                    dv = dv + SHta @ dp
        else:
            dv = dvf + SHta @ p
            md = pb.modes(p)
            # one refinement on the branch: with an ill-conditioned mass matrix the solve leaves
            # cond(W) eps in the velocities, which would let a stuck block creep and a pressed one sink
            r = Ha @ (v + dv)
            if ba is not None:
                r = r + ba
            if ea is not None:
                r[: active.size] += shift
            dp = pb.with_q(r).solve_branch(md)
            if dp is not None and math.isfinite(float(dp.sum())) and in_cones(p + dp, pb.mu):
                p = p + dp
                dv = dv + SHta @ dp
        return dv, p, md, cols, sol
