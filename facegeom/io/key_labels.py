"""Key labels: the character's markers at a few key frames of a performance, as a CSV a person can edit.

The labels of the marker route (``facegeom animate --character HEAD --route
markers``): at each key frame of the take, where the character's markers are.
One row per labelled marker::

    # comment lines start with '#'
    frame,marker,vertex,x,y,z
    120,0,5123,1.52,-0.31,9.80

- ``frame``: the frame of the take (counted from its first frame, not from the
  window's start);
- ``marker``: the marker's index in the actor's layout (0 .. p - 1);
- ``vertex`` (optional column): the character's vertex carrying the marker; when
  present it must match the head the labels are used with (a file written for
  another head is refused);
- ``x, y, z``: the marker's position in the head's own units and axes (those of
  the head file).

A frame may list only some markers: the others keep their proposed position
(:func:`facegeom.pipelines.character_markers.propose_labels`). The frames
listed are key frames.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facegeom.errors import InputError
from facegeom.io.files import atomic_path, read_csv_rows
from facegeom.io.ints import check_int64

__all__ = ["KeyLabels", "read_key_labels", "write_key_labels", "KEY_LABEL_HEADERS"]

KEY_LABEL_HEADERS = (("frame", "marker", "x", "y", "z"), ("frame", "marker", "vertex", "x", "y", "z"))


@dataclass
class KeyLabels:
    """A key-labels file as read.

    Attributes
    ----------
    frames : (L,) int64
        The key frames (take frames), sorted, distinct.
    labels : (L, p, 3) float64
        The markers at those frames; NaN where the file gives none.
    vertices : (p,) int64 or None
        The character's marker vertices the file names (-1 where it names none), or None without the column.
    path : Path
    """

    frames: np.ndarray
    labels: np.ndarray
    vertices: np.ndarray | None
    path: Path

    def check_vertices(self, marker_vertices) -> None:
        """Refuse a file written for another head: its ``vertex`` column must match ``marker_vertices``."""
        if self.vertices is None:
            return
        mv = np.asarray(marker_vertices, dtype=np.int64)
        given = self.vertices >= 0
        bad = np.flatnonzero(given & (self.vertices != mv))
        if bad.size:
            m = int(bad[0])
            raise InputError(f"marker {m} sits on vertex {int(self.vertices[m])} in the labels but on vertex "
                             f"{int(mv[m])} of this head: the labels were made for another head", self.path)

    def filled(self, proposed) -> np.ndarray:
        """The labels with every marker the file does not give taken from ``proposed (L, p, 3)``."""
        P = np.asarray(proposed, dtype=np.float64)
        return np.where(np.isnan(self.labels), P, self.labels)


def _int(cell: str, what: str, line_no: int, path: Path) -> int:
    try:
        value = int(cell.strip())
    except ValueError:
        raise InputError(f"line {line_no}: {what} {cell.strip()[:40]!r} is not an integer", path) from None
    check_int64(value, what, line_no, path)
    if value < 0:
        raise InputError(f"line {line_no}: {what} {value} is negative", path)
    return value


def read_key_labels(path: str | os.PathLike, n_markers: int, n_frames: int | None = None) -> KeyLabels:
    """Read a key-labels CSV (see the module) for a layout of ``n_markers`` markers.

    ``n_frames``: when given, every frame must lie in ``[0, n_frames)`` (the take's length).

    Raises
    ------
    InputError
        One line naming the file (and the line): not a CSV of these columns, a
        cell that is not a number, a marker outside the layout, a frame outside
        the take, a marker given twice at one frame, one vertex given for two
        markers' rows that disagree, no rows.
    """
    path = Path(path)
    rows = [(i, r) for i, r in enumerate(read_csv_rows(path, "key labels"), start=1)
            if any(c.strip() for c in r) and not r[0].lstrip().startswith("#")]
    if not rows:
        raise InputError("empty key-labels file (expected the header frame,marker,x,y,z)", path)
    header = tuple(c.strip().lower() for c in rows[0][1])
    if header not in KEY_LABEL_HEADERS:
        raise InputError(f"wrong columns {','.join(c.strip() for c in rows[0][1])[:80]}; expected the header "
                         f"frame,marker,x,y,z (or frame,marker,vertex,x,y,z)", path)
    if len(rows) == 1:
        raise InputError("no label rows after the header", path)
    has_vertex = "vertex" in header
    got: dict[tuple[int, int], np.ndarray] = {}
    vertices = np.full(n_markers, -1, dtype=np.int64) if has_vertex else None
    for line_no, r in rows[1:]:
        if len(r) != len(header):
            raise InputError(f"line {line_no}: expected {len(header)} values, got {len(r)}", path)
        frame = _int(r[0], "frame", line_no, path)
        marker = _int(r[1], "marker", line_no, path)
        if marker >= n_markers:
            raise InputError(f"line {line_no}: marker {marker} is outside the layout's {n_markers} markers", path)
        if n_frames is not None and frame >= n_frames:
            raise InputError(f"line {line_no}: frame {frame} is outside the take's {n_frames} frames", path)
        if has_vertex:
            v = _int(r[2], "vertex", line_no, path)
            if vertices[marker] >= 0 and vertices[marker] != v:
                raise InputError(f"line {line_no}: marker {marker} is on vertex {v} here but on vertex "
                                 f"{int(vertices[marker])} on an earlier line", path)
            vertices[marker] = v
        try:
            xyz = np.array([float(c) for c in r[-3:]], dtype=np.float64)
        except ValueError:
            raise InputError(f"line {line_no}: a coordinate is not a number", path) from None
        if not np.isfinite(xyz).all():
            raise InputError(f"line {line_no}: a coordinate is NaN or inf", path)
        if (frame, marker) in got:
            raise InputError(f"line {line_no}: marker {marker} at frame {frame} is given twice", path)
        got[(frame, marker)] = xyz
    frames = np.array(sorted({f for f, _ in got}), dtype=np.int64)
    row = {int(f): i for i, f in enumerate(frames)}
    labels = np.full((frames.size, n_markers, 3), np.nan)
    for (f, m), xyz in got.items():
        labels[row[f], m] = xyz
    return KeyLabels(frames, labels, vertices, path)


def write_key_labels(path: str | os.PathLike, frames, labels, marker_vertices=None, comment: str | None = None) -> Path:
    """Write the labels ``(L, p, 3)`` at take frames ``(L,)`` as a key-labels CSV, atomically.

    ``marker_vertices (p,)``: the character's marker vertices (the ``vertex`` column); ``comment``: lines written
    first, each prefixed with ``#``. Markers that are NaN are left out (they stay proposed when read back).
    """
    path = Path(path)
    frames = np.asarray(frames, dtype=np.int64).reshape(-1)
    L = np.asarray(labels, dtype=np.float64)
    if L.ndim != 3 or L.shape[0] != frames.size or L.shape[2] != 3:
        raise InputError(f"labels must be ({frames.size}, p, 3) for {frames.size} frames, got {L.shape}", path)
    if frames.size == 0 or (frames < 0).any() or np.unique(frames).size != frames.size:
        raise InputError("key frames must be distinct, non-negative and at least one", path)
    if np.isinf(L).any():
        raise InputError("labels contain inf", path)
    mv = None if marker_vertices is None else np.asarray(marker_vertices, dtype=np.int64).reshape(-1)
    if mv is not None and mv.size != L.shape[1]:
        raise InputError(f"{mv.size} marker vertices for {L.shape[1]} markers", path)
    lines = [f"# {c}" for c in (comment or "").splitlines()]
    lines.append("frame,marker,vertex,x,y,z" if mv is not None else "frame,marker,x,y,z")
    for i in np.argsort(frames):
        for m in range(L.shape[1]):
            if np.isnan(L[i, m]).any():
                continue
            v = f"{mv[m]}," if mv is not None else ""
            lines.append(f"{frames[i]},{m},{v}" + ",".join(repr(float(c)) for c in L[i, m]))
    with atomic_path(path) as tmp:
        Path(tmp).write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
