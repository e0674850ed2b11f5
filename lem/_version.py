"""The version of the lcp-lem distribution (both packages, lcp and lem): the one place it is written.

pyproject.toml reads it; it lives in lem, the lowest layer, so that lcp and lem can both import it.
"""

__version__ = "0.1.0"
