"""What every mesh reader shares: the :class:`MeshData` result and checked number parsing.

Text readers hand rows of tokens (bytes) to :func:`split_rows` and
:func:`parse_floats` / :func:`parse_ints`; these parse in C-level loops (``map``
over the tokens, ``numpy.fromiter``), never per line in Python, and report the
first bad token with the line it is on. Memory stays a small multiple of the
file size: every token is at least one byte of the file.
"""
from __future__ import annotations

import re
import warnings
from dataclasses import dataclass
from itertools import compress
from operator import itemgetter
from pathlib import Path

import numpy as np

from facegeom.errors import InputError
from facegeom.io.ints import INT64_MAX, INT64_MIN

__all__ = ["MeshData", "read_file_bytes", "text_rows", "split_rows", "parse_floats", "parse_ints", "pick", "check_finite", "quote"]


@dataclass(frozen=True)
class MeshData:
    """Vertices and polygon faces read from a file (0-based indices, checked).

    Attributes
    ----------
    vertices : (n, 3) float64
        Finite vertex positions.
    corners : (k,) int64
        The vertex indices of every face, face after face; each in ``[0, n)``.
    offsets : (m + 1,) int64
        Face ``i`` is ``corners[offsets[i]:offsets[i + 1]]``; every face has at
        least 3 corners.
    """

    vertices: np.ndarray
    corners: np.ndarray
    offsets: np.ndarray

    @property
    def n_faces(self) -> int:
        """Number of polygon faces ``m``."""
        return int(self.offsets.shape[0] - 1)

    @property
    def sizes(self) -> np.ndarray:
        """``(m,)`` int64: the number of corners of each face."""
        return np.diff(self.offsets)

    def triangles(self) -> np.ndarray:
        """Fan triangulation of the faces.

        Returns
        -------
        (t, 3) int64
            Face ``i`` with ``s`` corners ``c`` gives ``s - 2`` triangles
            ``(c[0], c[j], c[j + 1])``, in face order (``t = sum(s - 2)``).
        """
        sizes = self.sizes
        if sizes.size and (sizes == 3).all():
            return self.corners.reshape(-1, 3)
        n_tri = sizes - 2
        face = np.repeat(np.arange(sizes.size), n_tri)
        first = self.offsets[:-1][face]
        j = np.arange(face.size) - np.repeat(np.cumsum(n_tri) - n_tri, n_tri) + 1
        c = self.corners
        return np.stack([c[first], c[first + j], c[first + j + 1]], axis=1).astype(np.int64, copy=False)

    def polygons(self) -> list[np.ndarray]:
        """The faces as a list of ``(s_i,)`` int64 arrays of vertex indices."""
        return np.split(self.corners, self.offsets[1:-1])


def read_file_bytes(path: Path) -> bytes:
    """The whole content of ``path``; a missing, folder or unreadable path is an :class:`InputError`.

    Returns
    -------
    bytes
        The file content (the readers need it all: memory is O(file size)).
    """
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise InputError("file not found", path) from None
    except IsADirectoryError:
        raise InputError("is a folder, not a file", path) from None
    except OSError as exc:
        raise InputError(f"cannot read the file ({exc.__class__.__name__})", path) from None


def quote(token: bytes, limit: int = 40) -> str:
    """A token for an error message: decoded leniently (non-UTF-8 bytes escaped) and shortened."""
    text = token[:limit].decode("utf-8", "backslashreplace")
    return repr(text + ("..." if len(token) > limit else ""))


_COMMENT = re.compile(rb"#[^\n]*")


def text_rows(data: bytes) -> tuple[list[bytes], np.ndarray]:
    """The non-blank lines of a text file, ``#`` comments removed, and their 1-based line numbers.

    Lines end with ``\\n``, ``\\r\\n``, or ``\\r`` in a file without ``\\n``.

    Returns
    -------
    rows : list of bytes, length r
    lines : (r,) int64
    """
    if b"\n" not in data:
        data = data.replace(b"\r", b"\n")
    if b"#" in data:
        data = _COMMENT.sub(b"", data)
    lines = data.split(b"\n")
    filled = list(map(bytes.strip, lines))
    keep = np.fromiter(map(bool, filled), dtype=bool, count=len(filled))
    return list(compress(lines, filled)), np.flatnonzero(keep) + 1


_MARK = b"\x00"


def split_rows(rows: list[bytes]) -> tuple[list[bytes], np.ndarray]:
    """The whitespace-separated tokens of ``rows`` and how many each row has.

    Parameters
    ----------
    rows : list of bytes, length r
        Lines (or parts of lines) without their keyword.

    Returns
    -------
    tokens : list of bytes
        Every token, row after row.
    sizes : (r,) int64
        Number of tokens of each row.
    """
    if not rows:
        return [], np.zeros(0, dtype=np.int64)
    tokens = b" \x00 ".join(rows).split()
    marks = np.fromiter(map(_MARK.__eq__, tokens), dtype=bool, count=len(tokens))
    where = np.flatnonzero(marks)
    if where.size == len(rows) - 1:
        bounds = np.r_[-1, where, len(tokens)]
        sizes = np.diff(bounds) - 1
        if where.size:
            tokens = list(compress(tokens, (~marks).tolist()))
        return tokens, sizes.astype(np.int64)
    split = [r.split() for r in rows]  # a row held the marker itself: count row by row
    return [t for s in split for t in s], np.fromiter(map(len, split), dtype=np.int64, count=len(split))


def parse_floats(tokens: list[bytes], where, path: Path) -> np.ndarray:
    """Parse tokens as float64 (``nan`` / ``inf`` parse too; see :func:`check_finite`).

    Parameters
    ----------
    tokens : list of bytes, length k
    where : callable
        ``where(i)`` describes the place of token ``i`` for an error ("line 12").
    path : Path
        Named in errors.

    Returns
    -------
    (k,) float64
    """
    try:
        return np.fromiter(map(float, tokens), dtype=np.float64, count=len(tokens))
    except ValueError:
        i = _first_bad(tokens, float)
        raise InputError(f"{where(i)}: {quote(tokens[i])} is not a number", path) from None


def parse_ints(tokens: list[bytes], where, path: Path) -> np.ndarray:
    """Parse tokens as int64 (decimal integers, optionally signed).

    Parameters
    ----------
    tokens : list of bytes, length k
    where : callable
        ``where(i)`` describes the place of token ``i`` for an error ("line 12").
    path : Path
        Named in errors.

    Returns
    -------
    (k,) int64
    """
    if not tokens:
        return np.zeros(0, dtype=np.int64)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", DeprecationWarning)
            out = np.fromstring(b" ".join(tokens), dtype=np.int64, sep=" ")
        if out.size == len(tokens) and not ((out == INT64_MAX) | (out == INT64_MIN)).any():
            return out
    except (ValueError, DeprecationWarning):
        pass
    try:  # exactly, or find the bad token (fromstring clamps overflows and stops at junk)
        return np.fromiter(map(_int64, tokens), dtype=np.int64, count=len(tokens))
    except (ValueError, OverflowError):
        i = _first_bad(tokens, _int64)
        raise InputError(f"{where(i)}: {quote(tokens[i])} is not an integer index", path) from None



def _int64(token: bytes) -> int:
    v = int(token)
    if not INT64_MIN <= v <= INT64_MAX:
        raise OverflowError
    return v


def _first_bad(tokens: list[bytes], parse) -> int:
    for i, t in enumerate(tokens):
        try:
            parse(t)
        except (ValueError, OverflowError):
            return i
    raise AssertionError("no bad token")  # pragma: no cover - only called after a failure


def pick(items: list, index: np.ndarray) -> list:
    """``[items[i] for i in index]`` in C.

    Parameters
    ----------
    items : list, length k
    index : (j,) int array
        Positions in ``items``.

    Returns
    -------
    list, length j
    """
    if index.size == 0:
        return []
    if index.size == 1:
        return [items[int(index[0])]]
    return list(itemgetter(*index.tolist())(items))


def check_finite(V: np.ndarray, name, path: Path) -> None:
    """Raise if a vertex has a NaN or inf coordinate.

    Parameters
    ----------
    V : (n, 3) float64
    name : callable
        ``name(i)`` names vertex ``i`` (0-based row) as the file counts it, e.g. "vertex 4 (line 5)".
    path : Path
        Named in the error.
    """
    bad = ~np.isfinite(V).all(axis=1)
    if bad.any():
        raise InputError(f"{name(int(np.flatnonzero(bad)[0]))} has a NaN or inf coordinate", path)
