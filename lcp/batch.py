"""Many Jean-Pratt scenes of one structure at once (public face of :mod:`lcp.sweeps.batch`)."""
from lcp.sweeps.batch import *  # noqa: F401,F403
from lcp.sweeps.batch import __all__  # noqa: F401
