r"""The LEM on the spatial sliding branch: a point mass sliding in a plane with disk Coulomb friction.

While the sliding velocity U (a 2-vector) is non-zero, U' = b - a U/|U|, X' = U, with b the
in-plane applied acceleration and a = mu N / m the friction deceleration (N constant). The
engine (:func:`lem.solve`) needs a polynomial field; U/|U| is not one, but becomes one with the
auxiliary variable w = 1/|U|:

``formulation="velocity"`` (default), state (U1, U2, w, X1, X2)::

    U' = b - a w U,    w' = -w**3 U.U' = a w**2 - w**3 (b.U),    X' = U

(w' uses w**2 |U|**2 = 1, which holds on the branch: the field is exact there and of degree 4).

``formulation="direction"``, state (c, d, w, s, X1, X2) with (c, d) = U/|U|, s = |U|, w = 1/s::

    (c, d)' = w (b - (b.e) e),  w' = w**2 (a - b.e),  s' = b.e - a,  X' = s e,   e = (c, d)

(degree 3; exact on the branch c**2 + d**2 = 1, w s = 1).

Both are exact on the branch and carry the motion to round-off with restarts. The velocity form
is the default: five variables instead of six and a quarter fewer moments at the same degree
(degree 8 with restarts: 83 moments against 147), hence faster, with the same accuracy (incline with
mu = tan(theta), horizontal launch, t <= 2 s: 1e-15 against the exact solution). The direction
form keeps every variable but w bounded and its field has a lower degree; it is there for
comparison.

Both blow up where the block stops: w = 1/|U| -> inf, so the Taylor series of the solution about
a restart point t_c converges only for |t - t_c| < t_stop - t_c and the restart steps shrink
geometrically towards the stop. :func:`solve_spatial_sliding` therefore runs the engine in
windows that end before the stop: since d/dt (b.U/|U|) = |b|**2 - (b.U/|U|)**2 >= 0 (times w), the
deceleration a - b.U/|U| never grows, so the stop is no earlier than t + |U| / (a - b.U/|U|); each
window covers 0.9 of that bound. Once |U| < ``stop_speed`` |U(0)|, the last straight bit is
closed by the constant-deceleration formula and the block sticks (|b| <= a) or slips from rest
along b (the exact, polynomial continuation; w is not defined there).

Examples
--------
An incline of 30 degrees with mu = tan(30 deg), launched horizontally at 2 m/s: the speed tends
to v0/2 = 1.

>>> import math
>>> from lem.spatial_sliding import solve_spatial_sliding
>>> g, th = 9.81, math.radians(30)
>>> res = solve_spatial_sliding([0.0, 2.0], 2.0, accel=[g * math.sin(th), 0.0], decel=g * math.sin(th),
...                             t_eval=[0.0, 1.0, 2.0])
>>> res.success, [round(float(v), 6) for v in res.speed]
(True, [2.0, 1.000149, 1.0])
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .fields import PolynomialField
from .propagation import solve
from .validation import check_float, check_int, finite_vector

__all__ = ["SpatialSlidingResult", "solve_spatial_sliding", "spatial_sliding_field"]

_FORMS = {"velocity": 5, "direction": 6}


def _e(n, *idx):
    e = [0] * n
    for i in idx:
        e[i] += 1
    return tuple(e)


def spatial_sliding_field(accel, decel, formulation: str = "velocity") -> PolynomialField:
    """The polynomial vector field of the sliding branch (see the module docstring).

    Parameters
    ----------
    accel : 2-vector
        In-plane applied acceleration b.
    decel : float
        Friction deceleration a = mu N / m >= 0.
    formulation : "velocity" or "direction"
        State (U1, U2, w, X1, X2) or (c, d, w, s, X1, X2).

    Examples
    --------
    >>> f = spatial_sliding_field([1.0, 0.0], 2.0)
    >>> f.n, f.degree
    (5, 4)
    >>> f(0.0, [0.0, 2.0, 0.5, 0.0, 0.0]).tolist()      # U' = b - a U/|U|, w' = a w^2 - w^3 b.U
    [1.0, -2.0, 0.5, 0.0, 2.0]
    """
    b1, b2 = (float(v) for v in finite_vector("accel", accel, 2))
    check_float("decel", decel, 0.0)
    a = float(decel)
    if formulation == "velocity":
        n = 5
        U1, U2, W = 0, 1, 2
        comps = [{_e(n): b1, _e(n, W, U1): -a},
                 {_e(n): b2, _e(n, W, U2): -a},
                 {_e(n, W, W): a, _e(n, W, W, W, U1): -b1, _e(n, W, W, W, U2): -b2},
                 {_e(n, U1): 1.0},
                 {_e(n, U2): 1.0}]
    elif formulation == "direction":
        n = 6
        C, D, W, S = 0, 1, 2, 3
        comps = [{_e(n, W): b1, _e(n, W, C, C): -b1, _e(n, W, C, D): -b2},
                 {_e(n, W): b2, _e(n, W, C, D): -b1, _e(n, W, D, D): -b2},
                 {_e(n, W, W): a, _e(n, W, W, C): -b1, _e(n, W, W, D): -b2},
                 {_e(n, C): b1, _e(n, D): b2, _e(n): -a},
                 {_e(n, S, C): 1.0},
                 {_e(n, S, D): 1.0}]
    else:
        raise ValueError(f"formulation must be 'velocity' or 'direction', got {formulation!r}")
    return PolynomialField(comps)


def _to_state(U, X, formulation):
    s = math.hypot(U[0], U[1])
    if formulation == "velocity":
        return np.array([U[0], U[1], 1.0 / s, X[0], X[1]])
    return np.array([U[0] / s, U[1] / s, 1.0 / s, s, X[0], X[1]])


def _physical(y, err, formulation):
    """(x, y, vx, vy) rows and their error estimates from the engine's state rows."""
    if formulation == "velocity":
        return np.vstack([y[3], y[4], y[0], y[1]]), np.vstack([err[3], err[4], err[0], err[1]])
    c, d, s = y[0], y[1], y[3]
    ec, ed, es = err[0], err[1], err[3]
    return (np.vstack([y[4], y[5], s * c, s * d]),
            np.vstack([err[4], err[5], np.abs(c) * es + np.abs(s) * ec, np.abs(d) * es + np.abs(s) * ed]))


@dataclass
class SpatialSlidingResult:
    """What :func:`solve_spatial_sliding` returns.

    Attributes
    ----------
    t : (m,) output times
    x, y, vx, vy, speed : (m,) positions and velocity in the plane
    error_estimate : (4, m)
        Engine estimates for (x, y, vx, vy): the window's own a-posteriori estimate plus the sum
        of the previous windows' final estimates (0 on the exact stick/slip continuation beyond
        the stop, apart from what was carried there).
    status : int
        The worst engine status over the windows (0: every estimate met rtol/atol; 1: some did
        not; < 0: a window failed, the outputs from its start on are NaN).
    message : str
    t_stop : float
        The stop time reached (inf if the block was still sliding at t_end).
    n_windows, n_restarts : int
        Engine calls (windows before the stop) and restart segments over all of them.
    """

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    vx: np.ndarray
    vy: np.ndarray
    speed: np.ndarray
    error_estimate: np.ndarray
    status: int
    message: str
    t_stop: float
    n_windows: int
    n_restarts: int

    @property
    def success(self) -> bool:
        return self.status >= 0


def solve_spatial_sliding(v0, t_end, *, accel=(0.0, 0.0), decel=0.0, x0=(0.0, 0.0), t_eval=None,
                          formulation: str = "velocity", degree: int = 8, restart="auto",
                          rtol: float = 1e-12, atol: float = 1e-13, stop_speed: float = 1e-9,
                          window_fraction: float = 0.9) -> SpatialSlidingResult:
    """Solve the sliding of a point mass in a plane with disk friction by the LEM engine.

    Parameters
    ----------
    v0 : 2-vector
        Initial sliding velocity (non-zero: the branch needs |U| > 0).
    t_end : float
        Final time (> 0).
    accel : 2-vector
        In-plane applied acceleration b (gravity's in-plane part plus force / mass).
    decel : float
        Friction deceleration a = mu N / m >= 0 (N constant).
    x0 : 2-vector
        Initial position.
    t_eval : array_like, optional
        Output times in [0, t_end], increasing (default: 0, every window end, t_end).
    formulation : "velocity" or "direction"
        Polynomial form of the field (see :func:`spatial_sliding_field`).
    degree, restart, rtol, atol
        Engine options (:class:`lem.result.LEMOptions`): truncation degree, restart policy,
        tolerances of its error control.
    stop_speed : float
        Relative speed |U| / |U(0)| below which the stop is closed analytically (0 < stop_speed < 1).
    window_fraction : float
        Share of the guaranteed time before the stop covered by one window (0 < . < 1).

    Returns
    -------
    SpatialSlidingResult

    Examples
    --------
    Oblique launch on a horizontal plane (mu g = 2.943): stop at v0 / (mu g), then rest.

    >>> res = solve_spatial_sliding([1.2, 1.6], 1.0, decel=2.943, t_eval=[0.5, 1.0])
    >>> round(res.t_stop, 12), round(float(res.x[-1]), 12), float(res.speed[-1])
    (0.67957866123, 0.407747196738, 0.0)
    """
    v0 = finite_vector("v0", v0, 2)
    b = finite_vector("accel", accel, 2)
    check_float("decel", decel, 0.0)
    a = float(decel)
    X0 = finite_vector("x0", x0, 2)
    check_float("t_end", t_end, 0.0, strict=True)
    t_end = float(t_end)
    if formulation not in _FORMS:
        raise ValueError(f"formulation must be 'velocity' or 'direction', got {formulation!r}")
    check_int("degree", degree, 1)
    check_float("stop_speed", stop_speed, 0.0, strict=True)
    if not stop_speed < 1:
        raise ValueError(f"stop_speed must be < 1, got {stop_speed!r}")
    check_float("window_fraction", window_fraction, 0.0, strict=True)
    if not window_fraction < 1:
        raise ValueError(f"window_fraction must be < 1, got {window_fraction!r}")
    s0 = math.hypot(v0[0], v0[1])
    if s0 == 0:
        raise ValueError("v0 must be non-zero: the sliding branch needs |U| > 0 (w = 1/|U|)")
    if t_eval is not None:
        te = finite_vector("t_eval", t_eval)
        if te.size == 0 or np.any(te < 0) or np.any(te > t_end) or np.any(np.diff(te) <= 0):
            raise ValueError("t_eval must be increasing times in [0, t_end]")
    else:
        te = None
    fld = spatial_sliding_field(b, a, formulation)
    opts = {"degree": degree, "restart": restart, "rtol": rtol, "atol": atol, "warn": False}
    bnorm = math.hypot(b[0], b[1])

    T, P, E = [0.0], [np.array([X0[0], X0[1], v0[0], v0[1]])], [np.zeros(4)]
    t, U, X = 0.0, v0.copy(), X0.copy()
    carried = np.zeros(4)
    status, message, n_windows, n_restarts = 0, "", 0, 0
    t_stop = math.inf
    while t < t_end:
        s = math.hypot(U[0], U[1])
        dec = a - float(b @ U) / s
        if dec > 0 and s <= stop_speed * s0:
            # the last straight bit: constant deceleration to rest (its curvature is below rounding)
            t_stop = t + s / dec
            last = (t, X.copy(), U.copy(), dec)
            X = X + U * (s / (2 * dec))
            break
        h = t_end - t
        if dec > 0:
            h = min(h, window_fraction * s / dec)
        t1 = min(t_end, t + h)
        pts = [] if te is None else [p for p in te if t < p < t1]
        res = solve(fld, (t, t1), _to_state(U, X, formulation), t_eval=[*pts, t1], **opts)
        n_windows += 1
        n_restarts += res.n_restarts
        if res.status < 0 or not np.all(np.isfinite(res.y)):
            status, message = min(res.status, -1), res.message
            t_stop = math.nan
            break
        if res.status > status:
            status, message = res.status, res.message
        phys, err = _physical(res.y, res.error_estimate, formulation)
        for i in range(res.t.size):
            T.append(float(res.t[i]))
            P.append(phys[:, i])
            E.append(np.nan_to_num(err[:, i], nan=0.0) + carried)
        carried = E[-1].copy()
        X, U = phys[:2, -1].copy(), phys[2:, -1].copy()
        t = t1
    T, P, E = np.array(T), np.array(P).T, np.array(E).T
    if te is None:
        te_out = T if not math.isfinite(t_stop) else np.append(T, [v for v in (t_stop, t_end) if v > T[-1]])
    else:
        te_out = te
    m = te_out.size
    out = np.full((4, m), np.nan)
    est = np.full((4, m), np.nan)
    for i, tt in enumerate(te_out):
        j = np.flatnonzero(T == tt)
        if j.size:
            out[:, i], est[:, i] = P[:, j[0]], E[:, j[0]]
        elif math.isfinite(t_stop) and tt < t_stop:
            tl, Xl, Ul, dl = last
            dt, sl = tt - tl, math.hypot(*Ul)
            out[:, i] = [*(Xl + Ul * (dt - 0.5 * dl * dt * dt / sl)), *(Ul * (1 - dl * dt / sl))]
            est[:, i] = carried
        elif math.isfinite(t_stop) and tt >= t_stop:
            dt = tt - t_stop
            extra = 0.0 if bnorm <= a else bnorm - a   # stick, or slip from rest along b
            e1 = b / bnorm if bnorm > 0 else np.zeros(2)
            out[:, i] = [X[0] + 0.5 * extra * dt * dt * e1[0], X[1] + 0.5 * extra * dt * dt * e1[1],
                         extra * dt * e1[0], extra * dt * e1[1]]
            est[:, i] = carried
    if status == 0:
        message = "Converged: every window's error estimate met atol + rtol*|y|."
    if math.isfinite(t_stop):
        message += f" Stopped at t = {t_stop:.15g}."
    return SpatialSlidingResult(te_out, out[0], out[1], out[2], out[3], np.hypot(out[2], out[3]), est,
                                status, message, float(t_stop), n_windows, n_restarts)
