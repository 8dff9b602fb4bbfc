"""Vertex-indexed CSV files (markers, landmarks, any CSV with a ``vertex_id`` column).

:func:`read_vertex_csv` keeps every column as text, so a marker file with extra
columns (names, labels) can be checked against a mesh and its rows named in
messages; the strict formats are read by :mod:`facegeom.io.markers` and
:mod:`facegeom.io.fitfiles`.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facegeom.errors import InputError
from facegeom.io.ints import check_int64

__all__ = ['VertexCSV', 'read_vertex_csv']


@dataclass
class VertexCSV:
    """A CSV with a ``vertex_id`` column (markers, landmarks); other columns are kept verbatim.

    Attributes
    ----------
    path : Path
        The file read.
    header : list of str
        Column names as written (stripped, case kept).
    rows : list of list of str
        The k data rows, every cell as text.
    ids : (k,) int64
        The ``vertex_id`` of each row, distinct and in ``[0, n_vertices)``.
    lines : (k,) int
        1-based line number of each row in the file.
    id_col : int
        Index of the ``vertex_id`` column.
    """

    path: Path
    header: list[str]
    rows: list[list[str]]
    ids: np.ndarray
    lines: np.ndarray
    id_col: int

    def label(self, k: int) -> str:
        """How a row is named in messages: its name column if any, else its line."""
        for key in ("name", "marker", "label", "landmark"):
            if key in self.header:
                return f"marker {self.rows[k][self.header.index(key)].strip()!r} (line {self.lines[k]}, " \
                       f"vertex_id {self.ids[k]})"
        return f"marker on line {self.lines[k]} (vertex_id {self.ids[k]})"


def read_vertex_csv(path: str | os.PathLike, n_vertices: int) -> VertexCSV:
    """Read a marker (``vertex_id,x,y,z``), landmark (``vertex_id,u,v``) or any CSV with a ``vertex_id`` column.

    The marker and landmark formats are checked by their own readers
    (:func:`facegeom.io.markers.read_markers`, :func:`facegeom.io.fitfiles.read_landmarks`);
    ids must be distinct and in ``[0, n_vertices)``.
    """
    from facegeom.io.files import read_csv_rows
    from facegeom.io.markers import MARKER_HEADER, read_markers

    path = Path(path)
    raw = read_csv_rows(path, "marker")
    numbered = [(i + 1, r) for i, r in enumerate(raw) if any(c.strip() for c in r)]
    if not numbered:
        raise InputError("empty marker file (expected a header with a vertex_id column)", path)
    header = [c.strip().lower() for c in numbered[0][1]]
    if tuple(header) == MARKER_HEADER:
        read_markers(path, n_vertices=n_vertices)
    elif tuple(header) == ("vertex_id", "u", "v"):
        from facegeom.io.fitfiles import read_landmarks

        ids_l, _ = read_landmarks(path)
        if ids_l.size and ids_l.max() >= n_vertices:
            raise InputError(f"vertex_id {int(ids_l.max())} is out of range: the mesh has {n_vertices} vertices",
                             path)
    if "vertex_id" not in header:
        raise InputError(f"no vertex_id column in the header {','.join(numbered[0][1])}", path)
    col = header.index("vertex_id")
    body = numbered[1:]
    if not body:
        raise InputError("no marker rows after the header", path)
    ids, lines, rows = [], [], []
    for line_no, r in body:
        if len(r) != len(header):
            raise InputError(f"line {line_no}: expected {len(header)} values, got {len(r)}", path)
        try:
            vid = int(r[col])
        except ValueError:
            raise InputError(f"line {line_no}: vertex_id {r[col]!r} is not an integer", path) from None
        check_int64(vid, "vertex_id", line_no, path)
        if not 0 <= vid < n_vertices:
            raise InputError(f"line {line_no}: vertex_id {vid} is out of range: the mesh has {n_vertices} vertices",
                             path)
        ids.append(vid)
        lines.append(line_no)
        rows.append(r)
    ids = np.array(ids, dtype=np.int64)
    uniq, cnt = np.unique(ids, return_counts=True)
    if (cnt > 1).any():
        raise InputError(f"vertex_id {int(uniq[cnt > 1][0])} is repeated", path)
    return VertexCSV(path, [c.strip() for c in numbered[0][1]], rows, ids, np.array(lines), col)
