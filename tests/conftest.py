"""Shared tolerances and hypothesis profiles (stated once, here)."""
import os

import matplotlib
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
