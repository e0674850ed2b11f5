"""Sweeps survive whatever a parameter set does, and bad scheduler addresses are named.

A set that raises (any exception, SystemExit, a KeyboardInterrupt raised by its own code) or that
kills its worker process (``os._exit``, a segfault) is a row with its status and message; every
other row is the serial run's, bit for bit. A scheduler address where no Dask scheduler answers
(refused, silent, HTTP, junk bytes) raises a ValueError naming it within the timeout.
"""
from __future__ import annotations

import contextlib
import os
import socket
import sys
import threading
import time

import numpy as np
import pytest

import lcp
from lcp.sweeps import parameter_sweep as ps
from lcp.sweeps.parameter_sweep import BUILD_FAILED, WORKER_DIED

pd = pytest.importorskip("pandas")


class _Interrupt(BaseException):
    """A BaseException that is not an Exception, like KeyboardInterrupt or GeneratorExit."""


def poisoned(poison=None, **p):
    """``lcp.scenes.jean_pratt`` unless told to fail in one of the ways a set's code can."""
    if poison == "raise":
        raise RuntimeError("poisoned set")
    if poison == "exit":
        sys.exit(3)
    if poison == "base":
        raise _Interrupt("a BaseException")
    if poison == "interrupt":
        raise KeyboardInterrupt
    if poison == "kill":
        os._exit(7)
    if poison == "segfault":
        import ctypes

        ctypes.string_at(0)  # reads address 0: SIGSEGV
    return lcp.scenes.jean_pratt(**p)


def _sets(poisons):
    rng = np.random.default_rng(11)
    sets = [{"R": float(R), "v0": float(v)} for R, v in zip(rng.uniform(0.1, 2.0, 12), rng.uniform(-2, 2, 12))]
    for i, kind in poisons.items():
        sets[i]["poison"] = kind
    return sets


def _assert_clean_rows_equal(df, poisons):
    """Every row without poison is the row of a sweep that had none, bit for bit."""
    clean = [{k: v for k, v in p.items() if k != "poison"} for p in _sets({})]
    expect = lcp.sweep(lcp.scenes.jean_pratt, clean, t_end=0.3, method="event")
    keep = [i for i in range(len(clean)) if i not in poisons]
    assert len(df) == len(clean)
    got = df.drop(columns=["poison"]).iloc[keep].reset_index(drop=True)
    want = expect.iloc[keep].reset_index(drop=True)
    pd.testing.assert_frame_equal(got, want, check_exact=True)
    a, b = got.select_dtypes(float).to_numpy(), want.select_dtypes(float).to_numpy()
    assert a.tobytes() == b.tobytes()
    assert got.success.all()


def test_serial_sweep_keeps_every_row_past_exceptions_and_system_exit():
    poisons = {2: "raise", 5: "exit", 9: "base"}
    df = lcp.sweep(poisoned, _sets(poisons), t_end=0.3, method="event")
    _assert_clean_rows_equal(df, poisons)
    for i, word in ((2, "RuntimeError: poisoned set"), (5, "SystemExit"), (9, "_Interrupt: a BaseException")):
        assert not df.success[i] and df.status[i] == BUILD_FAILED and word in df.message[i]
    assert "sys.exit(3)" in df.message[5]


def test_serial_sweep_stops_for_the_users_keyboard_interrupt():
    with pytest.raises(KeyboardInterrupt):
        lcp.sweep(poisoned, _sets({1: "interrupt"}), t_end=0.3, method="event")


def test_keyboard_interrupt_raised_off_the_main_thread_is_the_sets_failure():
    # Ctrl-C reaches the main thread only: elsewhere (a Dask worker's task thread) the set raised it
    out = {}
    thread = threading.Thread(target=lambda: out.setdefault(
        "df", lcp.sweep(poisoned, _sets({1: "interrupt"}), t_end=0.3, method="event")))
    thread.start()
    thread.join(120)
    df = out["df"]
    assert not df.success[1] and df.status[1] == BUILD_FAILED and df.message[1] == "KeyboardInterrupt"
    _assert_clean_rows_equal(df, {1: "interrupt"})


def test_map_sets_on_error_in_this_process():
    rows, _ = ps.map_sets(lambda x: 1 / x, [1, 0, 4], on_error=lambda p, msg: (p, msg))
    assert rows == [1.0, (0, "ZeroDivisionError: division by zero"), 0.25]
    with pytest.raises(ValueError, match="on_error"):
        ps.map_sets(abs, [1], on_error=3)


def test_a_set_that_kills_its_worker_costs_only_its_own_row():
    """One worker: raise, SystemExit and os._exit on it; the dead worker is replaced."""
    pytest.importorskip("dask.distributed")
    poisons = {1: "raise", 4: "exit", 7: "kill"}
    df = lcp.sweep(poisoned, _sets(poisons), workers=1, t_end=0.3, method="event", chunk_size=4)
    _assert_clean_rows_equal(df, poisons)
    assert df.status[1] == BUILD_FAILED and "RuntimeError: poisoned set" in df.message[1]
    assert df.status[4] == BUILD_FAILED and "SystemExit" in df.message[4]
    assert df.status[7] == WORKER_DIED and "died while running this parameter set" in df.message[7]
    assert not df.success[[1, 4, 7]].any()


@pytest.mark.slow  # a 2-worker cluster of the caller's (Dask's default of 3 allowed deaths), segfaults
def test_poisoned_sets_on_a_users_cluster(tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    poisons = {0: "segfault", 3: "kill", 6: "exit", 10: "raise"}
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, distributed.Client(cluster) as client:
        df = lcp.sweep(poisoned, _sets(poisons), client=client, t_end=0.3, method="event", chunk_size=3)
        client.wait_for_workers(1, timeout=60)  # a dead worker is replaced (TimeoutError if none is)
        assert client.run_on_scheduler(lambda dask_scheduler: dask_scheduler.allowed_failures) == 3  # restored
        # map_sets without on_error: the others run, then the failure is named
        with pytest.raises(RuntimeError, match=r"1 of 4 sets failed on the cluster.*set 2 \(\{'poison': 'kill'\}\)"):
            ps.map_sets(_build_and_run, [{}, {}, {"poison": "kill"}, {}], client=client, chunk_size=2)
    _assert_clean_rows_equal(df, poisons)
    assert df.status[0] == WORKER_DIED and df.status[3] == WORKER_DIED
    assert df.status[6] == BUILD_FAILED and df.status[10] == BUILD_FAILED


def _build_and_run(p):
    return lcp.simulate(poisoned(**p), 0.1, method="event").q[-1, 0]


def test_workers_on_a_short_sweep_says_so():
    pytest.importorskip("dask.distributed")
    with pytest.warns(UserWarning, match="workers=2") as seen:
        df = lcp.sweep(lcp.scenes.jean_pratt, [{"R": 0.5}], workers=2, t_end=0.3, method="event")
    assert df.attrs["note"] == str(seen[0].message)
    assert df.success.all()


# -- scheduler addresses ---------------------------------------------------------------------

@contextlib.contextmanager
def _server(kind):
    """A loopback server that accepts and then answers HTTP, sends junk, or says nothing."""
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(8)
    srv.settimeout(0.2)
    stop = threading.Event()

    def serve():
        conns = []
        while not stop.is_set():
            try:
                conn, _ = srv.accept()
            except OSError:
                continue
            conns.append(conn)
            if kind == "http":
                conn.settimeout(2.0)
                with contextlib.suppress(OSError):
                    conn.recv(65536)
                    conn.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n")
            elif kind == "junk":
                conn.sendall(bytes(range(256)) * 16)
        for conn in conns:
            conn.close()

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield f"tcp://127.0.0.1:{srv.getsockname()[1]}"
    finally:
        stop.set()
        thread.join(5)
        srv.close()


@contextlib.contextmanager
def _refused():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))  # bound, not listening: connections are refused
    try:
        yield f"tcp://127.0.0.1:{s.getsockname()[1]}"
    finally:
        s.close()


@pytest.mark.parametrize("kind", ["http", "junk", "silent", "refused"])
def test_an_address_without_a_scheduler_is_named_within_the_timeout(kind, monkeypatch):
    pytest.importorskip("dask.distributed")
    monkeypatch.setattr(ps, "CONNECT_TIMEOUT", 1.5)
    with (_refused() if kind == "refused" else _server(kind)) as address:
        t0 = time.perf_counter()
        with pytest.raises(ValueError, match=f"'{address}'") as err:
            lcp.sweep(lcp.scenes.jean_pratt, [{"R": 0.5}], client=address, t_end=0.3)
        elapsed = time.perf_counter() - t0
    assert elapsed < 1.5 + 1.5  # the timeout, and the probe thread's hard deadline beyond it
    assert isinstance(err.value, ConnectionError)  # what callers caught before
    assert "MemoryError" not in str(err.value) or "not Dask's protocol" in str(err.value)


@pytest.mark.parametrize("address, word", [("http://127.0.0.1:80", "scheme"), ("tcp://127.0.0.1", "port")])
def test_a_malformed_address_is_named(address, word):
    pytest.importorskip("dask.distributed")
    with pytest.raises(ValueError, match=word) as err:
        lcp.sweep(lcp.scenes.jean_pratt, [{"R": 0.5}], client=address, t_end=0.3)
    assert repr(address) in str(err.value)


def test_a_running_scheduler_passes_the_probe_and_a_worker_does_not():
    distributed = pytest.importorskip("dask.distributed")
    with distributed.LocalCluster(n_workers=1, processes=False, dashboard_address=None) as cluster:
        ps._probe_scheduler(cluster.scheduler_address, 2.0)  # no exception
        worker = next(iter(cluster.workers.values())).address
        with pytest.raises(ValueError, match=f"'{worker}'.*answered as a Dask Worker"):
            ps._probe_scheduler(worker, 2.0)
