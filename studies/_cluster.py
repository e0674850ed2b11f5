"""Where a study's independent pieces of work run: in this process, or on a Dask cluster.

The studies that sweep (``stability``, ``shock_limit``, ``work_precision``, ``lem_convergence``)
accept ``--workers N`` (a new LocalCluster of N worker processes) and ``--scheduler ADDRESS`` (a
running cluster; its workers must be able to import this project). Each piece of work is a
module-level function of the study applied to plain arguments (an index, a few numbers), so it
pickles; it rebuilds what it needs from them and returns numbers that do not depend on where it
ran. Only wall times differ (and pieces running side by side share the machine's cores).

Example
-------
>>> from studies._cluster import pieces
>>> pieces(abs, [-1, 2, -3], None)
[1, 2, 3]
"""
from __future__ import annotations

import functools
import importlib
import sys
import time

from lcp.sweeps.parameter_sweep import cluster, map_sets

__all__ = ["add_options", "cluster", "pieces"]


def add_options(parser):
    """Add ``--workers N`` and ``--scheduler ADDRESS`` to a study's argument parser."""
    g = parser.add_argument_group("where the study's pieces run (default: this process)")
    g.add_argument("--workers", type=int, default=None, metavar="N",
                   help="run the pieces on a new local Dask cluster of N worker processes")
    g.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run the pieces on a running Dask cluster (e.g. tcp://host:8786)")
    return parser


def _importable(fn):
    """``fn`` as the worker processes can import it: a study run as ``python -m studies.x`` defines
    its functions in ``__main__``, which a worker's ``__main__`` is not."""
    if isinstance(fn, functools.partial):
        return functools.partial(_importable(fn.func), *fn.args, **fn.keywords)
    if getattr(fn, "__module__", None) == "__main__":
        spec = getattr(sys.modules["__main__"], "__spec__", None)
        if spec is not None and spec.name:
            return getattr(importlib.import_module(spec.name), fn.__qualname__)
    return fn


#: a serial sweep whose first piece says it will take longer than this (seconds) prints its estimate
ESTIMATE_FROM = 10.0


def pieces(fn, items, client, desc: str = "pieces") -> list:
    """``[fn(x) for x in items]`` in this process (``client`` None) or on ``client``'s cluster,
    one item per task (a study's pieces are few and unequal), with a progress bar.

    In this process, a long sweep first prints an estimate of its duration (on standard error):
    the first piece's time multiplied by the number of pieces. Pieces differ in cost, so it is an
    order of magnitude, which the progress bar then refines."""
    items = list(items)
    if client is not None:
        return map_sets(_importable(fn), items, progress=True, desc=desc, client=client, chunk_size=1)[0]
    if not items:
        return []
    t0 = time.perf_counter()
    first = fn(items[0])
    seconds = (time.perf_counter() - t0) * len(items)
    if seconds >= ESTIMATE_FROM:
        print(f"{desc}: {len(items)} pieces, about {_duration(seconds)} in all (from the first piece's "
              f"time; pieces differ in cost)", file=sys.stderr, flush=True)
    return [first, *(map_sets(fn, items[1:], progress=True, desc=desc)[0] if len(items) > 1 else [])]


def _duration(seconds: float) -> str:
    """A duration in the unit a reader expects: seconds, minutes or hours."""
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"
