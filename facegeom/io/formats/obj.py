"""Wavefront OBJ: ``v`` and ``f`` records, read and checked with numpy.

Accepted: ``v x y z`` (extra columns such as ``w`` or colours ignored); ``f``
with corners ``v``, ``v/vt``, ``v/vt/vn`` or ``v//vn`` (only ``v`` is used),
positive (1-based) and negative (relative: ``-1`` is the last vertex defined
before the face) indices, polygons of any size; ``\\`` line continuations;
comments (also after the numbers) and every other record (``vt``, ``vn``, ``g``, ``o``, ``s``,
``usemtl``, ``mtllib``, ``l``, ``p``, unknown ones) are ignored. Lines end with
``\\n``, ``\\r\\n`` or (a file without ``\\n``) ``\\r``; leading blanks are allowed.

Refused, with the 1-based line number: a ``v`` line with fewer than three
numbers or a token that is not a number, a NaN/inf coordinate (naming the
vertex 1-based, as OBJ counts), a face with fewer than three corners, a corner
that is not an integer, index 0, an index outside the vertices (quoted as
written in the file).
"""
from __future__ import annotations

import re
from itertools import compress
from pathlib import Path

import numpy as np

from facegeom.errors import InputError
from facegeom.io.formats.common import MeshData, check_finite, parse_floats, parse_ints, pick, split_rows

__all__ = ["read_obj"]

_CONTINUATION = re.compile(rb"\\(\r?\n)")
_CONTINUED = re.compile(rb"^[^\n]*\\\r?\n(?:[^\n]*\\\r?\n)*[^\n]*", re.M)
_SLASH = re.compile(rb"(\S)/\S*")
_BLANK = np.zeros(256, dtype=bool)
_BLANK[[9, 10, 11, 12, 13, 32]] = True
_INDENT = np.zeros(256, dtype=bool)
_INDENT[[9, 11, 12, 32]] = True


def _join(m: re.Match) -> bytes:
    """A line continued by ``\\`` as one line, followed by as many empty lines as it spanned."""
    text = m.group(0)
    return _CONTINUATION.sub(b" ", text) + b"\n" * text.count(b"\n")


def _records(lines: list[bytes], index: np.ndarray, keyword: bytes) -> tuple[list[bytes], np.ndarray]:
    """The tokens after the keyword of the records ``lines[index]`` and how many each has."""
    rows = pick(lines, index)
    if b"#" in keyword.join(rows):  # a comment after the numbers
        rows = [r.split(b"#", 1)[0] for r in rows]
    tokens = b"\n".join(rows).split()
    marks = np.fromiter(map(keyword.__eq__, tokens), dtype=bool, count=len(tokens))
    at = np.flatnonzero(marks)
    if at.size != len(rows):  # the keyword also stands inside a record: count row by row
        return split_rows([r.split(None, 1)[1] if len(r.split(None, 1)) > 1 else b"" for r in rows])
    return list(compress(tokens, (~marks).tolist())), np.diff(np.r_[at, len(tokens)]) - 1


#: Bytes parsed at a time: the per-line and per-token Python objects of one part stay around 30 times its size,
#: so a 250 MB file reads in about its own size plus the arrays, not 4 GB.
CHUNK_BYTES = 8 << 20


def _parts(data: bytes, size: int):
    """``data`` in pieces of about ``size`` bytes cut after a newline, each with the number of lines before it."""
    start, line0 = 0, 0
    while start < len(data):
        end = data.find(b"\n", min(start + size, len(data)) - 1)
        end = len(data) if end < 0 else end + 1
        part = data[start:end]
        yield part, line0
        line0 += part.count(b"\n")
        start = end


def _parse_part(path: Path, data: bytes, line0: int, faces: bool):
    """The ``v`` and ``f`` records of one part starting after line ``line0``: vertices, their line numbers, the
    raw face corner indices, corners per face and the faces' line numbers (1-based, of the whole file)."""
    lines = data.split(b"\n")
    starts = np.r_[0, np.flatnonzero(np.frombuffer(data, dtype=np.uint8) == 10) + 1]
    padded = np.r_[np.frombuffer(data, dtype=np.uint8), 10, 10]
    if _INDENT[padded[starts]].any():
        lines = list(map(bytes.lstrip, lines))
        head = np.array([ln[:2].ljust(2, b"\n") for ln in lines], dtype="S2").view(np.uint8).reshape(-1, 2)
        first, second = head[:, 0], head[:, 1]
    else:
        first, second = padded[starts], padded[starts + 1]
    vlines = np.flatnonzero((first == ord("v")) & _BLANK[second])
    vtok, vsizes = _records(lines, vlines, b"v")
    vlines = vlines + 1 + line0
    short = np.flatnonzero(vsizes < 3)
    if short.size:
        raise InputError(f"line {vlines[short[0]]}: a vertex needs three coordinates", path)
    if (vsizes != 3).any():  # keep x y z of longer rows (w, colours)
        begin = np.cumsum(vsizes) - vsizes
        keep = (begin[:, None] + np.arange(3)).ravel()
        vtok = pick(vtok, keep)
    row_of_token = lambda i: f"line {vlines[i // 3]}"  # noqa: E731
    V = parse_floats(vtok, row_of_token, path).reshape(-1, 3)
    del vtok
    empty = np.zeros(0, np.int64)
    if not faces:
        return V, vlines, empty, empty, empty
    flines = np.flatnonzero((first == ord("f")) & _BLANK[second])
    ftok, fsizes = _records(lines, flines, b"f")
    del lines
    if b"/" in data:
        ftok = [_SLASH.sub(rb"\1", t) if b"/" in t else t for t in ftok]
    flines = flines + 1 + line0
    short = np.flatnonzero(fsizes < 3)
    if short.size:
        k = short[0]
        raise InputError(f"line {flines[k]}: a face needs at least 3 vertices, got {fsizes[k]}", path)
    face_of = np.repeat(np.arange(fsizes.size), fsizes)
    raw = parse_ints(ftok, lambda i: f"line {flines[face_of[i]]}", path)
    return V, vlines, raw, fsizes, flines


def read_obj(path: Path, data: bytes, faces: bool = True) -> MeshData:
    """Parse the OBJ ``data`` read from ``path``.

    Parameters
    ----------
    path : Path
        Named in errors.
    data : bytes
        The whole file.
    faces : bool
        Parse the ``f`` records; ``False`` reads the vertices only (point clouds).

    Returns
    -------
    MeshData
        ``(n, 3)`` vertices and the polygons (0-based), not triangulated.

    Raises
    ------
    InputError
        See the module docstring.
    """
    if b"\n" not in data:
        data = data.replace(b"\r", b"\n")
    if b"\\" in data:  # join continued lines; the empty lines added after them keep the line numbers
        data = _CONTINUED.sub(_join, data)
    got = [_parse_part(path, part, line0, faces) for part, line0 in _parts(data, CHUNK_BYTES)]
    if not got:
        got = [_parse_part(path, data, 0, faces)]
    V = np.concatenate([g[0] for g in got]) if len(got) > 1 else got[0][0]
    vlines = np.concatenate([g[1] for g in got])
    check_finite(V, lambda i: f"vertex {i + 1} (line {vlines[i]})", path)
    n = V.shape[0]
    if not faces:
        return MeshData(V, np.zeros(0, np.int64), np.zeros(1, np.int64))
    raw = np.concatenate([g[2] for g in got])
    fsizes = np.concatenate([g[3] for g in got])
    flines = np.concatenate([g[4] for g in got])
    del got
    before = np.searchsorted(vlines, flines)  # vertices defined before each face
    offsets = np.r_[0, np.cumsum(fsizes)].astype(np.int64)
    face_of = np.repeat(np.arange(fsizes.size), fsizes)
    before = before[face_of]
    idx = np.where(raw < 0, before + raw, raw - 1)
    bad = np.flatnonzero((raw == 0) | (idx < 0) | (idx >= n))
    if bad.size:
        i = bad[0]
        line = flines[face_of[i]]
        if raw[i] == 0:
            raise InputError(f"line {line}: vertex index 0 (OBJ indices start at 1)", path)
        if raw[i] < 0:
            raise InputError(f"line {line}: relative vertex index {raw[i]} is outside the "
                             f"{before[i]} vertices defined before it", path)
        raise InputError(f"line {line}: vertex index {raw[i]} is outside 1..{n}", path)
    return MeshData(V, idx.astype(np.int64, copy=False), offsets)
