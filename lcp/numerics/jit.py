"""numba's ``njit`` where numba is installed, and a plain-Python stand-in where it is not.

Every compiled kernel of the package is decorated with :func:`njit` from here, so that one flag,
:data:`HAVE_NUMBA`, says whether the kernels run compiled. Without numba the decorated functions
run as plain Python (correct but slow) and keep ``py_func`` as numba's do, so tests can call the
Python reference of a kernel either way. numba is a dependency; the stand-in serves where it
cannot be imported (and the reference is tested through ``py_func`` and ``compiled=False``).

numba is first imported by the package here, so numba's cache folder is set here first
(:func:`lcp.numerics.cache.configure_numba`: ``<LCP_CACHE_DIR>/numba/<digest of the kernel sources>`` unless ``NUMBA_CACHE_DIR``
is set). Imports :mod:`lcp.numerics.cache` only.
"""
from __future__ import annotations

__all__ = ["HAVE_NUMBA", "njit"]

from lcp.numerics.cache import configure_numba

configure_numba()

try:
    from numba import njit

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - exercised by the fallback tests through py_func
    HAVE_NUMBA = False

    def njit(*args, **kwargs):
        def wrap(f):
            f.py_func = f
            return f
        return wrap(args[0]) if args and callable(args[0]) else wrap
