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


# ----------------------------------------------------------------------------- figure hygiene
def legend(ax, ncol: int = 1, fontsize: float = 7.5, **kw):
    """A legend beside the axes (right), so that it never covers data, listing only entries a reader can see.

    An entry is dropped when its line has data but none of it is finite inside the axes' limits (an
    off-scale or all-NaN series); a line with no data at all is a deliberate proxy (a marker style
    explained once) and is kept. The figure's layout engine is set to "constrained", which makes
    room for a legend outside the axes.
    """
    from matplotlib.lines import Line2D
    import numpy as np

    ax.figure.set_layout_engine("constrained")
    (x0, x1), (y0, y1) = sorted(ax.get_xlim()), sorted(ax.get_ylim())
    keep = []
    for h, lab in zip(*ax.get_legend_handles_labels()):
        if isinstance(h, Line2D) and len(h.get_xdata()):
            x = np.asarray(h.get_xdata(), dtype=float)
            y = np.asarray(h.get_ydata(), dtype=float)
            inside = np.isfinite(x) & np.isfinite(y) & (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)
            if not inside.any():
                continue
        keep.append((h, lab))
    if not keep:
        return None
    return ax.legend(*zip(*keep), loc="upper left", bbox_to_anchor=(1.01, 1.0), ncol=ncol,
                     fontsize=fontsize, frameon=False, **kw)


def floored(ax, x, y, floor: float, fmt: str = "o-", label: str | None = None, **kw):
    """Plot y >= 0 on a log axis with a floor: values below it are marked, never hidden or mislabelled.

    Values >= floor are drawn as usual. Non-zero values below the floor are drawn at the floor as
    downward triangles ("below <floor>"), exact zeros at the floor as crosses ("exactly 0"), without
    a line through them, and a legend entry says so once per axes (call :func:`legend`).
    """
    import numpy as np

    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    above = np.where(y >= floor, y, np.nan)
    (line,) = ax.plot(x, above, fmt, label=label, **kw)
    color = line.get_color()
    tiny = (y > 0) & (y < floor)
    zero = y == 0
    if tiny.any():
        ax.plot(x[tiny], np.full(tiny.sum(), floor), "v", color=color, mfc="none", ms=7,
                label=f"{label}: below {floor:g}" if label else None)
    if zero.any():
        ax.plot(x[zero], np.full(zero.sum(), floor), "x", color=color, ms=7,
                label=f"{label}: exactly 0" if label else None)
    if label is None and (tiny.any() or zero.any()) and not getattr(ax, "_floor_noted", False):
        # unlabelled series: the legend explains the floor's markers with the markers themselves
        # (proxies without data, which legend() keeps)
        ax.plot([], [], "v", color="0.3", mfc="none", ms=7, ls="none", label=f"below {floor:g} (drawn at it)")
        ax.plot([], [], "x", color="0.3", ms=7, ls="none", label=f"exactly 0 (drawn at {floor:g})")
        ax._floor_noted = True
    return line
