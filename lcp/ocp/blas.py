"""One BLAS thread for CasADi's OpenBLAS while an optimal control problem is solved.

IPOPT's linear solver (MUMPS, in CasADi's wheels) calls the OpenBLAS that CasADi ships, which
starts one thread per core. The KKT systems of the transcriptions are sparse and banded, their
dense fronts small: the threads wait on each other more than they compute, and where the cores are
shared they spin against the other processes. Measured on nosnoc's seven friction blocks (Radau,
N = 50, 8450 variables; 2 cores, load 3-4): the sigma = 0.1 stage of the homotopy took 68-71 s on
two threads and 20-24 s on one, the whole homotopy 181 s and 65 s; on the motor and the two-block
chain (a few hundred variables) the times and every iterate are the same either way. The thread
count also changes the rounding of the dense kernels, so one thread makes a solve's iterates the
same on every machine, whatever its cores.

:func:`one_blas_thread` sets the count to one on entry and restores it on exit (nested and
concurrent solves: the first entry sets it, the last exit restores it). It leaves the library
alone where the user chose the count (``OPENBLAS_NUM_THREADS`` or ``OMP_NUM_THREADS`` set) or where
CasADi's folder has no OpenBLAS with ``openblas_set_num_threads`` (another build): then nothing
changes. NumPy's own BLAS is another library and is not touched.

Imports CasADi (to find its folder), the standard library and :mod:`lcp.ocp.held`.
"""
from __future__ import annotations

import contextlib
import ctypes
import functools
import glob
import os
import re
from collections.abc import Iterator

from lcp.ocp.held import Held

__all__ = ["casadi_openblas", "one_blas_thread"]


@functools.lru_cache(maxsize=1)
def casadi_openblas():
    """CasADi's OpenBLAS as a ctypes library with ``openblas_get_num_threads`` and
    ``openblas_set_num_threads``, or None (not found, or without those symbols).

    The wheels hold the library under several names, copies rather than links
    (``libcasadi-tp-openblas.so``, ``.so.0``, ``.so.0.3``): the one loaded is the file its soname
    names (``.so.0``), and loading another copy would make a second library whose thread count
    MUMPS never reads. So the file already mapped in this process comes first (Linux), then the
    name with one version number, then the others."""
    try:
        import casadi
    except ImportError:  # pragma: no cover - CasADi is a dependency
        return None
    folder = os.path.dirname(casadi.__file__)
    found = [p for p in glob.glob(os.path.join(folder, "*openblas*"))
             if p.endswith((".so", ".dylib", ".dll")) or re.search(r"\.so(\.\d+)+$", p)]
    try:
        with open("/proc/self/maps") as fh:
            mapped = {line.split()[-1] for line in fh if "openblas" in line}
    except OSError:
        mapped = set()

    def rank(path):
        base = os.path.basename(path)
        return (path not in mapped, not re.search(r"\.so\.\d+$", base), base)

    for path in sorted(found, key=rank):
        try:
            lib = ctypes.CDLL(path)
            lib.openblas_get_num_threads.restype = ctypes.c_int
            lib.openblas_set_num_threads.argtypes = [ctypes.c_int]
        except (OSError, AttributeError):
            continue
        return lib
    return None


def _user_chose() -> bool:
    return any(os.environ.get(v) for v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"))


def _one_thread():
    lib = casadi_openblas()
    saved = int(lib.openblas_get_num_threads())
    if saved != 1:
        lib.openblas_set_num_threads(1)
    return saved


def _restore(saved) -> None:
    if saved != 1:
        casadi_openblas().openblas_set_num_threads(saved)


_HELD = Held(_one_thread, _restore)


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """CasADi's OpenBLAS on one thread inside the block, its count restored after (module docstring)."""
    if _user_chose() or casadi_openblas() is None:
        yield
        return
    with _HELD():
        yield
