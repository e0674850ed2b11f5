"""Newton-Euler kinematics qdot = T(t, q) v, and unit quaternions kept on their sphere.

A system whose velocities are not the rates of its coordinates (a free rigid body: q = position and
unit quaternion, 7 numbers; v = linear velocity and body angular velocity, 6) is written
``System(q, v, ..., kinematics=T, unit_quaternions=(3,))`` with T an n_q x n_v CasADi expression
of t and q. The mass matrix, the forces and the contact reactions then live in v-space, and every
Jacobian the integrators use maps v: H = (dg/dq) T (docs/rigid_bodies.md).

Holds the checks of T (:func:`kinematics_matrix` when the System is built, :func:`check_kinematics_at`
at a start), of the declared quaternions (:func:`quaternion_starts`, :func:`quaternion_start`), the
quaternion algebra (:func:`quat_mul`, :func:`quat_exp`) and the position update of a step,
:func:`advance_positions`, which both methods use. Imports NumPy and CasADi only; never the System
(passed in), the contact problem, time stepping or events.

The position update
-------------------
Over a step of size h with a velocity w held constant (Moreau-Jean's v_theta), every coordinate moves
by ``h T(t, q) w`` (T at the start of the step), except the unit quaternions: their rows of T w are
``B p`` with B = d(T w)_p/dp, which for the quaternion kinematics p' = 1/2 p (x) (0, omega) is
skew-symmetric with B^2 = -beta^2 I (beta = |omega|/2). Such a block is advanced by the exact
exponential map ``p+ = expm(h B) p = cos(h beta) p + sin(h beta)/beta B p``, i.e.
p+ = p (x) exp(h omega / 2): the rotation of a body spinning at the constant omega, exactly, and on
the sphere to rounding; then p+ is divided by its norm, so that rounding does not accumulate over
millions of steps. A quaternion block of any other form (a kinematics the user wrote differently)
(not skew, or with rows of T w that are not B p) is advanced by ``p + h (T w)_p`` and projected
onto the sphere (first order, like the rest of the step).
"""
from __future__ import annotations

import math

import casadi as ca
import numpy as np

__all__ = ["QUATERNION_ROUND", "advance_positions", "attach_kinematics", "check_kinematics_at", "kinematics_functions",
           "kinematics_options", "normalized_expr", "position_update_function", "kinematics_matrix", "normalize_quaternions", "refuse_kinematics",
           "quat_exp", "quat_mul", "quaternion_start", "quaternion_starts"]

_EPS = float(np.finfo(float).eps)
#: a start quaternion whose norm is 1 within this is normalised without a note (rounding)
QUATERNION_ROUND = 64 * _EPS


def kinematics_matrix(T, q: ca.SX, v: ca.SX, t: ca.SX) -> ca.SX | None:
    """T as an n_q x n_v SX of (t, q), or None for ``T is None`` (the identity); ValueError naming
    ``kinematics`` when it is not one."""
    if T is None:
        return None
    shape = (q.shape[0], v.shape[0])
    try:
        T = T if isinstance(T, ca.SX) else ca.SX(np.asarray(T, dtype=float) if not isinstance(T, ca.DM) else T)
    except Exception as exc:  # noqa: BLE001 - CasADi raises NotImplementedError/RuntimeError variously
        raise ValueError("kinematics must be a CasADi SX expression or a numeric array (n_q x n_v)") from exc
    if T.shape != shape:
        raise ValueError(f"kinematics must have shape (n_q, n_v) = {shape}, got {T.shape}")
    if ca.depends_on(T, v):
        raise ValueError("kinematics T(t, q) must not depend on the velocities v (qdot = T(t, q) v)")
    known = ca.vertcat(t, q)
    free = [s.name() for s in ca.symvar(T) if not ca.depends_on(s, known)]
    if free:
        raise ValueError(f"kinematics depends on symbols the System does not have: {free}")
    if not ca.depends_on(T, known):
        vals = np.array(ca.evalf(T), dtype=float)
        if not np.all(np.isfinite(vals)):
            raise ValueError("kinematics must be finite")
        if np.linalg.matrix_rank(vals) < shape[1]:
            raise ValueError(f"kinematics must have full column rank n_v = {shape[1]} (every velocity moves q)")
    return T


def attach_kinematics(system, T, unit_quaternions, velocity_names, names) -> tuple:
    """Set the kinematics attributes of a System being built: ``n``, ``n_q``, ``has_kinematics``,
    ``unit_quaternions``, ``names`` and ``velocity_names``; return (T checked or None, n)."""
    q, v = system.q_sym, system.v_sym
    if T is not None and (not isinstance(v, ca.SX) or not v.is_symbolic() or v.shape[1] != 1):
        raise ValueError("v must be a column of CasADi SX symbols (casadi.SX.sym('v', n_v)) for a system with "
                         "kinematics")
    system.n, system.n_q = n, nq = v.shape[0], q.shape[0]
    T = kinematics_matrix(T, q, v, system.t_sym)
    system.has_kinematics = T is not None
    system.unit_quaternions = quaternion_starts(unit_quaternions, nq)
    system.names = tuple(names) if names is not None else tuple(f"q{i}" for i in range(nq))
    if len(system.names) != nq:
        raise ValueError(f"names must have {nq} entries, got {len(system.names)}")
    #: the velocities' names (the coordinates' without kinematics), for messages about forces
    system.velocity_names = system.names if T is None else (
        tuple(velocity_names) if velocity_names is not None else tuple(f"v{i}" for i in range(n)))
    if len(system.velocity_names) != n:
        raise ValueError(f"velocity_names must have {n} entries, got {len(system.velocity_names)}")
    return T, n


def kinematics_functions(system) -> None:
    """Set ``kinematics_expr`` (T, n_q x n_v; the identity by default), ``kinematics_fn`` ((t, q) -> T)
    and ``qdot_fn`` ((t, q, v) -> T v): what a compiled engine evaluates for the position update."""
    t, q, v = system.t_sym, system.q_sym, system.v_sym
    T = system.__dict__["_T"]
    system.kinematics_expr = ca.SX.eye(system.n) if T is None else T
    system.kinematics_fn = ca.Function("kinematics", [t, q], [system.kinematics_expr])
    system.qdot_fn = ca.Function("qdot", [t, q, v], [ca.mtimes(system.kinematics_expr, v)])


def kinematics_options(system) -> dict:
    """The System keywords that rebuild ``system``'s kinematics (empty without kinematics)."""
    if not system.has_kinematics:
        return {}
    return {"kinematics": system.kinematics_expr, "unit_quaternions": system.unit_quaternions,
            "velocity_names": system.velocity_names}


def check_kinematics_at(system, q, t: float = 0.0) -> None:
    """ValueError naming ``kinematics`` where T(t, q) is not finite or not of full column rank."""
    T = np.array(system.kinematics_fn(t, q), dtype=float)
    if not np.all(np.isfinite(T)):
        raise ValueError(f"kinematics T(t, q) is not finite at q0 = {np.asarray(q).tolist()}")
    if T.shape[1] and np.linalg.matrix_rank(T) < T.shape[1]:
        raise ValueError(f"kinematics T(t, q) does not have full column rank {T.shape[1]} at q0 "
                         f"= {np.asarray(q).tolist()} (some velocity does not move the coordinates)")


def quaternion_starts(starts, n_q: int) -> tuple:
    """The start indices of the unit quaternions, checked: integers, four coordinates inside q each,
    not overlapping (ValueError naming ``unit_quaternions``)."""
    try:
        out = tuple(int(i) for i in starts)
    except (TypeError, ValueError):
        raise ValueError(f"unit_quaternions must be a sequence of start indices, got {starts!r}") from None
    if any(float(i) != int(i) for i in starts):
        raise ValueError(f"unit_quaternions must be integers, got {starts!r}")
    taken = set()
    for i in out:
        if i < 0 or i + 4 > n_q:
            raise ValueError(f"unit_quaternions: the quaternion at {i} does not fit in the {n_q} coordinates")
        if taken & set(range(i, i + 4)):
            raise ValueError(f"unit_quaternions: the quaternion at {i} overlaps another")
        taken |= set(range(i, i + 4))
    return out


def quaternion_start(system, q0, tol: float):
    """q0 with its unit quaternions normalised, and a note (or None).

    Within :data:`QUATERNION_ROUND` of norm 1 a quaternion is normalised silently (rounding);
    within ``tol`` with a note; beyond it a ValueError naming the coordinate."""
    starts = getattr(system, "unit_quaternions", ())
    if not starts:
        return q0, None
    q = np.array(q0, dtype=float)
    moved = []
    for i in starts:
        r = math.sqrt(float(q[i:i + 4] @ q[i:i + 4]))
        off = abs(r - 1.0)
        name = system.names[i]
        if not off <= tol:
            raise ValueError(f"q0: the unit quaternion at coordinate {name!r} (q[{i}:{i + 4}]) has norm {r:.17g}, "
                             f"off by {off:.3g} (more than {tol:g}): give a unit quaternion")
        if off > QUATERNION_ROUND:
            moved.append(f"{name!r} off by {off:.3g}")
        q[i:i + 4] /= r
    if not moved:
        return q, None
    return q, f"The start's unit quaternions were normalised (lcp.model.kinematics): {', '.join(moved)}."


def normalize_quaternions(system, q: np.ndarray) -> np.ndarray:
    """q with every declared unit quaternion divided by its norm (in place; returned)."""
    for i in system.unit_quaternions:
        p = q[i:i + 4]
        p /= math.sqrt(float(p @ p))
    return q


def normalized_expr(system, q):
    """q (an SX or MX column) with every declared unit quaternion divided by its norm, symbolically."""
    parts, at = [], 0
    for i in system.unit_quaternions:
        parts += [q[at:i], q[i:i + 4] / ca.norm_2(q[i:i + 4])]
        at = i + 4
    return ca.vertcat(*parts, q[at:])


def quat_mul(a, b) -> np.ndarray:
    """The quaternion product a (x) b (scalar first)."""
    a0, av = a[0], np.asarray(a[1:], dtype=float)
    b0, bv = b[0], np.asarray(b[1:], dtype=float)
    return np.concatenate([[a0 * b0 - av @ bv], a0 * bv + b0 * av + np.cross(av, bv)])


def quat_exp(w) -> np.ndarray:
    """exp((0, w)) = (cos |w|, sin|w|/|w| w), the unit quaternion of a rotation by 2|w| about w."""
    w = np.asarray(w, dtype=float)
    a = math.sqrt(float(w @ w))
    s = math.sin(a) / a if a > 1e-8 else 1.0 - a * a / 6.0  # sin(a)/a to rounding below 1e-8
    return np.concatenate([[math.cos(a)], s * w])


def increment_function(system) -> ca.Function:
    """(t, q, w) -> (T w, B_1, ..., B_k): the rate of q and each quaternion's 4 x 4 block
    B = d(T w)_p/dp, built once per system (kept on the system: it is part of its kinematics)."""
    fn = system.__dict__.get("_increment_fn")
    if fn is None:
        t, q, v = system.t_sym, system.q_sym, system.v_sym
        rate = ca.mtimes(system.kinematics_expr, v)
        blocks = [ca.jacobian(rate[i:i + 4], q[i:i + 4]) for i in system.unit_quaternions]
        fn = system._increment_fn = ca.Function("position_increment", [t, q, v], [rate] + blocks)
    return fn


def position_update_function(system) -> ca.Function:
    """(t, q, w, h) -> q+: :func:`advance_positions` (without the compensated sum) as one CasADi
    Function, for an engine that evaluates the step itself (a compiled loop).

    Every unit quaternion is advanced by the exponential map cos(h beta) p + sin(h beta)/beta B p,
    beta^2 = -tr(B^2)/4, then normalised. The map is exact only where the quaternion's rows of
    T w are B p with B skew and B^2 = -beta^2 I (the form p' = 1/2 p (x) (0, omega) of
    :mod:`lcp.model.rigid_body`, or p' = 1/2 (0, omega) (x) p): that is checked here at a few
    random states, and a ValueError naming ``kinematics`` says where it fails (the Python loop's
    :func:`advance_positions` then falls back by itself, state by state).

    Examples
    --------
    >>> import numpy as np
    >>> from lcp.model.rigid_body import free_body, bodies_system
    >>> s = bodies_system([free_body(1.0, [1.0, 2.0, 3.0])])
    >>> f = position_update_function(s)
    >>> q = np.array(f(0.0, [0, 0, 0, 1.0, 0, 0, 0], [1.0, 0, 0, 0, 0, 2.0], 0.5)).ravel()
    >>> np.allclose(q, [0.5, 0, 0, np.cos(0.5), 0, 0, np.sin(0.5)], rtol=0, atol=1e-16)
    True
    """
    _check_quaternion_rows(system)
    t, q, w, h = ca.SX.sym("t"), ca.SX.sym("q", system.n_q), ca.SX.sym("w", system.n), ca.SX.sym("h")
    outs = increment_function(system)(t, q, w)
    outs = outs if isinstance(outs, (list, tuple)) else [outs]
    q_new = q + h * outs[0]
    parts, at = [], 0
    for i, B in zip(system.unit_quaternions, outs[1:]):
        p = q[i:i + 4]
        beta = ca.sqrt(ca.fmax(-ca.trace(ca.mtimes(B, B)) / 4, 0))
        x = h * beta
        sinc = ca.if_else(x > 1e-8, ca.sin(x) / ca.fmax(x, 1e-300), 1 - x * x / 6)
        p_new = ca.cos(x) * p + h * sinc * ca.mtimes(B, p)
        parts += [q_new[at:i], p_new / ca.norm_2(p_new)]
        at = i + 4
    return ca.Function("position_update", [t, q, w, h], [ca.vertcat(*parts, q_new[at:])], ["t", "q", "w", "h"],
                       ["q_next"])


def _check_quaternion_rows(system, samples: int = 3) -> None:
    """ValueError naming ``kinematics`` where a quaternion's rows of T w are not B p with B skew and
    B^2 = -beta^2 I, at a few random states (unit quaternions, other coordinates and w in [-1, 1])."""
    if not system.unit_quaternions:
        return
    rng = np.random.default_rng(0)
    fn = increment_function(system)
    for _ in range(samples):
        q = rng.uniform(-1, 1, system.n_q)
        normalize_quaternions(system, q)
        w = rng.uniform(-1, 1, system.n)
        outs = fn(rng.uniform(0, 1), q, w)
        rate = np.array(outs[0], dtype=float).ravel()
        for i, B in zip(system.unit_quaternions, outs[1:]):
            B = np.array(B, dtype=float)
            p = q[i:i + 4]
            scale = float(np.max(np.abs(B))) + 1e-300
            tol = 1e3 * _EPS * scale
            beta2 = -float(np.trace(B @ B)) / 4
            if (np.max(np.abs(B @ p - rate[i:i + 4])) > tol or np.max(np.abs(B + B.T)) > tol
                    or np.max(np.abs(B @ B + beta2 * np.eye(4))) > tol * scale):
                raise ValueError(f"kinematics: the rows of the unit quaternion at q[{i}:{i + 4}] are not of the form "
                                 "B(w) p with B skew and B^2 = -beta^2 I (p' = 1/2 p (x) (0, omega)): the exponential "
                                 "map does not apply")


def _exp_block(B: np.ndarray, p: np.ndarray, h: float):
    """expm(h B) p for a skew B with B^2 = -beta^2 I (to rounding), else None."""
    scale = float(np.max(np.abs(B)))
    if scale == 0.0:
        return p.copy()
    B2 = B @ B
    beta2 = -float(np.trace(B2)) / 4.0
    tol = 64 * _EPS * scale
    if np.max(np.abs(B + B.T)) > tol or np.max(np.abs(B2 + beta2 * np.eye(4))) > tol * scale:
        return None
    beta = math.sqrt(max(beta2, 0.0))
    x = h * beta
    s = h * (math.sin(x) / x if x > 1e-8 else 1.0 - x * x / 6.0)  # sin(h beta)/beta
    return math.cos(x) * p + s * (B @ p)


def advance_positions(system, t: float, q: np.ndarray, w: np.ndarray, h: float,
                      comp: np.ndarray | None = None):
    """The position update of a step (module docstring): (q+, compensation).

    q+ = q + h T(t, q) w by a compensated (Kahan) sum when ``comp`` is given, the unit quaternions
    by the exponential map and normalised (their compensation reset to zero).
    """
    outs = increment_function(system)(t, q, w)
    outs = outs if isinstance(outs, (list, tuple)) else [outs]
    inc = h * np.array(outs[0], dtype=float).ravel()
    if comp is None:
        q_new, comp_new = q + inc, None
    else:
        y = inc - comp
        q_new = q + y
        comp_new = (q_new - q) - y
    for i, B in zip(system.unit_quaternions, outs[1:]):
        p = q[i:i + 4]
        B = np.array(B, dtype=float)
        rate = inc[i:i + 4] / h if h else inc[i:i + 4]
        # the exponential map needs rows of T w that are B p (linear in p, nothing else in them)
        linear = np.max(np.abs(B @ p - rate)) <= 64 * _EPS * (float(np.max(np.abs(B))) * 2 + float(np.max(np.abs(rate))))
        p_new = _exp_block(B, p, h) if linear else None
        if p_new is None:
            p_new = q_new[i:i + 4]
        q_new[i:i + 4] = p_new / math.sqrt(float(p_new @ p_new))
        if comp_new is not None:
            comp_new[i:i + 4] = 0.0
    return q_new, comp_new


def refuse_kinematics(system, what: str) -> None:
    """ValueError naming ``kinematics`` when ``system`` has Newton-Euler kinematics and ``what``
    (a path written for v = qdot) cannot handle them: it would move q by h v, which is wrong."""
    if getattr(system, "has_kinematics", False):
        raise ValueError(f"{what} does not support Newton-Euler kinematics (System(..., kinematics=T), "
                         "n_q != n_v or qdot = T(q) v): use lcp.simulate(..., method='moreau-jean') with "
                         "scheme='moreau-jean' (the Python loop) or method='event'")
