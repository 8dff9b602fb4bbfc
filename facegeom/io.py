"""Mesh and marker files, read with clear errors and written atomically.

Meshes: OBJ, PLY (ascii or binary) and OFF through libigl's
``read_triangle_mesh`` / ``write_triangle_mesh``; polygons are fan-triangulated
on reading. Markers: CSV with the header ``vertex_id,x,y,z``.

Every writer writes to a temporary file in the destination folder and renames
it into place, so an interrupted or failed write never leaves a half-written
file.
"""
from __future__ import annotations

import contextlib
import csv
import io as _io
import os
import re
import tempfile
from pathlib import Path

import igl
import numpy as np

from .errors import InputError
from .interfaces import as_faces, as_handles, as_vertices
from .utils import quiet_native

__all__ = [
    "MESH_FORMATS",
    "MARKER_HEADER",
    "atomic_path",
    "read_mesh",
    "write_mesh",
    "read_markers",
    "write_markers",
]

MESH_FORMATS = (".obj", ".ply", ".off")
MARKER_HEADER = ("vertex_id", "x", "y", "z")


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike):
    """Yield a temporary path next to ``path``; rename it onto ``path`` on success.

    The temporary file keeps ``path``'s suffix (libigl picks the format by it).
    On any exception the temporary file is removed and ``path`` is untouched.
    """
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise InputError("output folder does not exist", folder)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=folder)
    os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def _check_mesh_path(path: Path) -> None:
    if not path.exists():
        raise InputError("file not found", path)
    if path.is_dir():
        raise InputError("is a folder, not a mesh file", path)
    if path.suffix.lower() not in MESH_FORMATS:
        raise InputError(f"unsupported mesh format {path.suffix!r}; use one of {', '.join(MESH_FORMATS)}", path)
    if path.stat().st_size == 0:
        raise InputError("empty file", path)


_NONFINITE = re.compile(rb"(?i)(?<![a-z])(nan|inf|infinity)(?![a-z])")


def read_mesh(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read a triangle mesh (OBJ, PLY, OFF; polygons fan-triangulated).

    Returns
    -------
    V : (n, 3) float64
    F : (m, 3) int64

    Raises
    ------
    InputError
        Missing, empty, unreadable or malformed file; NaN/inf coordinates;
        faces indexing past the vertex count. The message names the file.
    """
    path = Path(path)
    _check_mesh_path(path)
    try:
        with quiet_native((2,)):
            V, F = igl.read_triangle_mesh(str(path))[:2]
    except RuntimeError:
        head = path.read_bytes()[:1 << 22]
        if path.suffix.lower() != ".ply" and _NONFINITE.search(head):
            raise InputError("vertex coordinates contain NaN or inf", path) from None
        raise InputError("malformed mesh: libigl could not parse it", path) from None
    V = np.asarray(V)
    F = np.asarray(F)
    if V.size == 0 or V.ndim != 2:
        raise InputError("malformed mesh: no vertex could be read", path)
    if V.shape[1] != 3:
        raise InputError(f"vertices must be 3-D, got {V.shape[1]} coordinates", path)
    if F.size == 0:
        if F.ndim == 2 and F.shape[0] > 0:
            raise InputError("malformed or truncated mesh: its faces could not be read", path)
        raise InputError("the mesh has no face", path)
    if F.ndim != 2 or F.shape[1] != 3:
        raise InputError("malformed or truncated mesh: its faces could not be read as polygons", path)
    V = as_vertices(V, "vertex coordinates", path)
    F = as_faces(F, V.shape[0], "faces", path)
    return V, F


def write_mesh(path: str | os.PathLike, V, F) -> Path:
    """Write a triangle mesh atomically; the format follows the suffix (.obj, .ply, .off).

    OBJ and OFF are ascii with 15 significant digits, PLY is binary with doubles.
    """
    path = Path(path)
    if path.suffix.lower() not in MESH_FORMATS:
        raise InputError(f"unsupported mesh format {path.suffix!r}; use one of {', '.join(MESH_FORMATS)}", path)
    V = as_vertices(V)
    F = as_faces(F, V.shape[0])
    with atomic_path(path) as tmp:
        with quiet_native((2,)):
            if path.suffix.lower() == ".ply":  # binary doubles: libigl's ascii PLY keeps 6 digits only
                ok = igl.writePLY(str(tmp), V, F, encoding=igl.FileEncoding.Binary)
            else:
                ok = igl.write_triangle_mesh(str(tmp), V, F)
        if ok is False:
            raise InputError("libigl could not write the mesh", path)
    return path


def read_csv_rows(path: Path, what: str) -> list[list[str]]:
    """Every row of the text CSV ``path`` (blank rows included, so indices are line numbers - 1).

    One-line errors naming ``path``: missing, a folder (``what`` names the
    expected kind of file), not decodable as UTF-8 text.
    """
    if not path.exists():
        raise InputError("file not found", path)
    if path.is_dir():
        raise InputError(f"is a folder, not a {what} file", path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read as text ({exc.__class__.__name__})", path) from None
    return list(csv.reader(_io.StringIO(text)))


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
    """Write a marker CSV (``vertex_id,x,y,z``) atomically."""
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
