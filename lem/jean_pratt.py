"""The Jean-Pratt parameters: their checks, the exact tangent of the slide, and the shock number.

One home for what both branches need about the scene's numbers: :mod:`lcp` (scenes, exact
solutions, batch runs) and :mod:`lem` (the paper's series) import them from here.

Notation (paper): ``t = tan(alpha)``, ``A = m + M t**2``, friction coefficient ``R``, and the shock
number ``kappa = R M t / A``. A sliding motion with v0 > 0 exists if and only if kappa < 1.

Examples
--------
>>> import math
>>> from lem.jean_pratt import kappa, tan_alpha
>>> tan_alpha(math.pi / 4), kappa(1.0, 1.0, math.pi / 4, 2.0)
(1.0, 1.0)
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["tan_alpha", "check_parameters", "kappa"]


def tan_alpha(alpha):
    """tan(alpha), exact where rounding would otherwise decide the physics.

    ``math.tan(pi/4)`` is 0.9999999999999999, which puts R = 2 (kappa = 1 exactly for m = M = 1) on
    the wrong side of the shock limit; the angles with an exact rational tangent (0, +-pi/4) are
    returned exactly. Scalars give a float, arrays an array of the same shape.
    """
    if type(alpha) is float or np.ndim(alpha) == 0:  # (a float first: np.ndim costs more than the rest)
        alpha = float(alpha)
        if alpha == 0.0:
            return 0.0
        if alpha == math.pi / 4:
            return 1.0
        if alpha == -math.pi / 4:
            return -1.0
        return math.tan(alpha)
    alpha = np.asarray(alpha, dtype=float)
    t = np.tan(alpha)
    t = np.where(alpha == math.pi / 4, 1.0, t)
    t = np.where(alpha == -math.pi / 4, -1.0, t)
    return np.where(alpha == 0.0, 0.0, t)


def check_parameters(m, M, alpha, R, g=9.81):
    """Raise a ValueError naming the first Jean-Pratt parameter out of range.

    Scalars or arrays (a batch of scenes): every entry must be in range.
    """
    vals = (m, M, alpha, R, g)
    if all(type(x) in (int, float) for x in vals):  # one scene: plain float checks, no NumPy calls
        for name, val in zip(("m", "M", "alpha", "R", "g"), vals):
            if not math.isfinite(val):
                raise ValueError(f"{name} must be a finite number, got {val!r}")
        if m > 0 and M >= 0 and R >= 0 and g >= 0 and abs(alpha) < math.pi / 2:
            return
    for name, val in (("m", m), ("M", M), ("alpha", alpha), ("R", R), ("g", g)):
        if np.ndim(val) == 0 and not isinstance(val, (int, float, np.floating, np.integer)):
            raise ValueError(f"{name} must be a finite number, got {val!r}")
        if not np.all(np.isfinite(np.asarray(val, dtype=float))):
            raise ValueError(f"{name} must be a finite number, got {val!r}")
    for name, val, ok, rule in (("m", m, np.greater, "> 0"), ("M", M, np.greater_equal, ">= 0"),
                                ("R (friction coefficient)", R, np.greater_equal, ">= 0"),
                                ("g", g, np.greater_equal, ">= 0")):
        if not np.all(ok(val, 0)):
            raise ValueError(f"{name} must be {rule}, got {val!r}")
    if not np.all(np.abs(alpha) < math.pi / 2):
        raise ValueError(f"alpha must lie strictly inside (-pi/2, pi/2), got {alpha!r}")


def kappa(m: float, M: float, alpha: float, R: float) -> float:
    """Shock number kappa = R M tan(alpha) / (m + M tan(alpha)^2)."""
    check_parameters(m, M, alpha, R)
    t = tan_alpha(alpha)
    return R * M * t / (m + M * t * t)
