"""What every study shares: the command line, headless plotting and CSV writing."""
from __future__ import annotations

import argparse
import csv
import os
from pathlib import Path
from typing import Iterable, Sequence

import matplotlib

# Studies run on machines without a screen (CI, clusters): never pick an interactive backend.
matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after the backend is chosen)


def parse_args(name: str, description: str, argv: Sequence[str] | None = None, extra=None):
    """Parse ``[--out DIR] [--quick]`` (plus study-specific options added by ``extra(parser)``)."""
    p = argparse.ArgumentParser(prog=f"python -m studies.{name}", description=description)
    p.add_argument("--out", type=Path, default=Path("figures") / name,
                   help=f"output folder for PNG figures and CSV data (default figures/{name}/)")
    p.add_argument("--quick", action="store_true",
                   help="small, fast version of the study (what the test suite runs)")
    if extra is not None:
        extra(p)
    return p.parse_args(argv)


def out_dir(out: os.PathLike | str | None, name: str) -> Path:
    """The output folder, created if needed."""
    path = Path(out) if out is not None else Path("figures") / name
    path.mkdir(parents=True, exist_ok=True)
    return path


def write_csv(path: os.PathLike | str, header: Sequence[str], rows: Iterable[Sequence]) -> Path:
    """Write rows with a header line; floats keep full precision (repr) so the data can be re-checked."""
    path = Path(path)
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(list(header))
        for r in rows:
            w.writerow([repr(float(x)) if isinstance(x, float) else x for x in r])
    return path


def save(fig, path: os.PathLike | str, dpi: int = 130) -> Path:
    """Save a figure as PNG and close it (studies never call ``show()``)."""
    path = Path(path)
    fig.savefig(path, dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    return path
