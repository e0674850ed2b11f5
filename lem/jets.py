"""Jets: truncated multivariate power series, for exact Taylor coefficients of analytic fields.

The LEM engine needs the Taylor polynomial of ``f`` at each expansion centre up to the truncation
degree. :class:`Jet` carries it through NumPy arithmetic and ufuncs; :class:`MonomialSpace` is the
packed index of the monomials a jet (or a moment system) lives on. Jets also record the distance
to every singularity of ``f`` they pass through (:data:`RADIUS_TRUST`).

Examples
--------
>>> import numpy as np
>>> from lem.jets import Jet, monomial_space
>>> space = monomial_space(1, 5)
>>> x = Jet.variable(space, 0, 0.0)
>>> [round(float(v), 6) for v in np.tanh(x).c]
[0.0, 1.0, 0.0, -0.333333, 0.0, 0.133333]
"""
from __future__ import annotations

import functools
import math
import numbers

import numpy as np

__all__ = ["RADIUS_TRUST", "Jet", "MonomialSpace", "index_powers", "monomial_space"]

#: A state whose singular arguments (tanh(v/eps), 1/u, log u, ...) move this fraction of the way to
#: the nearest singularity of f is outside what f's Taylor series can be trusted to represent.
RADIUS_TRUST = 0.9


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


def index_powers(n: int, D: int) -> np.ndarray:
    base = D + 1
    if n * math.log2(base) > 62:
        raise ValueError(f"degree {D} in {n} variables is too large to index (base**n > 2**62)")
    return base ** np.arange(n, dtype=np.int64)


class MonomialSpace:
    """Packed index of all monomials of n variables up to total degree D, sorted by code."""

    def __init__(self, n: int, D: int):
        exps = _multi_indices(n, D)
        self.n, self.D = n, D
        self.pw = index_powers(n, D)
        codes = exps @ self.pw
        order = np.argsort(codes)
        self.codes = codes[order]
        self.exps = exps[order]
        self.deg = self.exps.sum(axis=1)
        self.size = self.codes.size


@functools.lru_cache(maxsize=16)
def monomial_space(n: int, D: int) -> MonomialSpace:
    return MonomialSpace(n, D)


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


def _merge(a: Jet, b: Jet) -> tuple:
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

    __slots__ = ("c", "sing", "space")
    __array_priority__ = 1000

    def __init__(self, space: MonomialSpace, coeffs: np.ndarray, sing: tuple = ()):
        self.space = space
        self.c = coeffs
        # singularities met on the way: (|coefficients of the argument's displacement|, R), the
        # argument's distance R to the nearest singularity of the function applied to it
        self.sing = sing

    # construction ------------------------------------------------------------------------------
    @classmethod
    def constant(cls, space: MonomialSpace, value: float) -> Jet:
        c = np.zeros(space.size)
        c[0] = value
        return cls(space, c)

    @classmethod
    def variable(cls, space: MonomialSpace, i: int, value: float) -> Jet:
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

    def _mulc(self, other: Jet) -> np.ndarray:
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

    def _compose(self, name: str, p: float = 0.0) -> Jet:
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
