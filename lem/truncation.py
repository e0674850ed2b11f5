r"""Toma's Linear Equivalence Method (LEM): truncated moment systems for analytic ODEs.

For ``y' = f(t, y)`` with ``f`` analytic in ``y``, LEM (Toma 1986-2007; it is Carleman linearization)
maps the nonlinear system to an infinite *linear* one for the moments ``v_gamma = w**gamma`` of the
displacement ``w = y - c`` from an expansion centre ``c``. Writing ``f_j(t, c + w) = sum_mu
a_{j,mu}(t) w**mu``,

.. math::  v_gamma' = \sum_j \gamma_j \sum_\mu a_{j\mu}(t)\, v_{\gamma - e_j + \mu},
           \qquad v_0 = 1,

which is the paper's (3.5) (there with ``c = 0``). Keeping the moments of total degree ``<= N``
gives the truncated system ``V' = A_N(t) V``; ``y`` is read off the degree-1 moments. This module

* builds ``A_N`` as a ``scipy.sparse`` matrix, keeping only the moments that the requested outputs
  depend on (a reachability search on the moment graph; with ``f(c) = 0`` the system is triangular
  in degree, otherwise the constant moment ``v_0 = 1`` couples every degree to the one below);
* takes ``f`` as a polynomial (:class:`PolynomialField`, coefficients may be callables of ``t``)
  or as any analytic function written with NumPy ufuncs (:class:`AnalyticField`), whose Taylor
  polynomial at the centre is computed exactly by truncated power-series ("jet") arithmetic, with
  ``t`` as an extra variable when ``f`` depends on it;
* solves with :func:`scipy.sparse.linalg.expm_multiply` for constant coefficients and with
  :func:`scipy.integrate.solve_ivp` when coefficients are given as functions of ``t``;
* re-centres the expansion on the current state (``restart=h`` or ``restart="auto"``), which makes
  the method converge on long horizons and beyond the first series' radius;
* reports how far each result can be trusted: the degree-``N`` answer is compared with degrees
  ``N - 2k, N - k, N + k``; the difference is the error estimate (carried across restarts through
  the propagators' own sensitivities), and growing differences mean the series diverges. Since
  differences cannot see a singularity of f whose Taylor coefficients underflow at the centre
  (tanh(v/eps) with v >> eps), the jets also record the distance to every singularity of f, and a
  state that moves 0.9 of the way there counts as diverging too (``status = -1`` and a
  :class:`LEMWarning`, never a silent answer).

It also returns Taylor coefficients of the solution in ``x`` (:func:`taylor_coefficients`) and in
the initial data (:func:`initial_data_coefficients`, :func:`double_series`), exactly in rational
arithmetic for rational polynomial fields: this is how the paper's series (3.20) should arise, and
:func:`tanh_ode_field` / :func:`moment_rhs_3_16` give the corrected (3.13)/(3.16) (physics.md §5).

Examples
--------
y'' = tanh y, y(0) = 0, y'(0) = 1 (the paper's (3.9) with z0 = 1):

>>> import numpy as np
>>> from lem.truncation import solve
>>> f = lambda t, y: [y[1], np.tanh(y[0])]
>>> res = solve(f, (0.0, 1.0), [0.0, 1.0], degree=61, rtol=1e-7)
>>> res.status, res.diverging
(0, False)
>>> round(float(res.y[0, -1]), 8)
1.15777894
>>> bool(res.error_estimate[0, -1] < 1e-9)   # the true error is 4e-11
True

At x = 2 the same expansion diverges, and says so:

>>> import warnings
>>> with warnings.catch_warnings():
...     warnings.simplefilter("ignore")
...     bad = solve(f, (0.0, 2.0), [0.0, 1.0], degree=61)
>>> bad.status, bad.diverging
(-1, True)
"""
from __future__ import annotations

import functools
import math
import numbers
import time
import warnings
from dataclasses import dataclass, field, fields
from fractions import Fraction
from typing import Callable, Mapping, Sequence

import numpy as np
import scipy.sparse as sp
from scipy.integrate import solve_ivp
from scipy.linalg import expm
from scipy.optimize import minimize
from scipy.sparse.linalg import expm_multiply

__all__ = [
    "STATUS_MESSAGES",
    "RADIUS_TRUST",
    "LEMWarning",
    "Jet",
    "PolynomialField",
    "AnalyticField",
    "as_field",
    "MomentSystem",
    "moment_system",
    "LEMOptions",
    "LEMStats",
    "LEMResult",
    "solve",
    "taylor_coefficients",
    "initial_data_coefficients",
    "double_series",
    "bernoulli_numbers",
    "tanh_taylor_coefficients",
    "tanh_ode_field",
    "moment_rhs_3_16",
    "smooth_friction_field",
]

#: status code -> meaning; ``success`` is ``status >= 0``.
STATUS_MESSAGES = {
    0: "Converged: the a-posteriori error estimate meets atol + rtol*|y| at every output point.",
    1: ("Successive truncations converge, but the error estimate exceeds atol + rtol*|y| at some "
        "output point: raise the degree or restart more often."),
    2: "Computed without an error estimate (check=False): the result is not verified.",
    -1: ("Successive truncations diverge, or the state leaves the disc where the Taylor series of "
         "f converges (radius_ratio >= 0.9): the result cannot be trusted; restart more often "
         "(restart=...) or shorten the interval."),
    -2: "The truncated moment system produced non-finite values (blow-up).",
    -3: "The restart step fell below min_step: the solution may have a singularity ahead.",
    -4: "The maximum number of restart segments was reached.",
    -5: "The integrator of the time-varying moment system failed.",
}


class LEMWarning(RuntimeWarning):
    """Raised (as a warning) whenever a LEM result is not to be trusted (``status < 0``)."""


_EPS = np.finfo(float).eps
# Differences between truncations below this (relative to max(1, |y|)) are rounding noise, not a
# trend: they never count as divergence. Measured noise of the degree-61 tanh system is ~1e-15.
_NOISE = 1e3 * _EPS
#: Small systems whose ||A|| dt exceeds this use a dense matrix exponential instead of expm_multiply.
_DENSE_NORM, _DENSE_DIM = 500.0, 600
#: A state whose singular arguments (tanh(v/eps), 1/u, log u, ...) move this fraction of the way to
#: the nearest singularity of f is outside what f's Taylor series can be trusted to represent.
RADIUS_TRUST = 0.9


# --------------------------------------------------------------------------------------------
# Multi-indices
# --------------------------------------------------------------------------------------------
@functools.lru_cache(maxsize=64)
def _multi_indices(n: int, D: int) -> np.ndarray:
    """All multi-indices of n variables with total degree <= D (rows), any order."""
    if n == 1:
        return np.arange(D + 1, dtype=np.int64)[:, None]
    blocks = []
    for first in range(D + 1):
        sub = _multi_indices(n - 1, D - first)
        blocks.append(np.hstack([np.full((sub.shape[0], 1), first, dtype=np.int64), sub]))
    return np.vstack(blocks)


def _powers(n: int, D: int) -> np.ndarray:
    base = D + 1
    if n * math.log2(base) > 62:
        raise ValueError(f"degree {D} in {n} variables is too large to index (base**n > 2**62)")
    return base ** np.arange(n, dtype=np.int64)


class _Space:
    """Packed index of all monomials of n variables up to total degree D, sorted by code."""

    def __init__(self, n: int, D: int):
        exps = _multi_indices(n, D)
        self.n, self.D = n, D
        self.pw = _powers(n, D)
        codes = exps @ self.pw
        order = np.argsort(codes)
        self.codes = codes[order]
        self.exps = exps[order]
        self.deg = self.exps.sum(axis=1)
        self.size = self.codes.size


@functools.lru_cache(maxsize=16)
def _space(n: int, D: int) -> _Space:
    return _Space(n, D)


# --------------------------------------------------------------------------------------------
# Jets: truncated multivariate power series, for exact Taylor coefficients of analytic f
# --------------------------------------------------------------------------------------------
def _inv_factorials(D: int) -> np.ndarray:
    out = np.empty(D + 1)
    out[0] = 1.0
    for k in range(1, D + 1):
        out[k] = out[k - 1] / k
    return out


def _univariate(name: str, u0: float, D: int, p: float = 0.0) -> np.ndarray:
    """Taylor coefficients g_0..g_D of g(u0 + s) in s, by closed forms or stable recursions."""
    g = np.zeros(D + 1)
    if name == "exp":
        return math.exp(u0) * _inv_factorials(D)
    if name in ("sinh", "cosh"):
        s, c = math.sinh(u0), math.cosh(u0)
        even, odd = (s, c) if name == "sinh" else (c, s)
        f = _inv_factorials(D)
        g[0::2] = even * f[0::2]
        g[1::2] = odd * f[1::2]
        return g
    if name in ("sin", "cos"):
        s, c = math.sin(u0), math.cos(u0)
        cyc = (s, c, -s, -c) if name == "sin" else (c, -s, -c, s)
        f = _inv_factorials(D)
        for k in range(D + 1):
            g[k] = cyc[k % 4] * f[k]
        return g
    if name in ("tanh", "tan"):
        # g' = 1 -+ g**2: (k+1) g_{k+1} = -+ sum_i g_i g_{k-i}; g_1 from sech**2 / sec**2 directly
        # so that tanh near +-1 does not lose digits to 1 - tanh**2.
        sgn = -1.0 if name == "tanh" else 1.0
        if name == "tanh":
            g[0] = math.tanh(u0)
            g1 = 1.0 / math.cosh(u0) ** 2 if abs(u0) < 350 else 0.0
        else:
            g[0] = math.tan(u0)
            g1 = 1.0 / math.cos(u0) ** 2
        if D >= 1:
            g[1] = g1
        for k in range(1, D):
            g[k + 1] = sgn * np.dot(g[: k + 1], g[k::-1]) / (k + 1)
        return g
    if name == "log":
        if not u0 > 0:
            raise ValueError(f"log is not analytic at {u0!r} (needs a positive argument)")
        g[0] = math.log(u0)
        for k in range(1, D + 1):
            g[k] = (-1.0) ** (k + 1) / (k * u0**k)
        return g
    if name == "power":
        if u0 == 0 or (u0 < 0 and p != int(p)):
            if p == int(p) and p >= 0:
                pass
            else:
                raise ValueError(f"u**{p} is not analytic at u = {u0!r}")
        if u0 == 0:  # non-negative integer power of a jet with zero value
            if 0 <= p <= D:
                g[int(p)] = 1.0
            return g
        g[0] = u0**p
        for k in range(1, D + 1):
            g[k] = g[k - 1] * (p - k + 1) / (k * u0)
        return g
    if name == "arctan":
        # arctan(u) = Im log(1 + i u): the log series at 1 + i u0 gives every coefficient.
        z0 = 1 + 1j * u0
        g[0] = math.atan(u0)
        for k in range(1, D + 1):
            g[k] = ((-1.0) ** (k + 1) * (1j / z0) ** k / k).imag
        return g
    raise ValueError(f"unknown univariate function {name!r}")


def _merge(a: "Jet", b: "Jet") -> tuple:
    if not b.sing or b.sing is a.sing:
        return a.sing
    if not a.sing:
        return b.sing
    seen = {id(x[0]) for x in a.sing}
    return a.sing + tuple(x for x in b.sing if id(x[0]) not in seen)


def _singularity_distance(name: str, u0: float, p: float = 0.0) -> float:
    """Distance from the real point u0 to the nearest complex singularity of the function: the
    radius of convergence of its Taylor series at u0 (inf for entire functions)."""
    if name in ("exp", "sinh", "cosh", "sin", "cos"):
        return math.inf
    if name == "tanh":
        return math.hypot(u0, math.pi / 2)       # poles at +-i pi/2 (+ i k pi)
    if name == "tan":
        d = (u0 - math.pi / 2) % math.pi          # poles at pi/2 + k pi
        return min(d, math.pi - d)
    if name == "arctan":
        return math.hypot(1.0, u0)                # branch points at +-i
    if name == "power" and p == int(p) and p >= 0:
        return math.inf
    return abs(u0)                                # log, sqrt, 1/u, u**p: singular at 0


class Jet:
    """A truncated power series in the displacement w from an expansion centre.

    LEM needs the Taylor coefficients of ``f`` at the centre up to the truncation degree. A jet
    carries them through NumPy arithmetic: :class:`AnalyticField` calls the user's ``fun(t, y)``
    with jets instead of floats, and every ufunc (``np.tanh``, ``np.sinh``, ``np.exp``, ...) or
    operator acts on the whole series, exactly up to rounding (no finite differences, no radius to
    choose). Exact zeros stay zero, so the sparsity of ``f`` (odd tanh, one-variable arguments) is
    kept.

    Supported: ``+ - * /``, ``**`` (integer or real), and the ufuncs add, subtract, multiply,
    divide, negative, positive, power, square, reciprocal, exp, expm1, log, log1p, sqrt, sin, cos,
    tan, sinh, cosh, tanh, arctan. Non-analytic operations (comparisons, abs, sign, ``float()``)
    raise ``TypeError``: LEM cannot expand them.
    """

    __slots__ = ("space", "c", "sing")
    __array_priority__ = 1000

    def __init__(self, space: _Space, coeffs: np.ndarray, sing: tuple = ()):
        self.space = space
        self.c = coeffs
        # singularities met on the way: (|coefficients of the argument's displacement|, R), the
        # argument's distance R to the nearest singularity of the function applied to it
        self.sing = sing

    # construction ------------------------------------------------------------------------------
    @classmethod
    def constant(cls, space: _Space, value: float) -> "Jet":
        c = np.zeros(space.size)
        c[0] = value
        return cls(space, c)

    @classmethod
    def variable(cls, space: _Space, i: int, value: float) -> "Jet":
        c = np.zeros(space.size)
        c[0] = value
        if space.D >= 1:
            code = space.pw[i]
            c[np.searchsorted(space.codes, code)] = 1.0
        return cls(space, c)

    @property
    def value(self) -> float:
        """The value at the centre (the zero-degree coefficient)."""
        return float(self.c[0])

    def coefficients(self) -> dict:
        """Non-zero coefficients as ``{exponent tuple: value}``."""
        nz = np.flatnonzero(self.c)
        return {tuple(int(e) for e in self.space.exps[i]): float(self.c[i]) for i in nz}

    # arithmetic --------------------------------------------------------------------------------
    def _coerce(self, other):
        if isinstance(other, Jet):
            if other.space is not self.space:
                raise ValueError("jets from different expansions cannot be combined")
            return other
        if isinstance(other, (numbers.Real, np.number)) or (
                isinstance(other, np.ndarray) and other.ndim == 0):
            return Jet.constant(self.space, float(other))
        return None

    def _mulc(self, other: "Jet") -> np.ndarray:
        sp_ = self.space
        a, b = self.c, other.c
        ia, ib = np.flatnonzero(a), np.flatnonzero(b)
        out = np.zeros(sp_.size)
        if ia.size == 0 or ib.size == 0:
            return out
        if ia.size < ib.size:
            ia, ib, a, b = ib, ia, b, a
        da, db = sp_.deg[ia], sp_.deg[ib]
        ca, cb = sp_.codes[ia], sp_.codes[ib]
        av, bv = a[ia], b[ib]
        chunk = max(1, 2_000_000 // ib.size)
        for s in range(0, ia.size, chunk):
            sl = slice(s, s + chunk)
            mask = (da[sl, None] + db[None, :]) <= sp_.D
            if not mask.any():
                continue
            # codes add without carries because every exponent stays <= D
            codes = (ca[sl, None] + cb[None, :])[mask]
            vals = (av[sl, None] * bv[None, :])[mask]
            idx = np.searchsorted(sp_.codes, codes)
            out += np.bincount(idx, weights=vals, minlength=sp_.size)
        return out

    def __add__(self, other):
        o = self._coerce(other)
        return NotImplemented if o is None else Jet(self.space, self.c + o.c, _merge(self, o))

    __radd__ = __add__

    def __sub__(self, other):
        o = self._coerce(other)
        return NotImplemented if o is None else Jet(self.space, self.c - o.c, _merge(self, o))

    def __rsub__(self, other):
        o = self._coerce(other)
        return NotImplemented if o is None else Jet(self.space, o.c - self.c, _merge(self, o))

    def __mul__(self, other):
        if isinstance(other, (numbers.Real, np.number)):
            return Jet(self.space, self.c * float(other), self.sing)
        o = self._coerce(other)
        return NotImplemented if o is None else Jet(self.space, self._mulc(o), _merge(self, o))

    __rmul__ = __mul__

    def __truediv__(self, other):
        if isinstance(other, (numbers.Real, np.number)):
            return Jet(self.space, self.c / float(other), self.sing)
        o = self._coerce(other)
        return NotImplemented if o is None else self * o.reciprocal()

    def __rtruediv__(self, other):
        o = self._coerce(other)
        return NotImplemented if o is None else o * self.reciprocal()

    def __neg__(self):
        return Jet(self.space, -self.c, self.sing)

    def __pos__(self):
        return self

    def __pow__(self, p):
        if isinstance(p, Jet):
            return (p * self.log()).exp()
        if isinstance(p, (numbers.Integral, np.integer)) and p >= 0:
            result, base, e = Jet.constant(self.space, 1.0), self, int(p)
            while e:
                if e & 1:
                    result = result * base
                e >>= 1
                if e:
                    base = base * base
            return result
        return self._compose("power", float(p))

    def __rpow__(self, base):
        return (self * math.log(float(base))).exp()

    def _compose(self, name: str, p: float = 0.0) -> "Jet":
        u0 = float(self.c[0])
        g = _univariate(name, u0, self.space.D, p)
        delta = Jet(self.space, self.c.copy())
        delta.c[0] = 0.0
        r = Jet.constant(self.space, g[-1])
        for gk in g[-2::-1]:
            r = r * delta
            r.c[0] += gk
        if not np.all(np.isfinite(r.c)):
            raise ValueError(f"{name} of a jet with value {u0!r} is not finite")
        R = _singularity_distance(name, u0, p)
        sing = self.sing
        if np.isfinite(R):
            sing = sing + ((np.abs(delta.c), R),)
        r.sing = sing
        return r

    def reciprocal(self):
        return self._compose("power", -1.0)

    def exp(self):
        return self._compose("exp")

    def expm1(self):
        r = self._compose("exp")
        r.c[0] -= 1.0
        return r

    def log(self):
        return self._compose("log")

    def log1p(self):
        return (self + 1.0)._compose("log")

    def sqrt(self):
        return self._compose("power", 0.5)

    def square(self):
        return self * self

    def sin(self):
        return self._compose("sin")

    def cos(self):
        return self._compose("cos")

    def tan(self):
        return self._compose("tan")

    def sinh(self):
        return self._compose("sinh")

    def cosh(self):
        return self._compose("cosh")

    def tanh(self):
        return self._compose("tanh")

    def arctan(self):
        return self._compose("arctan")

    _UFUNCS = {
        "add": lambda a, b: a + b, "subtract": lambda a, b: a - b,
        "multiply": lambda a, b: a * b, "true_divide": lambda a, b: a / b,
        "divide": lambda a, b: a / b, "power": lambda a, b: a ** b,
        "negative": lambda a: -a, "positive": lambda a: +a,
    }
    _UNARY = ("square", "reciprocal", "exp", "expm1", "log", "log1p", "sqrt", "sin", "cos", "tan",
              "sinh", "cosh", "tanh", "arctan")

    def __array_ufunc__(self, ufunc, method, *inputs, **kwargs):
        if method != "__call__" or kwargs:
            return NotImplemented
        name = ufunc.__name__
        if name in self._UFUNCS:
            return self._UFUNCS[name](*inputs)
        if name in self._UNARY and len(inputs) == 1:
            return getattr(inputs[0], name)()
        raise TypeError(f"np.{name} is not supported on LEM jets (not analytic or not implemented); "
                        f"supported: {sorted(self._UFUNCS) + list(self._UNARY)}")

    def _not_analytic(self, *args):
        raise TypeError("LEM expands f in Taylor series: comparisons, abs, sign, float() and branching "
                        "on the state are not analytic operations; write f with NumPy ufuncs")

    __lt__ = __le__ = __gt__ = __ge__ = __abs__ = __float__ = __int__ = __bool__ = _not_analytic

    def __repr__(self):
        return f"Jet(value={self.value!r}, degree<={self.space.D}, nonzeros={np.count_nonzero(self.c)})"


# --------------------------------------------------------------------------------------------
# Vector fields
# --------------------------------------------------------------------------------------------
@dataclass
class _Expansion:
    """Taylor polynomial of the field at a centre: w_j' = sum vals * w**exps (per term)."""

    n: int                       # number of moment variables (n, or n + 1 when t is a state)
    comp: np.ndarray             # (T,) component index of each term
    exps: np.ndarray             # (T, n) exponents
    vals: np.ndarray             # (T,) float or object (Fraction) coefficients
    varying: list = field(default_factory=list)  # [(a(t), comp, exps, vals)]: a(t) * polynomial
    time_augmented: bool = False
    # [(exps over (y, t), |coefficients|, R)]: an argument of f whose displacement (majorant
    # sum |a| |w|**e, in y and t) must stay below R, the distance to a singularity of f
    radii: list = field(default_factory=list)

    def truncated(self, D: int) -> "_Expansion":
        keep = self.exps.sum(axis=1) <= D
        var = []
        for a, c, e, v in self.varying:
            k = e.sum(axis=1) <= D
            var.append((a, c[k], e[k], v[k]))
        return _Expansion(self.n, self.comp[keep], self.exps[keep], self.vals[keep], var,
                          self.time_augmented, self.radii)

    def radius_ratio(self, w: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """max over singular arguments of |their displacement| / R at displacements w (n, m) of
        the state after times tau (m,); 0 for polynomial and entire fields."""
        m = tau.size
        if not self.radii:
            return np.zeros(m)
        W = np.vstack([np.abs(w), np.abs(tau)[None, :]])
        out = np.zeros(m)
        with np.errstate(over="ignore", invalid="ignore"):
            for exps, a, R in self.radii:
                mono = np.prod(W[None, :, :] ** exps[:, :, None], axis=1)
                out = np.maximum(out, (a @ mono) / R)
        return np.where(np.isfinite(out), out, np.inf)

    @property
    def has_constant(self) -> bool:
        z = self.exps.sum(axis=1) == 0
        if np.any(z & (self.vals != 0)):
            return True
        return any(np.any(e.sum(axis=1) == 0) for _, _, e, _ in self.varying)


def _is_exact_number(x) -> bool:
    return isinstance(x, (numbers.Rational,)) and not isinstance(x, bool)


class PolynomialField:
    r"""A polynomial vector field ``y_j' = sum_mu a_{j,mu}(t) y**mu`` (the paper's (3.1)).

    Parameters
    ----------
    components : sequence of mappings
        One mapping per component ``j``: ``{exponent tuple mu: coefficient}``. A coefficient is a
        number (int and :class:`fractions.Fraction` keep exact rational arithmetic available) or a
        callable ``a(t)`` returning a float (time-varying coefficients, only needed to be
        continuous: such fields are integrated with ``solve_ivp``).

    Examples
    --------
    The Coulomb slide q'' = -1 as ``q' = v, v' = -1``:

    >>> f = PolynomialField([{(0, 1): 1}, {(0, 0): -1}])
    >>> f.n, f.degree, f.autonomous, f.exact
    (2, 1, True, True)
    >>> f(0.0, [0.0, 2.0]).tolist()
    [2.0, -1.0]
    """

    def __init__(self, components: Sequence[Mapping]):
        if isinstance(components, Mapping) or not isinstance(components, Sequence) or not components:
            raise ValueError("components must be a non-empty sequence of {exponent tuple: coefficient} "
                             "mappings, one per component")
        n = len(components)
        terms = []
        for j, comp in enumerate(components):
            if not isinstance(comp, Mapping):
                raise ValueError(f"components[{j}] must be a mapping {{exponent tuple: coefficient}}")
            cterms = []
            for mu, a in comp.items():
                mu = tuple(mu) if not isinstance(mu, numbers.Integral) else (mu,)
                if len(mu) != n or any((not isinstance(e, (numbers.Integral, np.integer))) or e < 0
                                       for e in mu):
                    raise ValueError(f"components[{j}]: exponent {mu!r} must be a tuple of {n} "
                                     f"non-negative integers")
                mu = tuple(int(e) for e in mu)
                if callable(a):
                    cterms.append((mu, a))
                    continue
                if isinstance(a, bool) or not isinstance(a, (numbers.Real, np.number)):
                    raise ValueError(f"components[{j}][{mu}]: coefficient must be a real number or "
                                     f"a callable of t, got {a!r}")
                if not _is_exact_number(a) and not np.isfinite(float(a)):
                    raise ValueError(f"components[{j}][{mu}]: coefficient must be finite, got {a!r}")
                if a != 0:
                    cterms.append((mu, a if _is_exact_number(a) else float(a)))
            terms.append(tuple(cterms))
        self.n = n
        self.terms = tuple(terms)
        self.autonomous = not any(callable(a) for comp in terms for _, a in comp)
        self.exact = all(_is_exact_number(a) for comp in terms for _, a in comp)
        self.degree = max((sum(mu) for comp in terms for mu, _ in comp), default=0)

    def __call__(self, t, y) -> np.ndarray:
        """Evaluate f(t, y) with floats (for reference integrators such as ``solve_ivp``)."""
        y = np.asarray(y, dtype=float)
        out = np.zeros((self.n,) + y.shape[1:])
        for j, comp in enumerate(self.terms):
            for mu, a in comp:
                coef = a(t) if callable(a) else float(a)
                m = coef
                for i, e in enumerate(mu):
                    if e:
                        m = m * y[i] ** e
                out[j] = out[j] + m
        return out

    def expansion(self, t: float, centre, degree: int) -> _Expansion:
        exact = self.exact and all(_is_exact_number(c) for c in centre)
        if exact:
            centre = [Fraction(c) for c in centre]
        else:
            centre = [float(c) for c in centre]
        const: dict = {}
        varying: list = []
        for j, comp in enumerate(self.terms):
            for mu, a in comp:
                shifted = _shift_monomial(mu, centre, degree, exact)
                if callable(a):
                    varying.append((a, {(j, nu): v for nu, v in shifted.items()}))
                else:
                    for nu, v in shifted.items():
                        const[(j, nu)] = const.get((j, nu), 0) + a * v
        comp, exps, vals = _terms_to_arrays(const, self.n, exact)
        var = []
        for a, d in varying:
            c2, e2, v2 = _terms_to_arrays(d, self.n, False)
            var.append((a, c2, e2, v2))
        return _Expansion(self.n, comp, exps, vals, var)


def _shift_monomial(mu, centre, degree, exact):
    """(c + w)**mu = sum_nu prod binom(mu_i, nu_i) c_i**(mu_i - nu_i) w**nu, |nu| <= degree."""
    parts = [{}]
    parts[0][()] = Fraction(1) if exact else 1.0
    for i, m in enumerate(mu):
        ci = centre[i]
        new = {}
        for nu, v in parts[0].items():
            for k in range(m + 1):
                if ci == 0 and k < m:
                    continue
                coef = math.comb(m, k) * (ci ** (m - k) if m - k else 1)
                new[nu + (k,)] = v * coef
        parts[0] = new
    return {nu: v for nu, v in parts[0].items() if sum(nu) <= degree and v != 0}


def _terms_to_arrays(d: dict, n: int, exact: bool):
    items = [(j, nu, v) for (j, nu), v in d.items() if v != 0]
    comp = np.array([j for j, _, _ in items], dtype=np.int64)
    exps = np.array([nu for _, nu, _ in items], dtype=np.int64).reshape(len(items), n)
    if exact:
        vals = np.empty(len(items), dtype=object)
        vals[:] = [v for _, _, v in items]
    else:
        vals = np.array([float(v) for _, _, v in items], dtype=float)
    return comp, exps, vals


class AnalyticField:
    """An analytic vector field given as a Python function ``fun(t, y)`` written with NumPy ufuncs.

    The LEM engine calls ``fun`` with :class:`Jet` arguments to get the exact Taylor polynomial of
    ``f`` at each expansion centre, up to the truncation degree (higher terms cannot enter the
    truncated system). ``t`` is expanded too: if the result depends on it, ``t`` becomes an extra
    state variable (``t' = 1``), so analytic time dependence is handled by the same linear system.

    Parameters
    ----------
    fun : callable ``fun(t, y) -> sequence of n values``
        Must work both for floats (``y`` an array) and for jets (``y`` an object array of jets):
        use ``np.tanh(y[0])``, not ``math.tanh(y[0])``, and no branching on the state.
    n : int
        Number of components.

    Examples
    --------
    >>> import numpy as np
    >>> f = AnalyticField(lambda t, y: [y[1], np.tanh(y[0])], 2)
    >>> e = f.expansion(0.0, [0.0, 0.0], 5)
    >>> sorted((int(j), tuple(int(i) for i in mu), round(float(v), 6)) for j, mu, v in zip(e.comp, e.exps, e.vals))
    [(0, (0, 1), 1.0), (1, (1, 0), 1.0), (1, (3, 0), -0.333333), (1, (5, 0), 0.133333)]
    """

    exact = False

    def __init__(self, fun: Callable, n: int):
        if not callable(fun):
            raise ValueError("fun must be callable as fun(t, y)")
        if not isinstance(n, numbers.Integral) or n < 1:
            raise ValueError(f"n must be a positive integer, got {n!r}")
        self.fun = fun
        self.n = int(n)
        self.autonomous = None  # decided from the jets at each expansion

    def __call__(self, t, y) -> np.ndarray:
        return np.asarray(self.fun(t, np.asarray(y, dtype=float)), dtype=float)

    def expansion(self, t: float, centre, degree: int) -> _Expansion:
        n = self.n
        space = _space(n + 1, degree)
        Y = np.empty(n, dtype=object)
        for i in range(n):
            Y[i] = Jet.variable(space, i, float(centre[i]))
        T = Jet.variable(space, n, float(t))
        try:
            out = self.fun(T, Y)
        except TypeError as exc:
            raise TypeError(f"fun(t, y) could not be expanded in Taylor series: {exc}") from exc
        out = list(out)
        if len(out) != n:
            raise ValueError(f"fun(t, y) returned {len(out)} components, expected {n}")
        coefs = []
        for j, o in enumerate(out):
            if isinstance(o, Jet):
                c = o.c
            elif isinstance(o, (numbers.Real, np.number)) or (isinstance(o, np.ndarray) and o.ndim == 0):
                c = np.zeros(space.size)
                c[0] = float(o)
            else:
                raise ValueError(f"fun(t, y)[{j}] is neither a number nor a jet: {o!r}")
            if not np.all(np.isfinite(c)):
                raise ValueError(f"the Taylor coefficients of fun(t, y)[{j}] at y = {list(centre)} "
                                 f"are not finite")
            coefs.append(c)
        coefs = np.array(coefs)
        radii, seen = [], set()
        for o in out:
            for a, R in (o.sing if isinstance(o, Jet) else ()):
                nz = np.flatnonzero(a)
                if id(a) in seen or nz.size == 0:
                    continue  # an argument that does not move cannot reach its singularity
                seen.add(id(a))
                radii.append((space.exps[nz], a[nz], R))
        t_dep = bool(np.any(coefs[:, space.exps[:, n] > 0] != 0))
        jj, ii = np.nonzero(coefs)
        if t_dep:
            comp = np.concatenate([jj, [n]])
            exps = np.vstack([space.exps[ii], np.zeros((1, n + 1), dtype=np.int64)])
            vals = np.concatenate([coefs[jj, ii], [1.0]])
            return _Expansion(n + 1, comp.astype(np.int64), exps, vals, [], True, radii)
        return _Expansion(n, jj.astype(np.int64), space.exps[ii][:, :n].copy(), coefs[jj, ii],
                          radii=radii)


def as_field(fun, n: int | None = None):
    """Turn what the user passed into a field: a field object, a list of dicts, or ``fun(t, y)``."""
    if isinstance(fun, (PolynomialField, AnalyticField)):
        f = fun
    elif isinstance(fun, Sequence) and not isinstance(fun, (str, bytes)) and fun and all(
            isinstance(c, Mapping) for c in fun):
        f = PolynomialField(fun)
    elif callable(fun):
        if n is None:
            raise ValueError("n (the number of components) is needed for a callable fun")
        f = AnalyticField(fun, n)
    else:
        raise ValueError("fun must be a PolynomialField, AnalyticField, a list of "
                         "{exponent tuple: coefficient} dicts, or a callable fun(t, y)")
    if n is not None and f.n != n:
        raise ValueError(f"fun has {f.n} components but y0 has {n}")
    return f


# --------------------------------------------------------------------------------------------
# The truncated moment system
# --------------------------------------------------------------------------------------------
@dataclass
class MomentSystem:
    r"""The truncated LEM system ``V' = (A + sum_i a_i(t) A_i) V`` for ``v_gamma = w**gamma``.

    Attributes
    ----------
    A : scipy.sparse.csr_matrix, shape (dimension, dimension)
        Constant part of the moment matrix (float; for exact fields see :attr:`triplets`).
    varying : list of (callable, csr_matrix)
        Time-varying parts ``a_i(t) A_i`` (empty for constant coefficients).
    exponents : ndarray of int, shape (dimension, n)
        The multi-index gamma of each kept moment (sorted by code).
    degree : int
        Truncation degree N (maximum total degree of the kept moments).
    outputs : ndarray of int
        Positions of the degree-1 moments ``w_i`` of the output components.
    constant_index : int or None
        Position of ``v_0 = 1`` when it is needed (``f(centre) != 0``).
    triplets : tuple (rows, cols, values) or None
        The entries with exact (``Fraction``) values when the field is rational.
    n_vars : int
        Number of moment variables (n, or n + 1 when t is a state).
    """

    A: sp.csr_matrix
    varying: list
    exponents: np.ndarray
    degree: int
    outputs: np.ndarray
    constant_index: int | None
    triplets: tuple | None
    n_vars: int
    codes: np.ndarray
    pw: np.ndarray

    @property
    def dimension(self) -> int:
        return int(self.exponents.shape[0])

    @property
    def nnz(self) -> int:
        return int(self.A.nnz + sum(B.nnz for _, B in self.varying))

    def index(self, gamma) -> int:
        """Position of moment gamma (ValueError if it is not kept)."""
        g = np.asarray(gamma, dtype=np.int64)
        if g.shape != (self.n_vars,) or g.sum() > self.degree or np.any(g < 0):
            raise ValueError(f"gamma {tuple(gamma)} is not a moment of this system")
        code = int(g @ self.pw)
        i = int(np.searchsorted(self.codes, code))
        if i >= self.codes.size or self.codes[i] != code:
            raise ValueError(f"moment {tuple(gamma)} is not kept (no output depends on it)")
        return i

    def initial_moments(self, w0) -> np.ndarray:
        """V(0) = w0**gamma for the kept moments."""
        w0 = np.asarray(w0, dtype=float)
        return np.prod(w0[None, :] ** self.exponents, axis=1)


def _targets(G: np.ndarray, comp: np.ndarray, exps: np.ndarray, N: int, chunk: int = 2_000_000):
    """All (row, column multi-index, term) with row gamma in G: gamma - e_j + mu, degree <= N."""
    rows_out, cols_out, terms_out = [], [], []
    n = G.shape[1]
    for j in np.unique(comp):
        tj = np.flatnonzero(comp == j)
        rj = np.flatnonzero(G[:, j] >= 1)
        if rj.size == 0 or tj.size == 0:
            continue
        base = G[rj].copy()
        base[:, j] -= 1
        bdeg = base.sum(axis=1)
        mus = exps[tj]
        mdeg = mus.sum(axis=1)
        step = max(1, chunk // max(1, tj.size * n))
        for s in range(0, rj.size, step):
            sl = slice(s, s + step)
            mask = (bdeg[sl, None] + mdeg[None, :]) <= N
            r_idx, t_idx = np.nonzero(mask)
            rows_out.append(rj[sl][r_idx])
            cols_out.append(base[sl][r_idx] + mus[t_idx])
            terms_out.append(tj[t_idx])
    if not rows_out:
        return (np.zeros(0, np.int64), np.zeros((0, n), np.int64), np.zeros(0, np.int64))
    return np.concatenate(rows_out), np.vstack(cols_out), np.concatenate(terms_out)


def _build_system(exp: _Expansion, N: int, out_components, prune: bool, max_dimension: int,
                  exact: bool = False) -> MomentSystem:
    n = exp.n
    pw = _powers(n, N)
    parts = [(None, exp.comp, exp.exps, exp.vals)] + list(exp.varying)
    all_comp = np.concatenate([p[1] for p in parts])
    all_exps = np.vstack([p[2] for p in parts]) if parts else np.zeros((0, n), np.int64)
    uniq = {}
    for j, mu in zip(all_comp.tolist(), map(tuple, all_exps.tolist())):
        uniq[(j, mu)] = True
    pat_comp = np.array([j for j, _ in uniq], dtype=np.int64)
    pat_exps = np.array([mu for _, mu in uniq], dtype=np.int64).reshape(len(uniq), n)

    eye = np.eye(n, dtype=np.int64)
    if prune:
        known = np.unique(eye[list(out_components)] @ pw)
        frontier = eye[list(out_components)]
        while frontier.shape[0]:
            _, cols, _ = _targets(frontier, pat_comp, pat_exps, N)
            if cols.shape[0] == 0:
                break
            ccodes, first = np.unique(cols @ pw, return_index=True)
            new = ~np.isin(ccodes, known)
            frontier = cols[first[new]]
            known = np.union1d(known, ccodes[new])
            if known.size > max_dimension:
                raise ValueError(f"the moment system exceeds max_dimension={max_dimension} "
                                 f"(degree {N}, {n} variables)")
        codes = np.sort(known)
        exps_R = np.zeros((codes.size, n), dtype=np.int64)
        rem = codes.copy()
        for i in range(n):
            exps_R[:, i] = rem % (N + 1)
            rem //= (N + 1)
    else:
        allm = _space(n, N)
        keep = allm.deg >= (0 if exp.has_constant else 1)
        codes, exps_R = allm.codes[keep], allm.exps[keep]
        if codes.size > max_dimension:
            raise ValueError(f"the moment system exceeds max_dimension={max_dimension} "
                             f"(degree {N}, {n} variables)")
    dim = codes.size

    def assemble(comp, exps, vals, want_exact=False):
        rows, cols, terms = _targets(exps_R, comp, exps, N)
        cidx = np.searchsorted(codes, cols @ pw)
        if cidx.size and (np.any(cidx >= dim) or np.any(codes[np.minimum(cidx, dim - 1)] != cols @ pw)):
            raise AssertionError("moment closure violated")  # pragma: no cover - internal invariant
        mult = exps_R[rows, comp[terms]]
        if want_exact:
            v = np.empty(terms.size, dtype=object)
            v[:] = [int(m) * vals[t] for m, t in zip(mult.tolist(), terms.tolist())]
            return rows, cidx, v
        v = mult * np.asarray(vals, dtype=float)[terms]
        return sp.csr_matrix((v, (rows, cidx)), shape=(dim, dim))

    A = assemble(exp.comp, exp.exps, exp.vals)
    triplets = assemble(exp.comp, exp.exps, exp.vals, want_exact=True) if exact else None
    varying = [(a, assemble(c, e, v)) for a, c, e, v in exp.varying]
    outputs = np.searchsorted(codes, eye[list(out_components)] @ pw)
    const = int(np.searchsorted(codes, 0)) if codes.size and codes[0] == 0 else None
    return MomentSystem(A, varying, exps_R, N, outputs, const, triplets, n, codes, pw)


def moment_system(fun, degree: int, *, centre=None, t: float = 0.0, outputs=None, prune: bool = True,
                  n: int | None = None, max_dimension: int = 200_000) -> MomentSystem:
    """Build the truncated LEM moment system of ``fun`` at an expansion centre.

    Parameters
    ----------
    fun : PolynomialField, AnalyticField, list of dicts, or callable ``fun(t, y)``
        The vector field (a callable needs ``n``).
    degree : int
        Truncation degree N >= 1 (also the degree of f's Taylor polynomial).
    centre : array_like, optional
        Expansion centre c (default: the origin, as in the paper).
    t : float
        Time at which time-dependent coefficients are expanded.
    outputs : sequence of int, optional
        Components whose degree-1 moments must be exact outputs (default all); only the moments
        they depend on are kept when ``prune`` is true.
    prune : bool
        Keep only the moments the outputs need (default) or every moment up to degree N.

    Returns
    -------
    MomentSystem

    Examples
    --------
    y'' = tanh y keeps only odd-degree moments (tanh is odd), as in the paper's (3.17):

    >>> import numpy as np
    >>> S = moment_system(lambda t, y: [y[1], np.tanh(y[0])], 5, n=2)
    >>> S.dimension, sorted(set(S.exponents.sum(axis=1).tolist()))
    (12, [1, 3, 5])
    """
    _check_int("degree", degree, 1)
    f = as_field(fun, n)
    c = [0] * f.n if centre is None else _finite_vector("centre", centre, f.n, allow_exact=True)
    outs = _check_outputs(outputs, f.n)
    exp = f.expansion(t, list(c), degree)
    exact = bool(getattr(f, "exact", False)) and all(_is_exact_number(x) for x in c)
    return _build_system(exp, degree, outs, prune, max_dimension, exact=exact)


# --------------------------------------------------------------------------------------------
# Options and results
# --------------------------------------------------------------------------------------------
def _check_int(name, v, lo):
    if isinstance(v, bool) or not isinstance(v, (numbers.Integral, np.integer)) or v < lo:
        raise ValueError(f"{name} must be an integer >= {lo}, got {v!r}")


def _check_float(name, v, lo=None, strict=False, allow_none=False):
    if v is None and allow_none:
        return
    if isinstance(v, bool) or not isinstance(v, (numbers.Real, np.number)) or not np.isfinite(v):
        raise ValueError(f"{name} must be a finite number, got {v!r}")
    if lo is not None and (v <= lo if strict else v < lo):
        raise ValueError(f"{name} must be {'>' if strict else '>='} {lo}, got {v!r}")


def _finite_vector(name, v, n=None, allow_exact=False):
    if allow_exact and isinstance(v, (list, tuple)) and all(_is_exact_number(x) for x in v):
        arr = list(v)
        if n is not None and len(arr) != n:
            raise ValueError(f"{name} must have {n} components, got {len(arr)}")
        return arr
    try:
        arr = np.asarray(v, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a 1-D array of finite numbers") from exc
    if arr.ndim != 1 or (n is not None and arr.size != n):
        raise ValueError(f"{name} must be a 1-D array of {n if n is not None else 'some'} numbers, "
                         f"got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {v!r}")
    return arr


def _check_outputs(outputs, n):
    if outputs is None:
        return tuple(range(n))
    outs = tuple(outputs)
    if not outs or any(isinstance(i, bool) or not isinstance(i, (numbers.Integral, np.integer))
                       or not 0 <= i < n for i in outs) or len(set(outs)) != len(outs):
        raise ValueError(f"outputs must be distinct component indices in [0, {n}), got {outputs!r}")
    return tuple(int(i) for i in outs)


@dataclass(frozen=True)
class LEMOptions:
    """Options of :func:`solve` (validated on construction).

    Attributes
    ----------
    degree : int
        Truncation degree N >= 1 of the moment system (default 20).
    restart : None, float or "auto"
        None: one expansion over the whole interval (the paper's plain LEM). A positive float h:
        re-centre on the current state every h. "auto": choose each segment from the error
        estimate (like a step-size controller).
    centre : "origin", "initial" or array
        Expansion centre of the plain (un-restarted) engine. "origin" is the paper's choice (then
        the degree-N truncation is the degree-N Taylor polynomial of the flow in the initial data).
    check : bool
        Compute the a-posteriori estimate from degrees N - 2k, N - k, N + k (default True).
    check_step : int
        k (default 2, so that odd fields such as tanh always gain a new non-zero degree).
    rtol, atol : float
        Tolerance of the trust test ``error <= atol + rtol*|y|`` (and of the auto restart).
    taylor_degree : int or None
        Degree of the Taylor polynomial of an analytic f (default: the truncation degree, beyond
        which terms cannot enter the truncated system).
    prune : bool
        Keep only the moments the outputs depend on (default True).
    max_dimension : int
        Refuse to build larger moment systems (ValueError).
    max_segments : int
        Give up (status -4) after this many restart segments.
    radius_fraction : float
        With restart="auto", a segment may carry f's singular arguments at most this fraction of
        the way to the nearest singularity of f (0 < radius_fraction < 0.9; default 0.5).
    first_step, min_step, max_step : float or None
        Segment lengths of the auto restart (defaults: 1/(1 + |Jacobian of f|), 1e-12 of the
        interval, the whole interval).
    ivp_method, ivp_rtol, ivp_atol
        ``solve_ivp`` settings for time-varying coefficients (DOP853, 1e-12, 1e-14).
    warn : bool
        Issue a :class:`LEMWarning` when the result is not to be trusted (status < 0).
    """

    degree: int = 20
    restart: object = None
    centre: object = "origin"
    check: bool = True
    check_step: int = 2
    rtol: float = 1e-10
    atol: float = 1e-12
    taylor_degree: int | None = None
    prune: bool = True
    max_dimension: int = 200_000
    max_segments: int = 10_000
    radius_fraction: float = 0.5
    first_step: float | None = None
    min_step: float | None = None
    max_step: float | None = None
    ivp_method: str = "DOP853"
    ivp_rtol: float = 1e-12
    ivp_atol: float = 1e-14
    warn: bool = True

    def __post_init__(self):
        _check_int("degree", self.degree, 1)
        _check_int("check_step", self.check_step, 1)
        _check_int("max_dimension", self.max_dimension, 1)
        _check_int("max_segments", self.max_segments, 1)
        if self.taylor_degree is not None:
            _check_int("taylor_degree", self.taylor_degree, 1)
        r = self.restart
        if isinstance(r, str):
            if r != "auto":
                raise ValueError(f"restart must be None, a positive step or 'auto', got {r!r}")
        elif r is not None:
            _check_float("restart", r, 0.0, strict=True)
        for name in ("rtol", "atol", "ivp_rtol", "ivp_atol"):
            _check_float(name, getattr(self, name), 0.0)
        if self.rtol == 0 and self.atol == 0:
            raise ValueError("rtol and atol cannot both be 0")
        for name in ("first_step", "min_step", "max_step"):
            _check_float(name, getattr(self, name), 0.0, strict=True, allow_none=True)
        if isinstance(self.centre, str):
            if self.centre not in ("origin", "initial"):
                raise ValueError(f"centre must be 'origin', 'initial' or an array, got {self.centre!r}")
        else:
            _finite_vector("centre", self.centre, allow_exact=True)
        if self.ivp_method not in ("DOP853", "RK45", "Radau", "BDF", "LSODA"):
            raise ValueError(f"ivp_method must be one of DOP853, RK45, Radau, BDF, LSODA, "
                             f"got {self.ivp_method!r}")
        _check_float("radius_fraction", self.radius_fraction, 0.0, strict=True)
        if not self.radius_fraction < RADIUS_TRUST:
            raise ValueError(f"radius_fraction must be < {RADIUS_TRUST}, got {self.radius_fraction!r}")
        if self.restart == "auto" and not self.check:
            raise ValueError("restart='auto' needs check=True (segments are chosen from the estimate)")
        for name in ("check", "prune", "warn"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be True or False, got {getattr(self, name)!r}")

    @classmethod
    def from_kwargs(cls, **kwargs) -> "LEMOptions":
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(kwargs) - known)
        if unknown:
            raise ValueError(f"unknown option(s) {unknown}; known options: {sorted(known)}")
        return cls(**kwargs)


@dataclass
class LEMStats:
    """Counters of a LEM solve.

    Attributes
    ----------
    n_segments : int
        Accepted expansion segments (1 for the plain engine).
    n_rejected : int
        Segments rejected by the auto restart.
    n_systems : int
        Moment systems built (all degrees, all segments, rejected ones included).
    n_propagations : int
        expm_multiply / solve_ivp calls.
    build_time, solve_time : float
        Seconds spent building moment systems (Taylor expansion + sparse assembly) and solving them.
    max_nnz : int
        Largest number of non-zeros of a degree-N moment matrix.
    taylor_degree : int
        Degree of f's Taylor polynomial used at degree N.
    time_varying : bool
        Coefficients depended on t through callables (solve_ivp path).
    time_augmented : bool
        An analytic f depended on t, which became a state variable.
    """

    n_segments: int = 0
    n_rejected: int = 0
    n_systems: int = 0
    n_propagations: int = 0
    build_time: float = 0.0
    solve_time: float = 0.0
    max_nnz: int = 0
    taylor_degree: int = 0
    time_varying: bool = False
    time_augmented: bool = False


@dataclass
class LEMResult:
    """Result of :func:`solve`, in the style of ``scipy.integrate.solve_ivp``.

    Attributes
    ----------
    t : ndarray, shape (m,)
        Output points.
    y : ndarray, shape (n_out, m)
        Degree-N LEM solution of the output components at ``t``.
    status : int
        See :data:`STATUS_MESSAGES`; ``success = status >= 0``.
    message : str
        Why the solve stopped or how far it can be trusted (names the first failing point).
    error_estimate : ndarray, shape (n_out, m)
        A-posteriori error estimate of ``y`` (differences of truncations, propagated across
        restarts with the LEM sensitivity); NaN where not computed.
    diverging_points : ndarray of bool, shape (m,)
        Points where successive truncations grow (the series diverges there).
    convergence_ratio : ndarray, shape (m,)
        Largest ratio of successive truncation differences (< 1 converging); NaN if unknown.
    sensitivity : ndarray, shape (n_out, n, m)
        d y(t) / d y0, from the same propagators (used e.g. for shooting).
    degree : int
        Truncation degree N.
    check_degrees : tuple of int
        Degrees compared for the estimate.
    moment_dimension : int
        Largest number of moments of a degree-N system.
    n_restarts : int
        Number of re-centrings (segments - 1).
    restart_points : ndarray
        Centres' times (segment starts) and the final time.
    stats : LEMStats
    radius_ratio : ndarray, shape (m,)
        How far the state has moved towards the nearest singularity of f seen from the expansion
        centre (the displacement of each singular argument of f, such as v/eps in tanh(v/eps),
        over its distance to the singularity); from :data:`RADIUS_TRUST` = 0.9 on, f's Taylor
        series no longer represents f and the point counts as diverging. 0 for polynomial and
        entire f.
    """

    t: np.ndarray
    y: np.ndarray
    status: int
    message: str
    error_estimate: np.ndarray
    diverging_points: np.ndarray
    convergence_ratio: np.ndarray
    sensitivity: np.ndarray
    degree: int
    check_degrees: tuple
    moment_dimension: int
    n_restarts: int
    restart_points: np.ndarray
    stats: LEMStats
    radius_ratio: np.ndarray | None = None

    @property
    def success(self) -> bool:
        return self.status >= 0

    @property
    def diverging(self) -> bool:
        """True when successive truncations diverge at some output point."""
        return bool(np.any(self.diverging_points))

    def __repr__(self) -> str:
        return (f"LEMResult(status={self.status}, degree={self.degree}, "
                f"moment_dimension={self.moment_dimension}, n_restarts={self.n_restarts}, "
                f"max_error_estimate={np.nanmax(self.error_estimate, initial=0.0):.3g}, "
                f"message={self.message!r})")


# --------------------------------------------------------------------------------------------
# Propagation of one expansion segment
# --------------------------------------------------------------------------------------------
class _Blowup(Exception):
    pass


class _IVPFailure(Exception):
    pass


def _propagate(S: MomentSystem, B: np.ndarray, taus: np.ndarray, t_c: float, opts: LEMOptions,
               stats: LEMStats) -> tuple:
    """Moments' output rows at each tau (relative to t_c), shape (len(taus), n_out, ncols), and the
    rounding level of the first column there, shape (len(taus),), in units of the scaled moments.

    The rounding level is what the propagation itself cannot resolve: about eps times the number
    of matrix-vector products (~ ||A||_1 tau) times what feeds the output rows, |v_i| + tau
    (|A| |V|)_i (for solve_ivp: its rtol instead of eps). Differences between truncations below
    it are noise, not a trend.
    """
    out = np.empty((taus.size, S.outputs.size, B.shape[1]))
    noise = np.empty(taus.size)
    t0 = time.perf_counter()
    if not S.varying:
        absA = abs(S.A).tocsr()
        anorm = float(absA.sum(axis=0).max()) if S.A.nnz else 0.0
        V, prev = B, 0.0
        for i, tau in enumerate(taus):
            dt = tau - prev
            if dt != 0.0:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)
                    if anorm * abs(dt) > _DENSE_NORM and S.dimension <= _DENSE_DIM:
                        # stiff segment (a smoothed friction law after the stop: rates ~ 1/eps):
                        # expm_multiply needs ~||A|| dt products, scaling and squaring log2 of it
                        V = expm(S.A.toarray() * dt) @ V
                    else:
                        # traceA=0 turns off expm_multiply's shift by trace(A)/n: for moment
                        # matrices (diagonal ~ degree x growth rate) the shift costs digits, 3e-13
                        # instead of 1e-16 on the logistic equation at degree 60
                        V = expm_multiply(S.A * dt, V, traceA=0.0)
                stats.n_propagations += 1
                if not np.all(np.isfinite(V)):
                    stats.solve_time += time.perf_counter() - t0
                    raise _Blowup(t_c + tau)
            out[i] = V[S.outputs]
            feed = np.abs(V[S.outputs, 0]) + abs(tau) * (absA[S.outputs] @ np.abs(V[:, 0]))
            noise[i] = _EPS * (16.0 + 4.0 * anorm * abs(tau)) * feed.max(initial=0.0)
            prev = tau
    else:
        ncols = B.shape[1]

        def rhs(tau, v):
            V = v.reshape(-1, ncols)
            dV = S.A @ V
            for a, Ai in S.varying:
                dV = dV + a(t_c + tau) * (Ai @ V)
            return dV.ravel()

        res = solve_ivp(rhs, (0.0, taus[-1]), B.ravel(), method=opts.ivp_method, t_eval=taus,
                        rtol=opts.ivp_rtol, atol=opts.ivp_atol)
        stats.n_propagations += 1
        if res.status < 0 or res.y.shape[1] != taus.size:
            stats.solve_time += time.perf_counter() - t0
            raise _IVPFailure(res.message)
        Y = res.y.T.reshape(taus.size, -1, ncols)
        if not np.all(np.isfinite(Y)):
            stats.solve_time += time.perf_counter() - t0
            raise _Blowup(t_c + taus[-1])
        out[:] = Y[:, S.outputs, :]
        noise[:] = 10.0 * opts.ivp_rtol * np.abs(Y[:, S.outputs, 0]).max(axis=1)
    stats.solve_time += time.perf_counter() - t0
    return out, noise


@dataclass
class _Segment:
    y: np.ndarray        # (n_out, m) degree-N values
    local: np.ndarray    # (n_out, m) local error estimate
    jac: np.ndarray      # (n_out, n, m) d y / d state at start
    ratio: np.ndarray    # (m,)
    diverging: np.ndarray  # (m,) bool
    dim: int
    nnz: int
    radius: np.ndarray   # (m,) displacement of f's singular arguments / distance to singularity


def _scales(exp: _Expansion, w0: np.ndarray, h: float, t_c: float, N: int) -> np.ndarray:
    """Powers of two rho_i by which the moments are scaled: they are propagated as (w/rho)**gamma.

    The scaling is the similarity A -> D^-1 A D, D = diag(rho**gamma), which changes nothing in
    exact arithmetic (nor, with powers of two, in rounding), but matters twice in practice:

    * expm_multiply controls its error relative to the whole moment vector, so rho must be close
      to the displacement |w| actually reached: if rho >> |w| the degree-1 moments drown under
      v_0 = 1 (the slide q'' = -1 lost its -t**2/2 that way); if rho << |w| the high moments
      (w/rho)**N swamp them. Hence rho_i lies between |w0_i| and a two-term estimate
      r = |w0| + h a0 + h J (|w0| + h a0) of the displacement over the segment (a0 = f(centre),
      J = |Jacobian|), and as close to r as the next point allows;
    * its cost grows with the norm of A: unscaled, large Taylor coefficients of f (sinh(lambda y)
      with z ~ 1e5 near a pole of Troesch's solution) need 1e4-1e5 matrix-vector products per
      segment. Within [max(|w0|, r / 2**20), r], rho is the largest scale whose row-sum bound
      max_j sum_mu |a_jmu| rho**mu / rho_j (of A / |gamma|, convex in log rho) is within a factor
      4 of the smallest: it drops below r only when that tames large coefficients (tanh beyond
      its radius pi/2, where r overestimates the displacement).
    """
    n = exp.n
    comp = [exp.comp] + [c for _, c, _, _ in exp.varying]
    exps = [exp.exps] + [e for _, _, e, _ in exp.varying]
    vals = [np.asarray(exp.vals, dtype=float)] + [float(a(t_c)) * np.asarray(v, dtype=float)
                                                  for a, _, _, v in exp.varying]
    comp, exps, vals = np.concatenate(comp), np.vstack(exps), np.abs(np.concatenate(vals))
    keep = vals > 0
    comp, exps, vals = comp[keep], exps[keep], vals[keep]
    if comp.size == 0 or not np.all(np.isfinite(vals)):
        return np.ones(n)
    deg = exps.sum(axis=1)
    a0, J = np.zeros(n), np.zeros((n, n))
    np.add.at(a0, comp[deg == 0], vals[deg == 0])
    one = deg == 1
    np.add.at(J, (comp[one], np.argmax(exps[one], axis=1)), vals[one])
    # |w(t)| <= expm(t |J|) (|w0| + t a0) to first order: the growth of the linearization matters,
    # since the top moments of a truncation grow like exp(N lambda t) (w0/rho)**N when rho is small
    with np.errstate(over="ignore", invalid="ignore"):
        r = expm(np.minimum(abs(h) * J, 700.0 / n)) @ (np.abs(w0) + abs(h) * a0)
    r = np.where(np.isfinite(r), r, np.finfo(float).max)
    B = max(1, int(600 // max(N, 1)))
    with np.errstate(divide="ignore"):
        up = np.where(r > 0, np.ceil(np.log2(np.where(r > 0, r, 1.0))), 0.0)
        lo = np.where(w0 != 0, np.ceil(np.log2(np.where(w0 != 0, np.abs(w0), 1.0))), up - 20)
    up, lo = np.clip(up, -B, B), np.clip(lo, -B, B)
    lo = np.minimum(lo, up)
    if np.all(lo == up):
        return np.exp2(up)
    exps = exps.astype(float)
    L = np.log2(vals)
    comps = np.unique(comp)
    members = [np.flatnonzero(comp == j) for j in comps]
    sizes = up - lo + 1
    if np.prod(sizes) <= 20000:
        # few candidates (the usual case): evaluate the exact bound on the whole grid
        axes = [np.arange(l, u + 1) for l, u in zip(lo, up)]
        U = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, n)
        X = L[None, :] + U @ exps.T
        F = np.full(U.shape[0], -np.inf)
        for j, mem in zip(comps, members):
            Xj = X[:, mem]
            m = Xj.max(axis=1)
            F = np.maximum(F, m + np.log2(np.exp2(Xj - m[:, None]).sum(axis=1)) - U[:, j])
        # the largest scales (closest to the displacement estimate) whose bound is within a
        # factor 4 of the best: a smaller rho is only worth it when it tames big coefficients
        best = np.flatnonzero(F <= F.min() + 2.0)
        return np.exp2(U[best[np.argmax(U[best].sum(axis=1))]])
    beta = 8.0  # smooth max over components; convex in u = log2(rho), so a local solver suffices

    def objective(u):
        X = L + exps @ u
        g = np.empty(comps.size)
        grads = np.zeros((comps.size, n))
        for k, (j, mem) in enumerate(zip(comps, members)):
            Xj = X[mem]
            m = Xj.max()
            w = np.exp2(Xj - m)
            sw = w.sum()
            g[k] = m + np.log2(sw) - u[j]
            grads[k] = (w / sw) @ exps[mem]
            grads[k, j] -= 1.0
        gm = g.max()
        p = np.exp2(beta * (g - gm))
        ps = p.sum()
        return gm + np.log2(ps) / beta, (p / ps) @ grads

    res = minimize(objective, up.copy(), jac=True, method="L-BFGS-B",
                   bounds=list(zip(lo.tolist(), up.tolist())), options={"maxiter": 100})
    u = np.clip(np.round(res.x if np.all(np.isfinite(res.x)) else up), lo, up)
    # as on the grid: move up towards the displacement estimate while the bound stays within 4x
    fmin = objective(u)[0]
    for i in range(n):
        while u[i] < up[i]:
            trial = u.copy()
            trial[i] += 1
            if objective(trial)[0] > fmin + 2.0:
                break
            u = trial
    return np.exp2(u)


def _scaled(S: MomentSystem, scale: np.ndarray) -> MomentSystem:
    """The same system for the moments V / scale (a diagonal similarity transform)."""
    if np.all(scale == 1.0):
        return S
    Dm = sp.diags(scale)
    Di = sp.diags(1.0 / scale)
    A = (Di @ S.A @ Dm).tocsr()
    varying = [(a, (Di @ B @ Dm).tocsr()) for a, B in S.varying]
    return MomentSystem(A, varying, S.exponents, S.degree, S.outputs, S.constant_index, None,
                        S.n_vars, S.codes, S.pw)


def _segment(fld, t_c: float, state: np.ndarray, centre, taus: np.ndarray, outs, opts: LEMOptions,
             degrees: tuple, stats: LEMStats) -> _Segment:
    """Propagate one expansion about ``centre`` from ``state`` at t_c to t_c + taus."""
    N = opts.degree
    n = fld.n
    Dmax = max(degrees)
    tdeg = Dmax if opts.taylor_degree is None else min(opts.taylor_degree, Dmax)
    t0 = time.perf_counter()
    full = fld.expansion(t_c, list(centre), tdeg)
    stats.build_time += time.perf_counter() - t0
    stats.time_varying |= bool(full.varying)
    stats.time_augmented |= full.time_augmented
    w0 = np.zeros(full.n)
    w0[:n] = np.asarray(state, dtype=float) - np.asarray([float(c) for c in centre])
    rho = _scales(full, w0, float(taus[-1]), t_c, max(degrees))
    values, jac, dim, nnz = {}, None, 0, 0
    noise = np.zeros((len(outs), taus.size))
    for D in degrees:
        t0 = time.perf_counter()
        exp = full.truncated(D if opts.taylor_degree is None else min(opts.taylor_degree, D))
        S = _build_system(exp, D, outs, opts.prune, opts.max_dimension)
        stats.build_time += time.perf_counter() - t0
        stats.n_systems += 1
        V0 = S.initial_moments(w0)
        scale = np.prod(rho[None, :] ** S.exponents, axis=1)
        S_run = _scaled(S, scale)
        if D == N:
            # d V0 / d w0_j = gamma_j w0**(gamma - e_j): propagating it gives the sensitivity.
            cols = [V0]
            for j in range(n):
                g = S.exponents
                e = g.copy()
                e[:, j] -= 1
                with np.errstate(invalid="ignore"):
                    dv = np.where(g[:, j] > 0, g[:, j] * np.prod(w0[None, :] ** np.maximum(e, 0), axis=1), 0.0)
                cols.append(dv)
            B = np.column_stack(cols) / scale[:, None]
            dim, nnz = S.dimension, S.nnz
            stats.taylor_degree = exp.exps.sum(axis=1).max(initial=0)
        else:
            B = (V0 / scale)[:, None]
        P, nz = _propagate(S_run, B, taus, t_c, opts, stats)
        P = P * rho[list(outs)][None, :, None]
        noise = np.maximum(noise, rho[list(outs)][:, None] * nz[None, :])
        c_out = np.array([float(centre[i]) for i in outs])
        values[D] = P[:, :, 0].T + c_out[:, None]
        if D == N:
            jac = np.transpose(P[:, :, 1:], (1, 2, 0))
    yN = values[N]
    m = taus.size
    local = np.full(yN.shape, np.nan)
    ratio = np.full(m, np.nan)
    diverging = np.zeros(m, dtype=bool)
    if opts.check and len(degrees) > 1:
        k = opts.check_step
        d3 = np.abs(values[N + k] - yN)
        d2 = np.abs(yN - values[N - k]) if (N - k) in values else None
        d1 = np.abs(values[N - k] - values[N - 2 * k]) if (N - 2 * k) in values else None
        floor = np.maximum(_NOISE * np.maximum(1.0, np.abs(yN)), noise)
        local = d3.copy()
        if d2 is not None:
            with np.errstate(divide="ignore", invalid="ignore"):
                r32 = np.where(d3 > floor, d3 / np.maximum(d2, 1e-300), 0.0)
            grow = (d3 > floor) & (r32 >= 1.0)
            if d1 is not None:
                # one freak small difference (a coefficient that happens to vanish) must not decide:
                # divergence needs growth over the last step and over two steps.
                grow &= d3 >= d1
                with np.errstate(divide="ignore", invalid="ignore"):
                    expected = np.where(d1 > 0, d2 * d2 / np.where(d1 > 0, d1, 1.0), 0.0)
                local = np.maximum(local, np.where(d2 > floor, expected, 0.0))
            # moments so large that rounding alone exceeds the solution: the series has blown up
            # even if the differences cannot show a trend any more
            grow |= noise > np.maximum(np.abs(yN), opts.atol)
            diverging = np.any(grow, axis=0)
            ratio = np.max(r32, axis=0)
            # geometric tail of the remaining degrees: slow convergence (ratio near 1) must not
            # pass for accuracy (the ratio is capped so a freak value cannot make it infinite)
            q_tail = np.clip(np.where(d2 > floor, r32, 0.0), 0.0, 0.95)
            local = local / (1.0 - q_tail)
    # Truncation differences cannot see a singularity of f whose Taylor coefficients are tiny at
    # the centre (tanh(v/eps) saturated: sech**2 underflows, every truncation agrees, and the state
    # slides across v = 0 where tanh turns). The jets know where each singularity is: beyond
    # RADIUS_TRUST of the distance, f's own series no longer represents f.
    W = np.zeros((n, m))
    W[list(outs)] = yN - c_out[:, None]
    radius = full.radius_ratio(W, taus)
    diverging = diverging | (radius >= RADIUS_TRUST)
    return _Segment(yN, local, jac, ratio, diverging, dim, nnz, radius)


# --------------------------------------------------------------------------------------------
# solve
# --------------------------------------------------------------------------------------------
def _degrees(opts: LEMOptions) -> tuple:
    N, k = opts.degree, opts.check_step
    if not opts.check:
        return (N,)
    return tuple(d for d in (N - 2 * k, N - k, N, N + k) if d >= 1)


def solve(fun, x_span, y0, *, t_eval=None, outputs=None, **options) -> LEMResult:
    """Solve ``y' = f(t, y)``, ``y(x0) = y0`` by the truncated Linear Equivalence Method.

    Parameters
    ----------
    fun : callable ``fun(t, y)``, list of ``{exponent tuple: coefficient}`` dicts, or a field
        The vector field: an analytic function written with NumPy ufuncs (see
        :class:`AnalyticField`) or a polynomial (:class:`PolynomialField`; coefficients may be
        callables of ``t``).
    x_span : (x0, x1)
        Interval of integration (x1 may be smaller than x0).
    y0 : array_like, shape (n,)
        Initial state.
    t_eval : array_like, optional
        Output points inside the interval, ordered from x0 to x1. Default: x0, x1 and every
        restart point.
    outputs : sequence of int, optional
        Components to return (default all); without restarts only the moments they need are built.
    **options
        Any field of :class:`LEMOptions` (``degree``, ``restart``, ``rtol``, ...). Unknown names
        raise ``ValueError``.

    Returns
    -------
    LEMResult
        ``t`` (m,), ``y`` (n_out, m), ``error_estimate`` (n_out, m), ``status``/``message``/
        ``success``, ``diverging``, ``sensitivity`` (n_out, n, m), ``moment_dimension``,
        ``n_restarts`` and ``stats``.

    Notes
    -----
    The plain engine (``restart=None``) expands once about ``centre`` (the origin by default,
    as in the paper): with f(0) = 0 its degree-N answer is the degree-N Taylor polynomial of the
    flow in the initial data, which converges only inside that series' radius, a radius that
    shrinks with x. The trust test compares degrees N - 2k, N - k, N, N + k: differences that
    keep growing flag divergence (status -1, :class:`LEMWarning`); otherwise the last difference
    (or its geometric extrapolation, if larger) is the error estimate. With restarts the local
    estimates are carried forward through the LEM sensitivity d y / d y0.

    Examples
    --------
    The sliding block q'' = -1 is reproduced exactly at every degree:

    >>> res = solve([{(0, 1): 1}, {(0, 0): -1}], (0.0, 2.0), [0.0, 1.5], degree=1, check=False)
    >>> res.y[:, -1].tolist()
    [1.0, -0.5]

    Restarts carry y'' = tanh y beyond the radius of the first expansion:

    >>> import numpy as np
    >>> f = lambda t, y: [y[1], np.tanh(y[0])]
    >>> res = solve(f, (0.0, 2.0), [0.0, 1.0], degree=16, restart="auto")
    >>> res.success, res.n_restarts > 0, bool(np.all(res.error_estimate < 1e-9))
    (True, True, True)
    """
    opts = LEMOptions.from_kwargs(**options)
    y0 = _finite_vector("y0", y0)
    n = y0.size
    fld = as_field(fun, n)
    try:
        x0, x1 = (float(v) for v in x_span)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"x_span must be a pair (x0, x1), got {x_span!r}") from exc
    if not (np.isfinite(x0) and np.isfinite(x1)) or x0 == x1:
        raise ValueError(f"x_span must be two distinct finite numbers, got {x_span!r}")
    direction = 1.0 if x1 > x0 else -1.0
    outs = _check_outputs(outputs, n)
    if t_eval is not None:
        te = _finite_vector("t_eval", t_eval)
        if te.size == 0:
            raise ValueError("t_eval must not be empty")
        if np.any(direction * (te - x0) < 0) or np.any(direction * (te - x1) > 0):
            raise ValueError("t_eval must lie inside x_span")
        if np.any(direction * np.diff(te) <= 0):
            raise ValueError("t_eval must be strictly ordered from x0 to x1")
    else:
        te = None
    if opts.restart is not None and not isinstance(opts.centre, str):
        raise ValueError("centre applies only to the plain engine (restart=None); restarts "
                         "re-centre on the current state")

    stats = LEMStats()
    degrees = _degrees(opts)
    if opts.restart is None:
        if isinstance(opts.centre, str):
            centre = np.zeros(n) if opts.centre == "origin" else y0.copy()
        else:
            centre = _finite_vector("centre", opts.centre, n, allow_exact=True)
        t_out = te if te is not None else np.array([x0, x1])
        return _solve_plain(fld, x0, y0, centre, t_out, outs, opts, degrees, stats)
    return _solve_restarted(fld, x0, x1, direction, y0, te, outs, opts, degrees, stats)


def _status_from(y, err, div, opts, t, nonfinite_at=None):
    if nonfinite_at is not None:
        return -2, f"{STATUS_MESSAGES[-2]} (at t = {nonfinite_at:.6g})"
    if np.any(div):
        i = int(np.argmax(div))
        return -1, f"{STATUS_MESSAGES[-1]} (first at t = {t[i]:.6g})"
    if not opts.check:
        return 2, STATUS_MESSAGES[2]
    tol = opts.atol + opts.rtol * np.abs(y)
    bad = ~(err <= tol)
    if np.any(bad):
        i = int(np.argmax(np.any(bad, axis=0)))
        return 1, (f"{STATUS_MESSAGES[1]} (first at t = {t[i]:.6g}: estimate "
                   f"{np.nanmax(err[:, i]):.3g})")
    return 0, STATUS_MESSAGES[0]


def _finish(res: LEMResult, opts: LEMOptions) -> LEMResult:
    if res.status < 0 and opts.warn:
        warnings.warn(res.message, LEMWarning, stacklevel=3)
    return res


def _solve_plain(fld, x0, y0, centre, t_out, outs, opts, degrees, stats) -> LEMResult:
    n = fld.n
    taus = t_out - x0
    nz = taus != 0.0
    m = t_out.size
    y = np.empty((len(outs), m))
    err = np.zeros((len(outs), m))
    jac = np.zeros((len(outs), n, m))
    ratio = np.full(m, np.nan)
    rad = np.zeros(m)
    div = np.zeros(m, dtype=bool)
    y[:, ~nz] = y0[list(outs)][:, None]
    jac[:, :, ~nz] = np.eye(n)[list(outs)][:, :, None]
    status_nf = None
    dim = nnz = 0
    if np.any(nz):
        try:
            seg = _segment(fld, x0, y0, centre, taus[nz], outs, opts, degrees, stats)
            y[:, nz], err[:, nz], jac[:, :, nz] = seg.y, seg.local, seg.jac
            ratio[nz], div[nz], rad[nz] = seg.ratio, seg.diverging, seg.radius
            dim, nnz = seg.dim, seg.nnz
        except _Blowup as exc:
            status_nf = exc.args[0]
            y[:, nz] = np.nan
            err[:, nz] = np.inf
        except _IVPFailure as exc:
            y[:, nz] = np.nan
            res = LEMResult(t_out, y, -5, f"{STATUS_MESSAGES[-5]} ({exc.args[0]})", err, div, ratio,
                            jac, opts.degree, degrees, dim, 0, np.array([x0, t_out[-1]]), stats, rad)
            return _finish(res, opts)
    if not opts.check:
        err[:, nz] = np.nan
    stats.n_segments = 1
    stats.max_nnz = nnz
    status, msg = _status_from(y, err, div, opts, t_out, status_nf)
    res = LEMResult(t_out, y, status, msg, err, div, ratio, jac, opts.degree, degrees, dim, 0,
                    np.array([x0, t_out[-1]]), stats, rad)
    return _finish(res, opts)


def _auto_ratio(seg: _Segment, h: float, span: float, opts: LEMOptions) -> float:
    """Local estimate over its share of the tolerance (error per unit step: the local estimates
    of all segments then add up to at most atol + rtol*|y| before amplification by the flow)."""
    # ... but never below the rounding level of the state, which no degree can beat.
    tol = np.maximum((opts.atol + opts.rtol * np.abs(seg.y)) * (h / span), 16 * _EPS * np.abs(seg.y))
    with np.errstate(invalid="ignore", divide="ignore"):
        q = np.nanmax(seg.local / tol) if seg.local.size else 0.0
    return float(q) if np.isfinite(q) or np.isinf(q) else np.inf


def _solve_restarted(fld, x0, x1, direction, y0, te, outs, opts, degrees, stats) -> LEMResult:
    n = fld.n
    allc = tuple(range(n))
    span = abs(x1 - x0)
    auto = opts.restart == "auto"
    min_step = opts.min_step if opts.min_step is not None else 1e-12 * max(span, abs(x0), 1.0)
    max_step = opts.max_step if opts.max_step is not None else span
    if auto:
        if opts.first_step is not None:
            h = opts.first_step
        else:
            e1 = fld.expansion(x0, list(y0), 1)
            lin = e1.exps.sum(axis=1) == 1
            J = np.zeros((e1.n, e1.n))
            np.add.at(J, (e1.comp[lin], np.argmax(e1.exps[lin], axis=1)), np.asarray(e1.vals[lin], float))
            h = 1.0 / (1.0 + np.abs(J).sum(axis=1).max(initial=0.0))
        h = min(h, max_step, span)
    else:
        h = min(float(opts.restart), span)
    # With w(t_c) = 0 the degree-N truncation is exact in x to order about 2N (the k-th
    # derivative only visits moments of degree <= (k + 1)/2): the local error behaves like h**(2N).
    order = 2 * opts.degree
    just_rejected = False
    t_c, state = x0, y0.copy()
    # Error propagation: the local error delta_k made in segment k reaches time t as
    # Phi(t, t_k) delta_k (signs unknown). Phi(t, t_k) = J(t) M_k is kept exactly for every earlier
    # segment (M_k = product of later segments' Jacobians): bounding with |J_m|...|J_1| instead
    # would grow like sqrt(2)**m for a mere rotation (an oscillator) and drown the estimate.
    Ms = np.zeros((0, n, n))
    deltas = np.zeros((0, n))
    S_tot = np.eye(n)                     # d state / d y0
    T_list, Y_list, E_list, J_list = [x0], [y0.copy()], [np.zeros(n)], [np.eye(n)]
    R_list, D_list, Q_list = [np.nan], [False], [0.0]
    restart_points = [x0]
    status_override = None
    dim_max = nnz_max = 0
    pending = list(te[direction * (te - x0) > 0]) if te is not None else None
    while direction * (x1 - t_c) > 0:
        if stats.n_segments >= opts.max_segments:
            status_override = (-4, f"{STATUS_MESSAGES[-4]} ({opts.max_segments}, at t = {t_c:.6g})")
            break
        h = min(h, abs(x1 - t_c))
        if abs(x1 - t_c) - h < 1e-14 * max(span, 1.0):
            h = abs(x1 - t_c)
        t_end = t_c + direction * h
        if pending is not None:
            inside = [p for p in pending if direction * (p - t_end) < 0]
            pts = inside + [t_end]
        else:
            pts = [t_end]
        taus = np.array(pts) - t_c
        try:
            seg = _segment(fld, t_c, state, state, taus, allc, opts, degrees, stats)
            failed = None
        except _Blowup as exc:
            seg, failed = None, ("blowup", exc.args[0])
        except _IVPFailure as exc:
            seg, failed = None, ("ivp", exc.args[0])
        if auto:
            if seg is not None:
                q = _auto_ratio(seg, h, span, opts)
                reach = float(seg.radius.max(initial=0.0))
                ok = (not np.any(seg.diverging)) and np.isfinite(q) and q <= 1.0 \
                    and reach <= opts.radius_fraction
            else:
                ok, q, reach = False, np.inf, 0.0
            if not ok:
                stats.n_rejected += 1
                if failed is not None and failed[0] == "ivp":
                    status_override = (-5, f"{STATUS_MESSAGES[-5]} ({failed[1]})")
                    break
                if not np.isfinite(q) or seg is None or np.any(seg.diverging):
                    fac = 0.3
                elif q > 1.0:
                    fac = max(0.2, min(0.7, 0.9 * q ** (-1.0 / order)))
                else:
                    fac = 0.7
                if reach > opts.radius_fraction:
                    # the displacement grows about linearly with the segment
                    fac = min(fac, max(0.1, 0.9 * opts.radius_fraction / reach))
                h *= fac
                just_rejected = True
                if h < min_step:
                    status_override = (-3, f"{STATUS_MESSAGES[-3]} (at t = {t_c:.6g}, step {h:.3g})")
                    break
                continue
        else:
            if seg is None:
                if failed[0] == "ivp":
                    status_override = (-5, f"{STATUS_MESSAGES[-5]} ({failed[1]})")
                else:
                    status_override = (-2, f"{STATUS_MESSAGES[-2]} (at t = {failed[1]:.6g})")
                break
        # accept the segment
        stats.n_segments += 1
        dim_max, nnz_max = max(dim_max, seg.dim), max(nnz_max, seg.nnz)
        loc = seg.local if opts.check else np.zeros_like(seg.y)
        for i, p in enumerate(pts):
            Ji = seg.jac[:, :, i]
            T_list.append(p)
            Y_list.append(seg.y[:, i].copy())
            carried = np.einsum("kij,kj->i", np.abs(np.matmul(Ji, Ms)), deltas) if deltas.size else 0.0
            E_list.append(carried + np.nan_to_num(loc[:, i], nan=0.0))
            J_list.append(Ji @ S_tot)
            R_list.append(seg.ratio[i])
            D_list.append(bool(seg.diverging[i]))
            Q_list.append(float(seg.radius[i]))
        state = seg.y[:, -1].copy()
        Ms = np.concatenate([np.matmul(seg.jac[:, :, -1], Ms), np.eye(n)[None]], axis=0)
        deltas = np.vstack([deltas, np.nan_to_num(loc[:, -1], nan=0.0)[None]])
        S_tot = J_list[-1].copy()
        t_c = t_end
        restart_points.append(t_c)
        if pending is not None:
            pending = [p for p in pending if direction * (p - t_end) > 0]
        if not auto and np.any(seg.diverging):
            break  # the state is garbage beyond this point: stop honestly
        if auto:
            # No growth right after a rejection: near the radius of convergence the error jumps
            # from rounding level to divergence within a factor 2 of h, and growing at once
            # would only be rejected again.
            q = _auto_ratio(seg, h, span, opts)
            cap = 1.0 if just_rejected else 2.0
            grow = cap if q <= 0 else min(cap, max(1.0, 0.9 * q ** (-1.0 / order)))
            reach = float(seg.radius.max(initial=0.0))
            if reach > 0:
                grow = min(grow, max(1.0, 0.9 * opts.radius_fraction / reach))
            h = min(h * grow, max_step)
            just_rejected = False
    T = np.array(T_list)
    Y = np.array(Y_list).T
    Ev = np.array(E_list).T
    Jv = np.transpose(np.array(J_list), (1, 2, 0))
    Rv = np.array(R_list)
    Dv = np.array(D_list)
    Qv = np.array(Q_list)
    if te is not None:
        wanted = set(te.tolist())
        keep = [i for i, tt in enumerate(T.tolist()) if tt in wanted]
        T, Y, Ev, Jv, Rv, Dv, Qv = (T[keep], Y[:, keep], Ev[:, keep], Jv[:, :, keep], Rv[keep],
                                    Dv[keep], Qv[keep])
    sel = list(outs)
    Y, Ev, Jv = Y[sel], Ev[sel], Jv[sel]
    if not opts.check:
        Ev = np.where(T[None, :] == x0, 0.0, np.nan)
    stats.max_nnz = nnz_max
    if np.any(Dv) or status_override is None:
        status, msg = _status_from(Y, Ev, Dv, opts, T)
    else:
        status, msg = status_override
    res = LEMResult(T, Y, status, msg, Ev, Dv, Rv, Jv, opts.degree, degrees, dim_max,
                    max(0, stats.n_segments - 1), np.array(restart_points), stats, Qv)
    return _finish(res, opts)


# --------------------------------------------------------------------------------------------
# Series: Taylor coefficients in x and in the initial data
# --------------------------------------------------------------------------------------------
def _rows_dict(rows, cols, vals):
    by_row: dict = {}
    for r, c, v in zip(rows.tolist(), cols.tolist(), list(vals)):
        by_row.setdefault(r, []).append((c, v))
    return by_row


def _want_exact(fld, exact, values) -> bool:
    possible = bool(getattr(fld, "exact", False)) and all(_is_exact_number(v) for v in values)
    if exact is None:
        return possible
    if exact and not possible:
        raise ValueError("exact=True needs a PolynomialField with int/Fraction coefficients and "
                         "int/Fraction data")
    return bool(exact)


def taylor_coefficients(fun, y0, order: int, *, x0: float = 0.0, exact=None, outputs=None):
    """Taylor coefficients of the solution in x about x0, generated by the LEM moment system.

    The system is expanded about ``y0`` itself (w(x0) = 0, so V(x0) = e_0) and the coefficients
    are ``c_k = (A**k V(x0))[w_i] / k!``. A truncation degree of ``order`` is always enough: the
    k-th derivative only visits moments of degree < k.

    Parameters
    ----------
    fun : field, list of dicts or callable ``fun(t, y)`` (autonomous or analytic in t)
    y0 : sequence, shape (n,)
        Initial state (int/Fraction entries with a rational polynomial field give exact results).
    order : int
        Highest power of (x - x0).
    exact : bool or None
        Rational arithmetic (default: whenever possible).

    Returns
    -------
    ndarray, shape (n_out, order + 1), of float, or of Fraction (object) when exact.

    Examples
    --------
    >>> from fractions import Fraction
    >>> c = taylor_coefficients(tanh_ode_field(7), [0, Fraction(1)], 7)
    >>> [str(v) for v in c[0]]
    ['0', '1', '0', '1/6', '0', '-1/120', '0', '-1/1008']
    """
    _check_int("order", order, 1)
    vals = list(y0)
    n = len(vals)
    fld = as_field(fun, n)
    ex = _want_exact(fld, exact, vals)
    if not ex:
        vals = list(_finite_vector("y0", [float(v) for v in vals], n))
    outs = _check_outputs(outputs, n)
    N = max(1, order)
    exp = fld.expansion(x0, vals, N)
    if exp.varying:
        raise ValueError("Taylor coefficients need coefficients analytic in t: give fun as an "
                         "AnalyticField rather than a PolynomialField with callable coefficients")
    S = _build_system(exp, N, outs, True, 10**7, exact=ex)
    if ex:
        by_row = _rows_dict(*S.triplets)
        u = {S.constant_index: Fraction(1)} if S.constant_index is not None else {}
        coeffs = np.empty((len(outs), order + 1), dtype=object)
        coeffs[:, 0] = [Fraction(vals[i]) for i in outs]
        for k in range(1, order + 1):
            u = {r: sum((v * u.get(c, 0) for c, v in entries), Fraction(0)) / k
                 for r, entries in by_row.items()}
            coeffs[:, k] = [u.get(int(p), Fraction(0)) for p in S.outputs]
        return coeffs
    u = np.zeros(S.dimension)
    if S.constant_index is not None:
        u[S.constant_index] = 1.0
    coeffs = np.empty((len(outs), order + 1))
    coeffs[:, 0] = [vals[i] for i in outs]
    for k in range(1, order + 1):
        u = (S.A @ u) / k
        coeffs[:, k] = u[S.outputs]
    return coeffs


def initial_data_coefficients(fun, x: float, degree: int, *, centre=None, x0: float = 0.0,
                              outputs=None, n: int | None = None) -> dict:
    r"""Coefficients of y(x) as a polynomial in the initial displacement ``y0 - centre``.

    ``y_i(x) ~ centre_i + sum_gamma C_gamma(x) (y0 - centre)**gamma``, read from the rows of
    ``exp((x - x0) A_N)`` that belong to the degree-1 moments. With ``f(centre) = 0`` these are
    exactly the Taylor coefficients of the flow in the initial data up to degree N.

    Returns
    -------
    dict mapping gamma (tuple) -> ndarray of shape (n_out,)

    Examples
    --------
    For y' = y: y(x) = e**x y0.

    >>> C = initial_data_coefficients([{(1,): 1.0}], 1.0, 3)
    >>> round(float(C[(1,)][0]), 12) == round(float(np.e), 12)
    True
    """
    _check_float("x", x)
    S = moment_system(fun, degree, centre=centre, t=x0, outputs=outputs, n=n)
    if S.varying:
        raise ValueError("initial_data_coefficients needs constant coefficients")
    E = np.zeros((S.dimension, S.outputs.size))
    E[S.outputs, np.arange(S.outputs.size)] = 1.0
    R = expm_multiply(S.A.T.tocsr() * (x - x0), E)
    out = {}
    for i, g in enumerate(S.exponents):
        if np.any(R[i] != 0):
            out[tuple(int(v) for v in g)] = R[i].copy()
    return out


def double_series(fun, order: int, degree: int, *, centre=None, outputs=None, exact=None,
                  n: int | None = None) -> dict:
    r"""Coefficients of ``x**k (y0 - centre)**gamma`` in the degree-N LEM solution.

    These are ``(A_N**k)[w_i, gamma] / k!``. With ``f(centre) = 0`` (the paper's homogeneous form)
    every coefficient with ``|gamma| <= N`` is exact: this is how series such as the paper's
    (3.20) arise, as polynomials in the initial data for each power of x.

    Returns
    -------
    dict mapping (k, gamma) -> ndarray (n_out,) of float, or of Fraction when exact

    Examples
    --------
    The x**5 term of y'' = tanh y, y(0) = 0, y'(0) = z0 is -z0 (2 z0**2 - 1) / 120:

    >>> c = double_series(tanh_ode_field(5), 5, 5)
    >>> [str(c[(5, (0, 1))][0]), str(c[(5, (0, 3))][0])]
    ['1/120', '-1/60']
    """
    _check_int("order", order, 0)
    _check_int("degree", degree, 1)
    fld = as_field(fun, n)
    c = [0] * fld.n if centre is None else list(centre)
    ex = _want_exact(fld, exact, c)
    S = moment_system(fld, degree, centre=c if ex else [float(v) for v in c], outputs=outputs)
    if S.varying:
        raise ValueError("double_series needs constant coefficients")
    out = {}
    if ex:
        by_row = _rows_dict(*S.triplets)
        rows = [{int(p): Fraction(1)} for p in S.outputs]
        for k in range(order + 1):
            for i, r in enumerate(rows):
                for col, v in r.items():
                    if v != 0:
                        g = tuple(int(e) for e in S.exponents[col])
                        arr = out.setdefault((k, g), np.array([Fraction(0)] * len(rows), dtype=object))
                        arr[i] = v
            if k == order:
                break
            new_rows = []
            for r in rows:
                nr: dict = {}
                for row, v in r.items():
                    for col, a in by_row.get(row, ()):
                        nr[col] = nr.get(col, 0) + v * a / (k + 1)
                new_rows.append(nr)
            rows = new_rows
        return out
    Rm = np.zeros((S.outputs.size, S.dimension))
    Rm[np.arange(S.outputs.size), S.outputs] = 1.0
    AT = S.A.T.tocsr()
    for k in range(order + 1):
        for col in np.flatnonzero(np.any(Rm != 0, axis=0)):
            out[(k, tuple(int(e) for e in S.exponents[col]))] = Rm[:, col].copy()
        Rm = (AT @ Rm.T).T / (k + 1)
    return out


# --------------------------------------------------------------------------------------------
# The paper's equations, with the corrected (3.13) and (3.16)
# --------------------------------------------------------------------------------------------
def bernoulli_numbers(m: int) -> list:
    """Bernoulli numbers B_0..B_m (B_1 = -1/2) as Fractions."""
    _check_int("m", m, 0)
    B = [Fraction(0)] * (m + 1)
    B[0] = Fraction(1)
    for k in range(1, m + 1):
        B[k] = -sum(math.comb(k + 1, j) * B[j] for j in range(k)) / Fraction(k + 1)
    return B


def tanh_taylor_coefficients(degree: int, exact: bool = True) -> list:
    """Coefficients of tanh y = sum_k c_k y**k, k = 0..degree, by the corrected (3.13).

    c_(2k-1) = 2**(2k) (2**(2k) - 1) B_(2k) / (2k)!  (1, -1/3, 2/15, -17/315, ...); the paper
    prints D_sigma**k where the power must be 2k - 1 (physics.md §5).
    """
    _check_int("degree", degree, 0)
    B = bernoulli_numbers(degree + 1)
    c = [Fraction(0)] * (degree + 1)
    for k in range(1, (degree + 1) // 2 + 1):
        if 2 * k - 1 <= degree:
            c[2 * k - 1] = Fraction(2 ** (2 * k) * (2 ** (2 * k) - 1)) * B[2 * k] / math.factorial(2 * k)
    return c if exact else [float(v) for v in c]


def tanh_ode_field(degree: int, exact: bool = True) -> PolynomialField:
    """The paper's (3.10) y' = z, z' = tanh y, with tanh replaced by its degree-``degree`` Taylor
    polynomial (corrected (3.13)); its moment system is the corrected (3.16)."""
    c = tanh_taylor_coefficients(degree, exact)
    return PolynomialField([{(0, 1): 1}, {(k, 0): ck for k, ck in enumerate(c) if ck != 0}])


def moment_rhs_3_16(j: int, k: int, degree: int) -> dict:
    """Right side of the corrected (3.16) for v_jk = y**j z**k, truncated at total degree ``degree``.

    v_jk' = j v_(j-1,k+1) + k sum_m c_(2m-1) v_(j+2m-1,k-1), written out independently of the
    engine so that tests can compare the two. Returns {(j', k'): coefficient (Fraction)}.
    """
    c = tanh_taylor_coefficients(degree + 1)
    out: dict = {}
    if j >= 1 and j + k <= degree:
        out[(j - 1, k + 1)] = out.get((j - 1, k + 1), 0) + Fraction(j)
    if k >= 1:
        for m in range(1, degree + 2):
            p = 2 * m - 1
            if j + p + k - 1 > degree:
                break
            out[(j + p, k - 1)] = out.get((j + p, k - 1), 0) + k * c[p]
    return out


def smooth_friction_field(B: float, eps: float) -> AnalyticField:
    """qdd = -B tanh(qd / eps) as (q, v)' = (v, -B tanh(v / eps)): a smooth Coulomb slide.

    As eps -> 0 it tends to the exact slide qdd = -B sign(qd) (physics.md §5 notes that the
    paper's (2.8) uses tanh(B q), of position, with the wrong sign).
    """
    _check_float("B", B)
    _check_float("eps", eps, 0.0, strict=True)
    B, eps = float(B), float(eps)
    return AnalyticField(lambda t, y: [y[1], -B * np.tanh(y[1] / eps)], 2)
