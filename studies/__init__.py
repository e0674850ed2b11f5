"""Study scripts: ``python -m studies.NAME [--out DIR] [--quick]``.

Each study module exposes ``run(out=None, quick=False, ...)`` returning the numbers behind its
figures (so tests can check them) and a ``main(argv)`` that writes PNG figures and CSV data.
"""
