"""Helpers shared by the benchmark protocols: timing (method specs: :mod:`facegeom.registry`; reports: :mod:`facegeom.bench.report`)."""
from __future__ import annotations

import time

import numpy as np

__all__ = ["median_time"]


def median_time(fn, repeat: int = 5) -> tuple[float, object]:
    """Median wall time of ``fn()`` over ``repeat`` calls (seconds) and the last result."""
    times, out = [], None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times)), out
