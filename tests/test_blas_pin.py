"""The suite's OpenBLAS kernel pin (conftest._pin_openblas_kernels) reaches the loaded libraries."""
import ctypes
import os

import numpy as np
import pytest
import scipy.linalg  # noqa: F401  (loads SciPy's OpenBLAS, the one the numba kernels call)


def _openblas_cores() -> dict:
    """The core name each of NumPy's and SciPy's OpenBLAS libraries reports (Linux: the libraries
    mapped into this process). CasADi's own OpenBLAS is left out: it is built for one core (CORE2),
    whatever the variable says."""
    try:
        with open("/proc/self/maps", encoding="ascii", errors="replace") as f:
            paths = sorted({line.split()[-1] for line in f if "scipy_openblas" in line and "/" in line})
    except OSError:
        return {}
    cores = {}
    for path in paths:
        lib = ctypes.CDLL(path)
        for sym in ("openblas_get_corename", "openblas_get_corename64_", "scipy_openblas_get_corename",
                    "scipy_openblas_get_corename64_"):
            fn = getattr(lib, sym, None)
            if fn is not None:
                fn.restype = ctypes.c_char_p
                cores[os.path.basename(path)] = fn().decode()
    return cores


@pytest.mark.skipif(os.environ.get("OPENBLAS_CORETYPE") != "Haswell", reason="no kernel pin on this machine")
def test_the_pinned_kernels_are_the_loaded_ones():
    np.ones((3, 3)) @ np.ones(3)  # (the library is loaded with NumPy; a product makes sure)
    cores = _openblas_cores()
    if not cores:
        pytest.skip("no OpenBLAS library found in this process's maps")
    assert set(cores.values()) == {"Haswell"}, cores
