"""The compiled-code cache: where it is, atomic and locked entries, corrupt entries rebuilt, and
many fresh processes compiling the same code at once."""
import os
from pathlib import Path
import subprocess
import sys
import threading

import pytest

from lcp.numerics import cache
from lcp.timestepping import compiled_step
from tests.cache_race import ROOT, race


def test_cache_dir_from_the_environment_and_by_default(tmp_path, monkeypatch):
    monkeypatch.setenv("LCP_CACHE_DIR", str(tmp_path / "a" / "b"))
    assert cache.cache_dir() == tmp_path / "a" / "b" and (tmp_path / "a" / "b").is_dir()
    monkeypatch.delenv("LCP_CACHE_DIR")
    default = cache.cache_dir()
    assert "lcp-lem" in default.parts and default.name.startswith(f"py{sys.version_info[0]}{sys.version_info[1]}-")
    (tmp_path / "file").write_text("")
    monkeypatch.setenv("LCP_CACHE_DIR", str(tmp_path / "file" / "sub"))  # below a regular file
    with pytest.raises(ValueError, match="LCP_CACHE_DIR"):
        cache.cache_dir()


@pytest.mark.parametrize("user_numba_dir", [False, True])
def test_numba_cache_in_the_cache_folder_unless_the_user_set_it(tmp_path, user_numba_dir):
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env.update(LCP_CACHE_DIR=str(tmp_path / "c"), PYTHONPATH=str(ROOT))
    if user_numba_dir:
        env["NUMBA_CACHE_DIR"] = str(tmp_path / "mine")
    code = "import lcp.numerics.jit, numba; print(numba.config.CACHE_DIR)"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    expected = tmp_path / "mine" if user_numba_dir else tmp_path / "c" / "numba" / cache.kernel_sources_tag()
    assert Path(out.stdout.strip()) == expected


def test_numba_folder_changes_with_any_kernel_module(tmp_path):
    """numba checks only a kernel's own file: the folder's digest must move when a callee's module
    (another kernel file) or a constant module changes, and not with the rest of the package."""
    import shutil

    copy = tmp_path / "pkg"
    for part in ("lcp", "lem"):
        shutil.copytree(ROOT / part, copy / part, ignore=shutil.ignore_patterns("__pycache__"))
    code = "from lcp.numerics import cache; print(cache.kernel_sources_tag())"

    def tag():
        env = dict(os.environ, PYTHONPATH=str(copy))
        return subprocess.run([sys.executable, "-c", code], env=env, cwd=copy, capture_output=True, text=True,
                              check=True).stdout.strip()

    base = tag()
    assert base == cache.kernel_sources_tag()  # same sources, same folder
    law = copy / "lcp" / "contact" / "law.py"
    law.write_text(law.read_text() + "\n# changed\n")
    changed = tag()
    assert changed != base
    other = copy / "lcp" / "ocp" / "problem.py"  # not compiled by numba
    other.write_text(other.read_text() + "\n# changed\n")
    assert tag() == changed


def test_entries_are_built_once_and_rebuilt_when_corrupt(tmp_path):
    entry = tmp_path / "x" / "thing.bin"
    builds = []

    def build(part):
        builds.append(part)
        assert part.parent == entry.parent and part != entry  # beside the entry, never the entry itself
        part.write_bytes(b"0123456789" * 100)

    assert cache.cached_entry(entry, build, Path.read_bytes) == b"0123456789" * 100
    assert cache.cached_entry(entry, build, Path.read_bytes) == b"0123456789" * 100
    assert len(builds) == 1
    with open(entry, "r+b") as fh:  # truncated, as by a full disk or a killed copy
        fh.truncate(37)
    assert cache.cached_entry(entry, build, Path.read_bytes) == b"0123456789" * 100
    assert len(builds) == 2
    with pytest.raises(RuntimeError, match="no compiler"):
        cache.cached_entry(tmp_path / "y" / "fails", lambda part: (_ for _ in ()).throw(RuntimeError("no compiler")),
                           Path.read_bytes)
    assert sorted(p.name for p in (tmp_path / "y").iterdir()) == ["fails.lock"]  # no entry, no partial file


def test_threads_wait_for_one_build(tmp_path):
    """The lock is taken per open file, so it serializes threads of one process too."""
    entry = tmp_path / "e"
    builds, results = [], []
    gate = threading.Barrier(6)

    def build(part):
        builds.append(1)
        part.write_text("built")

    def worker():
        gate.wait()
        results.append(cache.cached_entry(entry, build, Path.read_text))

    threads = [threading.Thread(target=worker) for _ in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert results == ["built"] * 6 and len(builds) == 1


@pytest.mark.skipif(compiled_step.c_compiler() is None, reason="no C compiler")
def test_truncated_library_rebuilt_not_loaded(tmp_path, monkeypatch):
    monkeypatch.setenv("LCP_CACHE_DIR", str(tmp_path))
    code = b"double twice(double x) { return 2.0 * x; }\n"
    assert compiled_step.build_library("t", code, load=lambda p: Path(p).read_bytes()) is not None
    (lib,) = tmp_path.glob("t_*.so")
    size = lib.stat().st_size
    lib.write_bytes(lib.read_bytes()[:1000])  # dlopen would map this and die of SIGBUS on use
    rebuilt = compiled_step.build_library("t", code, load=lambda p: Path(p).read_bytes())
    assert len(rebuilt) == size


def test_eight_processes_compile_the_same_code_at_once(tmp_path):
    """One empty cache, 8 fresh processes released together: no crash, the same numbers; then the
    C library and the numba kernel's module truncated: a new process rebuilds them, same numbers."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    res = race(8, tmp_path / "cache", tmp)
    assert res.crashes == 0, res.stderr_tails
    assert None not in res.digests and len(set(res.digests)) == 1
    names = sorted(p.name for p in (tmp_path / "cache").iterdir())
    assert not [n for n in names if n.endswith(".part") or n.endswith(".c")]  # nothing half-done left
    assert sum(n.endswith(".so") for n in names) == 1
    for pattern in ("lcp_mj_run_*.so", "lcp_batch_*.py"):
        (entry,) = (tmp_path / "cache").glob(pattern)
        entry.write_bytes(entry.read_bytes()[:200])
    again = race(1, tmp_path / "cache", tmp, lead_s=0.0)
    assert again.crashes == 0, again.stderr_tails
    assert again.digests == res.digests[:1]


@pytest.mark.slow
def test_fifty_processes_compile_the_same_code_at_once(tmp_path):
    res = race(50, tmp_path / "cache", tmp_path)
    assert res.crashes == 0, [e for e in res.stderr_tails if e.strip()][:3]
    assert None not in res.digests and len(set(res.digests)) == 1


def test_numba_is_a_core_dependency():
    """`pip install .` brings the compiled loops; the test extra does not have to."""
    tomllib = pytest.importorskip("tomllib")
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert any(d.replace(" ", "").startswith("numba>=") for d in project["dependencies"])
    assert project["optional-dependencies"]["fast"] == []  # kept so that old install lines work
