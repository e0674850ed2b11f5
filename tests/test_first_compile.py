"""A short run does not wait for the first compilation of the general loop's numba kernel.

- whether numba's cache holds a kernel's machine code is numba's own test (its index, this
  machine, this bytecode, the file's stamp): checked on a small cached function in a fresh
  interpreter, before and after its source changes;
- ``LCP_COMPILE`` (``background``, ``always``, ``off``; anything else a ValueError naming it) and
  the step threshold decide, and the message says which loop ran and why;
- the Python loop that a cold short run takes gives the compiled loop's results bit for bit;
- one background compilation per process, one at a time per cache (a marker), a stale marker
  taken over.
"""
from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

import lcp
from lcp.model.system import Contact, System
from lcp.numerics.jit import HAVE_NUMBA
from lcp.timestepping import codegen, first_compile

ROOT = Path(__file__).resolve().parents[1]

needs_numba = pytest.mark.skipif(not HAVE_NUMBA, reason="needs numba")


def _bowl():
    """A point in a circular bowl (curved gap: not a constant system)."""
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    r = ca.norm_2(q)
    return System(q, v, ca.SX.eye(2), ca.vertcat(0, -9.81),
                  contacts=[Contact(gap=1.0 - r, tangent_jacobian=ca.horzcat(-q[1], q[0]) / r, mu=0.3)])


_SOURCE = """
from numba import njit


@njit(cache=True)
def f(x):
    return x + {k}
"""


def _module(path: Path, k: int):
    path.write_text(textwrap.dedent(_SOURCE.format(k=k)))
    spec = importlib.util.spec_from_file_location(f"kmod_{os.getpid()}_{time.monotonic_ns()}", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _state_in_fresh_interpreter(path: Path) -> str:
    code = ("import importlib.util, sys; spec = importlib.util.spec_from_file_location('kmod', sys.argv[1]); "
            "m = importlib.util.module_from_spec(spec); spec.loader.exec_module(m); "
            "from lcp.timestepping.first_compile import kernel_state; print(kernel_state(m.f))")
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    out = subprocess.run([sys.executable, "-c", code, str(path)], env=env, capture_output=True, text=True, check=True)
    return out.stdout.strip()


@needs_numba
def test_the_cache_test_is_numbas_own(tmp_path):
    src = tmp_path / "kmod.py"
    mod = _module(src, 1)
    assert first_compile.kernel_state(mod.f) == "cold"
    assert mod.f(1.0) == 2.0
    assert first_compile.kernel_state(mod.f) == "loaded"
    assert _state_in_fresh_interpreter(src) == "cached"  # saved by the call above
    time.sleep(1.1)  # a new stamp (numba compares the file's modification time and size)
    _module(src, 22)
    assert _state_in_fresh_interpreter(src) == "cold"


def test_the_policy_is_read_and_checked(monkeypatch):
    monkeypatch.delenv(first_compile.ENV_VAR, raising=False)
    assert first_compile.policy() == "background"
    for value in ("always", "OFF", " background "):
        monkeypatch.setenv(first_compile.ENV_VAR, value)
        assert first_compile.policy() == value.strip().lower()
    monkeypatch.setenv(first_compile.ENV_VAR, "sometimes")
    with pytest.raises(ValueError, match="LCP_COMPILE='sometimes' is not one of"):
        first_compile.policy()


@pytest.mark.parametrize("state, policy, steps, defer", [
    ("cold", "off", 100, True), ("cold", "off", first_compile.COLD_MAX_STEPS, False),
    ("cold", "always", 100, False), ("cached", "off", 100, True), ("cached", "background", 100, True),
    ("cached", "off", first_compile.CACHED_MAX_STEPS, False), ("cached", "always", 100, False),
    ("loaded", "off", 100, False)])
def test_who_waits(monkeypatch, state, policy, steps, defer):
    monkeypatch.setattr(first_compile, "kernel_state", lambda kernel=None: state)
    monkeypatch.setattr(first_compile, "_SPENT", [0])
    monkeypatch.setenv(first_compile.ENV_VAR, policy)
    note = first_compile.deferred(steps)
    assert (note is not None) == defer
    if defer:
        assert "Python loop" in note and f"{steps} steps" in note and "LCP_COMPILE=always" in note
        assert ("not loaded in this process" in note) == (state == "cached")


def test_systems_the_loops_may_round_differently_never_wait(monkeypatch):
    monkeypatch.setattr(first_compile, "kernel_state", lambda kernel=None: "cold")
    monkeypatch.setenv(first_compile.ENV_VAR, "off")
    assert first_compile.deferred(100, exact=False) is None and first_compile.deferred(100) is not None


@needs_numba
@pytest.mark.skipif(codegen.c_compiler() is None, reason="needs a C compiler")
def test_two_contacts_run_compiled_however_cold(monkeypatch):
    from lcp.timestepping import general_loop

    calls = []
    real = general_loop.run_general_loop
    monkeypatch.setattr(general_loop, "run_general_loop", lambda *a, **k: calls.append(1) or real(*a, **k))
    monkeypatch.setattr(first_compile, "kernel_state", lambda kernel=None: "cold")
    monkeypatch.setenv(first_compile.ENV_VAR, "off")
    q, v = ca.SX.sym("q", 3), ca.SX.sym("v", 3)  # a point in a spherical bowl, and a wall x <= 0.5
    r = ca.norm_2(q)
    t1 = ca.vertcat(-q[1], q[0], 0) / ca.norm_2(q[:2])
    t2 = ca.cross(q / r, t1)
    s = System(q, v, ca.SX.eye(3), ca.vertcat(0, 0, -9.81),
               contacts=[Contact(gap=1.0 - r, tangent_jacobian=ca.horzcat(t1, t2).T, mu=0.3),
                         Contact(gap=0.5 - q[0], tangent=ca.vertcat(q[1], q[2]), mu=0.3)])
    res = lcp.simulate(s, 0.02, h=1e-3, q0=[0.3, 0.0, -np.sqrt(0.91)], v0=[0.0, 1.0, 0.0])
    assert calls == [1] and "Python loop" not in res.message


def test_a_process_of_short_runs_loads_the_cached_kernel_in_the_end(monkeypatch):
    monkeypatch.setattr(first_compile, "kernel_state", lambda kernel=None: "cached")
    monkeypatch.setattr(first_compile, "_SPENT", [0])
    monkeypatch.setenv(first_compile.ENV_VAR, "background")
    runs = [first_compile.deferred(400) is not None for _ in range(10)]
    k = (first_compile.CACHED_MAX_STEPS - 1) // 400  # runs whose steps stay below the budget
    assert runs == [True] * k + [False] * (10 - k)


@needs_numba
@pytest.mark.skipif(codegen.c_compiler() is None, reason="needs a C compiler")
def test_a_cold_short_run_takes_the_python_loop_with_the_same_bits(monkeypatch):
    from lcp.timestepping import general_loop

    calls = []
    real = general_loop.run_general_loop
    monkeypatch.setattr(general_loop, "run_general_loop", lambda *a, **k: calls.append(1) or real(*a, **k))
    kw = dict(h=1e-3, q0=[0.0, -1.0], v0=[0.8, 0.0])
    monkeypatch.setenv(first_compile.ENV_VAR, "always")
    compiled = lcp.simulate(_bowl(), 0.3, **kw)
    assert calls == [1]
    monkeypatch.setattr(first_compile, "kernel_state", lambda kernel=None: "cold")
    monkeypatch.setenv(first_compile.ENV_VAR, "off")
    cold = lcp.simulate(_bowl(), 0.3, **kw)
    assert calls == [1]  # not run again
    python = lcp.simulate(_bowl(), 0.3, fast=False, **kw)
    assert cold.success and "Python loop: the compiled general loop's kernel is not compiled" in cold.message
    assert compiled.message == python.message and cold.message.startswith(python.message)
    for name in ("t", "q", "v", "p_N", "p_T"):
        assert np.array_equal(getattr(cold, name), getattr(compiled, name)), name
        assert np.array_equal(getattr(cold, name), getattr(python, name)), name
    assert np.array_equal(cold.modes, compiled.modes)
    monkeypatch.setenv(first_compile.ENV_VAR, "often")
    with pytest.raises(ValueError, match="LCP_COMPILE"):
        lcp.simulate(_bowl(), 0.3, **kw)


class _FakePopen:
    started = []

    def __init__(self, args, **kw):
        _FakePopen.started.append((args, kw))


def test_one_background_compilation_at_a_time(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(first_compile.subprocess, "Popen", _FakePopen)
    monkeypatch.setattr(first_compile, "_STARTED", [])
    _FakePopen.started = []
    assert first_compile.compile_in_background() == "started"
    marker = tmp_path / first_compile.MARKER
    assert marker.exists() and len(_FakePopen.started) == 1
    args, kw = _FakePopen.started[0]
    assert args[2] == first_compile._WARM_UP and args[3] == str(marker)
    assert kw["env"][first_compile.ENV_VAR] == "always"
    assert kw["env"]["PYTHONPATH"].split(os.pathsep)[0] == str(ROOT)  # the lcp that runs here
    assert first_compile.compile_in_background() == "started" and len(_FakePopen.started) == 1
    monkeypatch.setattr(first_compile, "_STARTED", [])  # another process of the same machine
    assert first_compile.compile_in_background() == "elsewhere" and len(_FakePopen.started) == 1
    old = time.time() - 2 * first_compile.STALE_SECONDS
    os.utime(marker, (old, old))  # a compilation that died long ago
    assert first_compile.compile_in_background() == "started" and len(_FakePopen.started) == 2


@pytest.mark.slow
@needs_numba
@pytest.mark.skipif(codegen.c_compiler() is None, reason="needs a C compiler")
def test_the_background_process_fills_numbas_cache(tmp_path):
    """Fresh caches: a short run takes the Python loop and starts the background compilation; once
    it is done, a fresh interpreter finds the kernel cached (a short run still takes the Python
    loop: loading it would take longer) and a long run loads it."""
    env = {k: v for k, v in os.environ.items() if k != first_compile.ENV_VAR}
    env.update(LCP_CACHE_DIR=str(tmp_path / "c"), NUMBA_CACHE_DIR=str(tmp_path / "numba"), PYTHONPATH=str(ROOT))
    code = ("import sys; sys.path.insert(0, sys.argv[1]); from test_first_compile import _bowl; import lcp; "
            "from lcp.timestepping.first_compile import kernel_state; print(kernel_state()); "
            "r = lcp.simulate(_bowl(), float(sys.argv[2]), h=1e-3, q0=[0.0, -1.0], v0=[0.8, 0.0]); print(r.message)")
    run = [sys.executable, "-c", code, str(ROOT / "tests"), "0.05"]
    first = subprocess.run(run, env=env, capture_output=True, text=True, check=True).stdout
    assert first.startswith("cold") and "being compiled in a background process" in first
    marker = tmp_path / "numba" / first_compile.MARKER
    deadline = time.time() + 1200
    while marker.exists() and time.time() < deadline:
        time.sleep(2)
    assert not marker.exists()
    again = subprocess.run(run, env=env, capture_output=True, text=True, check=True).stdout
    assert again.startswith("cached") and "not loaded in this process" in again
    run[-1] = "4.0"  # 4000 steps: past the budget of short runs
    long = subprocess.run(run, env=env, capture_output=True, text=True, check=True).stdout
    assert long.startswith("cached") and "Python loop" not in long
