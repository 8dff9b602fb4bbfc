"""PLY (ascii, binary_little_endian, binary_big_endian), read and checked with numpy.

Accepted: elements in any order; a ``vertex`` element whose ``x``, ``y``, ``z``
have any numeric type, next to any other properties (normals, colours,
quality, texture coordinates, lists); a ``face`` element with a list
``vertex_indices`` (or ``vertex_index``) of any integer count and index types,
next to other properties, other lists included (per-face texture coordinates);
polygons of any size, mixed; a ``tristrips`` element (triangle strips, ``-1``
restarting a strip, as in scanners' and old Stanford files), as triangles; every other element (edges, materials, ...) is
skipped, in every encoding; ``comment`` and ``obj_info`` lines.

Checked before anything is allocated: the magic, the format, element counts
(non-negative integers), property types; the bytes (binary) or values (ascii)
that the header implies against what the file holds. A list count is read and
checked against the bytes that remain before it is followed. Truncation
anywhere is an error naming the element ("truncated in the face section"),
never zeros. Trailing data: blanks (and, in binary files, NUL bytes) after the
last element are tolerated; anything else is an error, as it means the header
does not describe the body.

Refused, naming the vertex or face 0-based as PLY counts: a NaN/inf
coordinate, a face with fewer than three corners, an index outside the vertices.
"""
from __future__ import annotations

import re
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facegeom.errors import InputError
from facegeom.io.formats.common import MeshData, check_finite, parse_floats, parse_ints, quote

__all__ = ["read_ply"]

_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_STRUCT = {"i1": "b", "u1": "B", "i2": "h", "u2": "H", "i4": "i", "u4": "I"}
_FORMATS = {"ascii": "", "binary_little_endian": "<", "binary_big_endian": ">"}
_END_HEADER = re.compile(rb"(?:^|\n)end_header[ \t]*(?:\r?\n|\Z)")
_INDEX_LISTS = ("vertex_indices", "vertex_index")


@dataclass(frozen=True)
class _Property:
    name: str
    code: str  # numpy type code of the value (of the items, for a list)
    count_code: str | None = None  # numpy type code of a list's count; None for a scalar


@dataclass(frozen=True)
class _Element:
    name: str
    count: int
    props: tuple[_Property, ...]


def _header(data: bytes, path: Path) -> tuple[str, list[_Element], int]:
    """(format, elements, offset of the body) after checking every header line."""
    if not re.match(rb"ply[ \t]*\r?\n", data):
        raise InputError("not a PLY file (it does not start with the line 'ply')", path)
    end = _END_HEADER.search(data)
    if end is None:
        raise InputError("malformed PLY header: no 'end_header' line (truncated?)", path)
    lines = data[:end.start()].decode("latin-1").split("\n")[1:]
    fmt, elements = None, []
    for no, line in enumerate(lines, start=2):
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        where = f"PLY header line {no}"
        if words[0] == "format":
            if len(words) != 3 or words[1] not in _FORMATS or fmt is not None:
                raise InputError(f"{where}: expected 'format ascii|binary_little_endian|binary_big_endian 1.0'",
                                 path)
            fmt = words[1]
        elif words[0] == "element":
            if len(words) != 3 or not words[2].isdigit() or not words[2].isascii():
                raise InputError(f"{where}: expected 'element <name> <count>' with a non-negative integer count",
                                 path)
            elements.append(_Element(words[1], int(words[2]), ()))
        elif words[0] == "property":
            if not elements:
                raise InputError(f"{where}: a property before any element", path)
            elements[-1] = _Element(elements[-1].name, elements[-1].count,
                                    elements[-1].props + (_property(words, where, path),))
        else:
            raise InputError(f"{where}: unknown keyword {quote(words[0].encode('latin-1'))}", path)
    if fmt is None:
        raise InputError("malformed PLY header: no 'format' line", path)
    return fmt, elements, end.end()


def _property(words: list[str], where: str, path: Path) -> _Property:
    if len(words) == 3 and words[1] in _TYPES:
        return _Property(words[2], _TYPES[words[1]])
    if len(words) == 5 and words[1] == "list" and words[2] in _TYPES and words[3] in _TYPES:
        if _TYPES[words[2]][0] not in "iu":
            raise InputError(f"{where}: a list count must have an integer type, not {words[2]}", path)
        return _Property(words[4], _TYPES[words[3]], _TYPES[words[2]])
    raise InputError(f"{where}: expected 'property <type> <name>' or 'property list <type> <type> <name>' "
                     f"with types among {', '.join(sorted(_TYPES))}", path)


def _wanted(elem: _Element, path: Path) -> dict[int, str]:
    """Property positions to keep -> their role: x/y/z of the vertices, the corners of the faces."""
    if elem.name == "vertex":
        names = [p.name for p in elem.props]
        want = {}
        for axis in "xyz":
            if axis not in names:
                raise InputError(f"the vertex element has no property {axis!r}", path)
            k = names.index(axis)
            if elem.props[k].count_code is not None:
                raise InputError(f"the vertex property {axis!r} is a list", path)
            want[k] = axis
        return want
    if elem.name in ("face", "tristrips"):
        for k, p in enumerate(elem.props):
            if p.name in _INDEX_LISTS:
                if p.count_code is None or p.code[0] not in "iu":
                    raise InputError(f"the {elem.name} property {p.name!r} must be a list of integers", path)
                return {k: "corners" if elem.name == "face" else "strips"}
        raise InputError(f"the {elem.name} element has no list 'vertex_indices'", path)
    return {}


def _strip_triangles(counts: np.ndarray, items: np.ndarray, path: Path) -> np.ndarray:
    """Triangle strips (``-1`` restarts a strip) -> triangles ``(t, 3)``, every other one turned to keep the winding;
    triangles with a repeated corner (the joints of stitched strips) left out."""
    if items.size > 50_000_000:
        raise InputError(f"the tristrips hold {items.size:,} indices, more than a mesh reader takes", path)
    ends = np.cumsum(counts)
    restart = items == -1
    if (items[~restart] < 0).any():
        raise InputError("a triangle strip holds a negative index other than -1", path)
    # a strip id per index: a new strip at every row start and after every -1
    starts = np.zeros(items.size, bool)
    starts[np.r_[0, ends[:-1]][counts > 0]] = True
    starts[1:] |= restart[:-1]
    sid = np.cumsum(starts) - 1
    pos = np.arange(items.size) - np.maximum.accumulate(np.where(starts, np.arange(items.size), 0))
    ok = ~restart
    i = np.flatnonzero(ok[:-2] & ok[1:-1] & ok[2:] & (sid[:-2] == sid[2:]) & (pos[:-2] + 2 == pos[2:]))
    a, b, c = items[i], items[i + 1], items[i + 2]
    odd = (pos[i] % 2) == 1
    tri = np.stack([np.where(odd, b, a), np.where(odd, a, b), c], axis=1)
    keep = (tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 0] != tri[:, 2])
    return tri[keep].astype(np.int64)


def _truncated(elem: _Element, row: int, path: Path) -> InputError:
    return InputError(f"truncated in the {elem.name} section (row {row} of {elem.count})", path)


# --------------------------------------------------------------------------- binary


def _binary_element(data: bytes, pos: int, elem: _Element, order: str, want: dict[int, str], path: Path):
    """Read one element from ``pos``: (position after it, {role: values or (counts, items)})."""
    sizes = [np.dtype(p.code).itemsize for p in elem.props]
    csizes = [0 if p.count_code is None else np.dtype(p.count_code).itemsize for p in elem.props]
    remaining = len(data) - pos
    min_row = sum(s if c == 0 else c for s, c in zip(sizes, csizes))
    if elem.count * min_row > remaining:
        raise InputError(f"truncated in the {elem.name} section: {elem.count} rows need at least "
                         f"{elem.count * min_row} bytes, {remaining} remain", path)
    if elem.count == 0 or min_row == 0:
        return pos, {role: np.zeros(0) if role in "xyz" else (np.zeros(0, np.int64), np.zeros(0, np.int64))
                     for role in want.values()}
    # the rows as if every list had the length it has in the first row
    counts0, off = [], pos
    for p, s, c in zip(elem.props, sizes, csizes):
        if c:
            if off + c > len(data):
                raise _truncated(elem, 0, path)
            n = int(np.frombuffer(data, order + p.count_code, 1, off)[0])
            if n < 0:
                raise InputError(f"{elem.name} row 0: negative list length {n}", path)
            counts0.append(n)
            off += c + n * s
        else:
            off += s
    row = off - pos
    if elem.count * row <= remaining:
        names, formats, offsets, lists = [], [], [], 0
        at = 0
        for k, (p, s, c) in enumerate(zip(elem.props, sizes, csizes)):
            if c:
                names.append(f"n{k}")
                formats.append(order + p.count_code)
                offsets.append(at)
                at += c
                if counts0[lists]:
                    names.append(f"v{k}")
                    formats.append((order + p.code, (counts0[lists],)))
                    offsets.append(at)
                at += counts0[lists] * s
                lists += 1
            else:
                if k in want:
                    names.append(f"v{k}")
                    formats.append(order + p.code)
                    offsets.append(at)
                at += s
        rows = np.frombuffer(data, np.dtype({"names": names, "formats": formats, "offsets": offsets,
                                             "itemsize": row}), elem.count, pos)
        lists = iter(counts0)
        uniform = all((rows[f"n{k}"] == next(lists)).all() for k, c in enumerate(csizes) if c)
        if uniform:
            out = {}
            for k, role in want.items():
                if csizes[k]:
                    n = counts0[sum(1 for c in csizes[:k] if c)]
                    items = rows[f"v{k}"].reshape(elem.count, n) if n else np.zeros((elem.count, 0))
                    out[role] = (np.full(elem.count, n, np.int64), items.astype(np.int64).ravel())
                else:
                    out[role] = rows[f"v{k}"].astype(np.float64)
            return pos + elem.count * row, out
    return _binary_walk(data, pos, elem, order, want, sizes, csizes, path)


def _binary_walk(data, pos, elem, order, want, sizes, csizes, path):
    """Row by row, for elements whose lists change length (mixed polygons)."""
    plan = [(k, s, struct.Struct(order + _STRUCT[p.count_code]) if c else None)
            for k, (p, s, c) in enumerate(zip(elem.props, sizes, csizes))]
    keep = {k: ([], []) for k in want}
    end = len(data)
    for r in range(elem.count):
        for k, s, counter in plan:
            if counter is None:
                if k in keep:
                    keep[k][0].append(pos)
                pos += s
                continue
            if pos + counter.size > end:
                raise _truncated(elem, r, path)
            n = counter.unpack_from(data, pos)[0]
            if n < 0:
                raise InputError(f"{elem.name} row {r}: negative list length {n}", path)
            pos += counter.size
            if k in keep:
                keep[k][0].append(pos)
                keep[k][1].append(n)
            pos += n * s
            if pos > end:
                raise _truncated(elem, r, path)
        if pos > end:
            raise _truncated(elem, r, path)
    buf = np.frombuffer(data, np.uint8)
    out = {}
    for k, role in want.items():
        starts = np.asarray(keep[k][0], np.int64)
        code = order + elem.props[k].code
        s = sizes[k]
        if csizes[k]:
            counts = np.asarray(keep[k][1], np.int64)
            first = np.repeat(starts, counts)
            step = np.arange(first.size) - np.repeat(np.cumsum(counts) - counts, counts)
            starts = first + step * s
        items = buf[starts[:, None] + np.arange(s)].copy().view(code).ravel()
        out[role] = (counts, items.astype(np.int64)) if csizes[k] else items.astype(np.float64)
    return pos, out


# --------------------------------------------------------------------------- ascii


def _ascii_element(tokens: list[bytes], pos: int, elem: _Element, want: dict[int, str], path: Path):
    """Read one element from token ``pos``: (token after it, {role: values or (counts, items)})."""
    lists = [k for k, p in enumerate(elem.props) if p.count_code is not None]
    width = len(elem.props)
    remaining = len(tokens) - pos
    if elem.count * width > remaining:
        raise InputError(f"truncated in the {elem.name} section: {elem.count} rows need at least "
                         f"{elem.count * width} values, {remaining} remain", path)
    where = lambda i: f"the {elem.name} section"  # noqa: E731
    if elem.count == 0 or width == 0:
        return pos, {role: np.zeros(0) if role in "xyz" else (np.zeros(0, np.int64), np.zeros(0, np.int64))
                     for role in want.values()}
    # the column of each property if every list has the length it has in the first row
    col, counts0, at = [], [], pos
    for k, p in enumerate(elem.props):
        col.append(at - pos)
        if p.count_code is not None:
            if at >= len(tokens):
                raise _truncated(elem, 0, path)
            n = parse_ints(tokens[at:at + 1], where, path)[0]
            if n < 0:
                raise InputError(f"{elem.name} row 0: negative list length {n}", path)
            counts0.append(int(n))
            at += 1 + int(n)
        else:
            at += 1
    row = at - pos
    stop = pos + elem.count * row
    if stop <= len(tokens) and all(tokens[pos + col[k]:stop:row].count(tokens[pos + col[k]]) == elem.count
                                   for k in lists):
        out = {}
        for k, role in want.items():
            if k in lists:
                n = counts0[lists.index(k)]
                items = [parse_ints(tokens[pos + col[k] + 1 + j:stop:row], where, path) for j in range(n)]
                flat = np.stack(items, axis=1).ravel() if n else np.zeros(0, np.int64)
                out[role] = (np.full(elem.count, n, np.int64), flat)
            else:
                out[role] = parse_floats(tokens[pos + col[k]:stop:row], where, path)
        return stop, out
    return _ascii_walk(tokens, pos, elem, want, path)


def _ascii_walk(tokens, pos, elem, want, path):
    """Row by row, for elements whose lists change length (mixed polygons)."""
    is_list = [p.count_code is not None for p in elem.props]
    keep = {k: ([], []) for k in want}
    end = len(tokens)
    for r in range(elem.count):
        for k, listed in enumerate(is_list):
            if pos >= end:
                raise _truncated(elem, r, path)
            if not listed:
                if k in keep:
                    keep[k][0].append(tokens[pos])
                pos += 1
                continue
            try:
                n = int(tokens[pos])
            except ValueError:
                raise InputError(f"{elem.name} row {r}: list length {quote(tokens[pos])} is not an integer",
                                 path) from None
            if n < 0:
                raise InputError(f"{elem.name} row {r}: negative list length {n}", path)
            if pos + 1 + n > end:
                raise _truncated(elem, r, path)
            if k in keep:
                keep[k][0].extend(tokens[pos + 1:pos + 1 + n])
                keep[k][1].append(n)
            pos += 1 + n
    where = lambda i: f"the {elem.name} section"  # noqa: E731
    out = {}
    for k, role in want.items():
        if is_list[k]:
            out[role] = (np.asarray(keep[k][1], np.int64), parse_ints(keep[k][0], where, path))
        else:
            out[role] = parse_floats(keep[k][0], where, path)
    return pos, out


def _ascii_tokens(body: bytes, elements, wants, path: Path) -> dict:
    """The ascii body read as one stream of values, exactly as the header describes it."""
    tokens = body.split()
    pos, found = 0, {}
    for elem, want in zip(elements, wants):
        pos, got = _ascii_element(tokens, pos, elem, want, path)
        found.update(got)
    if pos < len(tokens):
        raise InputError(f"{len(tokens) - pos} values after the last element (the header does not "
                         "describe the body)", path)
    return found


def _ascii_lines(body: bytes, elements, wants, path: Path) -> dict | None:
    """The ascii body read one element row per line, ignoring values past the header's properties.

    Some writers (MeshLab's VCG library, for faces with texture coordinates)
    put more values on a row than the header declares. When the body has
    exactly one non-blank line per element row, each row is read from its own
    line, so such extra values cannot shift the rows after them. Returns
    ``None`` when the line count does not match (the caller reports the
    stream reader's error); a line with too few values is an error.
    """
    lines = [ln.split() for ln in body.splitlines()]
    lines = [t for t in lines if t]
    if len(lines) != sum(e.count for e in elements):
        return None
    found, at = {}, 0
    for elem, want in zip(elements, wants):
        keep = {k: ([], []) for k in want}
        for r in range(elem.count):
            t, pos = lines[at + r], 0
            for k, p in enumerate(elem.props):
                if pos >= len(t):
                    raise InputError(f"{elem.name} row {r}: {len(t)} values, fewer than its properties need", path)
                if p.count_code is None:
                    if k in keep:
                        keep[k][0].append(t[pos])
                    pos += 1
                    continue
                try:
                    n = int(t[pos])
                except ValueError:
                    raise InputError(f"{elem.name} row {r}: list length {quote(t[pos])} is not an integer",
                                     path) from None
                if n < 0 or pos + 1 + n > len(t):
                    raise InputError(f"{elem.name} row {r}: list length {n} does not fit its line", path)
                if k in keep:
                    keep[k][0].extend(t[pos + 1:pos + 1 + n])
                    keep[k][1].append(n)
                pos += 1 + n
        at += elem.count
        where = lambda i, name=elem.name: f"the {name} section"  # noqa: E731
        for k, role in want.items():
            if elem.props[k].count_code is not None:
                found[role] = (np.asarray(keep[k][1], np.int64), parse_ints(keep[k][0], where, path))
            else:
                found[role] = parse_floats(keep[k][0], where, path)
    return found


# --------------------------------------------------------------------------- file


def read_ply(path: Path, data: bytes, faces: bool = True) -> MeshData:
    """Parse the PLY ``data`` read from ``path``.

    Parameters
    ----------
    path : Path
        Named in errors.
    data : bytes
        The whole file.
    faces : bool
        Check the faces; ``False`` reads the vertices only (point clouds; the
        other elements are still skipped with their size checked).

    Returns
    -------
    MeshData
        ``(n, 3)`` vertices and the polygons (0-based), not triangulated.

    Raises
    ------
    InputError
        See the module docstring.
    """
    fmt, elements, body = _header(data, path)
    names = [e.name for e in elements]
    for name in ("vertex", "face", "tristrips"):
        if names.count(name) > 1:
            raise InputError(f"the PLY header has {names.count(name)} {name} elements", path)
    if "vertex" not in names:
        raise InputError("no vertex element in the PLY header", path)
    wants = [_wanted(elem, path) for elem in elements]
    found = {}
    if fmt == "ascii":
        try:
            found = _ascii_tokens(data[body:], elements, wants, path)
        except InputError as exc:
            found = _ascii_lines(data[body:], elements, wants, path)
            if found is None:
                raise exc from None
    else:
        pos = body
        for elem, want in zip(elements, wants):
            pos, got = _binary_element(data, pos, elem, _FORMATS[fmt], want, path)
            found.update(got)
        if data[pos:].strip(b" \t\r\n\x00"):
            raise InputError(f"{len(data) - pos} bytes after the last element (the header does not "
                             "describe the body)", path)
    V = np.stack([found["x"], found["y"], found["z"]], axis=1)
    check_finite(V, lambda i: f"vertex {i} (0-based)", path)
    counts, corners = found.get("corners", (np.zeros(0, np.int64), np.zeros(0, np.int64)))
    if faces and "strips" in found:  # triangle strips (scanners' and old Stanford files): as triangles
        tri = _strip_triangles(*found["strips"], path)
        counts = np.r_[counts, np.full(len(tri), 3, np.int64)]
        corners = np.r_[corners, tri.ravel()]
    if not faces:
        return MeshData(V, np.zeros(0, np.int64), np.zeros(1, np.int64))
    short = np.flatnonzero(counts < 3)
    if short.size:
        raise InputError(f"face {short[0]} (0-based) has {counts[short[0]]} vertices; a face needs at least 3",
                         path)
    bad = np.flatnonzero((corners < 0) | (corners >= V.shape[0]))
    if bad.size:
        f = int(np.searchsorted(np.cumsum(counts), bad[0], side="right"))
        raise InputError(f"face {f} (0-based): vertex index {corners[bad[0]]} is outside 0..{V.shape[0] - 1}",
                         path)
    return MeshData(V, corners, np.r_[0, np.cumsum(counts)].astype(np.int64))
