"""Many single-contact scenes stepped together (parameter sweeps), by Moreau-Jean with exact Coulomb friction.

The step is the closed-form one of :mod:`lcp.timestepping.compiled_step` in its lean form, compiled by
numba over structure-of-arrays blocks of scenes (:mod:`lcp.sweeps.batch_kernel`: SIMD lanes across
the scenes of a block; threads, the GIL released, across contiguous ranges of blocks, one call per
thread), compiled once per machine. A NumPy path (the same closed form,
:func:`~lcp.contact.problem.planar_enum` on arrays) serves as a cross-check and as the fallback
where numba cannot be imported.

Only what a sweep needs is kept per scene: the final state, the number of sliding steps (so the
stop time of a slide-then-stick motion), and the largest |gap| seen (lift-off or sinking).
"""
from __future__ import annotations

from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
import math
import os
import time
import warnings

import numpy as np

from lem.jean_pratt import check_parameters, tan_alpha

from lcp.sweeps.batch_kernel import BLOCK, batch_kernel
from lcp.timestepping import compiled_step as compiled
from lcp.contact.problem import NUMPY_OPS, planar_enum, planar_refine
from lcp.model.start import consistent_start
from lcp.scenes.scene import Scene
from lcp.model.kinematics import refuse_kinematics
from lcp.timestepping.assembly import StepAssembly, kahan_add
from lcp.timestepping.moreau_jean import MoreauJeanOptions

__all__ = ["BatchResult", "jean_pratt_constants", "simulate_batch"]


@dataclass
class BatchResult:
    """Final states of a batch of scenes.

    Attributes
    ----------
    q, v : ndarray, shape (n_scenes, n)
        Final coordinates and velocities (after ``steps`` steps, at t = steps h).
    slide_steps : ndarray of int, shape (n_scenes,)
        Steps in which the contact slid; ``slide_steps * h`` bounds the stop time of a
        slide-then-stick motion from above by less than h.
    max_abs_gap : ndarray, shape (n_scenes,)
        Largest |gap| seen at the start of a step (lift-off or sinking; 0 for the Jean-Pratt scene).
    success : ndarray of bool, shape (n_scenes,)
        False where a step had no admissible case or the state became non-finite.
    steps : int
    h, theta : float
    path : str
        The path that ran: ``"compiled"`` or ``"numpy"``.
    stats : dict
        ``n_scenes``, the number of threads that ran (``threads``) and, when ``path="auto"`` fell
        back to NumPy, why (``fallback``; a :class:`RuntimeWarning` says so too).
    run_time, compile_time : float
        Seconds spent stepping, and generating/compiling or loading the compiled kernel (small when
        it was cached).
    """

    q: np.ndarray
    v: np.ndarray
    slide_steps: np.ndarray
    max_abs_gap: np.ndarray
    success: np.ndarray
    steps: int
    h: float
    theta: float
    path: str
    run_time: float = 0.0
    compile_time: float = 0.0
    stats: dict = field(default_factory=dict)

    @property
    def scene_steps_per_second(self) -> float:
        return self.q.shape[0] * self.steps / self.run_time if self.run_time > 0 else math.inf


def jean_pratt_constants(m, M, alpha, R, v0=1.0, g=9.81, phi=0.0, *, h: float, theta: float = 0.5):
    """Packed per-scene constants and initial states of many Jean-Pratt scenes (vectorized).

    The reduced model q = (x, y): mass [[m + M t^2, -M t], [-M t, m + M]], force (phi, -(m+M) g),
    gap y, tangent x. Returns (c, x0): shapes (n_constants, N) and (8, N).
    """
    arrs = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (m, M, alpha, R, v0, g, phi)))
    m, M, alpha, R, v0, g, phi = (a.ravel() for a in arrs)
    check_parameters(m, M, alpha, R, g)
    for name, a in (("v0", v0), ("phi", phi)):
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{name} must be finite")
    MoreauJeanOptions(h=h, theta=theta)  # validates h and theta
    t = tan_alpha(alpha)
    A00, A01, A11 = m + M * t * t, -M * t, m + M
    det = A00 * A11 - A01 * A01
    S00, S01, S11 = A11 / det, -A01 / det, A00 / det
    F0, F1 = phi, -(m + M) * g
    N = m.size
    one, zero = np.ones(N), np.zeros(N)
    # H = [[0, 1], [1, 0]]: normal y, tangent x; SHt = S H'; W = H S H'
    c = np.stack([h * (S00 * F0 + S01 * F1), h * (S01 * F0 + S11 * F1),   # a = h S F
                  S01, S00, S11, S01,                                       # SHt, row-major
                  S11, S01, S01, S00,                                       # W, row-major
                  zero, one, one, zero,                                     # H, row-major
                  zero, R, zero, np.full(N, h), np.full(N, theta)])
    x0 = np.zeros((8, N))
    x0[2] = v0
    return c, x0


def _numpy_step(Z, c, n):
    """The lean step of lcp.timestepping.compiled_step on arrays of scenes (columns): the same closed form."""
    q, v, cq, cv = Z[:n], Z[n:2 * n], Z[2 * n:3 * n], Z[3 * n:4 * n]
    a, SHt, W, H = c[:n], c[n:3 * n], c[3 * n:3 * n + 4], c[3 * n + 4:5 * n + 4]
    gap0, mu, e, h, th = c[5 * n + 4:]
    SHt = SHt.reshape(n, 2, -1)
    H = H.reshape(2, n, -1)
    vfree = v + a
    uN_minus = np.einsum("ij,ij->j", H[0], v)
    uN_free = np.einsum("ij,ij->j", H[0], vfree)
    uT_free = np.einsum("ij,ij->j", H[1], vfree)
    gap = gap0 + np.einsum("ij,ij->j", H[0], q)
    active = gap + h * ((1 - th) * uN_minus + th * uN_free) <= 0
    restitution = e * np.minimum(uN_minus, 0.0)  # approaching contacts only
    with np.errstate(divide="ignore", invalid="ignore"):
        pN, pT, mode, _ = planar_enum(W[0], W[1], W[2], W[3], uN_free + restitution, uT_free, mu, ops=NUMPY_OPS)
    pN = np.where(active, pN, 0.0)
    pT = np.where(active, pT, 0.0)
    inc = a + SHt[:, 0] * pN + SHt[:, 1] * pT
    v_try = v + inc
    with np.errstate(divide="ignore", invalid="ignore"):
        dpN, dpT = planar_refine(W[0], W[1], W[2], W[3],
                                 np.einsum("ij,ij->j", H[0], v_try) + restitution,
                                 np.einsum("ij,ij->j", H[1], v_try), mu, np.where(active, mode, -2), ops=NUMPY_OPS)
    inc = inc + SHt[:, 0] * dpN + SHt[:, 1] * dpT
    v_new, cv = kahan_add(v, inc, cv)
    q_new, cq = kahan_add(q, h * ((1 - th) * v + th * v_new), cq)
    Z[:n], Z[n:2 * n], Z[2 * n:3 * n], Z[3 * n:4 * n] = q_new, v_new, cq, cv
    Z[4 * n] += active * (mode >= 2)
    Z[4 * n + 1] = np.maximum(Z[4 * n + 1], np.abs(gap))


def simulate_batch(scenes: Sequence[Scene] | tuple[dict, np.ndarray], t_end: float, h: float, theta: float = 0.5,
                   path: str = "auto", threads: int | None = None) -> BatchResult:
    """Step many single-contact scenes together with Moreau-Jean (exact Coulomb per step).

    Parameters
    ----------
    scenes : sequence of Scene, or tuple (c, x0) from :func:`jean_pratt_constants`
        Constant single-contact scenes with state-independent forces (the Jean-Pratt family, a
        block on a line, ...). For large Jean-Pratt sweeps build the constants directly with
        :func:`jean_pratt_constants` (no CasADi model per scene).
    t_end : float
        Horizon; every scene takes ceil(t_end / h) steps.
    h, theta : float
        Step size and theta (the same for all scenes).
    path : {"auto", "compiled", "numpy"}
        ``"auto"`` is the compiled path (numba, vector lanes and threads, compiled once per machine
        into the compiled-code cache), NumPy where numba cannot be imported (with a
        :class:`RuntimeWarning`; the result's ``path`` names the path that ran).
    threads : int, optional
        Threads of the compiled path (default: the cores this process may run on).

    Returns
    -------
    BatchResult

    Examples
    --------
    >>> import numpy as np
    >>> from lcp.sweeps.batch import jean_pratt_constants, simulate_batch
    >>> R = np.linspace(0.1, 0.9, 5)
    >>> res = simulate_batch(jean_pratt_constants(1.0, 1.0, np.pi / 4, R, h=1e-3), 0.5, h=1e-3)
    >>> bool(res.success.all()), res.q.shape
    (True, (5, 2))
    """
    if path not in ("auto", "compiled", "numpy"):
        raise ValueError(f"path must be 'auto', 'compiled' or 'numpy', got {path!r}")
    MoreauJeanOptions(h=h, theta=theta)
    if not (isinstance(t_end, (int, float, np.floating)) and np.isfinite(t_end) and t_end > 0):
        raise ValueError(f"t_end must be finite and > 0, got {t_end!r}")
    if isinstance(scenes, tuple) and len(scenes) == 2 and isinstance(scenes[0], np.ndarray):
        c, x0 = scenes
        n = x0.shape[0] // 4
    else:
        c, x0, n = _pack_scenes(list(scenes), h, theta)
    n_scenes = c.shape[1]
    if c.shape[0] != compiled.n_constants(n, False) or x0.shape != (4 * n, n_scenes):
        raise ValueError("scene constants have the wrong shape")
    if np.any(c[-2] != h) or np.any(c[-1] != theta):
        raise ValueError("the scene constants were packed for another h or theta")
    if threads is None:
        threads = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    elif isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1:
        raise ValueError(f"threads must be a positive integer, got {threads!r}")
    steps = int(np.ceil(t_end / h * (1 - 1e-12)))
    t0 = time.perf_counter()
    fallback = None
    try:
        run = batch_kernel(n) if path in ("auto", "compiled") else None
        if run is None and path != "numpy":
            fallback = "numba cannot be imported"
    except NotImplementedError as exc:  # an SX operation the transcription does not know: NumPy instead
        run, fallback = None, f"the compiled kernel does not know an operation of the step ({exc})"
    t_compile = time.perf_counter() - t0
    if run is None and path == "compiled":
        raise RuntimeError(f"the compiled batch path cannot run: {fallback}")
    if fallback is not None:
        # the NumPy path gives the same numbers to rounding but runs far slower: a sweep should know
        warnings.warn(f"simulate_batch: compiled path unavailable ({fallback}); running the NumPy path",
                      RuntimeWarning, stacklevel=2)
    Z = np.vstack([x0, np.zeros((2, n_scenes))])
    t0 = time.perf_counter()
    if run is not None:
        Z, threads = _run_compiled(run, Z, c, steps, threads)
        used = "compiled"
    else:
        for _ in range(steps):
            _numpy_step(Z, c, n)
        used, threads = "numpy", 1
    run_time = time.perf_counter() - t0
    q, v = Z[:n].T.copy(), Z[n:2 * n].T.copy()
    ok = np.all(np.isfinite(Z[:4 * n]), axis=0)
    return BatchResult(q=q, v=v, slide_steps=Z[4 * n].astype(np.int64), max_abs_gap=Z[4 * n + 1].copy(),
                       success=ok, steps=steps, h=float(h), theta=float(theta), path=used, run_time=run_time,
                       compile_time=t_compile,
                       stats=dict(n_scenes=n_scenes, threads=threads,
                                  **({"fallback": fallback} if fallback is not None else {})))


def _run_compiled(run, Z, c, steps, threads):
    """Z advanced by the compiled kernel; returns (Z, threads used).

    The scenes are padded to whole blocks (copies of the first scene, dropped afterwards), and the
    blocks cut into one contiguous range per thread: one kernel call per thread, without the GIL.
    """
    n_scenes = Z.shape[1]
    nb = -(-n_scenes // BLOCK)
    width = nb * BLOCK
    Zp = np.empty((Z.shape[0], width))
    Cp = np.empty((c.shape[0], width))
    Zp[:, :n_scenes], Zp[:, n_scenes:] = Z, Z[:, :1]
    Cp[:, :n_scenes], Cp[:, n_scenes:] = c, c[:, :1]
    threads = int(min(threads, nb))
    cuts = [nb * i // threads for i in range(threads + 1)]
    if threads == 1:
        run(Zp, Cp, steps, 0, nb)
    else:
        with ThreadPoolExecutor(threads) as pool:
            list(pool.map(lambda i: run(Zp, Cp, steps, cuts[i], cuts[i + 1]), range(threads)))
    return Zp[:, :n_scenes], threads


def _pack_scenes(scenes, h, theta):
    cols, xs, n = [], [], None
    for sc in scenes:
        if not isinstance(sc, Scene):
            raise ValueError(f"scenes must be Scene objects, got {type(sc).__name__}")
        s = sc.system
        refuse_kinematics(s, f"lcp.batch (scene '{sc.name}')")
        if not compiled.applicable(s):
            raise ValueError(f"scene '{sc.name}' is not a constant single-contact system")
        asm = StepAssembly(s, h, theta)
        if compiled.needs_affine(asm):
            raise ValueError(f"scene '{sc.name}' has state-dependent forces: the batch path needs constant ones")
        if n is None:
            n = s.n
        elif s.n != n:
            raise ValueError("all scenes of a batch must have the same number of coordinates")
        q0, v0 = s.check_state(sc.q0, sc.v0)
        # the common start check (lcp.model.start): beyond rounding, the batch refuses rather than
        # projects, since it has no per-scene message to say so
        _, _, note = consistent_start(s, q0, v0)
        if note is not None:
            raise ValueError(f"scene '{sc.name}': its start is not consistent with its contact ({note}); the "
                             "batch path does not project starts: fix q0 or run lcp.simulate, which does")
        cols.append(compiled.pack(asm, affine=False))
        xs.append(np.concatenate([q0, v0, np.zeros(2 * n)]))
    if not cols:
        raise ValueError("scenes is empty")
    return np.array(cols).T, np.array(xs).T, n

