"""Problem files (public face of :mod:`lcp.io.fclib`): FCLib HDF5 and Siconos ``.dat`` files."""
from lcp.io.fclib import *  # noqa: F401,F403
from lcp.io.fclib import __all__  # noqa: F401
