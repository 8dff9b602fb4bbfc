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

Limits
------
- A file over 8 MiB (:data:`MAX_KEY_LABEL_BYTES`) is refused by its size
  before it is read: labels are a few key frames (10 by default, tens when
  edited) of the layout's 80 markers, about 60 bytes a row (50 key frames:
  250 kB); 8 MiB holds over 1,500 key frames.
- A coordinate beyond 1e12 (:data:`MAX_COORDINATE`, what every mesh reader
  refuses) is refused naming its line and value.
- Where the labels meet the head (:func:`check_labels_on_head`, before any
  work): a label more than the head's size outside the head's bounding box
  (:data:`MAX_OUTSIDE`: labels of another head, or in other units), and the
  labels of a key frame squashed to one point, one line or one plane, or to
  less than a quarter of the spread of the face's markers as proposed
  (:data:`MIN_SPREAD`) are refused in one line, naming the key frame.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facegeom.errors import InputError
from facegeom.io.files import atomic_path
from facegeom.io.ints import check_int64

__all__ = ["KeyLabels", "read_key_labels", "write_key_labels", "check_labels_on_head", "KEY_LABEL_HEADERS",
           "MAX_KEY_LABEL_BYTES", "MAX_COORDINATE", "MAX_OUTSIDE", "MIN_SPREAD"]

KEY_LABEL_HEADERS = (("frame", "marker", "x", "y", "z"), ("frame", "marker", "vertex", "x", "y", "z"))

#: A key-labels file larger than this is refused before it is read: labels are a few key frames (10 by default,
#: tens when edited) of the layout's 80 markers at ~60 bytes a row (50 key frames: 250 kB); 8 MiB holds over
#: 1,500 key frames and reads in ~5 s and under 200 MB (100 MB once took 2.5 GB before its refusal).
MAX_KEY_LABEL_BYTES = 8 << 20

#: A coordinate beyond this is refused (as by every mesh reader, :data:`facegeom.io.mesh.MAX_COORDINATE`): no real
#: head reaches it in any unit, and the retargeter's squared distances would overflow (1e308 was an IndexError).
MAX_COORDINATE = 1e12

#: A label farther than this many head sizes (the diagonal of the head's bounding box) outside that box is refused:
#: markers sit on the face and move millimetres to centimetres; one a head's size away is a label of another head
#: or in other units.
MAX_OUTSIDE = 1.0

#: A key frame's labels spreading less than this fraction of the face's markers as proposed (along each of their
#: three main axes) are refused: no expression shrinks the face to a quarter of its size, or flattens it onto a
#: line or a plane; such labels (all at one point, 2-D labels, metres for a head in centimetres) squash the head.
MIN_SPREAD = 0.25


def _q(text: str) -> str:
    text = text.strip()
    return repr(text if len(text) <= 80 else text[:80] + "…")


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
        raise InputError(f"line {line_no}: {what} {_q(cell)} is not an integer", path) from None
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
        One line naming the file (and the line): a file over
        :data:`MAX_KEY_LABEL_BYTES` (refused before it is read), not a CSV of
        these columns, a cell that is not a number, a coordinate beyond
        :data:`MAX_COORDINATE`, a marker outside the layout, a frame outside
        the take, a marker given twice at one frame, one vertex given for two
        markers' rows that disagree, no rows.
    """
    from facegeom.io.shape_names import _capped_csv_rows

    path = Path(path)
    read = _capped_csv_rows(path, MAX_KEY_LABEL_BYTES, "key-labels CSV",
                            "labels are a few key frames of 80 markers, tens of kB")
    rows = [(i, r) for i, r in enumerate(read, start=1)
            if any(c.strip() for c in r) and not r[0].lstrip().startswith("#")]
    if not rows:
        raise InputError("empty key-labels file (expected the header frame,marker,x,y,z)", path)
    header = tuple(c.strip().lower() for c in rows[0][1])
    if header not in KEY_LABEL_HEADERS:
        raise InputError(f"wrong columns {_q(','.join(c.strip() for c in rows[0][1]))}; expected the header "
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
        big = np.flatnonzero(np.abs(xyz) > MAX_COORDINATE)
        if big.size:
            raise InputError(f"line {line_no}: {'xyz'[big[0]]} {_q(r[-3 + int(big[0])])} is beyond "
                             f"{MAX_COORDINATE:g}, which no head reaches in any unit", path)
        if (frame, marker) in got:
            raise InputError(f"line {line_no}: marker {marker} at frame {frame} is given twice", path)
        got[(frame, marker)] = xyz
    frames = np.array(sorted({f for f, _ in got}), dtype=np.int64)
    row = {int(f): i for i, f in enumerate(frames)}
    labels = np.full((frames.size, n_markers, 3), np.nan)
    for (f, m), xyz in got.items():
        labels[row[f], m] = xyz
    return KeyLabels(frames, labels, vertices, path)


def _spreads(P: np.ndarray) -> np.ndarray:
    """The RMS spread of points ``(p, 3)`` along their three main axes, widest first."""
    C = P - P.mean(axis=0)
    return np.linalg.svd(C, compute_uv=False) / np.sqrt(max(len(P), 1))


def check_labels_on_head(labels, keys, head_vertices=None, proposed=None, path=None, first_frame: int = 0) -> None:
    """Refuse labels no head has, in one line naming ``path`` (the key-labels file, if any) and the key frame.

    Parameters
    ----------
    labels : (L, p, 3)
        The labels at the key frames, NaN where none is given.
    keys : (L,) int
        The key frames (``first_frame`` is added when they are named: take frames).
    head_vertices : (n, 3), optional
        The head: every given label must lie within :data:`MAX_OUTSIDE` head sizes of its bounding box.
    proposed : (L, p, 3), optional
        The labels proposed at the key frames (the face's markers where the registration puts them): the labels of
        each key frame that gives any, the others filled from ``proposed``, must spread at least
        :data:`MIN_SPREAD` of the proposal's spread along each of their three main axes (not at one point, on
        one line or in one plane, not a fraction of the face's size).
    """
    L = np.asarray(labels, dtype=np.float64)
    keys = np.asarray(keys).reshape(-1)
    if L.ndim != 3 or L.shape[0] != keys.size or L.shape[2] != 3:
        return  # not labels of these key frames: the caller's shape check says so
    given = ~np.isnan(L).any(axis=2)

    def fail(k: int, what: str):
        raise InputError(f"key frame {int(keys[k]) + first_frame}: {what}", path)

    if head_vertices is not None:
        V = np.asarray(head_vertices, dtype=np.float64)
        lo, hi = V.min(axis=0), V.max(axis=0)
        size = float(np.linalg.norm(hi - lo))
        with np.errstate(invalid="ignore"):
            out = given & ((L < lo - MAX_OUTSIDE * size) | (L > hi + MAX_OUTSIDE * size)).any(axis=2)
        if out.any():
            k, m = (int(i) for i in np.argwhere(out)[0])
            x, y, z = L[k, m]
            fail(k, f"marker {m}'s label ({x:g}, {y:g}, {z:g}) lies more than the head's size ({size:.3g}) outside "
                    "the head: labels of another head, or in other units?")
    if proposed is not None:
        P = np.asarray(proposed, dtype=np.float64)
        full = np.where(given[..., None], L, P)
        for k in np.flatnonzero(given.any(axis=1)):
            s, ref = _spreads(full[k]), _spreads(P[k])
            if not (np.isfinite(ref).all() and ref[2] > 0):
                continue  # no proposal to measure the face by
            if s[0] <= 1e-9 * ref[0]:
                fail(k, f"the labels put all {L.shape[1]} markers at one point: that squashes the head")
            if s[0] < MIN_SPREAD * ref[0]:
                fail(k, f"the labels spread {s[0]:.3g} at most, under {MIN_SPREAD:g} of the {ref[0]:.3g} the face's "
                        "markers spread: that squashes the head (labels in other units?)")
            for axis, shape in ((1, "one line"), (2, "one plane")):
                if s[axis] < MIN_SPREAD * ref[axis]:
                    fail(k, f"the labels put the markers on {shape} (spread {s[axis]:.3g} across it, under "
                            f"{MIN_SPREAD:g} of the face's {ref[axis]:.3g}): that squashes the head"
                            + (" (2-D labels?)" if axis == 2 else ""))


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
