"""OFF (Object File Format): ``OFF``, ``COFF``, ``NOFF``, ``STOFF`` and their combinations.

Accepted: the keyword ``[ST][C][N]OFF`` with the counts ``vertices faces
[edges]`` on the same line or the next one; ``#`` comments, blank lines and
leading blanks anywhere; the counts glued to the keyword (``OFF8 6 12``); one
vertex or face per line, as every writer does. Columns after ``x y z``
(normals, colours, texture coordinates) and after a face's indices (its colour)
are ignored; lines after the last face too. A face section whose faces wrap
over several lines (one index per line, as some tools write) is read as a
stream of values when the per-line reading fails and the stream holds exactly
the announced faces and nothing else.

Checked before anything is allocated: the counts against the file size (a
vertex line holds at least 6 bytes, a face line 8) and against the lines that
follow. Refused, with the 1-based line number: a missing keyword, ``4OFF`` /
``nOFF`` (not 3-D), a short line, a NaN/inf coordinate (the vertex named
0-based, as OFF counts), a face with fewer than three corners, an index outside
the vertices.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from facegeom.errors import InputError
from facegeom.io.formats.common import MeshData, check_finite, parse_floats, parse_ints, pick, split_rows, text_rows

__all__ = ["read_off"]

_KEYWORD = re.compile(rb"(ST)?C?N?(4)?(n)?OFF")
_GLUED = re.compile(rb"((?:ST)?C?N?4?n?OFF)(\d+)")


def _stream_faces(rows: list[bytes], nf: int, n_vertices: int, path: Path) -> tuple[np.ndarray, np.ndarray] | None:
    """Faces read as one stream of values ``k i_1 .. i_k`` (lines not significant), or ``None``.

    ``None`` unless the stream holds exactly ``nf`` faces of at least three
    in-range corners and no value after them (so colour columns are never
    taken for faces).
    """
    tok = b" ".join(rows).split()
    counts, corners, pos = [], [], 0
    for _ in range(nf):
        if pos >= len(tok) or not tok[pos].isdigit():
            return None
        k = int(tok[pos])
        if k < 3 or pos + 1 + k > len(tok) or not all(t.isdigit() for t in tok[pos + 1:pos + 1 + k]):
            return None
        counts.append(k)
        corners.extend(int(t) for t in tok[pos + 1:pos + 1 + k])
        pos += 1 + k
    if pos != len(tok) or (corners and max(corners) >= n_vertices):
        return None
    return np.asarray(corners, np.int64), np.r_[0, np.cumsum(counts)].astype(np.int64)


def _counts(tokens: list[bytes], line: int, path: Path) -> tuple[int, int]:
    if len(tokens) not in (2, 3) or not all(t.isdigit() for t in tokens):
        raise InputError(f"line {line}: expected the counts 'vertices faces edges' (non-negative integers)", path)
    return int(tokens[0]), int(tokens[1])


def read_off(path: Path, data: bytes, faces: bool = True) -> MeshData:
    """Parse the OFF ``data`` read from ``path``.

    Parameters
    ----------
    path : Path
        Named in errors.
    data : bytes
        The whole file.
    faces : bool
        Parse the faces; ``False`` reads the vertices only (point clouds).

    Returns
    -------
    MeshData
        ``(n, 3)`` vertices and the polygons (0-based), not triangulated.

    Raises
    ------
    InputError
        See the module docstring.
    """
    rows, lines = text_rows(data)
    head = rows[0].split() if rows else []
    glued = _GLUED.fullmatch(head[0]) if head else None
    if glued:  # "OFF8 6 12": the counts start right after the keyword
        head = [glued.group(1), glued.group(2)] + head[1:]
    keyword = _KEYWORD.fullmatch(head[0]) if head else None
    if keyword is None:
        raise InputError("not an OFF file (the first line is not OFF, COFF, NOFF, STOFF, ...)", path)
    if keyword.group(2) or keyword.group(3):
        raise InputError("only 3-D OFF files are supported (not 4OFF / nOFF)", path)
    if len(head) > 1:
        (nv, nf), first = _counts(head[1:], lines[0], path), 1
    elif len(rows) > 1:
        (nv, nf), first = _counts(rows[1].split(), lines[1], path), 2
    else:
        raise InputError("truncated after the OFF keyword: no vertex and face counts", path)
    if nv * 6 + nf * 8 > len(data) + 1 or first + nv + nf > len(rows):
        raise InputError(f"truncated: the header announces {nv} vertices and {nf} faces, "
                         f"the file holds {len(rows) - first} lines after it", path)
    vlines = lines[first:first + nv]
    tok, sizes = split_rows(rows[first:first + nv])
    short = np.flatnonzero(sizes < 3)
    if short.size:
        raise InputError(f"line {vlines[short[0]]}: a vertex needs three coordinates", path)
    if (sizes != 3).any():
        start = np.cumsum(sizes) - sizes
        tok = pick(tok, (start[:, None] + np.arange(3)).ravel())
    V = parse_floats(tok, lambda i: f"line {vlines[i // 3]}", path).reshape(-1, 3)
    check_finite(V, lambda i: f"vertex {i} (0-based; line {vlines[i]})", path)
    if not faces:
        return MeshData(V, np.zeros(0, np.int64), np.zeros(1, np.int64))
    flines = lines[first + nv:first + nv + nf]
    tok, sizes = split_rows(rows[first + nv:first + nv + nf])
    start = np.cumsum(sizes) - sizes
    k = parse_ints(pick(tok, start), lambda i: f"line {flines[i]}", path)
    bad = np.flatnonzero((k < 3) | (k >= sizes))
    if bad.size:
        streamed = _stream_faces(rows[first + nv:], nf, V.shape[0], path)
        if streamed is not None:
            return MeshData(V, *streamed)
        f = bad[0]
        problem = f"a face needs at least 3 vertices, got {k[f]}" if k[f] < 3 else \
            f"the face announces {k[f]} vertices but lists {sizes[f] - 1}"
        raise InputError(f"line {flines[f]}: {problem}", path)
    offsets = np.r_[0, np.cumsum(k)].astype(np.int64)
    face_of = np.repeat(np.arange(k.size), k)
    at = np.repeat(start + 1, k) + np.arange(face_of.size) - offsets[:-1][face_of]
    corners = parse_ints(pick(tok, at), lambda i: f"line {flines[face_of[i]]}", path)
    bad = np.flatnonzero((corners < 0) | (corners >= V.shape[0]))
    if bad.size:
        raise InputError(f"line {flines[face_of[bad[0]]]}: vertex index {corners[bad[0]]} is outside "
                         f"0..{V.shape[0] - 1}", path)
    return MeshData(V, corners, offsets)
