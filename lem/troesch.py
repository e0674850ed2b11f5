"""Troesch's problem by shooting over the LEM propagator (Toma 1986).

    y'' = lambda sinh(lambda y),  y(0) = 0,  y(1) = 1.

The initial slope s = y'(0) is found by shooting: each trial integrates ``y' = z, z' = lambda
sinh(lambda y)`` over [0, 1] with the restarted LEM engine (:func:`lem.solve`), whose
propagators also give the sensitivity d y(1) / d s for Newton's method. y(1; s) increases with s
(y'' > 0 for y > 0), so the root is bracketed and Newton steps that leave the bracket are replaced
by bisection. For large lambda the shooting solution has a pole just beyond x = 1 (at x = 1.00135
for lambda = 10): too large an s puts the pole inside [0, 1], which the engine reports as a failed
trial (step size underflow or blow-up), and the trial then serves as an upper bracket.

Examples
--------
>>> from lem.troesch import solve_troesch, TROESCH_REFERENCE
>>> res = solve_troesch(1.0)
>>> res.success, abs(res.slope / TROESCH_REFERENCE[1.0] - 1) < 1e-9
(True, True)
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np

from .fields import AnalyticField
from .propagation import solve
from .result import LEMResult, LEMWarning

__all__ = [
    "STATUS_MESSAGES",
    "TROESCH_POLE_10",
    "TROESCH_REFERENCE",
    "TroeschResult",
    "shoot",
    "solve_troesch",
    "troesch_field",
]

#: High-accuracy y'(0) (20 digits).
TROESCH_REFERENCE = {
    0.5: 0.95904379541321905,
    1.0: 0.84520268530995106,
    5.0: 0.045750461406318740,
    10.0: 3.5833778463081369e-4,
}
#: Position of the pole of the lambda = 10 shooting solution.
TROESCH_POLE_10 = 1.00135

#: status code -> meaning; ``success`` is ``status >= 0``.
STATUS_MESSAGES = {
    0: "Converged: |y(1) - 1| and the slope correction are within tolerance, and every LEM "
       "trajectory met its error estimate.",
    1: "Converged in s, but the LEM error estimate of y(1) exceeds the tolerance: the slope is "
       "only as good as slope_error_estimate says.",
    -1: "No convergence within maxiter shooting iterations.",
    -2: "The final trajectory failed (the LEM engine did not reach x = 1).",
}


def troesch_field(lam: float) -> AnalyticField:
    """y' = z, z' = lam sinh(lam y) as an analytic field (exact Taylor coefficients via jets)."""
    lam = _check_lam(lam)
    return AnalyticField(lambda t, y: [y[1], lam * np.sinh(lam * y[0])], 2)


def _check_lam(lam) -> float:
    if isinstance(lam, bool) or not isinstance(lam, (int, float, np.floating, np.integer)) \
            or not np.isfinite(lam) or lam <= 0:
        raise ValueError(f"lam must be a finite positive number, got {lam!r}")
    return float(lam)


#: options of :func:`shoot` unless given
_SHOOT_DEFAULTS = {"degree": 16, "restart": "auto", "rtol": 1e-12, "atol": 1e-14}


def shoot(lam: float, s: float, **options) -> LEMResult:
    """Integrate y(0) = 0, y'(0) = s over [0, 1] with the (by default auto-restarted) LEM engine.

    ``options`` go to :func:`lem.solve` (defaults: degree 16, restart "auto",
    rtol 1e-12, atol 1e-14).
    """
    if not np.isfinite(s):
        raise ValueError(f"s must be finite, got {s!r}")
    opts = {**_SHOOT_DEFAULTS, **options}
    return solve(troesch_field(lam), (0.0, 1.0), [0.0, float(s)], **opts)


@dataclass
class TroeschResult:
    """Outcome of :func:`solve_troesch`.

    Attributes
    ----------
    lam : float
    slope : float
        y'(0) found.
    residual : float
        y(1) - 1 of the final trajectory.
    slope_error_estimate : float
        LEM error estimate of y(1) divided by d y(1)/d s, plus the last Newton correction.
    status : int
        See :data:`STATUS_MESSAGES`; ``success = status >= 0``.
    message : str
    iterations : int
        Shooting trials (LEM integrations).
    failed_trials : int
        Trials whose trajectory did not reach x = 1 (pole inside the interval).
    n_segments : int
        LEM segments of the final trajectory.
    dyds : float
        d y(1) / d s at the solution (the conditioning of the shooting).
    history : list of (s, y1 or nan, status)
    solution : LEMResult
        The final trajectory (t, y, error_estimate, ...).
    reference : float or None
        Value from :data:`TROESCH_REFERENCE` if lam is listed.
    relative_error : float or None
        |slope / reference - 1|.
    """

    lam: float
    slope: float
    residual: float
    slope_error_estimate: float
    status: int
    message: str
    iterations: int
    failed_trials: int
    n_segments: int
    dyds: float
    history: list = field(default_factory=list)
    solution: LEMResult | None = None
    reference: float | None = None
    relative_error: float | None = None

    @property
    def success(self) -> bool:
        return self.status >= 0


def _initial_slope(lam: float) -> float:
    # linear problem y'' = lam**2 y for small lam; for large lam the shooting solution has its
    # pole at x_p = ln(8 / s) / lam, and y(1) = 1 needs x_p - 1 = (2/lam) exp(-lam/2) (from
    # y ~ -(2/lam) ln(lam (x_p - x) / 2) near the pole): s = 8 exp(-lam) exp(-2 exp(-lam/2)),
    # 0.1 % below the root at lam = 5 and 0.07 % at lam = 10, on the side without a pole.
    return min(lam / math.sinh(lam), 8.0 * math.exp(-lam - 2.0 * math.exp(-0.5 * lam)))


def solve_troesch(lam: float, *, s0: float | None = None, xtol: float = 1e-13, ftol: float = 1e-12,
                  maxiter: int = 80, **options) -> TroeschResult:
    """Solve Troesch's problem for y'(0) by bracketed Newton shooting over the LEM propagator.

    Parameters
    ----------
    lam : float
        lambda > 0.
    s0 : float, optional
        First guess of y'(0) (default: min(lam/sinh(lam), 8 exp(-lam - 2 exp(-lam/2))), the
        linear and the large-lambda asymptotic slopes).
    xtol, ftol : float
        Stop when the Newton correction is below ``xtol * s`` or |y(1) - 1| <= ftol.
    maxiter : int
        Maximum number of trials.
    **options
        Passed to :func:`lem.solve` (``degree``, ``rtol``, ``restart`` ...).

    Returns
    -------
    TroeschResult

    Examples
    --------
    >>> r = solve_troesch(0.5)
    >>> round(r.slope, 12)
    0.959043795413
    """
    lam = _check_lam(lam)
    for name, v in (("xtol", xtol), ("ftol", ftol)):
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be finite and > 0, got {v!r}")
    if isinstance(maxiter, bool) or not isinstance(maxiter, int) or maxiter < 1:
        raise ValueError(f"maxiter must be a positive integer, got {maxiter!r}")
    s = _initial_slope(lam) if s0 is None else float(s0)
    if not (np.isfinite(s) and s > 0):
        raise ValueError(f"s0 must be finite and > 0, got {s0!r}")
    options.setdefault("warn", False)  # failed trials are expected (overshoot): reported below
    lo, hi = 0.0, math.inf        # y(1; lo) < 1 < y(1; hi) (hi: overshoot or pole inside [0, 1])
    history, failed = [], 0
    best = None
    status, message = -1, STATUS_MESSAGES[-1]
    # Far from the root a loose tolerance is enough to steer Newton (|F| >> error): it saves most
    # of the cost, since the first trials pass close to the pole for large lambda.
    coarse = dict(options)
    coarse["rtol"] = max(options.get("rtol", 1e-12), 1e-7)
    coarse["atol"] = max(options.get("atol", 1e-14), 1e-9)
    # the default first slope is within 1 % of the root for every lambda (linear or pole
    # asymptotics): Newton from it needs the requested tolerance at once, not a coarse trial
    near = s0 is None
    hints = {}
    for it in range(1, maxiter + 1):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", LEMWarning)
            trial = dict(options if near else coarse)
            if near in hints and "step_hint" not in options:
                trial["step_hint"] = hints[near]  # (coarse segments are too long for a fine trial)
            res = shoot(lam, s, **trial)
        reached = res.status >= 0 or res.status == 1
        if not reached or res.t[-1] != 1.0:
            failed += 1
            history.append((s, math.nan, res.status))
            hi = min(hi, s)
            s = _bisect(lo, hi)
            continue
        # the next trial (s moved a little) tries the segments this one accepted: most of the
        # step controller's rejections are spent finding them again
        hints[near] = tuple(np.diff(res.restart_points))
        F = float(res.y[0, -1]) - 1.0
        dF = float(res.sensitivity[0, 1, -1])
        history.append((s, F + 1.0, res.status))
        if F < 0:
            lo = max(lo, s)
        else:
            hi = min(hi, s)
        step = _newton_step(lam, F, dF)
        if near:
            best = (s, F, dF, res)
            if abs(F) <= ftol or (np.isfinite(step) and abs(step) <= xtol * s):
                s_new = s + step if np.isfinite(step) else s
                slope = s_new if lo <= s_new <= hi else s
                est = float(res.error_estimate[0, -1]) / dF + abs(step)
                status = 0 if res.status == 0 else 1
                return _result(lam, slope, F, est, status, STATUS_MESSAGES[status], it, failed, res,
                               dF, history)
        elif abs(F) < 1e-3:
            near = True  # from now on every trial uses the requested tolerance
        s_new = s + step if np.isfinite(step) else math.nan
        if not (lo < s_new < hi):
            s_new = _bisect(lo, hi)
        s = s_new
    if best is None:
        return TroeschResult(lam, math.nan, math.nan, math.inf, -2, STATUS_MESSAGES[-2], maxiter,
                             failed, 0, math.nan, history, None, TROESCH_REFERENCE.get(lam), None)
    s, F, dF, res = best
    est = float(res.error_estimate[0, -1]) / dF + abs(F / dF)
    return _result(lam, s, F, est, status, message, maxiter, failed, res, dF, history)


def _newton_step(lam: float, F: float, dF: float) -> float:
    """Newton step on G = (2/lam) (1 - exp(-lam F / 2)) for an overshoot (F > 0), on F otherwise.

    Beyond the root the pole x_p of the shooting solution nears x = 1, and there
    y ~ -(2/lam) log(lam (x_p - x) / 2) (y'' ~ (lam/2) exp(lam y)): y(1; s) grows only like a
    logarithm of the distance to the pole, which plain Newton descends in many small steps, while
    exp(-lam y(1) / 2) is about linear in s. G = F + O(F**2) at the root, so the last steps and
    the stopping test are Newton's on F.
    """
    if not dF > 0:
        return math.nan
    if F <= 0:
        return -F / dF
    return -(2.0 / lam) * math.expm1(min(0.5 * lam * F, 700.0)) / dF


def _bisect(lo: float, hi: float) -> float:
    if not np.isfinite(hi):
        return 2.0 * lo if lo > 0 else 1.0
    # geometric mean: the slopes of interest span orders of magnitude (8 exp(-lam))
    return math.sqrt(lo * hi) if lo > 0 else 0.5 * hi


def _result(lam, slope, F, est, status, message, it, failed, res, dF, history) -> TroeschResult:
    ref = TROESCH_REFERENCE.get(lam)
    rel = abs(slope / ref - 1.0) if ref is not None else None
    return TroeschResult(lam, float(slope), float(F), float(est), status, message, it, failed,
                         res.stats.n_segments, float(dF), history, res, ref, rel)
