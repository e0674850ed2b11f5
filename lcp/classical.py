"""Classical systems with their references (public face of :mod:`lcp.scenes.classical`)."""
from lcp.scenes.classical import *  # noqa: F401,F403
from lcp.scenes.classical import __all__  # noqa: F401
