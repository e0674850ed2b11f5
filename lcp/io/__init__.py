"""Problem files: FCLib's HDF5 files and Siconos's ``.dat`` files (the public face is :mod:`lcp.fclib`).

Imports :mod:`lcp.contact` only.
"""
