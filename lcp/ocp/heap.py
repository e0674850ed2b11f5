"""The C heap kept across IPOPT's factorizations while an optimal control problem is solved.

IPOPT's linear solver (MUMPS, in CasADi's wheels) allocates its workspace afresh for every
factorization of the KKT matrix and frees it after. IPOPT asks MUMPS for 1000 % more workspace
than MUMPS estimates (``mumps_mem_percent``), so on the larger transcriptions the block is tens of
megabytes: on nosnoc's seven friction blocks (Radau, N = 50, 8450 variables) 56 MB, allocated
twice per IPOPT iteration. glibc's allocator serves blocks above its mmap threshold (at most 32 MB)
with a fresh ``mmap`` and returns them with ``munmap``, so every factorization faults in the pages
of a new zeroed block: in the first homotopy stage of the seven blocks (128 iterations) 1.0 s of
the 4.9 s were spent in the kernel (strace: 269 ``munmap`` of 56426496 bytes). Served from the heap
and kept there, the same block is reused: the same stage took 3.6 s, with the same iterates (the
allocator does not change any arithmetic).

:func:`kept_heap` does that inside its block: glibc's ``mallopt`` with ``M_MMAP_MAX`` = 0 (no block
from ``mmap``) and a trim threshold of 2 GB (free memory at the heap's top is kept); on exit the
defaults are set again (65536 mapped blocks, a trim threshold of 128 kB) and ``malloc_trim`` gives
the kept memory back. Nested and concurrent solves: the first entry sets, the last exit restores.
After the first use glibc no longer adapts its mmap threshold to the sizes it sees (any
``mallopt`` call turns that off); it stays where it was.

Nothing changes where the C library is not glibc, or where the user tuned the allocator
(``MALLOC_MMAP_MAX_``, ``MALLOC_MMAP_THRESHOLD_``, ``MALLOC_TRIM_THRESHOLD_``, ``MALLOC_TOP_PAD_``,
or ``glibc.malloc`` tunables in ``GLIBC_TUNABLES``).

Imports the standard library and :mod:`lcp.ocp.held`.
"""
from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import functools
import os
import sys
from collections.abc import Iterator

from lcp.ocp.held import Held

__all__ = ["glibc", "kept_heap"]

# glibc's mallopt parameters (malloc.h)
M_TRIM_THRESHOLD, M_MMAP_MAX = -1, -4
#: glibc's defaults, set again on exit
DEFAULT_TRIM_THRESHOLD, DEFAULT_MMAP_MAX = 128 * 1024, 65536
#: the trim threshold inside the block (mallopt takes an int)
KEPT_TRIM_THRESHOLD = 2**31 - 1

_USER_VARS = ("MALLOC_MMAP_MAX_", "MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_TOP_PAD_")


@functools.lru_cache(maxsize=1)
def glibc():
    """The process's C library as a ctypes library with ``mallopt`` and ``malloc_trim``, where it
    is glibc (it has ``gnu_get_libc_version``); else None."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        lib = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        lib.gnu_get_libc_version.restype = ctypes.c_char_p
        lib.mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
        lib.mallopt.restype = ctypes.c_int
        lib.malloc_trim.argtypes = [ctypes.c_size_t]
        lib.malloc_trim.restype = ctypes.c_int
    except (OSError, AttributeError):
        return None
    return lib


def _user_chose() -> bool:
    return any(os.environ.get(v) for v in _USER_VARS) or "glibc.malloc" in os.environ.get("GLIBC_TUNABLES", "")


def _keep() -> None:
    lib = glibc()
    lib.mallopt(M_MMAP_MAX, 0)
    lib.mallopt(M_TRIM_THRESHOLD, KEPT_TRIM_THRESHOLD)


def _give_back(_) -> None:
    lib = glibc()
    lib.mallopt(M_MMAP_MAX, DEFAULT_MMAP_MAX)
    lib.mallopt(M_TRIM_THRESHOLD, DEFAULT_TRIM_THRESHOLD)
    lib.malloc_trim(0)


_HELD = Held(_keep, _give_back)


@contextlib.contextmanager
def kept_heap() -> Iterator[None]:
    """Large blocks from the heap, and the heap's free top kept, inside the block (module
    docstring); the allocator's defaults set again after, and the kept memory given back."""
    if _user_chose() or glibc() is None:
        yield
        return
    with _HELD():
        yield
