"""The one folder of compiled code: CasADi's C libraries, generated numba kernels and numba's cache.

Location: ``$LCP_CACHE_DIR`` when set, else a per-user folder
(``$XDG_CACHE_HOME/lcp-lem/<python>-<platform>``, ``~/.cache/...`` without XDG; ``%LOCALAPPDATA%``
on Windows), and a folder in the temporary directory when that one cannot be written. Entries are
named by a hash of their source, flags and tool versions, so a stale entry is never picked up; the
whole folder can be deleted at any time.

Many processes (Dask workers, pytest-xdist, a shell loop of studies) may want the same entry at
once. Every entry is therefore

- built into a temporary file **in the same folder** and moved into place with :func:`os.replace`
  (atomic within one file system), so a reader never sees a half-written file, and a file already
  loaded by another process is never rewritten in place (rewriting a loaded shared library changes
  the mapped pages under that process, which crashes it later, typically at exit);
- built under an inter-process lock (``fcntl.flock`` on ``<entry>.lock``; ``msvcrt.locking`` on
  Windows), so one process compiles and the others wait and load its result;
- checked before it is loaded, against the SHA-256 digest recorded beside it when it was built: a
  corrupt entry (a truncated file, which the loader would map and then crash on) is rebuilt.

numba's own cache goes to the ``numba/<digest>`` subfolder, named by a digest of the kernels'
sources (:func:`kernel_sources_tag`: numba itself would load a kernel whose callee changed stale):
:func:`configure_numba` sets ``NUMBA_CACHE_DIR`` there unless the user has set it, and :mod:`lcp.numerics.jit` calls it before it
imports numba. Imports nothing of the package.
"""
from __future__ import annotations

from collections.abc import Callable, Iterator
import contextlib
import functools
import hashlib
import os
from pathlib import Path
import re
import sys
import sysconfig
import tempfile
from typing import TypeVar

__all__ = ["ENV_VAR", "cache_dir", "configure_numba", "entry_lock", "write_atomic", "cached_entry", "kernel_sources_tag",
           "numba_cache_dir"]

#: the environment variable that moves the cache
ENV_VAR = "LCP_CACHE_DIR"

T = TypeVar("T")


def _tag() -> str:
    """Python version and platform: compiled code of one interpreter is useless to another."""
    return f"py{sys.version_info[0]}{sys.version_info[1]}-{sysconfig.get_platform()}"


def _user_base() -> Path:
    if sys.platform == "win32":
        local = os.environ.get("LOCALAPPDATA")
        return (Path(local) if local else Path.home() / "AppData" / "Local") / "lcp-lem" / "Cache"
    if sys.platform == "darwin":
        return Path.home() / "Library" / "Caches" / "lcp-lem"
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg and os.path.isabs(xdg) else Path.home() / ".cache") / "lcp-lem"


def _writable(folder: Path) -> bool:
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=folder, prefix=".probe-")
        os.close(fd)
        os.unlink(probe)
        return True
    except OSError:
        return False


def cache_dir() -> Path:
    """The folder of compiled code (created): ``$LCP_CACHE_DIR`` when set, else the per-user cache
    folder ``<user cache>/lcp-lem/<python>-<platform>``, else (not writable) a per-user folder in the
    temporary directory.

    Read on every call, so a process may change ``LCP_CACHE_DIR`` (the tests do) except for numba's
    part, fixed when numba is first configured (:func:`configure_numba`).

    Raises
    ------
    ValueError
        If ``LCP_CACHE_DIR`` is set but is not a folder that can be created and written.
    """
    env = os.environ.get(ENV_VAR)
    if env:
        folder = Path(env).expanduser()
        if not _writable(folder):
            raise ValueError(f"{ENV_VAR}={env!r} is not a folder this process can create and write")
        return folder
    return _default_dir()


@functools.lru_cache(maxsize=1)
def _default_dir() -> Path:
    folder = _user_base() / _tag()
    if _writable(folder):
        return folder
    # a read-only home (containers, some clusters): per user, so that nobody loads another's code
    user = os.getuid() if hasattr(os, "getuid") else os.environ.get("USERNAME", "user")
    folder = Path(tempfile.gettempdir()) / f"lcp-lem-{user}" / _tag()
    folder.mkdir(parents=True, exist_ok=True)
    return folder


#: the packages whose modules may hold numba kernels
_KERNEL_PACKAGES = ("lcp", "lem")


@functools.lru_cache(maxsize=1)
def kernel_sources_tag() -> str:
    """A digest of the sources the numba kernels are compiled from (16 hex digits).

    numba checks a cached kernel against its own file's time stamp only: a kernel whose callee (a
    kernel of another module) or whose global constant (inlined at compile time) changed would be
    loaded stale, silently computing with the old code. The cache therefore lives in a folder named
    by this digest, taken over every module that uses numba and every module of the package those
    import from (their callees and constants); other edits keep the compiled kernels. Reading and
    hashing them costs a few ms once per process. Old folders are left for the user to delete.
    """
    root = Path(__file__).resolve().parents[2]
    digest = hashlib.sha256()
    try:
        sources = {p: p.read_bytes() for pkg in _KERNEL_PACKAGES for p in root.joinpath(pkg).rglob("*.py")}
        chosen = set()
        for path, text in sources.items():
            if b"njit" not in text:
                continue
            chosen.add(path)
            for mod in re.findall(rb"^\s*from\s+((?:lcp|lem)(?:\.\w+)+)\s+import", text, re.M):
                base = root.joinpath(*mod.decode().split("."))
                for cand in (base.with_suffix(".py"), base / "__init__.py"):
                    if cand in sources:
                        chosen.add(cand)
        for path in sorted(chosen):
            digest.update(str(path.relative_to(root)).encode())
            digest.update(sources[path])
    except OSError:  # sources not readable (a zipped install): one folder per process start instead
        digest.update(str(os.getpid()).encode())
    return digest.hexdigest()[:16]


def numba_cache_dir() -> Path:
    """numba's cache folder for this process: ``NUMBA_CACHE_DIR`` when set, else
    ``<cache_dir()>/numba/<kernel_sources_tag()>``."""
    env = os.environ.get("NUMBA_CACHE_DIR")
    return Path(env) if env else cache_dir() / "numba" / kernel_sources_tag()


def configure_numba() -> None:
    """Point numba's cache at ``<cache_dir()>/numba/<kernel_sources_tag()>`` unless
    ``NUMBA_CACHE_DIR`` is already set.

    Must run before numba reads its configuration; where numba was imported earlier (by the user or
    another package) its configuration is reloaded so that the kernels decorated afterwards use it.
    """
    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    try:
        folder = cache_dir() / "numba" / kernel_sources_tag()
        folder.mkdir(parents=True, exist_ok=True)
    except (OSError, ValueError):  # numba's default (__pycache__ beside the sources) then
        return
    os.environ["NUMBA_CACHE_DIR"] = str(folder)
    numba = sys.modules.get("numba")
    if numba is not None:  # already imported: its config was read from the old environment
        numba.config.reload_config()


@contextlib.contextmanager
def entry_lock(entry: Path) -> Iterator[None]:
    """Hold an exclusive inter-process lock for ``entry`` (on ``<entry>.lock``), blocking until free.

    The lock file is left in place: removing it would let a third process lock a new file while the
    second still holds the old one.
    """
    lock_path = entry.with_name(entry.name + ".lock")
    fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        if os.name == "nt":  # pragma: no cover - Windows
            import msvcrt

            while True:
                try:
                    msvcrt.locking(fd, msvcrt.LK_LOCK, 1)
                    break
                except OSError:  # LK_LOCK gives up after 10 s: keep waiting for the compiler
                    continue
            try:
                yield
            finally:
                os.lseek(fd, 0, os.SEEK_SET)
                msvcrt.locking(fd, msvcrt.LK_UNLCK, 1)
        else:
            import fcntl

            fcntl.flock(fd, fcntl.LOCK_EX)
            try:
                yield
            finally:
                fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)


def write_atomic(entry: Path, build: Callable[[Path], None]) -> None:
    """Make ``entry`` by ``build(part)`` writing a temporary file in the same folder, then move it
    into place with :func:`os.replace`. The temporary file is removed if ``build`` fails."""
    fd, part = tempfile.mkstemp(dir=entry.parent, prefix=f".{entry.name}.", suffix=".part")
    os.close(fd)
    try:
        build(Path(part))
        os.replace(part, entry)
    finally:
        if os.path.exists(part):
            os.unlink(part)


def _digest(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _intact(entry: Path) -> bool:
    """Whether ``entry`` has the content recorded in its ``.sha256`` companion when it was built.

    Loading is not a safe test: the loader maps a truncated shared library without complaint and
    the process dies of SIGBUS when it touches the missing pages.
    """
    try:
        return _digest(entry) == entry.with_name(entry.name + ".sha256").read_text().strip()
    except OSError:
        return False


def cached_entry(entry: Path, build: Callable[[Path], None], load: Callable[[Path], T]) -> T:
    """``load(entry)``, building the entry first where it is missing or corrupt.

    An entry is intact when its content has the digest recorded beside it (``<entry>.sha256``,
    written after the entry, both atomically). The fast path (an intact entry) takes no lock.
    Otherwise, under :func:`entry_lock`: check again (another process may have just built it), else
    build, record the digest and load. A corrupt entry (truncated, overwritten) is thus rebuilt, not
    loaded; a load that still fails (for instance when ``load`` raises) falls back to one rebuild.

    Parameters
    ----------
    entry : Path
        The cache file (its folder is created).
    build : callable
        ``build(part)`` writes the entry's content to the path ``part`` (a temporary file beside
        ``entry``); it may raise, and then nothing is cached.
    load : callable
        Loads the entry; its value is returned.
    """
    entry.parent.mkdir(parents=True, exist_ok=True)
    if _intact(entry):
        try:
            return load(entry)
        except Exception:  # an intact file that does not load: rebuilt below, under the lock
            pass
    with entry_lock(entry):
        if _intact(entry):
            try:
                return load(entry)
            except Exception:
                pass
        write_atomic(entry, build)
        digest = _digest(entry)
        write_atomic(entry.with_name(entry.name + ".sha256"), lambda part: part.write_text(digest + "\n"))
        return load(entry)
