"""Numerical utilities below every physics concept: deferred imports, numba's ``njit`` (or its
stand-in), and the block-diagonal structure of sparse matrices with its compiled products.

Modules: :mod:`~lcp.numerics.lazy` (deferred SciPy), :mod:`~lcp.numerics.jit` (``njit``,
``HAVE_NUMBA``), :mod:`~lcp.numerics.block_diagonal` (blocks of a sparse symmetric matrix, their
check and inverse), :mod:`~lcp.numerics.block_products` (S H', H S H', S x on compressed arrays).
Imports nothing else of ``lcp``.
"""
