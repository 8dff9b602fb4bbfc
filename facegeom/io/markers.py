"""Marker files: CSV ``vertex_id,x,y,z``, read with clear errors, written atomically.

Positions are in the mesh's units (cm for the ICT face). CSVs with further
columns (marker names...) are read by :mod:`facegeom.io.vertex_csv`.
"""
from __future__ import annotations

import csv
import os
from pathlib import Path

import numpy as np

from facegeom.errors import InputError
from facegeom.interfaces import as_handles, as_vertices
from facegeom.io.files import atomic_path, read_csv_rows
from facegeom.io.ints import check_int64

__all__ = ['MARKER_HEADER', 'read_markers', 'write_markers']


MARKER_HEADER = ("vertex_id", "x", "y", "z")


def read_markers(path: str | os.PathLike, n_vertices: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Read a marker CSV with the header ``vertex_id,x,y,z``.

    Parameters
    ----------
    path : path
    n_vertices : int, optional
        When given, every ``vertex_id`` must lie in ``[0, n_vertices)``.

    Returns
    -------
    ids : (k,) int64, distinct
    positions : (k, 3) float64, finite
    """
    path = Path(path)
    rows = [r for r in read_csv_rows(path, "marker") if any(c.strip() for c in r)]
    if not rows:
        raise InputError("empty marker file (expected the header vertex_id,x,y,z)", path)
    header = tuple(c.strip().lower() for c in rows[0])
    if header != MARKER_HEADER:
        raise InputError(f"wrong columns {','.join(rows[0])!s}; expected the header vertex_id,x,y,z", path)
    if len(rows) == 1:
        raise InputError("no marker rows after the header", path)
    ids, pos = [], []
    for line_no, r in enumerate(rows[1:], start=2):
        if len(r) != 4:
            raise InputError(f"line {line_no}: expected 4 values, got {len(r)}", path)
        try:
            vid = int(r[0])
        except ValueError:
            raise InputError(f"line {line_no}: vertex_id {r[0]!r} is not an integer", path) from None
        check_int64(vid, "vertex_id", line_no, path)
        try:
            xyz = [float(c) for c in r[1:]]
        except ValueError:
            raise InputError(f"line {line_no}: a coordinate is not a number", path) from None
        if not np.all(np.isfinite(xyz)):
            raise InputError(f"line {line_no}: coordinate is NaN or inf", path)
        ids.append(vid)
        pos.append(xyz)
    ids = np.array(ids, dtype=np.int64)
    if (ids < 0).any():
        raise InputError(f"vertex_id {int(ids[ids < 0][0])} is negative", path)
    ids = as_handles(ids, n_vertices if n_vertices is not None else int(ids.max()) + 1, "vertex_id", path)
    return ids, np.array(pos, dtype=np.float64)


def write_markers(path: str | os.PathLike, ids, positions) -> Path:
    """Write a marker CSV (``vertex_id,x,y,z``) atomically.

    Parameters
    ----------
    path : path
        The ``.csv`` to write; its folder must exist.
    ids : (k,) int array
        Distinct, non-negative vertex ids, k >= 1.
    positions : (k, 3) float array
        Finite marker positions (written with full precision).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    InputError
        Empty, repeated or negative ids; positions not ``(k, 3)`` or not
        finite; a different number of ids and positions.
    """
    path = Path(path)
    ids = np.asarray(ids)
    positions = as_vertices(positions, "marker positions")
    ids = as_handles(ids, int(np.max(ids)) + 1 if ids.size else 1, "vertex_id")
    if ids.shape[0] != positions.shape[0]:
        raise InputError(f"{ids.shape[0]} ids but {positions.shape[0]} positions", path)
    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(MARKER_HEADER)
            for i, p in zip(ids.tolist(), positions.tolist()):
                w.writerow([i, repr(p[0]), repr(p[1]), repr(p[2])])
    return path
