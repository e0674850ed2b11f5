"""Stress of the compiled-code cache: many fresh processes compiling the same code at once.

Run: ``python benchmarks/cache_stress.py [--processes 50] [--rounds 2]``.

Each round starts N new interpreters on one empty cache folder (``LCP_CACHE_DIR``), released
together; each runs a Jean-Pratt scene on the compiled one-contact path (CasADi's C library) and a
batch of 300 scenes (the numba kernel) and prints a digest of its numbers (``tests/cache_race.py``).
Reported: processes that crashed (non-zero exit status, signals included), distinct digests (1
expected), wall time. Two layouts per round: the cache on a different file system than the
temporary folder (``/dev/shm`` against the default temporary folder where both exist: the setting
of the users' report of 3 crashes in 51 processes) and both on the same one.
"""
from __future__ import annotations

import argparse
import os
from pathlib import Path
import shutil
import sys
import tempfile

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.cache_race import race  # noqa: E402


def layouts():
    tmp = Path(tempfile.gettempdir())
    shm = Path("/dev/shm")
    out = []
    if shm.is_dir() and os.access(shm, os.W_OK) and os.stat(shm).st_dev != os.stat(tmp).st_dev:
        out.append(("cache on /dev/shm, temporary folder on " + str(tmp), shm, tmp))
    out.append(("cache and temporary folder on " + str(tmp), tmp, tmp))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--processes", type=int, default=50)
    ap.add_argument("--rounds", type=int, default=1)
    args = ap.parse_args(argv)
    print(f"{args.processes} processes per round, {os.cpu_count()} cores, load {os.getloadavg()}")
    print("| layout | round | crashes | distinct digests | wall (s) |")
    print("|---|---|---|---|---|")
    total = 0
    for name, cache_base, tmp_base in layouts():
        for k in range(args.rounds):
            cache = Path(tempfile.mkdtemp(prefix="lcp-cache-stress-", dir=cache_base))
            tmp = Path(tempfile.mkdtemp(prefix="lcp-tmp-stress-", dir=tmp_base))
            try:
                res = race(args.processes, cache, tmp)
            finally:
                shutil.rmtree(cache, ignore_errors=True)
                shutil.rmtree(tmp, ignore_errors=True)
            total += res.crashes
            print(f"| {name} | {k + 1} | {res.crashes} | {len(set(res.digests))} | {res.wall_s:.0f} |", flush=True)
            for err in res.stderr_tails:
                if err.strip():
                    print("  stderr of a worker:", err[-800:].replace("\n", "\n    "))
                    break
    print(f"crashes in total: {total}")
    return total


if __name__ == "__main__":
    sys.exit(1 if main() else 0)
