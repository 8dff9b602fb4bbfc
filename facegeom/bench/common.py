"""Helpers shared by the benchmark protocols: timing, tables, CSV (method specs: :mod:`facegeom.registry`)."""
from __future__ import annotations

import csv
import platform
import time
from pathlib import Path

import numpy as np

from facegeom.errors import InputError
from facegeom.io import atomic_path

__all__ = ["median_time", "write_csv", "format_table", "machine_note"]


def median_time(fn, repeat: int = 5) -> tuple[float, object]:
    """Median wall time of ``fn()`` over ``repeat`` calls (seconds) and the last result."""
    times, out = [], None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times)), out


def write_csv(path: Path, rows: list[dict]) -> Path:
    if not rows:
        raise InputError("nothing to write", path)
    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
    return path


def format_table(header: list[str], rows: list[list]) -> str:
    """A GitHub-markdown table."""
    def fmt(x):
        if isinstance(x, float):
            return f"{x:.3g}" if abs(x) < 1000 else f"{x:.0f}"
        return str(x)
    cells = [[fmt(c) for c in r] for r in rows]
    widths = [max(len(h), *(len(r[i]) for r in cells)) for i, h in enumerate(header)]
    line = lambda r: "| " + " | ".join(c.ljust(w) for c, w in zip(r, widths)) + " |"  # noqa: E731
    return "\n".join([line(header), "|" + "|".join("-" * (w + 2) for w in widths) + "|", *map(line, cells)])


def machine_note() -> str:
    import os

    return f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"
