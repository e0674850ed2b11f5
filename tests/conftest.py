"""Shared tolerances and hypothesis profiles (stated once, here)."""
import os
import platform


def _pin_openblas_kernels() -> None:
    """Fix OpenBLAS's kernels to its AVX2 ("Haswell") ones on x86-64 CPUs that have AVX2 and FMA.

    OpenBLAS chooses its kernels by CPU when it loads. On an AVX-512 machine (measured on an AMD
    EPYC: "SkylakeX") the small matrix products of NumPy's and SciPy's OpenBLAS round differently
    from the numba kernels: the compiled loops then agree with the Python loops to rounding
    (5.6e-17 in q on the tipping rod) instead of bit for bit, and IPOPT's paths through the
    non-convex optimal-control problems change (44 tests failed there; all pass with the pin). The
    pin makes a checkout pass or fail the same way on every such machine. It must be set before
    NumPy is imported; a value the user sets is kept."""
    if "OPENBLAS_CORETYPE" in os.environ or platform.machine().lower() not in ("x86_64", "amd64"):
        return
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as f:
            flags = next((line.split(":", 1)[1].split() for line in f if line.startswith("flags")), [])
    except OSError:
        return
    if {"avx2", "fma"} <= set(flags):
        os.environ["OPENBLAS_CORETYPE"] = "Haswell"


_pin_openblas_kernels()

import matplotlib  # noqa: E402  (after the pin: it imports NumPy)
import pytest
from hypothesis import HealthCheck, settings

matplotlib.use("Agg")

#: |x - exact| may exceed the scheme's own bound B h^2 / 8 by rounding only
X_ROUNDING = 1e-12
#: no lift-off, no sinking in the Jean-Pratt scene
Y_TOL = 1e-12
#: relative accuracy of mean normal forces p_N / h against the exact mean force
N_RTOL = 1e-6
#: Coulomb (complementarity) residual per step, impulse units
RESIDUAL_TOL = 1e-9

# "default" keeps CI fast and reproducible: the same examples on every run (derandomized), so a
# clean checkout passes or fails the same way; "thorough" (HYPOTHESIS_PROFILE=thorough, with -m slow)
# draws >= 1000 fresh random examples, the search for new counterexamples, whose finds become explicit
# @example cases
settings.register_profile("default", max_examples=25, deadline=None, derandomize=True,
                          suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("thorough", max_examples=1000, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))

# the tests of the compiled general loop run it, whether or not its numba kernel was compiled on this
# machine before (a short run would take the Python loop while it is not: lcp.timestepping.first_compile,
# tested in test_first_compile.py with the policy set there)
os.environ.setdefault("LCP_COMPILE", "always")


@pytest.fixture
def tol():
    return dict(x=X_ROUNDING, y=Y_TOL, N=N_RTOL, residual=RESIDUAL_TOL)
