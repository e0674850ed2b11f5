"""The controlled model of an optimal control problem: the control force B(q) u on a System."""
from __future__ import annotations

import warnings

import casadi as ca
import numpy as np

from lcp.model.control import ControlSchedule
from lcp.model.system import System

__all__ = ["add_control", "controlled_system", "tangential_push"]


def tangential_push(system: System, contact: int = 0) -> ca.SX:
    """Control matrix B(q) = H_T(q)' of one contact: a force along that contact's tangent.

    For the Jean-Pratt block this is the horizontal force on m (``phi`` in the scene).

    Examples
    --------
    >>> import casadi as ca, numpy as np
    >>> from lcp.scenes import jean_pratt
    >>> from lcp.ocp import tangential_push
    >>> np.array(ca.evalf(tangential_push(jean_pratt().system))).ravel()
    array([1., 0.])
    """
    if not isinstance(system, System):
        raise ValueError(f"system must be a System, got {type(system).__name__}")
    m = system.n_contacts
    if not isinstance(contact, (int, np.integer)) or not 0 <= contact < m:
        raise ValueError(f"contact must be an index in [0, {m}), got {contact!r}")
    return system.H_expr[m + contact, :].T


def _control_matrix(system: System, B) -> ca.SX:
    """B as an (n, nu) SX of the system's q only, or ValueError naming control_matrix."""
    n = system.n
    try:
        Bx = B if isinstance(B, ca.SX) else ca.SX(np.asarray(B, dtype=float))
    except Exception as exc:
        raise ValueError("control_matrix must be an array or a CasADi SX expression of q") from exc
    if Bx.shape[0] != n:
        if Bx.numel() == n:
            Bx = ca.reshape(Bx, n, 1)
        else:
            raise ValueError(f"control_matrix must have {n} rows, got shape {Bx.shape}")
    if Bx.shape[1] < 1:
        raise ValueError("control_matrix must have at least one column")
    if ca.depends_on(Bx, ca.vertcat(system.v_sym, system.t_sym)):
        raise ValueError("control_matrix may depend on q only")
    qs = {s.name() for s in ca.symvar(system.q_sym)}
    if any(s.name() not in qs for s in ca.symvar(Bx)):
        raise ValueError("control_matrix contains symbols other than the system's q")
    return Bx


def add_control(system: System, control_matrix, u_min=-np.inf, u_max=np.inf) -> System:
    """The system with a control input u entering as the force B(q) u, bounded by u_min, u_max.

    Parameters
    ----------
    system : System
        Uncontrolled.
    control_matrix : array_like or casadi.SX, shape (n, nu)
        B(q), e.g. :func:`tangential_push`.
    u_min, u_max : float or array_like, shape (nu,)

    Returns
    -------
    System
        ``System(..., force=F + B u, control=u, control_bounds=(u_min, u_max))``.

    Examples
    --------
    >>> import lcp
    >>> from lcp.ocp import add_control, tangential_push
    >>> s = lcp.scenes.jean_pratt(v0=0.0).system
    >>> c = add_control(s, tangential_push(s), -20, 20)
    >>> c.nu, c.control_bounds[1]
    (1, array([20.]))
    """
    if system.is_controlled:
        raise ValueError("the system already has a control input; give control_matrix only for an "
                         "uncontrolled system")
    B = _control_matrix(system, control_matrix)
    u = ca.SX.sym("u", B.shape[1])
    try:
        bounds = (np.broadcast_to(np.asarray(u_min, dtype=float), (B.shape[1],)),
                  np.broadcast_to(np.asarray(u_max, dtype=float), (B.shape[1],)))
    except ValueError as exc:
        raise ValueError(f"u_min and u_max must have {B.shape[1]} entries") from exc
    if np.any(np.isnan(bounds[0])) or np.any(np.isnan(bounds[1])) or np.any(bounds[0] > bounds[1]):
        raise ValueError(f"u_min and u_max must satisfy u_min <= u_max, got {u_min!r}, {u_max!r}")
    return System(system.q_sym, system.v_sym, system.mass_expr, system.force_expr + ca.mtimes(B, u),
                  contacts=system.contacts, constraints=system.constraints_expr if system.n_bilateral else None,
                  t=system.t_sym, names=system.names, breakpoints=system.breakpoints, control=u,
                  control_bounds=bounds)


def controlled_system(system: System, control_matrix, t_nodes, u_nodes) -> System:
    """Deprecated: the system with the control force B(q) u(t) added, u linear between the nodes.

    Use ``add_control(system, B).with_control(ControlSchedule(t_nodes, u_nodes, hold="linear"))``
    (or ``lcp.simulate(..., control=schedule)``), which also integrates the control's impulse over
    each Moreau-Jean step exactly.

    Examples
    --------
    >>> import lcp, warnings
    >>> from lcp.ocp import controlled_system, tangential_push
    >>> sc = lcp.scenes.jean_pratt(v0=0.0)
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore")
    ...     s = controlled_system(sc.system, tangential_push(sc.system), [0, 1], [0.0, 20.0])
    >>> s.force([0, 0], [0, 0], t=0.5)
    array([ 10.  , -19.62])
    """
    warnings.warn("controlled_system is deprecated: use lcp.ocp.add_control(system, B).with_control("
                  "lcp.model.control.ControlSchedule(t, u, hold='linear'))", DeprecationWarning, stacklevel=2)
    B = _control_matrix(system, control_matrix)
    t_nodes = np.asarray(t_nodes, dtype=float).ravel()
    u_nodes = np.asarray(u_nodes, dtype=float)
    try:
        u_nodes = u_nodes.reshape(len(t_nodes), -1)
    except ValueError as exc:
        raise ValueError("u_nodes must have one row per node") from exc
    if u_nodes.shape[1] != B.shape[1]:
        raise ValueError(f"u_nodes must have {B.shape[1]} columns, got {u_nodes.shape[1]}")
    try:
        schedule = ControlSchedule(t_nodes, u_nodes, hold="linear")
    except ValueError as exc:
        raise ValueError(f"t_nodes/u_nodes: {exc}") from exc
    return add_control(system, B).with_control(schedule)
