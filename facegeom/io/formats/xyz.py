"""XYZ point clouds: one point per line, whitespace-separated columns, the first three used.

Further columns (normals, colours) are ignored; ``#`` comments and blank lines
are skipped. Refused, with the 1-based line number: a line with fewer than
three numbers, a token that is not a number, a NaN/inf coordinate (the point
named 0-based).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from facegeom.errors import InputError
from facegeom.io.formats.common import check_finite, parse_floats, pick, split_rows, text_rows

__all__ = ["read_xyz"]


def read_xyz(path: Path, data: bytes) -> np.ndarray:
    """Parse the XYZ ``data`` read from ``path``.

    Parameters
    ----------
    path : Path
        Named in errors.
    data : bytes
        The whole file.

    Returns
    -------
    (n, 3) float64
        Finite points (``n`` may be 0).

    Raises
    ------
    InputError
        See the module docstring.
    """
    rows, lines = text_rows(data)
    tok, sizes = split_rows(rows)
    short = np.flatnonzero(sizes < 3)
    if short.size:
        raise InputError(f"line {lines[short[0]]}: a point needs three coordinates", path)
    if (sizes != 3).any():
        start = np.cumsum(sizes) - sizes
        tok = pick(tok, (start[:, None] + np.arange(3)).ravel())
    P = parse_floats(tok, lambda i: f"line {lines[i // 3]}", path).reshape(-1, 3)
    check_finite(P, lambda i: f"point {i} (0-based; line {lines[i]})", path)
    return P
