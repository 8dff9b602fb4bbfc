"""Triangle-mesh files (OBJ, PLY, OFF), read with clear errors and written atomically.

Reading and writing go through libigl (``read_triangle_mesh`` /
``write_triangle_mesh``; binary PLY through ``writePLY``); polygons are
fan-triangulated on reading. :func:`write_mesh` writes through
:func:`facegeom.io.files.atomic_path`, so an interrupted or failed write never
leaves a half-written file. A file that cannot be read is an
:class:`~facegeom.errors.InputError` naming it.
"""
from __future__ import annotations

import os
import re
from pathlib import Path

import igl
import numpy as np

from facegeom.errors import InputError
from facegeom.interfaces import as_faces, as_vertices
from facegeom.io.files import atomic_path
from facegeom.native import quiet_native

__all__ = [
    "MESH_FORMATS",
    "read_mesh",
    "write_mesh",
]

MESH_FORMATS = (".obj", ".ply", ".off")


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


