"""Compiled Moreau-Jean stepping for constant single-contact systems (the fast exact path).

When the mass matrix, the contact kinematics and the (affine) forces are constant and there is one
planar contact, a whole Moreau-Jean step is a fixed arithmetic expression: the free velocity is
affine in the state, and the contact problem has the closed form :func:`~lcp.contact.problem.planar_enum`.
CasADi builds that step as an SX Function, ``mapaccum`` chains it over a chunk of steps, and the
chunk is compiled to C once per machine (in the compiled-code cache, :mod:`lcp.numerics.cache`, by a
hash of its source), so no Python runs per step.

The step takes the state x = (q, v) and a vector c of per-scene constants (:func:`pack`), so the same
step serves one scene (:func:`simulate_compiled`) and, in its lean form compiled by numba, many
scenes at once (``lcp.sweeps.batch_kernel``).
"""
from __future__ import annotations

from collections.abc import Callable
import functools
import hashlib
import os
from pathlib import Path
import shutil
import subprocess
import sys
import tempfile
from typing import TypeVar

import casadi as ca
import numpy as np

from lcp.contact.problem import CASADI_OPS, MODE_NAMES, planar_enum, planar_refine
from lcp.numerics import cache
from lcp.timestepping.outcome import free_velocity_overflows

__all__ = ["applicable", "pack", "step_function", "chunk_function", "simulate_compiled"]

T = TypeVar("T")

#: steps per compiled chunk: long enough that the per-call overhead (~10 us) vanishes per step
CHUNK = 2000


def applicable(system) -> bool:
    """Whether the compiled path applies: constant system, exactly one planar contact, no control
    schedule (a schedule of one piece makes a constant system whose control the constant compiled
    loop adds per step: :mod:`lcp.timestepping.compiled_loop`)."""
    return bool(system.is_constant and system.n_contacts == 1 and not system.is_spatial
                and getattr(system, "control_schedule", None) is None)


def _layout(n: int, affine: bool):
    """Names and sizes of the packed per-scene constants. Without ``affine`` the free velocity
    does not depend on the state (constant forces), which saves 4 n^2 operations per step."""
    parts = [("a", n)] + ([("Bq", n * n), ("Bv", n * n)] if affine else [])
    return parts + [("SHt", 2 * n), ("W", 4), ("H", 2 * n), ("gap0", 1), ("mu", 1), ("e", 1), ("h", 1),
                    ("theta", 1)]


def n_constants(n: int, affine: bool = True) -> int:
    return sum(k for _, k in _layout(n, affine))


def needs_affine(asm) -> bool:
    """Whether the free velocity depends on the state (springs, dampers, bilateral constraints)."""
    return not (asm.force_constant and asm.T.shape[1] == 0)


def pack(asm, affine: bool = True) -> np.ndarray:
    """Per-scene constants of a constant single-contact system (from a Moreau-Jean assembly).

    The free velocity is dv = a + Bq q + Bv v (exact for affine, time-independent forces with the
    implicit theta linearization and constant bilateral constraints).
    """
    S, T, h, th = asm.S, asm.T, asm.h, asm.theta
    a = S @ (h * asm.F0)
    Bq = h * S @ asm.Kq
    Bv = S @ (h * asm.Cv + h * h * th * asm.Kq)
    if T.shape[1]:
        a = a + T @ (-asm.phi_t)
        Bv = Bv - T @ asm.G
    if not affine and (np.any(Bq) or np.any(Bv)):
        raise ValueError("this system's free velocity depends on its state: pack it with affine=True")
    sys_ = asm.sys
    return np.concatenate([a] + ([Bq.ravel(), Bv.ravel()] if affine else [])
                          + [asm.SHt.ravel(), asm.W.ravel(), asm.H.ravel(),
                             [asm.gap0[0], sys_.mu[0], sys_.e[0], h, th]])


def _unpack(c, n, affine):
    out, i = {}, 0
    for name, k in _layout(n, affine):
        out[name] = c[i:i + k]
        i += k
    # NumPy ravel is row-major, CasADi reshape column-major: hence the transposes
    Bq = ca.reshape(out["Bq"], n, n).T if affine else None
    Bv = ca.reshape(out["Bv"], n, n).T if affine else None
    SHt = ca.reshape(out["SHt"], 2, n).T
    H = ca.reshape(out["H"], n, 2).T
    return (out["a"], Bq, Bv, SHt, out["W"], H, out["gap0"], out["mu"], out["e"], out["h"], out["theta"])


def _kahan_sx(s, inc, comp):
    """s + inc by Kahan's compensated sum on CasADi expressions: (new sum, new compensation).

    Unlike :func:`lcp.timestepping.assembly.kahan_add`, fmax(., -1e308) hides the sum from CasADi's simplifier,
    which would cancel (t - s) - y to 0 (it knows fmax(x, -inf) = x, so the bound must be finite).
    """
    y = inc - comp
    t = ca.fmax(s + y, -1e308)
    return t, (t - s) - y


@functools.lru_cache(maxsize=None)
def step_function(n: int, affine: bool = True, lean: bool = False) -> ca.Function:
    """One Moreau-Jean step x = (q, v, c_q, c_v) -> x+ for a constant single-contact system with n
    coordinates (c_q, c_v: the compensations of the Kahan sums of q and v).

    Full form ``(x, c) -> (x+, info)``, info = (p_N, p_T, mode, residual, n_distinct); mode is -2
    for an inactive contact and -1 where no case of the contact problem is admissible (then p and
    x+ are NaN). Lean form (for batches) ``(z, c) -> z+`` with z = (x, n_slide, max|gap|): only the
    number of sliding steps and the largest gap are kept besides the state.
    """
    nc = n_constants(n, affine)
    c = ca.SX.sym("c", nc)
    if lean:
        z = ca.SX.sym("z", 4 * n + 2)
        x, extra = z[:4 * n], z[4 * n:]
    else:
        x = ca.SX.sym("x", 4 * n)
    q, v, cq, cv = x[:n], x[n:2 * n], x[2 * n:3 * n], x[3 * n:]
    a, Bq, Bv, SHt, W, H, gap0, mu, e, h, th = _unpack(c, n, affine)
    dvf = a + ca.mtimes(Bq, q) + ca.mtimes(Bv, v) if affine else a
    vfree = v + dvf
    uN_minus = ca.dot(H[0, :].T, v)
    uN_free = ca.dot(H[0, :].T, vfree)
    uT_free = ca.dot(H[1, :].T, vfree)
    gap = gap0 + ca.dot(H[0, :].T, q)
    # active when the free motion closes the gap within the step (robust to a +1e-21 rounding gap)
    active = gap + h * ((1 - th) * uN_minus + th * uN_free) <= 0
    # Newton restitution acts only on an approaching contact (a separating one is not bounced back)
    qN = uN_free + e * ca.fmin(uN_minus, 0)
    W00, W01, W10, W11 = W[0], W[1], W[2], W[3]  # row-major packing of the 2 x 2 operator
    pN, pT, mode, n_distinct = planar_enum(W00, W01, W10, W11, qN, uT_free, mu, ops=CASADI_OPS)
    pN = ca.if_else(active, pN, 0)
    pT = ca.if_else(active, pT, 0)
    # one refinement on the branch (as the Python loop): removes cond(W) eps from the velocities
    dv = dvf + ca.mtimes(SHt, ca.vertcat(pN, pT))
    v_try = v + dv
    dpN, dpT = planar_refine(W00, W01, W10, W11, ca.dot(H[0, :].T, v_try) + e * ca.fmin(uN_minus, 0),
                             ca.dot(H[1, :].T, v_try), mu, ca.if_else(active, mode, -2), ops=CASADI_OPS)
    pN, pT = pN + dpN, pT + dpT
    dv = dv + ca.mtimes(SHt, ca.vertcat(dpN, dpT))
    # compensated (Kahan) sums of v and q, as in the Python loop: over 1e6 steps plain sums drift
    v_new, cv_new = _kahan_sx(v, dv, cv)
    q_new, cq_new = _kahan_sx(q, h * ((1 - th) * v + th * v_new), cq)
    x_new = ca.vertcat(q_new, v_new, cq_new, cv_new)
    if lean:
        sliding = active * (mode >= 2)
        extra_new = ca.vertcat(extra[0] + sliding, ca.fmax(extra[1], ca.fabs(gap)))
        return ca.Function(f"mj_step_lean_{n}_{int(affine)}", [z, c], [ca.vertcat(x_new, extra_new)],
                           ["z", "c"], ["z_next"])
    mode = ca.if_else(active, mode, -2)
    # Coulomb residual (natural map, impulse units), as ContactProblem.residual
    uN = W00 * pN + W01 * pT + qN
    uT = W10 * pN + W11 * pT + uT_free
    rN = ca.fmin(pN, uN / W00)
    s_ = mu * ca.fmax(pN, 0)
    rT = pT - ca.fmin(ca.fmax(pT - uT / W11, -s_), s_)
    res = ca.if_else(active, ca.fmax(ca.fabs(rN), ca.fabs(rT)), 0)
    return ca.Function("mj_step", [x, c], [x_new, ca.vertcat(pN, pT, mode, res, ca.if_else(active, n_distinct, 1))],
                       ["x", "c"], ["x_next", "info"])


def c_compiler():
    return shutil.which(os.environ.get("CC", "gcc")) or shutil.which("cc")


def generate_c(fn: ca.Function) -> bytes:
    """C source of a CasADi Function (CasADi's code generator)."""
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / f"{fn.name()}.c"
        cg = ca.CodeGenerator(src.name, {"with_header": False})
        cg.add(fn)
        cg.generate(tmp + os.sep)
        return src.read_bytes()


def build_library(name: str, code: bytes, load: Callable[[str], T] | None = None) -> T | None:
    """Compile C source to a shared library in the compiled-code cache (:mod:`lcp.numerics.cache`)
    and load it: ``load(path)`` (default :class:`ctypes.CDLL`).

    The entry is named by a hash of source, flags and versions; it is built under an inter-process
    lock into a temporary file beside it and moved into place, and an entry whose content differs
    from the digest recorded at its build (truncated, overwritten) is rebuilt, not loaded. None when
    no working compiler is found.
    """
    cc = c_compiler()
    if cc is None:
        return None
    if load is None:
        import ctypes

        load = ctypes.CDLL
    flags = ["-O3", "-fPIC", "-shared"]
    key = hashlib.sha256(code + " ".join(flags).encode() + sys.version.encode()
                         + ca.__version__.encode()).hexdigest()[:16]
    lib = cache.cache_dir() / f"{name}_{key}.so"

    def build(part: Path) -> None:
        fd, src = tempfile.mkstemp(dir=lib.parent, prefix=f".{name}.", suffix=".c")
        try:
            with os.fdopen(fd, "wb") as fh:
                fh.write(code)
            subprocess.run([cc, *flags, src, "-o", str(part), "-lm"], check=True, capture_output=True, timeout=300)
        finally:
            os.unlink(src)

    try:
        return cache.cached_entry(lib, build, lambda path: load(str(path)))
    except (subprocess.SubprocessError, OSError):  # no working compiler after all
        return None


def _compile(fn: ca.Function) -> ca.Function:
    """Compile a CasADi Function once per machine; the CasADi VM (slower, same results) without a compiler."""
    ext = build_library(fn.name(), generate_c(fn), load=lambda path: ca.external(fn.name(), path))
    return ext if ext is not None else fn


@functools.lru_cache(maxsize=None)
def chunk_function(n: int, affine: bool = True, steps: int = CHUNK, compiled: bool = True) -> ca.Function:
    """``steps`` chained Moreau-Jean steps (mapaccum), compiled: x0, c -> (X (4n x steps), info (5 x steps))."""
    x0, c = ca.MX.sym("x0", 4 * n), ca.MX.sym("c", n_constants(n, affine))
    X, info = step_function(n, affine).mapaccum(steps)(x0, ca.repmat(c, 1, steps))
    fn = ca.Function(f"mj_chunk_{n}_{int(affine)}_{steps}", [x0, c], [X, info], ["x0", "c"], ["X", "info"])
    return _compile(fn) if compiled else fn


def _bound_chunk(n: int, c: np.ndarray, affine: bool, compiled: bool = True):
    """A compiled chunk bound to NumPy buffers: calling it runs CHUNK steps from ``x`` in place of
    any CasADi DM conversion (which would cost more than the steps themselves)."""
    fn = chunk_function(n, affine, CHUNK, compiled)
    buf, run = fn.buffer()
    x = np.zeros(4 * n)
    c = np.ascontiguousarray(c, dtype=float)
    X = np.zeros((CHUNK, 4 * n))  # C-order (CHUNK, 4n) is CasADi's column-major (4n, CHUNK)
    info = np.zeros((CHUNK, 5))
    buf.set_arg(0, memoryview(x))
    buf.set_arg(1, memoryview(c))
    buf.set_res(0, memoryview(X))
    buf.set_res(1, memoryview(info))
    # keep the buffer object alive with the closure; c must outlive it too
    return (lambda: (run(), buf, c)), x, X, info


_RUN_DRIVER = """
CASADI_SYMBOL_EXPORT long {name}(const casadi_real* x0, const casadi_real* c, long steps, casadi_real* X,
                                 casadi_real* info) {{
  const casadi_real* arg[{sz_arg}];
  casadi_real* res[{sz_res}];
  casadi_int iw[{sz_iw}];
  casadi_real w[{sz_w}];
  long k;
  for (k = 0; k < steps; ++k) {{
    arg[0] = k ? X + (k - 1) * {nx} : x0;
    arg[1] = c;
    res[0] = X + k * {nx};
    res[1] = info + k * 5;
    if ({step}(arg, res, iw, w, 0)) return k;
  }}
  return steps;
}}
"""


@functools.lru_cache(maxsize=None)
def run_library(n: int, affine: bool = True):
    """Any number of steps of :func:`step_function` in one C call: CasADi's C code of the step,
    driven by a loop, compiled once per machine.

    Unlike a chunk (a ``mapaccum`` over a fixed number of steps) it runs exactly the steps asked
    for; the step's arithmetic is the same generated C, so the results are the same bits. Returns a
    ctypes function ``(x0, c, steps, X, info) -> steps run`` (X: (steps, 4n), info: (steps, 5), C
    order), or None without a working compiler.
    """
    import ctypes

    step = step_function(n, affine)
    name = f"lcp_mj_run_{n}_{int(affine)}"
    driver = _RUN_DRIVER.format(name=name, step=step.name(), nx=4 * n, sz_arg=max(1, step.sz_arg()),
                                sz_res=max(1, step.sz_res()), sz_iw=max(1, step.sz_iw()), sz_w=max(1, step.sz_w()))
    lib = build_library(name, generate_c(step) + driver.encode())
    if lib is None:
        return None
    fn = getattr(lib, name)
    dp = ctypes.POINTER(ctypes.c_double)
    fn.argtypes = [dp, dp, ctypes.c_long, dp, dp]
    fn.restype = ctypes.c_long
    return fn


def _chunk_runner(n: int, c: np.ndarray, affine: bool, compiled: bool, n_steps: int):
    """``run(take)``: ``take`` (<= CHUNK) steps from the state ``x`` into the first rows of ``X``
    (4n per step) and ``info`` (5 per step); returns (run, x, X, info). The compiled driver
    (:func:`run_library`) where a C compiler is found, a CasADi chunk otherwise (which always runs
    CHUNK steps; the caller keeps the first ``take``)."""
    rows = min(CHUNK, max(n_steps, 1))
    lib = run_library(n, affine) if compiled else None
    if lib is None:
        run_chunk, x, X, info = _bound_chunk(n, c, affine, compiled)
        return (lambda take: run_chunk()), x, X, info
    import ctypes

    x = np.zeros(4 * n)
    c = np.ascontiguousarray(c, dtype=float)
    X = np.zeros((rows, 4 * n))
    info = np.zeros((rows, 5))
    dp = ctypes.POINTER(ctypes.c_double)
    args = [a.ctypes.data_as(dp) for a in (x, c, X, info)]

    def run(take):
        lib(args[0], args[1], take, args[2], args[3])
        return c  # c must outlive the pointers

    return run, x, X, info


def simulate_compiled(asm, q0, v0, n_steps: int, save_every: int = 1, compiled: bool = True):
    """Run n_steps compiled steps; returns arrays (Q, V, PN, PT, modes, residuals, n_distinct).

    Saved rows: every ``save_every``-th state (and the impulses of the step that led to it), so that
    long runs keep only what is asked for. The arrays stop at the first failed step, whose index is
    returned last but one (None if every step succeeded); last, whether that step failed by
    overflow (its free velocity or its end state not finite: the Python loop's status -2) rather
    than by a contact problem without an admissible case.
    """
    n = asm.n
    affine = needs_affine(asm)
    c = pack(asm, affine)
    run_chunk, x, Xbuf, Ibuf = _chunk_runner(n, c, affine, compiled, n_steps)
    n_saved = n_steps // save_every
    Q = np.empty((n_saved + 1, n))
    V = np.empty((n_saved + 1, n))
    info_saved = np.empty((n_saved, 5))
    x[:n], x[n:2 * n], x[2 * n:] = q0, v0, 0.0
    Q[0], V[0] = q0, v0
    modes_count = np.zeros(5, dtype=np.int64)  # inactive, open, stick, slide+, slide-
    max_res, n_amb = 0.0, 0
    done = 0
    fail, overflow = None, False
    while done < n_steps:
        take = min(CHUNK, n_steps - done)
        run_chunk(take)
        X, info = Xbuf[:take], Ibuf[:take]  # (take, 4n) and (take, 5): one row per step
        if not (np.isfinite(X).all() and (info[:, 2] != -1).all()):
            take = int(np.flatnonzero((info[:, 2] == -1) | ~np.all(np.isfinite(X), axis=1))[0])
            start = X[take - 1] if take else x  # the state the failed step started from
            fv = start[n:2 * n] + asm.at((done + take) * asm.h, start[:n], start[n:2 * n])[0]
            overflow = info[take, 2] != -1 or free_velocity_overflows(fv)
            X, info = X[:take], info[:take]
            fail = done + take
        # steps done + 1 .. done + take; keep those whose index is a multiple of save_every
        if save_every == 1:
            Q[done + 1:done + take + 1] = X[:, :n]
            V[done + 1:done + take + 1] = X[:, n:2 * n]
            info_saved[done:done + take] = info
        else:
            idx = np.arange(done + 1, done + take + 1)
            keep = idx % save_every == 0
            rows = idx[keep] // save_every
            Q[rows] = X[keep, :n]
            V[rows] = X[keep, n:2 * n]
            info_saved[rows - 1] = info[keep]
        m = info[:, 2].astype(np.int64)
        modes_count += np.bincount(m + 2, minlength=6)[[0, 2, 3, 4, 5]]
        if take:
            max_res = max(max_res, float(np.max(info[:, 3])))
            n_amb += int(np.count_nonzero(info[:, 4] > 1))
            x[:] = X[take - 1]
        done += take
        if fail is not None:
            break
    last = done // save_every
    counts = {"inactive": int(modes_count[0])}
    counts.update({MODE_NAMES[k]: int(modes_count[k + 1]) for k in range(4)})
    return (Q[:last + 1], V[:last + 1], info_saved[:last, 0], info_saved[:last, 1],
            info_saved[:last, 2].astype(np.int8), counts, max_res, n_amb, done, fail, bool(overflow))
