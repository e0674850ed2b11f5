"""The first compilation of the general loop's numba kernel: whether a run waits for it.

numba compiles the compiled general loop's kernel (:func:`lcp.timestepping.general_kernels.run_general`)
once per machine and keeps the machine code in its cache (``<LCP_CACHE_DIR>/numba``); that first
compilation takes half a minute to a minute and more on a loaded machine, while a short run of a
non-constant system takes a fraction of a second in the Python loop. So a run whose kernel is
neither loaded in this process nor found in numba's cache, and which has fewer than
:data:`COLD_MAX_STEPS` steps, takes the Python loop (the same results: the two loops agree bit for
bit on the tested scenes), and the kernel is compiled in a background process for the later runs.
Loading the kernel from numba's cache costs about a second as well (a fresh interpreter's first
compiled run of 300 steps: 0.9-1.2 s, the Python loop 0.2 s), so while it is cached but not loaded
the short runs of a process take the Python loop too, up to :data:`CACHED_MAX_STEPS` steps in all
(a process that goes on making short runs then loads it). The result's message says so. Only systems on which the two loops give the same bits are
served so (at most one contact: the kernel solves several contacts' steps by NSGS, to the solver's
tolerance); the others always wait for the compiled loop. The environment variable ``LCP_COMPILE`` chooses:

- ``background`` (the default): as above;
- ``always``: the compiled loop, paying the first compilation now;
- ``off``: as ``background`` but nothing is compiled in the background (the first run of at least
  :data:`COLD_MAX_STEPS` steps compiles the kernel).

Whether the machine code is in numba's cache is numba's own test: its cache index for the kernel
holds an entry of this machine (the code generator's magic tuple) and of this kernel's bytecode,
with the source stamp of its file. A signature the index does not hold (a new argument type) is
compiled as before. Holds :func:`deferred`, :func:`kernel_state`, :func:`compile_in_background`.
Imports :mod:`lcp.numerics` and the general kernel; never the loops, the path choice or anything
above :mod:`lcp.timestepping`.
"""
from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

from lcp.numerics import cache

__all__ = ["CACHED_MAX_STEPS", "COLD_MAX_STEPS", "ENV_VAR", "POLICIES", "compile_in_background", "deferred", "kernel_state", "policy"]

#: environment variable choosing whether a run waits for the first compilation (module docstring)
ENV_VAR = "LCP_COMPILE"
POLICIES = ("background", "always", "off")
#: runs with fewer steps take the Python loop while the kernel is not compiled: at 100-300 us per
#: Python step, 50,000 steps take 5-15 s, less than the compilation (30-80 s measured)
COLD_MAX_STEPS = 50_000
#: Python-loop steps a process runs in all while the kernel is cached but not loaded: about a second
#: of Python steps (0.2-0.3 ms each), the time loading the kernel takes
CACHED_MAX_STEPS = 3_000
#: a background compilation older than this is taken for dead (its marker is ignored)
STALE_SECONDS = 900.0
#: the marker of a background compilation under way, in the compiled-code cache
MARKER = "numba_general_kernel.compiling"

#: the background process: a two-step run of a small non-constant system (a point on a curved floor)
#: through the compiled general loop compiles the kernel into numba's cache; the marker (argv[1]) is
#: removed at the end, whatever happens
_WARM_UP = """
import os, sys
try:
    import casadi as ca
    import lcp
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    system = lcp.System(q, v, ca.SX.eye(2), ca.vertcat(0.0, -9.81),
                        contacts=[lcp.Contact(gap=q[1] - 0.1 * q[0] ** 2, tangent=q[0], mu=0.3)])
    lcp.simulate(system, 2e-3, h=1e-3, q0=[0.0, 0.0], v0=[1.0, 0.0], projection=False)
finally:
    try:
        os.unlink(sys.argv[1])
    except OSError:
        pass
"""

_LOCK = threading.Lock()
_STARTED: list = []  # the background process of this process, once
_SPENT = [0]  # Python-loop steps this process ran while the kernel was cached but not loaded


def policy() -> str:
    """The value of ``LCP_COMPILE`` (``background`` when unset; ValueError naming it otherwise)."""
    value = os.environ.get(ENV_VAR, "").strip().lower() or "background"
    if value not in POLICIES:
        raise ValueError(f"{ENV_VAR}={os.environ.get(ENV_VAR)!r} is not one of {list(POLICIES)}")
    return value


def _kernel():
    from lcp.timestepping.general_kernels import run_general

    return run_general


def kernel_state(kernel=None) -> str:
    """``"loaded"`` (compiled or loaded in this process), ``"cached"`` (numba's cache holds machine
    code of this kernel's bytecode for this machine) or ``"cold"`` (neither, or the cache cannot be
    read: numba would compile on the first call)."""
    kernel = _kernel() if kernel is None else kernel
    if getattr(kernel, "signatures", None):
        return "loaded"
    try:  # numba's own test (numba.core.caching.Cache._index_key), without a signature
        fc = kernel._cache
        index = fc._cache_file._load_index()
        if not index:
            return "cold"
        codegen = kernel.targetctx.codegen()
        mine = fc._index_key(None, codegen)[1:]  # (magic tuple, bytecode hashes)
        return "cached" if any(tuple(key[1:]) == mine for key in index) else "cold"
    except Exception:  # noqa: BLE001 - a cache numba cannot read is a cold one
        return "cold"


def deferred(n_steps: int, exact: bool = True) -> str | None:
    """None where the compiled general loop runs now; else the note for the message of a run that
    takes the Python loop because the kernel is cold and the run short (starting the background
    compilation unless ``LCP_COMPILE=off``), or cached but not loaded and this process's short runs
    few (module docstring). ``exact``: whether the two loops give the same bits on this system;
    where they may not (the kernel's NSGS on several contacts agrees with the Python loop to the
    solver's tolerance only), the compiled loop always runs, so that a result never depends on
    the state of a cache."""
    how = policy()
    if how == "always" or not exact:
        return None
    state = kernel_state()
    if state == "cached":
        with _LOCK:
            if _SPENT[0] + n_steps >= CACHED_MAX_STEPS:
                return None
            _SPENT[0] += n_steps
        return (" (Python loop: the compiled general loop's kernel is compiled on this machine but not loaded in "
                f"this process; loading it takes about a second, more than this run of {n_steps} steps takes in "
                f"Python; {ENV_VAR}=always runs the compiled loop now)")
    if state != "cold" or n_steps >= COLD_MAX_STEPS:
        return None
    if how == "off":
        later = f"a run of at least {COLD_MAX_STEPS} steps compiles it"
    else:
        later = {"started": "it is being compiled in a background process for the next runs",
                 "elsewhere": "another process is compiling it",
                 "failed": f"no background process could be started: a run of at least {COLD_MAX_STEPS} "
                           "steps compiles it"}[compile_in_background()]
    return (" (Python loop: the compiled general loop's kernel is not compiled on this machine yet, a one-time "
            f"cost of a minute or so, more than this run of {n_steps} steps takes in Python; {later}; "
            f"{ENV_VAR}=always runs the compiled loop now)")


def _marker():
    """The marker of a background compilation: beside numba's cache (where the code will be)."""
    folder = os.environ.get("NUMBA_CACHE_DIR")
    return (Path(folder) if folder else cache.cache_dir()) / MARKER


def compile_in_background() -> str:
    """Start, once per process and machine-wide once at a time, a process that compiles the kernel
    into numba's cache (:data:`_WARM_UP`): ``"started"`` (now, or by this process before),
    ``"elsewhere"`` (another process's compilation is under way) or ``"failed"``."""
    with _LOCK:
        if _STARTED:
            return "started"
        try:
            marker = _marker()
            marker.parent.mkdir(parents=True, exist_ok=True)
            try:
                fd = os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            except FileExistsError:
                if time.time() - marker.stat().st_mtime < STALE_SECONDS:
                    return "elsewhere"
                marker.unlink(missing_ok=True)
                fd = os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            os.close(fd)
            # this package's folder first on the path: the process imports the lcp that runs here
            root = str(Path(__file__).resolve().parents[2])
            path = os.pathsep.join([root] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p])
            env = dict(os.environ, **{ENV_VAR: "always", "PYTHONPATH": path})
            proc = subprocess.Popen([sys.executable, "-c", _WARM_UP, str(marker)], env=env, stdin=subprocess.DEVNULL,
                                    stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        except (OSError, ValueError):  # no cache folder or no process: compiled at the first long run
            return "failed"
        _STARTED.append(proc)
        return "started"
