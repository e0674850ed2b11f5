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

Failures are rows too: a parameter set whose build or run raises (any exception, SystemExit
included), or whose simulation fails, appears with ``success`` False, its ``status`` and its
``message``; the sweep goes on. On a cluster, a set that kills its worker process (``os._exit``, a
segfault, running out of memory) is a row with status :data:`WORKER_DIED`: a chunk whose worker
died is run again one set per task, and a set whose worker dies again is run alone, so that only
the set that kills its worker is blamed; the worker is replaced (by its nanny) and every other row
is the one the serial loop gives.
"""
from __future__ import annotations

import contextlib
import functools
import itertools
import math
import numbers
import os
import sys
import threading
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # optional dependencies (the parallel extra), for annotations only
    import pandas as pd
    from dask.distributed import Client

__all__ = ["BUILD_FAILED", "WORKER_DIED", "cluster", "default_summary", "map_sets", "parameter_sets",
           "sweep"]

#: ``status`` of a row whose build or simulate call raised (its message names the exception)
BUILD_FAILED = -10
#: ``status`` of a row whose task could not finish on the cluster: its worker process died while
#: running it alone (a crash, ``os._exit``, out of memory), or its result could not come back
WORKER_DIED = -11
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
    # a system with kinematics (qdot = T(q) v) has fewer velocities than coordinates: numbered
    vnames = names if v.ndim == 2 and v.shape[1] == n else [f"v{i}" for i in range(v.shape[1] if v.ndim == 2 else 0)]
    for i, name in enumerate(vnames):
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
    except BaseException as exc:  # noqa: BLE001 - a failed set is a row, whatever the cause
        _reraise_user_interrupt(exc)
        row.update(success=False, status=BUILD_FAILED, message=_describe(exc))
    return row


def _reraise_user_interrupt(exc):
    """Re-raise a KeyboardInterrupt that can be the user's Ctrl-C, and only that.

    Python delivers SIGINT to the main thread only; a KeyboardInterrupt raised anywhere else (a
    Dask worker runs its tasks in a thread pool) was raised by the parameter set's own code, and
    is that set's failure like any other exception.
    """
    if isinstance(exc, KeyboardInterrupt) and threading.current_thread() is threading.main_thread():
        raise exc


def _describe(exc) -> str:
    text = str(exc)
    if isinstance(exc, SystemExit):
        text = f"the parameter set called sys.exit({exc.code!r})"
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _run_chunk(fn, chunk) -> tuple[list, float]:
    """The chunk's results and the seconds they took (the work a serial run would have done)."""
    t0 = time.perf_counter()
    return [fn(p) for p in chunk], time.perf_counter() - t0


#: the thread-count variables of the BLAS libraries, which Dask's workers would otherwise set to 1
_BLAS_THREADS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


class SchedulerAddressError(ValueError, ConnectionError):
    """A scheduler address that does not lead to a Dask scheduler (a ValueError naming the address;
    a ConnectionError too, for callers that catch that)."""


def _probe_scheduler(address: str, timeout: float):
    """Raise :class:`SchedulerAddressError` unless a Dask scheduler answers at ``address`` within
    ``timeout`` seconds.

    ``Client(address, timeout=...)`` cannot be trusted with an arbitrary address: a server that
    accepts the connection and then speaks HTTP or says nothing held it far beyond its timeout
    (150 s and more), and junk bytes read as a message length asked for exabytes. So the address is
    first asked, through distributed's own comm layer (its handshake, then the ``identity`` call),
    who it is, in a thread of its own with its own event loop, under ``asyncio.wait_for``; and the
    thread is abandoned if even that overruns (it is a daemon and holds nothing of the sweep's).
    """
    import asyncio

    from distributed.comm import connect, parse_address
    from distributed.comm.addressing import parse_host_port
    from distributed.comm.registry import get_backend

    where = f"the Dask scheduler address {address!r}"
    try:
        scheme, loc = parse_address(address)
        get_backend(scheme)
        if scheme in ("tcp", "tls", "ws", "wss"):
            parse_host_port(loc)
    except ValueError as exc:
        raise SchedulerAddressError(f"{where} is not an address Dask can use: {exc}") from None
    outcome = {}

    async def ask():
        # the connection's own deadline comes first, so that its cause (refused, unknown host)
        # is the one reported rather than the overall timeout's
        comm = await connect(address, timeout=0.8 * timeout)
        try:
            await comm.write({"op": "identity", "reply": True})
            return await comm.read()
        finally:
            comm.abort()

    def run():
        try:
            outcome["reply"] = asyncio.run(asyncio.wait_for(ask(), timeout))
        except BaseException as exc:  # noqa: BLE001 - anything the address does is reported below
            outcome["error"] = exc

    thread = threading.Thread(target=run, name=f"lcp-probe-{address}", daemon=True)
    thread.start()
    thread.join(timeout + 1.0)
    if thread.is_alive() or isinstance(outcome.get("error"), (asyncio.TimeoutError, TimeoutError)):
        raise SchedulerAddressError(f"cannot reach {where}: no answer from a Dask scheduler within "
                                    f"{timeout:g} s (CONNECT_TIMEOUT)")
    exc = outcome.get("error")
    if exc is not None:
        chain, e = [], exc
        while e is not None and e not in chain:
            chain.append(e)
            e = e.__cause__ or e.__context__
        # the first cause, below distributed's wrappers: refused, unknown host, ...
        root = next((e for e in reversed(chain[1:]) if isinstance(e, OSError) and str(e)), None)
        if isinstance(exc, OSError) and root is not None:
            why = f"{exc} ({type(root).__name__}: {root})"
        elif isinstance(exc, OSError):
            why = f"{type(exc).__name__}: {exc}"
        else:  # bytes that are not Dask's protocol: a garbled frame, a length of exabytes, ...
            why = (f"what it sent is not Dask's protocol (read as Dask's, it gave "
                   f"{type(exc).__name__}: {exc})")
        raise SchedulerAddressError(f"cannot reach {where}: {why}") from None
    reply = outcome.get("reply")
    kind = reply.get("type") if isinstance(reply, Mapping) else None
    if kind != "Scheduler":
        what = f"a Dask {kind}" if isinstance(kind, str) else f"an answer of type {type(reply).__name__}"
        raise SchedulerAddressError(f"cannot use {where}: it answered as {what}, not a Dask scheduler")


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
        _probe_scheduler(client, CONNECT_TIMEOUT)
        try:
            c = Client(client, timeout=CONNECT_TIMEOUT)
        except Exception as exc:  # noqa: BLE001 - it answered the probe a moment ago
            raise SchedulerAddressError(f"cannot connect to the Dask scheduler at {client!r} within "
                                        f"{CONNECT_TIMEOUT:g} s: {type(exc).__name__}: {exc}") from None
        return c, None, c
    import dask

    # processes, one thread each: the runs hold the GIL, so threads would not run them in
    # parallel; and no statistical profiler, whose sampling thread takes the GIL from these
    # pure-Python runs every few milliseconds (about 10% of a worker's time, measured). The workers
    # keep this process's BLAS thread settings: Dask sets them to 1 by default, and OpenBLAS's
    # results depend on its thread count in the last digit (a Radau solve of a 2 x 2 system: 15th
    # digit), which would break the serial loop's bit-for-bit rows. A task is declared failed the
    # first time its worker dies (Dask's default tries it on 4 workers, killing each in turn, and
    # then fails it and the innocent tasks queued beside it alike), and a worker is given one task
    # at a time (no task queued on it to die with it): a failed task is then the one that ran when
    # its worker died, and map_sets finds the set that killed it by running the chunk's sets on
    # their own.
    environ = {k: v for k, v in dask.config.get("distributed.nanny.pre-spawn-environ", {}).items()
               if k not in _BLAS_THREADS}
    environ.update({k: os.environ[k] for k in _BLAS_THREADS if k in os.environ})
    with dask.config.set({"distributed.worker.profile.enabled": False,
                          "distributed.nanny.pre-spawn-environ": environ,
                          "distributed.scheduler.allowed-failures": 0,
                          "distributed.scheduler.worker-saturation": 1.0}):
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
        An existing cluster, or its scheduler's address (a ``ValueError``, also a
        ``ConnectionError``, naming the address if no Dask scheduler answers there).

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
             desc: str = "sweep", on_error: Callable | None = None) -> tuple[list, dict]:
    """``[fn(p) for p in sets]``, in this process or on Dask, in chunks; the engine of :func:`sweep`.

    Studies whose unit of work is not a ``simulate`` call (a LEM solve, a work-precision point) use
    it directly. ``fn`` should not raise for a set that should become a row (catch inside it), and
    on a cluster it must be picklable (a module-level function, or ``functools.partial`` of one).
    ``workers``, ``client``, ``chunk_size`` and ``progress`` are those of :func:`sweep`; ``desc``
    labels the serial progress bar. Several calls can share one cluster (:func:`cluster`).

    On a cluster, a chunk that fails (``fn`` raised, or the worker process died under it) is run
    again one set per task, so that the other sets of the chunk still give their results; a set
    whose task fails again for a dead worker is run once more alone on the cluster, so that only
    a set that kills its worker by itself is counted as failed.

    Parameters
    ----------
    on_error : callable, optional
        ``on_error(p, message)`` gives the result for a set that failed: ``fn(p)`` raised (any
        BaseException, but for a KeyboardInterrupt in this process's main thread, which is the
        user's and stops the run), or its worker died. Without it, ``fn`` raising in this process
        propagates, and sets that failed on a cluster raise a ``RuntimeError`` naming them once all
        the others have run.

    Returns
    -------
    results : list
        ``fn(p)`` for each p, in order.
    info : dict
        ``workers`` (1 in this process) and ``chunk_size``; ``note``, when given, says that the
        ``workers=`` cluster took longer to start than all the sets took to run (it is also issued
        as a ``UserWarning``).

    Examples
    --------
    >>> from lcp.sweeps.parameter_sweep import map_sets
    >>> map_sets(abs, [-1, 2, -3])[0]
    [1, 2, 3]
    """
    if not callable(fn):
        raise ValueError(f"fn must be callable, got {type(fn).__name__}")
    if on_error is not None and not callable(on_error):
        raise ValueError(f"on_error must be callable or None, got {type(on_error).__name__}")
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
            if on_error is None:
                out.append(fn(p))
            else:
                try:
                    r = fn(p)
                except BaseException as exc:  # noqa: BLE001 - a failed set is a result too
                    _reraise_user_interrupt(exc)
                    r = on_error(p, _describe(exc))
                out.append(r)
            if bar is not None:
                bar.update(1)
        if bar is not None:
            bar.close()
        return out, {"workers": 1, "chunk_size": n}
    t0 = time.perf_counter()
    c, cluster, own = _connect(client, workers)
    start_s = time.perf_counter() - t0
    try:
        n_workers = max(1, len(c.scheduler_info().get("workers", {})) or (workers or 1))
        size = chunk_size or min(5000, max(1, math.ceil(n / (4 * n_workers))))
        n_chunks = max(1, math.ceil(n / size))
        previous = None if cluster is not None else _allowed_failures(c, 0)
        try:
            out, work_s, failed = _run_on_cluster(c, fn, sets, n_chunks, show,
                                                  one_task_per_worker=cluster is not None)
        finally:
            if previous is not None:
                _allowed_failures(c, previous)
    finally:
        if own is not None:
            own.close()
        if cluster is not None:
            cluster.close()
    if failed and on_error is None:
        listed = "; ".join(f"set {j} ({_short_repr(sets[j])}): {msg}" for j, msg in sorted(failed.items())[:5])
        more = f"; and {len(failed) - 5} more" if len(failed) > 5 else ""
        raise RuntimeError(f"{len(failed)} of {n} sets failed on the cluster (the other results were "
                           f"computed): {listed}{more}")
    for j, msg in failed.items():
        out[j] = on_error(sets[j], msg)
    info = {"workers": n_workers, "chunk_size": size}
    note = _short_sweep_note(n, workers, start_s, work_s)
    if note:
        info["note"] = note
        warnings.warn(note, UserWarning, stacklevel=2)
    return out, info


def _allowed_failures(c, value):
    """Set the scheduler's allowed worker deaths per task to ``value``; the previous value, or None
    if the scheduler does not allow it to be set.

    On a cluster the sweep did not start, Dask's default (3) lets a set that kills its worker kill
    four in a row, each replaced by its nanny, and then loses track of a task now and then (a hang
    seen in 2 of 3 runs of such a sweep with distributed 2026.8), so the sweep sets it to 0 while
    it runs and puts the old value back after.
    """
    def swap(dask_scheduler=None):
        old, dask_scheduler.allowed_failures = dask_scheduler.allowed_failures, value
        return old

    try:
        return c.run_on_scheduler(swap)
    except Exception:  # noqa: BLE001 - a scheduler that refuses: its own setting stays
        return None


def _short_repr(p, limit=120):
    text = repr(p)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _short_sweep_note(n, workers, start_s, work_s):
    """A note when ``workers=N`` cost more than it could save: the sets' own run time (measured on
    the workers, their cold start included, as the serial loop's would be) is shorter than the time
    taken to start the cluster, so the loop in this process would have finished sooner."""
    if workers is None:
        return None
    if work_s < start_s:
        return (f"workers={workers}: starting the cluster took {start_s:.2g} s, longer than the "
                f"{n} parameter sets took to run ({work_s:.2g} s in all); this sweep is faster in "
                f"this process (leave out workers=)")
    if n < workers:
        return (f"workers={workers}: only {n} parameter set{'s' if n != 1 else ''}, so {workers - n} of "
                f"the workers had nothing to do")
    return None


def _task_failure(exc) -> str:
    from distributed import KilledWorker

    if isinstance(exc, KilledWorker):
        worker = getattr(getattr(exc, "last_worker", None), "address", None)
        return (f"WorkerDied: the worker process{f' {worker}' if worker else ''} died while running "
                f"this parameter set on its own (a crash, os._exit, out of memory); the worker was "
                f"replaced and the other sets ran")
    return _describe(exc)


def _run_on_cluster(c, fn, sets, n_chunks, show, one_task_per_worker=False):
    """(results with None for failed sets, seconds of work measured in the tasks, {index: message}).

    ``one_task_per_worker``: the cluster gives each worker one task at a time and fails a task at
    its worker's first death (the one :func:`_connect` starts), so a single-set task that fails
    for a dead worker killed it; on another cluster it may have been queued on the dying worker,
    and is run again alone before it is blamed.
    """
    from distributed import KilledWorker, as_completed

    n = len(sets)
    out: list = [None] * n
    work_s = 0.0
    failed: dict = {}
    tasks: dict = {}

    def submit(ids):
        f = c.submit(_run_chunk, fn, [sets[j] for j in ids], pure=False)
        tasks[f] = ids
        return f

    # strided chunks (sets i, i + n_chunks, ...): neighbouring sets of a grid cost alike (a
    # corner of the grid may take the slow path throughout), so contiguous chunks would load
    # one worker with all the expensive ones
    first = [submit(list(range(i, n, n_chunks))) for i in range(n_chunks)]
    if show:
        from dask.distributed import progress as dask_progress

        dask_progress(first)
    suspects = []
    queue = as_completed(first)
    del first
    for f in queue:
        ids = tasks.pop(f)
        try:
            part, seconds = f.result()
        except Exception as exc:  # noqa: BLE001 - the task's failure, whatever it was
            f.release()
            if len(ids) > 1:  # which set was it? each on its own
                for j in ids:
                    queue.add(submit([j]))
            elif isinstance(exc, KilledWorker) and not one_task_per_worker:
                # the tasks queued on a dying worker fail with it: try it again alone
                suspects.append(ids[0])
            else:
                failed[ids[0]] = _task_failure(exc)
            continue
        # released at once: a result left on a worker that dies later would be computed again
        f.release()
        work_s += seconds
        for j, r in zip(ids, part):
            out[j] = r
    for j in suspects:  # one at a time, alone: a worker that dies now died of this set
        f = submit([j])
        try:
            part, seconds = f.result()
        except Exception as exc:  # noqa: BLE001
            failed[j] = _task_failure(exc)
        else:
            work_s += seconds
            out[j] = part[0]
        tasks.pop(f)
        f.release()
    return out, work_s, failed


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
        (``"tcp://host:8786"``). The address is asked who it is before use; one where no Dask
        scheduler answers (refused, silent, another protocol) raises a ``ValueError`` (also a
        ``ConnectionError``) naming it, within :data:`CONNECT_TIMEOUT` seconds.
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
        ``status``, ``message`` and the summary columns. A set whose build or run raised (any
        exception, SystemExit included) has ``status`` :data:`BUILD_FAILED` and the exception in
        ``message``; one that killed its worker process has :data:`WORKER_DIED`. ``df.attrs``
        holds ``wall_time`` (s), ``workers`` and ``chunk_size``, and ``note`` when ``workers=``
        cost more time than the sets took to run (also issued as a ``UserWarning``).

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
                          sets, workers=workers, client=client, chunk_size=chunk_size, progress=progress,
                          on_error=_failed_row)
    columns = list(dict.fromkeys(k for p in sets for k in p)) + ["success", "status", "message"]
    df = pd.DataFrame(rows)
    rest = [c for c in df.columns if c not in columns]
    df = df.reindex(columns=columns + rest)
    df.attrs.update(wall_time=time.perf_counter() - t0, **info)
    return df


def _failed_row(p, message) -> dict:
    """The row of a set whose task failed outside :func:`_run_one`'s reach (its worker died)."""
    status = WORKER_DIED if message.startswith("WorkerDied") else BUILD_FAILED
    return {**p, "success": False, "status": status, "message": message}


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
