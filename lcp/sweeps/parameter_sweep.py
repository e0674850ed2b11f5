"""Parameter sweeps: one scene per parameter set, simulated by any method, serially or on Dask.

:func:`sweep` calls ``build(**p)`` for every parameter set p, simulates the scene with
:func:`lcp.simulate`, and collects one table row per set. It runs in this process by default, on a
``dask.distributed`` LocalCluster of worker processes with ``workers=N``, or on an existing cluster
given a ``Client`` or a scheduler address.

Why the results do not depend on where they ran: every row is computed from its parameters alone,
by the same deterministic code (no shared state between rows: each scene is a new System, and the
per-process caches only hold compiled code keyed by structure), so a row computed on a worker is
the row the serial loop computes, bit for bit. The parameter sets travel to the workers by pickle,
which preserves every float exactly.

Why chunks: a Dask task costs about a millisecond of scheduling, more than an event-driven run of
the Jean-Pratt scene; the sets are therefore sent in chunks (a few per worker, ``chunk_size`` to
override), so that this overhead stays small. A chunk takes every k-th set (strided), so that the
expensive corner of a grid is shared among the workers rather than left to one. A worker keeps its
imports and its compiled kernels (cached per process) from one chunk to the next: they are built
once per worker, not per task.

Failures are rows too: a parameter set whose build or run raises, or whose simulation fails,
appears with ``success`` False, its ``status`` and its ``message``; the sweep goes on. A worker
lost mid-sweep costs nothing: Dask runs its chunks again elsewhere.
"""
from __future__ import annotations

import contextlib
import functools
import itertools
import math
import numbers
import os
import sys
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # optional dependencies (the parallel extra), for annotations only
    import pandas as pd
    from dask.distributed import Client

__all__ = ["BUILD_FAILED", "cluster", "default_summary", "map_sets", "parameter_sets", "sweep"]

#: ``status`` of a row whose build or simulate call raised (its message names the exception)
BUILD_FAILED = -10
#: a sweep with at least this many parameter sets shows a progress bar unless told otherwise
PROGRESS_MIN_SETS = 2000
#: seconds allowed to reach a scheduler given by address before the sweep gives up
CONNECT_TIMEOUT = 5.0

_SWEEP_OPTIONS = ("summary", "workers", "client", "chunk_size", "progress")


def parameter_sets(params) -> list[dict]:
    """The list of parameter dicts a sweep runs.

    Parameters
    ----------
    params : list of dict, or dict of sequences
        A list of parameter dicts is taken as it is. A dict of sequences is the full grid: every
        combination, the last key varying fastest (``itertools.product`` order); a scalar value is
        held fixed.

    Examples
    --------
    >>> from lcp.sweeps.parameter_sweep import parameter_sets
    >>> for p in parameter_sets({"R": [0.3, 0.5], "v0": [1.0, -1.0], "M": 2.0}):
    ...     print(p)
    {'R': 0.3, 'v0': 1.0, 'M': 2.0}
    {'R': 0.3, 'v0': -1.0, 'M': 2.0}
    {'R': 0.5, 'v0': 1.0, 'M': 2.0}
    {'R': 0.5, 'v0': -1.0, 'M': 2.0}
    """
    if isinstance(params, Mapping):
        keys = list(params)
        axes = []
        for k in keys:
            if not isinstance(k, str):
                raise ValueError(f"params keys must be parameter names (str), got {k!r}")
            val = params[k]
            if isinstance(val, (str, bytes)) or np.ndim(val) == 0:
                axes.append([_plain(val)])
            else:
                axis = [_plain(x) for x in np.asarray(val, dtype=object).ravel()]
                if not axis:
                    raise ValueError(f"params[{k!r}] is empty: the grid would have no point")
                axes.append(axis)
        return [dict(zip(keys, combo)) for combo in itertools.product(*axes)]
    if isinstance(params, (str, bytes)) or not isinstance(params, Sequence):
        raise ValueError("params must be a list of dicts or a dict of sequences (a grid), "
                         f"got {type(params).__name__}")
    out = []
    for i, p in enumerate(params):
        if not isinstance(p, Mapping):
            raise ValueError(f"params[{i}] must be a dict of parameters, got {type(p).__name__}")
        out.append({str(k): _plain(v) for k, v in p.items()})
    return out


def _plain(x):
    """NumPy scalars as Python numbers (the table's columns and the builders' checks like them)."""
    if isinstance(x, np.generic):
        return x.item()
    return x


def default_summary(result) -> dict:
    """The final state: ``q_<name>`` and ``v_<name>`` for each coordinate of the system."""
    names = getattr(result, "names", None)
    q, v = np.asarray(result.q), np.asarray(result.v)
    n = q.shape[1] if q.ndim == 2 else 0
    if not names or len(names) != n:
        names = [str(i) for i in range(n)]
    row = {}
    for i, name in enumerate(names):
        row[f"q_{name}"] = float(q[-1, i]) if q.shape[0] else math.nan
    for i, name in enumerate(names):
        row[f"v_{name}"] = float(v[-1, i]) if v.shape[0] else math.nan
    return row


def _run_one(build, p, summary, options) -> dict:
    """One row: build, simulate, summarise; an exception becomes a failed row with its message."""
    from lcp.simulation import simulate

    row = dict(p)
    try:
        scene = build(**p)
        result = simulate(scene, **options)
        if getattr(result, "names", None) is None:
            # the coordinate names, from the scene's numbers when it has them (its System may not
            # have been built, and building it just for names would cost more than the run)
            model = getattr(scene, "model", None)
            source = model if model is not None else getattr(scene, "system", scene)
            try:
                result.names = list(source.names)
            except AttributeError:  # a result class without the attribute: columns by index
                pass
        row.update(success=bool(result.success), status=int(result.status), message=str(result.message))
        extra = (summary or default_summary)(result)
        if not isinstance(extra, Mapping):
            raise ValueError(f"summary must return a dict of columns, got {type(extra).__name__}")
        clash = set(extra) & (set(p) | {"success", "status", "message"})
        if clash:
            raise ValueError(f"summary columns {sorted(clash)} clash with the parameter or status columns")
        row.update(extra)
    except Exception as exc:  # noqa: BLE001 - a failed set is a row, whatever the cause
        row.update(success=False, status=BUILD_FAILED, message=f"{type(exc).__name__}: {exc}")
    return row


def _run_chunk(fn, chunk) -> list:
    return [fn(p) for p in chunk]


#: the thread-count variables of the BLAS libraries, which Dask's workers would otherwise set to 1
_BLAS_THREADS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


def _connect(client, workers):
    """(client, cluster to close or None, client to close or None)."""
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError as exc:
        raise ImportError("a sweep on Dask needs dask.distributed: pip install 'lcp-lem[parallel]'") from exc
    if client is not None:
        if isinstance(client, Client):
            return client, None, None
        if not isinstance(client, str):
            raise ValueError(f"client must be a dask.distributed.Client or a scheduler address (str), "
                             f"got {type(client).__name__}")
        try:
            c = Client(client, timeout=CONNECT_TIMEOUT)
        except (OSError, TimeoutError) as exc:
            raise ConnectionError(f"cannot reach the Dask scheduler at {client!r} within "
                                  f"{CONNECT_TIMEOUT:g} s: {exc}") from None
        return c, None, c
    import dask

    # processes, one thread each: the runs hold the GIL, so threads would not run them in
    # parallel; and no statistical profiler, whose sampling thread takes the GIL from these
    # pure-Python runs every few milliseconds (about 10% of a worker's time, measured). The workers
    # keep this process's BLAS thread settings: Dask sets them to 1 by default, and OpenBLAS's
    # results depend on its thread count in the last digit (a Radau solve of a 2 x 2 system: 15th
    # digit), which would break the serial loop's bit-for-bit rows
    environ = {k: v for k, v in dask.config.get("distributed.nanny.pre-spawn-environ", {}).items()
               if k not in _BLAS_THREADS}
    environ.update({k: os.environ[k] for k in _BLAS_THREADS if k in os.environ})
    with dask.config.set({"distributed.worker.profile.enabled": False,
                          "distributed.nanny.pre-spawn-environ": environ}):
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None)
    c = Client(cluster)
    return c, cluster, c


@contextlib.contextmanager
def cluster(workers: int | None = None, client=None):
    """Where several :func:`map_sets` calls run: None (this process), or one Dask client for all.

    A study with several sweeps opens its cluster once (a LocalCluster takes seconds to start)
    and passes the client to each call; the cluster it started is closed on leaving.

    Parameters
    ----------
    workers : int, optional
        Start a LocalCluster of this many worker processes.
    client : dask.distributed.Client or str, optional
        An existing cluster, or its scheduler's address (``ConnectionError`` if unreachable).

    Examples
    --------
    >>> from lcp.sweeps.parameter_sweep import cluster, map_sets
    >>> with cluster() as c:  # neither workers nor client: this process
    ...     map_sets(abs, [-1, 2], client=c)[0]
    [1, 2]
    """
    _check_where(workers, client)
    if workers is None and client is None:
        yield None
        return
    c, started, own = _connect(client, workers)
    try:
        yield c
    finally:
        if own is not None:
            own.close()
        if started is not None:
            started.close()


def _check_where(workers, client):
    if workers is not None and (not isinstance(workers, numbers.Integral) or isinstance(workers, bool)
                                or workers < 1):
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    if workers is not None and client is not None:
        raise ValueError("give workers (a new LocalCluster) or client (an existing cluster), not both")


def _progress_bar(total, enabled, desc="sweep"):
    if not enabled:
        return None
    try:
        from tqdm.auto import tqdm
    except ImportError:  # a dependency of the package: say that the promised bar is missing, once
        warnings.warn("tqdm is not installed, so no progress bar is shown (pip install tqdm)", RuntimeWarning,
                      stacklevel=3)
        return None
    return tqdm(total=total, unit="set", desc=desc, file=sys.stderr)


def map_sets(fn: Callable, sets: Sequence, *, workers: int | None = None, client=None,
             chunk_size: int | None = None, progress: bool | None = None,
             desc: str = "sweep") -> tuple[list, dict]:
    """``[fn(p) for p in sets]``, in this process or on Dask, in chunks; the engine of :func:`sweep`.

    Studies whose unit of work is not a ``simulate`` call (a LEM solve, a work-precision point) use
    it directly. ``fn`` must not raise for a set that should become a row (catch inside it), and on
    a cluster it must be picklable (a module-level function, or ``functools.partial`` of one).
    ``workers``, ``client``, ``chunk_size`` and ``progress`` are those of :func:`sweep`; ``desc``
    labels the serial progress bar. Several calls can share one cluster (:func:`cluster`).

    Returns
    -------
    results : list
        ``fn(p)`` for each p, in order.
    info : dict
        ``workers`` (1 in this process) and ``chunk_size``.

    Examples
    --------
    >>> from lcp.sweeps.parameter_sweep import map_sets
    >>> map_sets(abs, [-1, 2, -3])[0]
    [1, 2, 3]
    """
    if not callable(fn):
        raise ValueError(f"fn must be callable, got {type(fn).__name__}")
    _check_where(workers, client)
    if chunk_size is not None and (not isinstance(chunk_size, numbers.Integral) or chunk_size < 1):
        raise ValueError(f"chunk_size must be a positive integer, got {chunk_size!r}")
    if progress is not None and not isinstance(progress, bool):
        raise ValueError(f"progress must be True, False or None, got {progress!r}")
    sets = list(sets)
    n = len(sets)
    show = progress if progress is not None else n >= PROGRESS_MIN_SETS
    out: list = []
    if workers is None and client is None:
        bar = _progress_bar(n, show, desc)
        for p in sets:
            out.append(fn(p))
            if bar is not None:
                bar.update(1)
        if bar is not None:
            bar.close()
        return out, {"workers": 1, "chunk_size": n}
    c, cluster, own = _connect(client, workers)
    try:
        n_workers = max(1, len(c.scheduler_info().get("workers", {})) or (workers or 1))
        size = chunk_size or min(5000, max(1, math.ceil(n / (4 * n_workers))))
        n_chunks = max(1, math.ceil(n / size))
        # strided chunks (sets i, i + n_chunks, ...): neighbouring sets of a grid cost alike (a
        # corner of the grid may take the slow path throughout), so contiguous chunks would load
        # one worker with all the expensive ones
        futures = [c.submit(_run_chunk, fn, sets[i::n_chunks], pure=False) for i in range(n_chunks)]
        if show:
            from dask.distributed import progress as dask_progress

            dask_progress(futures)
        out = [None] * n
        for i, part in enumerate(c.gather(futures)):
            out[i::n_chunks] = part
    finally:
        if own is not None:
            own.close()
        if cluster is not None:
            cluster.close()
    return out, {"workers": n_workers, "chunk_size": size}


def sweep(build: Callable, params: Sequence[Mapping] | Mapping[str, Sequence], *,
          summary: Callable | None = None, workers: int | None = None,
          client: Client | str | None = None, chunk_size: int | None = None, progress: bool | None = None,
          **simulate_options) -> pd.DataFrame:
    """Simulate one scene per parameter set and tabulate the results.

    Parameters
    ----------
    build : callable
        ``build(**p)`` returns a :class:`~lcp.scenes.Scene` (or a System, with ``q0``, ``v0`` and
        ``t_end`` among ``simulate_options``); ``lcp.scenes.jean_pratt`` for example. On a cluster
        it must be importable or picklable (a module-level function).
    params : list of dict, or dict of sequences
        The parameter sets; a dict of sequences is the full grid (:func:`parameter_sets`).
    summary : callable, optional
        ``summary(result) -> dict`` of extra columns per row; by default the final q and v
        (:func:`default_summary`).
    workers : int, optional
        Run on a new ``dask.distributed`` LocalCluster of this many worker processes (closed at
        the end). Without ``workers`` and ``client`` the sweep runs in this process.
    client : dask.distributed.Client or str, optional
        Run on an existing cluster: its Client, or the address of its scheduler
        (``"tcp://host:8786"``). An unreachable address raises ``ConnectionError`` within
        :data:`CONNECT_TIMEOUT` seconds.
    chunk_size : int, optional
        Parameter sets per task; by default about four tasks per worker (at least 1, at most 5000).
    progress : bool, optional
        Show a progress bar (tqdm, on stderr): by default for sweeps of :data:`PROGRESS_MIN_SETS`
        sets or more.
    **simulate_options
        Passed to :func:`lcp.simulate` for every set (``t_end``, ``method``, ``h``, ...), validated
        on the first set before anything is distributed.

    Returns
    -------
    pandas.DataFrame
        One row per parameter set, in the order of ``params``: the parameters, ``success``,
        ``status``, ``message`` and the summary columns. A set whose build or run raised has
        ``status`` :data:`BUILD_FAILED` and the exception in ``message``. ``df.attrs`` holds
        ``wall_time`` (s), ``workers`` and ``chunk_size``.

    Examples
    --------
    Stop positions of the Jean-Pratt block over a grid of friction coefficients and launch speeds,
    by the event-driven method (exact), in this process:

    >>> import lcp
    >>> df = lcp.sweep(lcp.scenes.jean_pratt, {"R": [0.3, 0.5], "v0": [1.0, 2.0]},
    ...                t_end=1.0, method="event")
    >>> df[["R", "v0", "success", "q_x"]].round(6).values.tolist()
    [[0.3, 1.0, True, 0.14441], [0.3, 2.0, True, 0.577642], [0.5, 1.0, True, 0.076453], [0.5, 2.0, True, 0.30581]]

    On a cluster: ``lcp.sweep(..., workers=2)`` for a local one, ``client="tcp://host:8786"`` for a
    running one.
    """
    import pandas as pd  # the sweeps extra; only sweeps need it

    if not callable(build):
        raise ValueError(f"build must be callable (e.g. lcp.scenes.jean_pratt), got {type(build).__name__}")
    if summary is not None and not callable(summary):
        raise ValueError(f"summary must be callable or None, got {type(summary).__name__}")
    sets = parameter_sets(params)
    if sets:
        _check_options(build, sets[0], simulate_options)
    t0 = time.perf_counter()
    rows, info = map_sets(functools.partial(_run_one, build, summary=summary, options=simulate_options),
                          sets, workers=workers, client=client, chunk_size=chunk_size, progress=progress)
    columns = list(dict.fromkeys(k for p in sets for k in p)) + ["success", "status", "message"]
    df = pd.DataFrame(rows)
    rest = [c for c in df.columns if c not in columns]
    df = df.reindex(columns=columns + rest)
    df.attrs.update(wall_time=time.perf_counter() - t0, **info)
    return df


def _check_options(build, first, options):
    """Unknown or invalid simulate options fail before anything runs (not as n failed rows)."""
    import inspect

    from lcp.simulation import simulate

    sig = inspect.signature(simulate)
    named = {k for k, prm in sig.parameters.items() if prm.kind is not inspect.Parameter.VAR_KEYWORD}
    if "scene" in options:
        raise ValueError("the scene comes from build(**p); do not pass scene= to sweep")
    clash = set(options) & set(_SWEEP_OPTIONS)
    if clash:  # cannot happen through the signature, kept for callers passing a dict
        raise ValueError(f"options {sorted(clash)} are sweep options, not simulate options")
    method = options.get("method", "moreau-jean")
    if method == "moreau-jean":
        unknown = set(options) - named
        if unknown:
            raise ValueError(f"unknown simulate options for method 'moreau-jean': {sorted(unknown)}")
    else:
        from lcp.events.options import EventOptions

        extra = {k: v for k, v in options.items() if k not in named}
        EventOptions.from_kwargs(**extra)  # raises ValueError naming an unknown option
