"""Compiled Moreau-Jean stepping for constant single-contact systems (the fast exact path).

When the mass matrix, the contact kinematics and the (affine) forces are constant and there is one
planar contact, a whole Moreau-Jean step is a fixed arithmetic expression: the free velocity is
affine in the state, and the contact problem has the closed form :func:`~lcp.contact_problem.planar_enum`.
CasADi builds that step as an SX Function, ``mapaccum`` chains it over a chunk of steps, and the
chunk is compiled to C once per machine (cached by a hash of its source), so no Python runs per step.

The step takes the state x = (q, v) and a vector c of per-scene constants (:func:`pack`), so the same
compiled code serves one scene (:func:`simulate_compiled`) and many scenes at once (``lcp.batch``).
"""
from __future__ import annotations

import functools
import hashlib
import os
from pathlib import Path
import shutil
import subprocess
import sys
import tempfile

import casadi as ca
import numpy as np

from .contact_problem import CASADI_OPS, MODE_NAMES, planar_enum

__all__ = ["applicable", "pack", "step_function", "chunk_function", "simulate_compiled", "cache_dir"]

#: steps per compiled chunk: long enough that the per-call overhead (~10 us) vanishes per step
CHUNK = 2000


def applicable(system) -> bool:
    """Whether the compiled path applies: constant system, exactly one contact."""
    return bool(system.is_constant and system.n_contacts == 1)


def n_constants(n: int) -> int:
    return n + 2 * n * n + 2 * n + 4 + 2 * n + 5


def pack(asm) -> np.ndarray:
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
    sys_ = asm.sys
    return np.concatenate([a, Bq.ravel(), Bv.ravel(), asm.SHt.ravel(), asm.W.ravel(), asm.H.ravel(),
                           [asm.gap0[0], sys_.mu[0], sys_.e[0], h, th]])


def _unpack(c, n):
    i = 0

    def take(k):
        nonlocal i
        out = c[i:i + k]
        i += k
        return out

    a = take(n)
    Bq = ca.reshape(take(n * n), n, n).T  # NumPy ravel is row-major, CasADi reshape column-major
    Bv = ca.reshape(take(n * n), n, n).T
    SHt = ca.reshape(take(2 * n), 2, n).T
    W = take(4)
    H = ca.reshape(take(2 * n), n, 2).T
    gap0, mu, e, h, th = (take(1) for _ in range(5))
    return a, Bq, Bv, SHt, W, H, gap0, mu, e, h, th


def _kahan(s, inc, comp):
    """s + inc by Kahan's compensated sum: (new sum, new compensation).

    fmax(., -1e308) hides the sum from CasADi's simplifier, which would cancel (t - s) - y to 0
    (it knows fmax(x, -inf) = x, so the bound must be finite).
    """
    y = inc - comp
    t = ca.fmax(s + y, -1e308)
    return t, (t - s) - y


@functools.lru_cache(maxsize=None)
def step_function(n: int) -> ca.Function:
    """One Moreau-Jean step x = (q, v, c_q, c_v) -> x+ for a constant single-contact system with n coordinates
    (c_q, c_v: the compensations of the Kahan sums of q and v).

    Outputs: x+ (2n) and (p_N, p_T, mode, residual, n_distinct); mode is -2 for an inactive contact
    and -1 where no case of the contact problem is admissible (then p is NaN and x+ too).
    """
    x = ca.SX.sym("x", 4 * n)
    c = ca.SX.sym("c", n_constants(n))
    q, v, cq, cv = x[:n], x[n:2 * n], x[2 * n:3 * n], x[3 * n:]
    a, Bq, Bv, SHt, W, H, gap0, mu, e, h, th = _unpack(c, n)
    dvf = a + ca.mtimes(Bq, q) + ca.mtimes(Bv, v)
    vfree = v + dvf
    uN_minus = ca.dot(H[0, :].T, v)
    uN_free = ca.dot(H[0, :].T, vfree)
    uT_free = ca.dot(H[1, :].T, vfree)
    # active when the free motion closes the gap within the step (robust to a +1e-21 rounding gap)
    gap_pred = gap0 + ca.dot(H[0, :].T, q) + h * ((1 - th) * uN_minus + th * uN_free)
    active = gap_pred <= 0
    qN = uN_free + e * uN_minus
    W00, W01, W10, W11 = W[0], W[2], W[1], W[3]  # row-major packing of the 2 x 2 operator
    pN, pT, mode, n_distinct = planar_enum(W00, W01, W10, W11, qN, uT_free, mu, ops=CASADI_OPS)
    pN = ca.if_else(active, pN, 0)
    pT = ca.if_else(active, pT, 0)
    mode = ca.if_else(active, mode, -2)
    # Coulomb residual (natural map, impulse units), as ContactProblem.residual
    uN = W00 * pN + W01 * pT + qN
    uT = W10 * pN + W11 * pT + uT_free
    rN = ca.fmin(pN, uN / W00)
    s = mu * ca.fmax(pN, 0)
    rT = pT - ca.fmin(ca.fmax(pT - uT / W11, -s), s)
    res = ca.if_else(active, ca.fmax(ca.fabs(rN), ca.fabs(rT)), 0)
    # compensated (Kahan) sums of v and q, as in the Python loop (_kahan): over 1e6 steps plain
    # sums would drift by rounding
    v_new, cv_new = _kahan(v, dvf + ca.mtimes(SHt, ca.vertcat(pN, pT)), cv)
    q_new, cq_new = _kahan(q, h * ((1 - th) * v + th * v_new), cq)
    return ca.Function("mj_step", [x, c], [ca.vertcat(q_new, v_new, cq_new, cv_new),
                                           ca.vertcat(pN, pT, mode, res, ca.if_else(active, n_distinct, 1))],
                       ["x", "c"], ["x_next", "info"])


def cache_dir() -> Path:
    """Where compiled chunks are kept (``$LCP_LEM_CACHE``, else the user cache folder)."""
    base = os.environ.get("LCP_LEM_CACHE")
    if base:
        return Path(base)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "lcp-lem"


def _compile(fn: ca.Function) -> ca.Function:
    """Compile a CasADi Function to a shared library once per machine; the CasADi VM if no compiler."""
    cc = shutil.which(os.environ.get("CC", "gcc")) or shutil.which("cc")
    if cc is None:
        return fn
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / f"{fn.name()}.c"
        cg = ca.CodeGenerator(src.name, {"with_header": False})
        cg.add(fn)
        cg.generate(tmp + os.sep)
        code = src.read_bytes()
    key = hashlib.sha256(code + sys.version.encode() + ca.__version__.encode()).hexdigest()[:16]
    lib = cache_dir() / f"{fn.name()}_{key}.so"
    if not lib.exists():
        lib.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory() as tmp:
            src = Path(tmp) / "chunk.c"
            src.write_bytes(code)
            part = Path(tmp) / lib.name
            try:
                subprocess.run([cc, "-O3", "-fPIC", "-shared", str(src), "-o", str(part), "-lm"],
                               check=True, capture_output=True, timeout=300)
            except (subprocess.SubprocessError, OSError):
                return fn  # no working compiler: the CasADi VM is slower but exact
            shutil.move(str(part), lib)  # atomic within a file system: safe for parallel workers
    return ca.external(fn.name(), str(lib))


@functools.lru_cache(maxsize=None)
def chunk_function(n: int, steps: int = CHUNK, compiled: bool = True) -> ca.Function:
    """``steps`` chained Moreau-Jean steps (mapaccum), compiled: x0, c -> (X (4n x steps), info (5 x steps))."""
    x0, c = ca.MX.sym("x0", 4 * n), ca.MX.sym("c", n_constants(n))
    X, info = step_function(n).mapaccum(steps)(x0, ca.repmat(c, 1, steps))
    fn = ca.Function(f"mj_chunk_{n}_{steps}", [x0, c], [X, info], ["x0", "c"], ["X", "info"])
    return _compile(fn) if compiled else fn


def _bound_chunk(n: int, c: np.ndarray, compiled: bool = True):
    """A compiled chunk bound to NumPy buffers: calling it runs CHUNK steps from ``x`` in place of
    any CasADi DM conversion (which would cost more than the steps themselves)."""
    fn = chunk_function(n, CHUNK, compiled)
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


def simulate_compiled(asm, q0, v0, n_steps: int, save_every: int = 1, compiled: bool = True):
    """Run n_steps compiled steps; returns arrays (Q, V, PN, PT, modes, residuals, n_distinct).

    Saved rows: every ``save_every``-th state (and the impulses of the step that led to it), so that
    long runs keep only what is asked for. The arrays stop at the first failed step, whose index is
    returned last (None if every step succeeded).
    """
    n = asm.n
    c = pack(asm)
    run_chunk, x, Xbuf, Ibuf = _bound_chunk(n, c, compiled)
    n_saved = n_steps // save_every
    Q = np.empty((n_saved + 1, n))
    V = np.empty((n_saved + 1, n))
    info_saved = np.empty((n_saved, 5))
    x[:n], x[n:2 * n], x[2 * n:] = q0, v0, 0.0
    Q[0], V[0] = q0, v0
    modes_count = np.zeros(5, dtype=np.int64)  # inactive, open, stick, slide+, slide-
    max_res, n_amb = 0.0, 0
    done = 0
    fail = None
    while done < n_steps:
        run_chunk()
        X, info = Xbuf.T, Ibuf.T  # (4n, CHUNK) and (5, CHUNK) views
        take = min(CHUNK, n_steps - done)
        X, info = X[:, :take], info[:, :take]
        bad = np.flatnonzero((info[2] == -1) | ~np.all(np.isfinite(X), axis=0))
        if bad.size:
            take = int(bad[0])
            X, info = X[:, :take], info[:, :take]
            fail = done + take
        # steps done + 1 .. done + take; keep those whose index is a multiple of save_every
        idx = np.arange(done + 1, done + take + 1)
        keep = idx % save_every == 0
        rows = idx[keep] // save_every
        Q[rows] = X[:n, keep].T
        V[rows] = X[n:2 * n, keep].T
        info_saved[rows - 1] = info[:, keep].T
        m = info[2].astype(np.int64)
        modes_count += np.bincount(m + 2, minlength=6)[[0, 2, 3, 4, 5]]
        if take:
            max_res = max(max_res, float(np.max(info[3])))
            n_amb += int(np.sum(info[4] > 1))
            x[:] = X[:, take - 1]
        done += take
        if fail is not None:
            break
    last = done // save_every
    counts = {"inactive": int(modes_count[0])}
    counts.update({MODE_NAMES[k]: int(modes_count[k + 1]) for k in range(4)})
    return (Q[:last + 1], V[:last + 1], info_saved[:last, 0], info_saved[:last, 1],
            info_saved[:last, 2].astype(np.int8), counts, max_res, n_amb, done, fail)
