"""The event method in closed form for one persistent contact of a constant system.

When a system has constant mass, contact kinematics and forces, no bilateral constraints and a
single contact that starts closed (g = 0, u_N = 0), every smooth phase has constant accelerations
and the whole motion is a short sequence of quadratic pieces: slide, stop, then stick for ever or
slide back. Each piece follows from the acceleration-level contact problem of that one contact,

    a = W lambda + b,   W = H A^-1 H',   b = H A^-1 F0,

in closed form (stick where its forces lie in the friction cone, the sliding branch p_T = -+mu p_N
otherwise), and each event is a linear root (the stop, u_T = 0). Nothing here calls CasADi or a
solver, so a new parameter set costs microseconds: this is the event path of the Jean-Pratt scene
and of any block on a flat support under constant loads.

:func:`single_contact_run` returns None whenever the general integrator is needed (the contact
opens or starts open, an impact, a Painleve case with no or several consistent modes, non-default
integrator options); the caller then runs :func:`lcp.events.event_driven`, whose answer this path
reproduces to rounding (tests compare the two on random parameters).
"""
from __future__ import annotations

import math

import numpy as np

from lcp.contact.problem import MODE_NAMES, SLIDE_NEG, SLIDE_POS, STICK
from lcp.result import STATUS_MESSAGES, SolverStats
from lcp.events.event_location import first_stop
from lcp.events.options import EventOptions, checked_times, times_inside
from lcp.events.records import Event, EventResult, Phase, make_record, new_event_result

__all__ = ["applicable", "event_options", "run_with_options", "single_contact_run"]

_DEFAULT = EventOptions()
_EPS = float(np.finfo(float).eps)


def event_options(options: dict) -> EventOptions:
    """``EventOptions.from_kwargs(**options)`` (validated), the defaults shared when none are given."""
    return EventOptions.from_kwargs(**options) if options else _DEFAULT


def run_with_options(model, q0, v0, t_end: float, options: dict) -> EventResult | None:
    """``single_contact_run(model, q0, v0, t_end, event_options(options))``, the same result.

    Where ``t_eval`` is the only option given (what a sweep passes), only it is checked, and the
    checked copy is the result's ``t``: the other options are the defaults, valid by construction.
    """
    if len(options) == 1 and "t_eval" in options and options["t_eval"] is not None:
        return _run(model, q0, v0, t_end, _DEFAULT, checked_times(options["t_eval"]))
    return _run(model, q0, v0, t_end, event_options(options), None)


def applicable(model, opts: EventOptions) -> bool:
    """Whether the structure allows this path (the initial state is checked by the run)."""
    if model.m != 1 or model.nb or not model.constant_forces:
        return False
    return (opts.smooth == _DEFAULT.smooth and opts.mode_solver == _DEFAULT.mode_solver
            and opts.impact_solver == _DEFAULT.impact_solver)


def _at_rest(W00, W01, W10, W11, bN, bT, mu):
    """(N, f, mode) of a closed contact at rest, a = W (N, f) + b, or None (the general path decides).

    Every case of the contact law is tried: open (the free motion separates), stick (forces in
    the friction cone up to the rounding of their own terms, not up to a tolerance relative to the
    normal force: a tangential load 1e-11 of the weight, without friction, does set the block in
    motion), and the two sliding directions (tangential acceleration of the sign of the slide).
    The one admissible case is returned; None where the contact opens, or where no case or several
    are admissible (Painleve: the general integrator reports it and picks a motion).
    """
    found = []
    if bN >= 0.0:
        found.append(None)  # open: a flight phase, which this path does not integrate
    det = W00 * W11 - W01 * W10
    if det > 0.0:
        N = (-bN * W11 + bT * W01) / det
        f = (-bT * W00 + bN * W10) / det
        rN = 8 * _EPS * (abs(bN * W11) + abs(bT * W01)) / det
        # (+ 1e-300 N: a residue in the subnormal range is rounding too, where eps times it underflows)
        rf = 8 * _EPS * (abs(bT * W00) + abs(bN * W10)) / det + 1e-300 * abs(N)
        if N > rN and abs(f) <= mu * (N + rN) + rf:
            found.append((N, f, STICK))
    for s, mode in ((1.0, SLIDE_POS), (-1.0, SLIDE_NEG)):
        a_coef = W00 - s * mu * W01
        if not a_coef > 0.0:
            continue
        N = -bN / a_coef
        aT = bT + (W10 - s * mu * W11) * N
        if N > 0.0 and s * aT > 8 * _EPS * (abs(bT) + abs((W10 - s * mu * W11) * N)) + 1e-300 * abs(bN):
            found.append((N, -s * mu * N, mode))
    return found[0] if len(found) == 1 else None


_OUTPUT = []


def _output():
    """The output writer (:mod:`.closed_form_kernels`, imported on first use: numba loads there)."""
    if not _OUTPUT:
        from lcp.events.closed_form_kernels import piece_output

        _OUTPUT.append(piece_output)
    return _OUTPUT[0]


try:  # LAPACK's solve without np.linalg.solve's wrapper (a third of its cost on a 2x2 system)
    from numpy.linalg._linalg import _raise_linalgerror_singular
    from numpy.linalg._umath_linalg import solve as _solve_gufunc

    # the error handling np.linalg.solve sets around the same call: a singular matrix raises LinAlgError
    @np.errstate(call=_raise_linalgerror_singular, invalid="call", over="ignore", divide="ignore", under="ignore")
    def _solve(A, B):
        return _solve_gufunc(A, B, signature="dd->d")
except ImportError:  # pragma: no cover - a NumPy without these internals
    _solve = np.linalg.solve


def _dot(a, b) -> float:
    s = 0.0
    for x, y in zip(a, b):
        s += x * y
    return s


def _coordinate(row) -> int:
    """The index of the only nonzero entry of a Jacobian row, or -1."""
    nz = [i for i, x in enumerate(row) if x != 0.0]
    return nz[0] if len(nz) == 1 else -1


def single_contact_run(model, q0, v0, t_end: float, opts: EventOptions) -> EventResult | None:
    """The event-driven motion of a single-contact constant system, or None (general path needed).

    Parameters
    ----------
    model : lcp.timestepping.constant_model.ConstantModel
        With one contact, no bilateral constraints, constant forces (:func:`applicable`).
    q0, v0 : ndarray (n,)
        Initial state, finite (checked by the caller).
    t_end : float
    opts : EventOptions

    Returns
    -------
    EventResult or None
    """
    return _run(model, q0, v0, t_end, opts, None)


def _run(model, q0, v0, t_end, opts, t_out):
    """:func:`single_contact_run` with the output times checked already (``t_out``), or None to
    take them from ``opts``."""
    if not applicable(model, opts):
        return None
    n = model.n
    A, H, mu = model.A, model.H, float(model.mu[0])
    # plain floats: a handful of coordinates, where each NumPy call would cost more than its work
    HN, HT = H[0].tolist(), H[1].tolist()
    q, v = q0.tolist(), v0.tolist()
    gap = float(model.gap0[0]) + _dot(HN, q)
    # the contact must start closed and at rest normally; anything else (flight, impact) is general
    if gap != 0.0 or _dot(HN, v) != 0.0:
        return None
    # A^-1 [H_N' H_T' F0 d+ d-] in one factorization, d+- = H_N -+ mu H_T the sliding directions
    # with the friction folded in (as the general integrator forms them, lcp.events.modes)
    # (the rows in floats: the same elementwise operations as NumPy's, without its per-call cost)
    X = _solve(A, np.array([[hn, ht, f, hn - mu * ht, hn + mu * ht]
                            for hn, ht, f in zip(HN, HT, model.F0.tolist())]))
    # a row that fixes one coordinate lets its condition be imposed exactly on that coordinate
    coord_N = _coordinate(HN)
    coord_T = _coordinate(HT)
    # (cN, cT, qdd_free, d+, d-) = A^-1 (H_N', H_T', F0, d+, d-), as lists of floats
    cN, cT, qdd_free, SDp, SDm = map(list, zip(*X.tolist()))
    if coord_N >= 0 and coord_T >= 0:
        # rows with one nonzero entry: each product H_i x of the NumPy path is the one term
        # c x[i] (the other terms are exact zeros), so floats give the same bits
        kN, kT = HN[coord_N], HT[coord_T]

        def rowN(x):
            return 0.0 + kN * x[coord_N]

        W00, W01, bN = rowN(cN), rowN(cT), rowN(qdd_free)
        W10, W11, bT = 0.0 + kT * cN[coord_T], 0.0 + kT * cT[coord_T], 0.0 + kT * qdd_free[coord_T]
        bN_np = bN
        sd_views = None
    else:
        (W00, W01, bN), (W10, W11, bT) = (H @ X[:, :3]).tolist()  # W = H A^-1 H', b = H A^-1 F0
        bN_np = float(H[0] @ X[:, 2])
        sd_views = (X[:, 3], X[:, 4])  # the sliding directions' products on the arrays of the NumPy path

        def rowN(x):
            return float(H[0] @ np.asarray(x))

    free_size = max(map(abs, qdd_free))
    iterations = 0
    pieces = []  # (t0, t1, q0, v0, P0, qdd, N, f, mode) per closed-form phase
    t_events = []
    t = 0.0
    PN = PT = 0.0
    for _ in range(4):  # slide, stop, stick or slide back: at most three pieces under constant data
        uT = _dot(HT, v)
        s = 1.0 if uT > 0 else -1.0
        if uT != 0.0:
            # the general integrator's arithmetic (lcp.events.modes.AccelProblem): the sliding
            # friction folded into the normal direction d = H_N - s mu H_T, so that the two paths
            # agree to the last bit on the event times they compute
            iterations += 1
            SD = SDp if s > 0 else SDm
            a_coef = rowN(SD) if sd_views is None else float(H[0] @ sd_views[s < 0])
            if not a_coef > 0.0:
                return None  # Painleve: no or several consistent sliding modes, general path decides
            N = -bN_np / a_coef
            if not N > 0.0:
                return None  # the contact would open: a flight phase
            f = -s * mu * N
            mode = SLIDE_POS if s > 0 else SLIDE_NEG
            qdd = [a + x * N for a, x in zip(qdd_free, SD)]
            acc_size = free_size + abs(N) * max(map(abs, SD))
            r = rowN(qdd) / W00
            qdd = [a - x * r for a, x in zip(qdd, cN)]  # normal acceleration: zero
        else:
            decided = _at_rest(W00, W01, W10, W11, bN, bT, mu)
            iterations += 3
            if decided is None:
                return None
            N, f, mode = decided
            qdd = [a + N * x + f * y for a, x, y in zip(qdd_free, cN, cT)]
            acc_size = free_size + max(abs(N * x) + abs(f * y) for x, y in zip(cN, cT))
            if mode == STICK:  # remove the rounding residues of H qdd = 0 in the mass metric
                aN, aT = _dot(HN, qdd), _dot(HT, qdd)
                det = W00 * W11 - W01 * W10
                dN, dT = (aN * W11 - aT * W01) / det, (aT * W00 - aN * W10) / det
                qdd = [a - dN * x - dT * y for a, x, y in zip(qdd, cN, cT)]
                if coord_T >= 0:
                    qdd[coord_T] = 0.0
            else:
                r = _dot(HN, qdd) / W00
                qdd = [a - r * x for a, x in zip(qdd, cN)]
        if coord_N >= 0:
            qdd[coord_N] = 0.0
        N, f, mode = float(N), float(f), int(mode)
        aT = _dot(HT, qdd)
        if abs(aT) <= 16 * _EPS * acc_size:
            aT = 0.0  # a deceleration at the rounding level of its terms (no friction, balanced loads)
        # signs compared, not the product (which underflows for tiny speeds and decelerations)
        t_stop = t + first_stop(uT, aT, 1.0 if mode == SLIDE_POS else -1.0) if mode != STICK else math.inf
        if not t_stop < t_end:
            pieces.append((t, t_end, q, v, [PN, PT], qdd, N, f, mode))
            break
        pieces.append((t, t_stop, q, v, [PN, PT], qdd, N, f, mode))
        dt = t_stop - t
        hdt2 = 0.5 * dt * dt
        q = [x + dt * y + hdt2 * z for x, y, z in zip(q, v, qdd)]
        v = [y + dt * z for y, z in zip(v, qdd)]
        # at the stop both contact velocities are zero: remove their rounding residues in the mass
        # metric, exactly on coordinate rows
        uN, uT = _dot(HN, v), _dot(HT, v)
        det = W00 * W11 - W01 * W10
        dN, dT = (uN * W11 - uT * W01) / det, (uT * W00 - uN * W10) / det
        v = [y - dN * x - dT * z for y, x, z in zip(v, cN, cT)]
        for i in (coord_N, coord_T):
            if i >= 0:
                v[i] = 0.0
        PN, PT = PN + dt * N, PT + dt * f
        t_events.append(t_stop)
        t = t_stop
    else:  # pragma: no cover - constant data allow no fourth piece
        return None
    t_out = opts.output_times(t_end) if t_out is None else times_inside(t_out, t_end)
    # rows (q, v, cumulative impulses) over the output times: c0 + dt c1 + dt^2/2 c2 per piece
    # (the general integrator's closed-form output, same operations), written in one call
    zeros = [0.0] * (n + 2)
    P = np.array([[p[0], p[1], p[6], p[7], p[8]] for p in pieces])
    C = np.array([[p[2] + p[3] + p[4] for p in pieces], [p[3] + p[5] + [p[6], p[7]] for p in pieces],
                  [p[5] + zeros for p in pieces]])
    Q, V, dPN, dPT, FN, FT, MD = _output()(t_out, P, C, n)
    k = len(pieces)
    stats = SolverStats()
    stats.steps = stats.solver_calls = k
    stats.iterations, stats.max_iterations = iterations, 4
    counts = stats.mode_counts
    phases = []
    for p in pieces:
        name = MODE_NAMES[p[8]]
        counts[name] += 1
        phases.append(make_record(Phase, p[0], p[1], (name,), "closed-form", 0, True))
    return new_event_result(t=t_out, q=Q, v=V, p_N=dPN, p_T=dPT, modes=MD[:-1], status=0,
                            message=STATUS_MESSAGES[0], stats=stats, method="event", solver="enumerate",
                            t_events=t_events, force_N=FN, force_T=FT,
                            events=[make_record(Event, te, "stop", 0) for te in t_events], impulses=[],
                            phases=phases, impacts=[], accumulations=[], nonunique_forces=0)
