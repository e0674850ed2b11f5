"""lcp.sweep: rows per parameter set, failures as rows, and the same table serially and on Dask."""
from __future__ import annotations

import os

import numpy as np
import pytest

import lcp
from lcp.sweeps.parameter_sweep import BUILD_FAILED, parameter_sets

pd = pytest.importorskip("pandas")


def test_grid_order_and_fixed_values():
    sets = parameter_sets({"R": np.array([0.3, 0.5]), "v0": [1.0, -1.0], "M": 2.0})
    assert sets == [{"R": 0.3, "v0": 1.0, "M": 2.0}, {"R": 0.3, "v0": -1.0, "M": 2.0},
                    {"R": 0.5, "v0": 1.0, "M": 2.0}, {"R": 0.5, "v0": -1.0, "M": 2.0}]
    assert all(type(p["R"]) is float for p in sets)  # NumPy scalars become Python numbers


@pytest.mark.parametrize("bad, word", [("R", "list of dicts"), ([1.0], "params[0]"), ({"R": []}, "empty")])
def test_bad_params_name_the_problem(bad, word):
    with pytest.raises(ValueError, match=word.replace("[", r"\[").replace("]", r"\]")):
        parameter_sets(bad)


def test_rows_match_the_exact_stop_and_failures_are_rows():
    params = [{"R": 0.5}, {"R": -1.0}, {"R": 0.3, "v0": -2.0}, {"m": 0.0}]
    df = lcp.sweep(lcp.scenes.jean_pratt, params, t_end=1.0, method="event")
    assert list(df.columns[:5]) == ["R", "v0", "m", "success", "status"]
    assert len(df) == 4
    for i in (0, 2):
        p = {k: v for k, v in params[i].items()}
        sc = lcp.scenes.jean_pratt(**p)
        assert df.success[i] and df.status[i] == 0
        assert abs(df.q_x[i] - sc.x_stop) <= 1e-15 * abs(sc.x_stop) + 1e-17
        assert df.v_x[i] == 0.0 and df.q_y[i] == 0.0
    for i, word in ((1, "R"), (3, "m must be")):
        assert not df.success[i] and df.status[i] == BUILD_FAILED and word in df.message[i]


def test_summary_columns_and_moreau_jean():
    df = lcp.sweep(lcp.scenes.jean_pratt, {"R": [0.4, 0.6]}, t_end=0.3, h=1e-3,
                   summary=lambda r: {"x_end": float(r.q[-1, 0]), "steps": r.stats.steps})
    assert list(df.columns) == ["R", "success", "status", "message", "x_end", "steps"]
    for R, x in zip(df.R, df.x_end):
        assert abs(x - lcp.scenes.jean_pratt(R=R).x_stop) < 1e-6  # the stop falls inside a step: O(h^2)
    assert df.steps.tolist() == [300, 300]


@pytest.mark.parametrize("kw, word", [({"workers": 0}, "workers"), ({"workers": 1, "client": "tcp://x:1"}, "not both"),
                                      ({"chunk_size": 0}, "chunk_size"), ({"hh": 1e-3}, "hh"),
                                      ({"method": "event", "rtoll": 1}, "rtoll"), ({"summary": 3}, "summary")])
def test_bad_options_fail_before_running(kw, word):
    with pytest.raises(ValueError, match=word):
        lcp.sweep(lcp.scenes.jean_pratt, [{"R": 0.5}], t_end=0.3, **kw)


def test_unreachable_scheduler_fails_fast(monkeypatch):
    pytest.importorskip("dask.distributed")
    import lcp.sweeps.parameter_sweep

    # the failure is what is checked, not the length of the wait (CONNECT_TIMEOUT, 5 s by default)
    monkeypatch.setattr(lcp.sweeps.parameter_sweep, "CONNECT_TIMEOUT", 0.5)
    with pytest.raises(ConnectionError, match="cannot reach the Dask scheduler"):
        lcp.sweep(lcp.scenes.jean_pratt, [{"R": 0.5}], client="tcp://127.0.0.1:9", t_end=0.3)


def _params():
    rng = np.random.default_rng(7)
    sets = [{"R": float(R), "v0": float(v), "phi": float(f)}
            for R, v, f in zip(rng.uniform(0.0, 2.5, 60), rng.uniform(-2, 2, 60), rng.uniform(-8, 8, 60))]
    return sets + [{"R": -0.1}]  # a failing set travels too


def test_local_cluster_of_processes_gives_the_serial_table_bit_for_bit():
    distributed = pytest.importorskip("dask.distributed")
    serial = lcp.sweep(lcp.scenes.jean_pratt, _params(), t_end=0.5, method="event")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, distributed.Client(cluster) as client:
        pids = set(client.run(os.getpid).values())
        assert len(pids) == 2 and os.getpid() not in pids  # worker processes, not threads
        on_cluster = lcp.sweep(lcp.scenes.jean_pratt, _params(), t_end=0.5, method="event",
                               client=client, chunk_size=7)
    assert serial.success.sum() == 60 and not serial.success.iloc[-1]
    pd.testing.assert_frame_equal(serial, on_cluster, check_exact=True)
    # bit for bit, NaNs of the failed row included
    a, b = serial.select_dtypes(float).to_numpy(), on_cluster.select_dtypes(float).to_numpy()
    assert a.tobytes() == b.tobytes()


def _blas_threads():
    return {k: os.environ.get(k) for k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")}


def test_workers_keep_this_process_blas_threads():
    """Dask sets the BLAS thread counts of its workers to 1; OpenBLAS's results depend on them in the
    last digit (a Radau solve of the work-precision study: 15th digit), so the cluster the package
    starts gives its workers this process's settings, set or not."""
    pytest.importorskip("dask.distributed")
    from lcp.sweeps.parameter_sweep import cluster

    here = _blas_threads()  # before the cluster: Dask writes its own values into this process too
    with cluster(workers=1) as client:
        seen = list(client.run(_blas_threads).values())
    assert seen == [here]


def _dies_once(marker, **p):
    """A build that kills its worker process the first time it runs (a lost worker)."""
    if not os.path.exists(marker):
        open(marker, "w").close()
        os._exit(1)
    return lcp.scenes.jean_pratt(**p)


@pytest.mark.slow
def test_a_lost_worker_costs_no_rows(tmp_path):
    pytest.importorskip("dask.distributed")
    import functools

    build = functools.partial(_dies_once, str(tmp_path / "died"))
    params = [{"R": 0.1 * (i + 1)} for i in range(12)]
    df = lcp.sweep(build, params, workers=2, chunk_size=3, t_end=0.3, method="event")
    assert (tmp_path / "died").exists()
    assert len(df) == 12 and df.success.all()
    assert df.R.tolist() == [p["R"] for p in params]
