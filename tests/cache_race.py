"""Many fresh processes racing to compile the same code into one empty compiled-code cache.

Used by ``tests/test_compiled_cache.py`` and ``benchmarks/cache_stress.py``. Each worker is a new
interpreter with ``LCP_CACHE_DIR`` set to the shared folder (and no ``NUMBA_CACHE_DIR``, so that
numba's cache is the folder's ``numba`` part); all workers wait for one start time, then run a
Jean-Pratt scene on the compiled one-contact path (CasADi's C library) and a batch of scenes (the
numba kernel), and print a digest of the numbers.
"""
from __future__ import annotations

from dataclasses import dataclass
import os
from pathlib import Path
import subprocess
import sys
import time

ROOT = Path(__file__).resolve().parents[1]

WORKER = r"""
import hashlib, sys, time
import numpy as np
import lcp
from lcp.batch import jean_pratt_constants, simulate_batch
start = float(sys.argv[1])
time.sleep(max(0.0, start - time.time()))
one = lcp.simulate(lcp.scenes.jean_pratt(R=0.4), 0.3, h=1e-3)
batch = simulate_batch(jean_pratt_constants(1.0, 1.0, 0.7, np.linspace(0.1, 0.9, 300), v0=1.5, h=1e-3), 0.3,
                       h=1e-3, path="compiled")
digest = hashlib.sha256()
for a in (one.q, one.v, batch.q, batch.v, batch.slide_steps):
    digest.update(np.ascontiguousarray(a).tobytes())
print("DIGEST", digest.hexdigest(), one.message if hasattr(one, "message") else "", flush=True)
"""


@dataclass
class Race:
    returncodes: list
    digests: list
    stderr_tails: list
    wall_s: float

    @property
    def crashes(self) -> int:
        return sum(rc != 0 for rc in self.returncodes)


def race(n: int, cache: Path, tmpdir: Path | None = None, lead_s: float | None = None) -> Race:
    """Start ``n`` workers on the cache folder ``cache`` (temporary folder ``tmpdir`` if given),
    released together ``lead_s`` seconds after the last one started (default: 1.5 s per 10)."""
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["LCP_CACHE_DIR"] = str(cache)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    if tmpdir is not None:
        env["TMPDIR"] = str(tmpdir)
    # imports take ~1-3 s per process on a loaded machine: release them together after that
    start = time.time() + (lead_s if lead_s is not None else 3.0 + 0.4 * n)
    t0 = time.perf_counter()
    procs = [subprocess.Popen([sys.executable, "-c", WORKER, repr(start)], env=env, cwd=str(ROOT),
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(n)]
    outs = [p.communicate(timeout=3600) for p in procs]
    digests = []
    for out, _ in outs:
        lines = [ln.split()[1] for ln in out.splitlines() if ln.startswith("DIGEST")]
        digests.append(lines[-1] if lines else None)
    return Race([p.returncode for p in procs], digests, [err[-1500:] for _, err in outs], time.perf_counter() - t0)
