"""Initial guesses: resampling a solution onto another grid, and filling every NLP variable."""
from __future__ import annotations

import numpy as np

from .results import OCPGuess

__all__ = ["resample", "x0_from_guess"]


def _interp(a, told, tnew):
    if not a.shape[1]:
        return np.zeros((len(tnew), 0))
    return np.stack([np.interp(tnew, told, a[:, j]) for j in range(a.shape[1])], axis=1)


def resample(res, N: int, hold: str) -> OCPGuess:
    """Interpolate a solution or guess onto N uniform steps (impulses as forces, rescaled by h).

    The control is sampled at interval midpoints (constant hold) or nodes (linear hold) of the
    new grid, from its own hold on the old one.
    """
    T = float(res.T)
    M = res.q.shape[0] - 1
    t_old = getattr(res, "t", None)
    if t_old is None or len(t_old) != M + 1:
        t_old = np.linspace(0.0, T, M + 1) if getattr(res, "steps", None) is None else \
            np.concatenate([[0.0], np.cumsum(res.steps)])
    t_new = np.linspace(0.0, T, N + 1)
    h_old = np.diff(t_old)[:, None]
    tm_old, tm_new = 0.5 * (t_old[1:] + t_old[:-1]), 0.5 * (t_new[1:] + t_new[:-1])
    u = np.asarray(res.u, dtype=float)
    if len(u) == M:  # constant hold on the old grid
        k = np.clip(np.searchsorted(t_old, tm_new if hold == "constant" else t_new, side="right") - 1, 0, M - 1)
        u_new = u[k]
    else:
        u_new = _interp(u, t_old, tm_new if hold == "constant" else t_new)
    return OCPGuess(T=T, q=_interp(res.q, t_old, t_new), v=_interp(res.v, t_old, t_new), u=u_new,
                    p_N=_interp(res.p_N / h_old, tm_old, tm_new) * (T / N),
                    p_T=_interp(res.p_T / h_old, tm_old, tm_new) * (T / N), source="resampled")


def x0_from_guess(pb, tr, gs: OCPGuess) -> np.ndarray:
    """Every NLP variable from a guess, the Coulomb multipliers and slacks from the impulses."""
    ix, N = tr.ix, pb.N
    x0 = np.zeros(len(tr.lbx))
    if pb.free_time:
        x0[ix["T"]] = np.clip(gs.T, *pb.T_bounds)
    steps = np.full(N, gs.T / N) if gs.steps is None else np.asarray(gs.steps, dtype=float)
    if pb.steps == "free":
        x0[ix["h"].ravel()] = steps
    for k in range(len(ix["u"])):
        x0[ix["u"][k]] = gs.u[k]
    for k in range(1, N + 1):
        x0[ix["q"][k - 1]] = gs.q[k]
        x0[ix["v"][k - 1]] = gs.v[k]
    m = pb.system.n_contacts
    if m:
        mu, e = pb.system.mu, pb.system.e
        for k in range(N):
            H = pb.system.contact_jacobian(gs.q[k])
            uN, uT = H[:m] @ gs.v[k + 1], H[m:] @ gs.v[k + 1]
            pN, pT = np.maximum(gs.p_N[k], 0.0) / steps[k], gs.p_T[k] / steps[k]  # forces
            bp, bm = np.maximum(pT, 0.0), np.maximum(-pT, 0.0)
            lam = np.abs(uT)
            vals = {"pN": pN, "bp": bp, "bm": bm, "lam": lam,
                    "wN": np.maximum(uN + e * np.minimum(H[:m] @ gs.v[k], 0.0), 0.0),
                    "wp": np.maximum(lam + uT, 0.0), "wm": np.maximum(lam - uT, 0.0),
                    "wl": np.maximum(mu * pN - bp - bm, 0.0)}
            for nm, val in vals.items():
                x0[ix[nm][k]] = val
    if pb.max_cost is not None:
        x0[ix["z"]] = 0.0
    return np.clip(x0, tr.lbx, tr.ubx)
