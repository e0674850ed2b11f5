"""Studies on a Dask cluster (``--workers N``, ``--scheduler ADDRESS``) give the serial numbers.

Each study runs in quick mode here and on a LocalCluster of two worker processes; every number
but a measured time must be the same, bit for bit (compared through ``repr``, so that NaN equals
NaN and -0.0 differs from 0.0).
"""
import dataclasses
import math

import numpy as np
import pytest

pytest.importorskip("dask.distributed")

from studies import _cluster, lem_convergence, shock_limit, stability, work_precision  # noqa: E402

TIMES = {"time_s", "seconds", "peak_mb", "build_s", "solve_s", "checked_solve_s"}


def same(a, b, path="result"):
    """Recursive bit-for-bit comparison, ignoring measured times; returns the first difference."""
    if dataclasses.is_dataclass(a):
        a, b = dataclasses.asdict(a), dataclasses.asdict(b)
    if isinstance(a, dict):
        if set(a) != set(b):
            return f"{path}: keys {sorted(set(a) ^ set(b), key=str)}"
        for k in a:
            if k in TIMES:
                continue
            d = same(a[k], b[k], f"{path}[{k!r}]")
            if d:
                return d
        return ""
    if isinstance(a, (list, tuple)):
        if len(a) != len(b):
            return f"{path}: length {len(a)} != {len(b)}"
        for i, (x, y) in enumerate(zip(a, b)):
            d = same(x, y, f"{path}[{i}]")
            if d:
                return d
        return ""
    if isinstance(a, np.ndarray):
        ok = a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()
        return "" if ok else f"{path}: arrays differ"
    if isinstance(a, float) or isinstance(b, float):
        return "" if repr(float(a)) == repr(float(b)) else f"{path}: {a!r} != {b!r}"
    return "" if a == b else f"{path}: {a!r} != {b!r}"


def test_options_are_parsed(tmp_path):
    import argparse

    p = _cluster.add_options(argparse.ArgumentParser())
    args = p.parse_args(["--workers", "2"])
    assert args.workers == 2 and args.scheduler is None
    assert p.parse_args(["--scheduler", "tcp://host:8786"]).scheduler == "tcp://host:8786"
    with pytest.raises(ValueError, match="not both"):
        shock_limit.run(out=tmp_path, quick=True, workers=2, scheduler="tcp://127.0.0.1:1")
    with pytest.raises(ValueError, match="workers"):
        lem_convergence.run(out=tmp_path, quick=True, workers=0)


def test_unreachable_scheduler_fails_fast(tmp_path, monkeypatch):
    import lcp.sweeps.parameter_sweep

    # the failure is what is checked, not the length of the wait (CONNECT_TIMEOUT, 5 s by default)
    monkeypatch.setattr(lcp.sweeps.parameter_sweep, "CONNECT_TIMEOUT", 0.5)
    with pytest.raises(ConnectionError, match="scheduler"):
        lem_convergence.main(["--quick", "--out", str(tmp_path), "--scheduler", "tcp://127.0.0.1:9"])


@pytest.mark.slow  # about 20-50 s: a LocalCluster, and the quick study twice
def test_shock_limit_with_two_workers_gives_the_serial_numbers(tmp_path):
    serial = shock_limit.run(out=tmp_path / "serial", quick=True)
    parallel = shock_limit.main(["--quick", "--out", str(tmp_path / "workers"), "--workers", "2"])
    for key in ("sweep", "hs", "checks", "convergence", "iterations"):
        assert not same(serial[key], parallel[key], key)
    reg_s, reg_p = serial["regimes"], parallel["regimes"]
    assert not same(reg_s["rows"], reg_p["rows"], "regime rows")
    assert set(reg_s["maps"]) == set(reg_p["maps"])
    for k in reg_s["maps"]:
        np.testing.assert_array_equal(reg_s["maps"][k], reg_p["maps"][k])
    # the CSV files (every number written) are the same, byte for byte
    for name in ("sweep.csv", "regimes.csv"):
        assert (tmp_path / "serial" / name).read_bytes() == (tmp_path / "workers" / name).read_bytes()


@pytest.mark.slow  # about 20-50 s: a LocalCluster, and the quick study twice
def test_lem_convergence_with_two_workers_gives_the_serial_numbers(tmp_path):
    serial = lem_convergence.run(out=tmp_path / "serial", quick=True)
    parallel = lem_convergence.run(out=tmp_path / "workers", quick=True, workers=2)
    for key in ("error_vs_degree", "troesch", "checks", "coefficients", "smooth_friction"):
        assert not same(serial[key], parallel[key], key)
    name = "error_vs_degree.csv"
    assert (tmp_path / "serial" / name).read_bytes() == (tmp_path / "workers" / name).read_bytes()


@pytest.mark.slow
def test_stability_with_two_workers_gives_the_serial_table(tmp_path):
    serial = stability.run(out=tmp_path / "serial", quick=True)
    parallel = stability.run(out=tmp_path / "workers", quick=True, workers=2)
    assert not same(serial["rows"], parallel["rows"], "rows")
    assert serial["counts"] == parallel["counts"]


@pytest.mark.slow
def test_work_precision_with_two_workers_gives_the_serial_errors(tmp_path):
    serial = work_precision.run(out=tmp_path / "serial", quick=True)
    parallel = work_precision.run(out=tmp_path / "workers", quick=True, workers=2)
    assert len(serial["rows"]) == len(parallel["rows"]) > 0
    for a, b in zip(serial["rows"], parallel["rows"]):
        # the errors and what each method claims are the same; times, and the repeat counts that
        # follow from them, are measured where each ran
        keys = set(a) - {"time_s", "repeats"}
        assert not same({k: a[k] for k in keys}, {k: b[k] for k in keys}, f"row {a['scene']}/{a['method']}")
    assert math.isfinite(parallel["seconds"])
