"""Landing the replay of an unstable trajectory: Newton steps on the control against the event replay.

A swing-up to an unstable upright amplifies errors: on the cart-pole at N = 20 a change of the
start state moves the final state 1.7e6 times as far. The exact-phase shooting joins its phases
to IPOPT's tolerance (1e-10) as CVODES integrates them (rtol 1e-12); amplified, those errors put
the optimizer's final state 5.6e-5 away from where its control really goes, and the replay check
fails although the trajectory is right to the shooting's tolerances.

The miss is then a small, smooth function of the control: :func:`land` corrects the control by
Newton steps on it, the final state's derivatives taken by finite differences of event replays
at a tight tolerance (:data:`LANDING_RTOL`), until that replay lands on the optimizer's final
state. The controls are taken from the last interval backwards (a late control's effect is
amplified least, and the trajectory before it is untouched) until the linear model can remove the
miss by a small change; controls at their bounds are kept. Where those Newton steps do not land,
the differences are taken again at a larger step (:data:`FD_STEPS`): the replay's own errors,
divided by a small step, can swamp a direction the controls move only weakly. The landed result is
checked again by
the event replay at that tolerance, whose own error is estimated by one more replay at
:data:`ESTIMATE_RTOL` and counted in the check (:func:`lcp.ocp.replay.replay_check`).

The replays are restarted at every node (each interval integrated on its own; a difference then
replays only from its interval on). The one integration over the whole schedule was less
accurate there: on the cart-pole's landed swing-up at N = 40 it moved by 4e-6 between rtol 1e-12
and 3e-14, not monotonically, while the restarted replays converged (2.0e-6 at 1e-12, 5.5e-7 at
1e-13, 5.3e-8 at 2.3e-14 from the landed 1.1e-9 at 3e-14) and Radau's at 1e-12 was 1.8e-7 from
it. A landing on the one integration would have left a true miss of 3e-6.

Measured on the cart-pole's swing-up at N = 20 (cost 571.12, replay miss 5.6e-5): nine controls
differenced (the last eight act while the cart sticks and move nothing), one Newton step, control
change 6.3e-6, 11 replays in 7.3 s; the replay at rtol 3e-14 then ends 1.7e-9 from the
optimizer's final state, the one at 1e-13 2.4e-7 (the estimate).
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from lcp.ocp.replay import event_pieces, replay_check

__all__ = ["ESTIMATE_RTOL", "JOIN_ERROR", "LANDING_RTOL", "Landing", "land", "landable"]

#: the event integrator's tolerance for the landing's replays (DOP853: SciPy's floor is 100 eps)
LANDING_RTOL = 3e-14
#: the looser tolerance of the second replay that estimates the landed check's integration error
ESTIMATE_RTOL = 1e-13
#: errors of the optimizer's trajectory that a landing may explain: the shooting's joins and
#: IPOPT's constraint tolerance (a miss larger than this many times the amplification is not a
#: conditioning error but another trajectory)
JOIN_ERROR = 1e-9
#: the finite-difference steps, relative to the control's range (1 where unbounded): the first,
#: then, where its Newton steps do not land, the second. On the two discs at N = 60 (under
#: OpenBLAS's AVX-512 kernels: shooting miss 8.2e-6, amplification 6.9e4) disc 2's final state
#: answers weakly to the controls (the smallest singular value of the differences 2.7e-6), and
#: the replay's own errors divided by the first step swamped that direction: its chord first
#: overshot (4.2e-5), then gained a factor 7.5 per step (1.1e-7 after four). The differences at the
#: second step differed from those by 10 %, and the chord landed in two steps (6.1e-10)
FD_STEPS = (1e-6, 1e-4)
#: the largest control change a landing may make, relative to the control's range
MAX_CHANGE = 1e-3
#: at most this many controls are differenced, and this many Newton steps taken. The two discs at
#: N = 60 needed 58: after the strike disc 2 moves on its own and the controls of the strike sit at
#: their bounds, so disc 2's final state answers only to the controls before it
MAX_COLUMNS = 120
NEWTON_STEPS = 4


@dataclasses.dataclass
class Landing:
    """A landed control: ``u`` (the result's layout), the replays it took (differences and
    Newton steps), the largest control change, the misses before and after (at
    :data:`LANDING_RTOL`), and the time."""

    u: np.ndarray
    replays: int
    columns: int
    steps: int
    change: float
    miss_before: float
    miss_after: float
    time: float


def landable(rc, tol: float) -> bool:
    """Whether a replay check's miss is one that :func:`land` addresses: an event replay that
    amplifies start errors so much that a trajectory exact to about ``tol / amplification`` (below
    1e-10) would be needed, and whose miss such errors explain (at most :data:`JOIN_ERROR` times
    the amplification), with the path constraints met."""
    a = rc.amplification
    return bool(rc.method.startswith("event") and np.isfinite(a) and tol / max(a, 1e-300) < 1e-10
                and rc.final_miss <= JOIN_ERROR * a and rc.path_violation <= tol)


def _replay(result, u, first: int = 0, start=None):
    """The nodes (q, v) from node ``first`` of the event replay of control ``u``, restarted at every
    node (from ``start`` at node ``first``)."""
    res = dataclasses.replace(result, u=u, control=result.problem.schedule(result.t, u))
    q, v, _ = event_pieces(res, restart=True, first=first, start=start, n_eval=2, rtol=LANDING_RTOL)
    return q, v


def _interval_of(pb, row: int) -> int:
    """The first control interval that control row ``row`` acts on (the affine hold has two rows per
    interval, the linear hold one per node)."""
    if pb.hold == "affine":
        return row // 2
    if pb.hold == "linear":
        return max(row - 1, 0)
    return row


def land(result, tol: float) -> Landing | None:
    """Correct ``result``'s control so that its event replay at :data:`LANDING_RTOL` ends within
    ``tol`` / 100 of the optimizer's final state (module docstring), with the differences at each
    step of :data:`FD_STEPS` in turn; None where the differenced controls cannot remove the miss by
    a change below :data:`MAX_CHANGE` of their range, or the Newton steps do not converge. A replay
    that fails raises RuntimeError."""
    t0 = time.perf_counter()
    target = np.concatenate([result.q[-1], result.v[-1]])
    u0 = np.array(result.u, dtype=float)
    qb, vb = _replay(result, u0)
    r0 = np.concatenate([qb[-1], vb[-1]]) - target
    before, goal, replays = float(np.max(np.abs(r0))), tol / 100.0, 1
    for fd in FD_STEPS:
        J, idx, alpha, n = _differences(result, u0, (qb, vb), r0, fd, goal)
        replays += n
        if alpha is None:
            continue
        u, r = u0.copy(), r0
        for steps in range(1, NEWTON_STEPS + 1):
            for (k, j), d in zip(idx, alpha):
                u[k, j] += d
            q1, v1 = _replay(result, u)
            r = np.concatenate([q1[-1], v1[-1]]) - target
            replays += 1
            if np.max(np.abs(r)) <= goal:
                return Landing(u=u, replays=replays, columns=len(idx), steps=steps,
                               change=float(np.max(np.abs(u - u0))), miss_before=before,
                               miss_after=float(np.max(np.abs(r))), time=time.perf_counter() - t0)
            alpha = -np.linalg.lstsq(J, r, rcond=1e-12)[0]  # (the chord: the same differences)
    return None


def _differences(result, u0, base, r, fd: float, goal: float):
    """(J, idx, alpha, replays): the final state's differences with respect to the controls
    ``idx`` ((row, component) pairs, from the last interval backwards, those at their bounds
    skipped), at the step ``fd`` of each control's range, taken until the least-squares change
    ``alpha`` removes the miss ``r`` to ``goal`` in the linear model with every change below
    :data:`MAX_CHANGE` of its range (alpha None where :data:`MAX_COLUMNS` controls do not)."""
    pb = result.problem
    qb, vb = base
    f0 = np.concatenate([qb[-1], vb[-1]])
    lo, hi = np.broadcast_to(pb.u_min, u0.shape[1:]), np.broadcast_to(pb.u_max, u0.shape[1:])
    span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    cols, idx, J = [], [], None
    for k in range(u0.shape[0] - 1, -1, -1):
        for j in range(u0.shape[1]):
            room = min(u0[k, j] - lo[j], hi[j] - u0[k, j])
            if room <= MAX_CHANGE * span[j]:
                continue  # at (or next to) a bound: kept
            eps = fd * span[j]
            up = u0.copy()
            up[k, j] += eps
            k0 = _interval_of(pb, k)  # (the replay before that interval is unchanged)
            q1, v1 = _replay(result, up, k0, (qb[k0], vb[k0]))
            cols.append((np.concatenate([q1[-1], v1[-1]]) - f0) / eps)
            idx.append((k, j))
        if not cols:
            continue
        J = np.array(cols).T
        a = -np.linalg.lstsq(J, r, rcond=1e-12)[0]
        if np.all(np.abs(a) <= MAX_CHANGE * span[[j for _, j in idx]]) and np.max(np.abs(J @ a + r)) <= goal:
            return J, idx, a, len(cols)
        if len(cols) >= MAX_COLUMNS:
            break
    return J, idx, None, len(cols)


def landed(result, rc, tol: float):
    """``result`` with its control landed (:func:`land`) and checked again by the event replay at
    :data:`LANDING_RTOL` (its integration error estimated at :data:`ESTIMATE_RTOL`), and a note
    saying what was done; (None, why not) where the landing fails or its check misses."""
    head = (f" The replay of the optimizer's control missed by {rc.final_miss:.2e} and amplifies start-state "
            f"errors {rc.amplification:.1e} times (an unstable trajectory)")
    try:
        ld = land(result, tol)
    except RuntimeError as exc:
        return None, f"{head}; landing it failed: {exc}."
    if ld is None:
        return None, (f"{head}; no control change below {MAX_CHANGE:g} of the control's range lands its "
                      f"replay at rtol {LANDING_RTOL:.0e} within {tol / 100:.1e}.")
    out = dataclasses.replace(result, u=ld.u, control=result.problem.schedule(result.t, ld.u))
    check = replay_check(out, tol, rtol=LANDING_RTOL, estimate_rtol=ESTIMATE_RTOL, restart=True)
    note = (f"{head}; Newton steps on the control against its event replay at rtol {LANDING_RTOL:.0e} "
            f"({ld.steps} {'step' if ld.steps == 1 else 'steps'}, {ld.columns} controls differenced, "
            f"{ld.replays} replays, {ld.time:.1f} s) changed it by at most {ld.change:.1e} and landed "
            f"that replay {ld.miss_after:.1e} from the optimizer's final state (the optimizer's states at the "
            f"nodes are {check.node_miss:.1e} from it at most).")
    if not check.ok:
        return None, f"{note} Its check missed: final-state miss {check.final_miss:.2e}, integration error " \
                     f"{check.integration_error:.2e}, path violation {check.path_violation:.2e}."
    out.replay = check
    return out, note
