"""Triangle-mesh files (OBJ, PLY, OFF), read with clear errors and written atomically.

Reading goes through the validating numpy readers of
:mod:`facegeom.io.formats` (no byte reaches native code; polygons are kept by
:func:`read_polygon_mesh` and fan-triangulated by :func:`read_mesh`); writing
through libigl (``write_triangle_mesh``; binary PLY through ``writePLY``). :func:`write_mesh` writes through
:func:`facegeom.io.files.atomic_path`, so an interrupted or failed write never
leaves a half-written file. A file that cannot be read is an
:class:`~facegeom.errors.InputError` naming it.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from facegeom.errors import InputError
from facegeom.interfaces import as_faces, as_vertices
from facegeom.io.files import atomic_path
from facegeom.io.formats import MeshData, read_mesh_data
from facegeom.native import quiet_native

__all__ = [
    "MESH_FORMATS",
    "read_mesh",
    "read_polygon_mesh",
    "write_mesh",
]

MESH_FORMATS = (".obj", ".ply", ".off")

#: The largest vertex coordinate read (a light year is 1e19 mm; squared distances of 1e154 overflow double precision).
MAX_COORDINATE = 1e12


def _check_mesh_path(path: Path) -> None:
    if not path.exists():
        raise InputError("file not found", path)
    if path.is_dir():
        raise InputError("is a folder, not a mesh file", path)
    if path.suffix.lower() not in MESH_FORMATS:
        raise InputError(f"unsupported mesh format {path.suffix!r}; use one of {', '.join(MESH_FORMATS)}", path)
    if path.stat().st_size == 0:
        raise InputError("empty file", path)


def read_mesh(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read a triangle mesh (OBJ, PLY, OFF; polygons fan-triangulated).

    Parameters
    ----------
    path : str or PathLike
        An ``.obj``, ``.ply`` or ``.off`` file.

    Returns
    -------
    V : (n, 3) float64
    F : (m, 3) int64

    Raises
    ------
    InputError
        Missing, empty, unreadable or malformed file; NaN/inf coordinates or beyond :data:`MAX_COORDINATE`;
        faces indexing past the vertex count. The message names the file.
    """
    mesh = read_polygon_mesh(path)
    return mesh.vertices, np.ascontiguousarray(mesh.triangles(), dtype=np.int64)


def read_polygon_mesh(path: str | os.PathLike) -> MeshData:
    """Read a mesh keeping its polygons (OBJ, PLY, OFF), checked like :func:`read_mesh`.

    Parameters
    ----------
    path : str or PathLike
        An ``.obj``, ``.ply`` or ``.off`` file.

    Returns
    -------
    MeshData
        ``vertices (n, 3)`` float64 (n >= 1), the polygons as ``corners (k,)``
        and ``offsets (m + 1,)`` int64 (m >= 1, 3 or more corners each);
        ``triangles()`` gives their fan triangulation ``(t, 3)``.

    Raises
    ------
    InputError
        As :func:`read_mesh`.
    """
    path = Path(path)
    _check_mesh_path(path)
    mesh = read_mesh_data(path)
    if mesh.vertices.shape[0] == 0:
        raise InputError("malformed mesh: no vertex could be read", path)
    if mesh.n_faces == 0:
        raise InputError("the mesh has no face", path)
    big = np.abs(mesh.vertices).max(axis=1) > MAX_COORDINATE
    if big.any():
        k = int(np.flatnonzero(big)[0])
        raise InputError(f"vertex {k + 1} has a coordinate of {np.abs(mesh.vertices[k]).max():.3g}: beyond "
                         f"{MAX_COORDINATE:g} in any unit no real mesh reaches, and distances overflow", path)
    return mesh


def write_mesh(path: str | os.PathLike, V, F) -> Path:
    """Write a triangle mesh atomically; the format follows the suffix (.obj, .ply, .off).

    OBJ and OFF are ascii with 15 significant digits, PLY is binary with doubles.
    """
    path = Path(path)
    if path.suffix.lower() not in MESH_FORMATS:
        raise InputError(f"unsupported mesh format {path.suffix!r}; use one of {', '.join(MESH_FORMATS)}", path)
    V = as_vertices(V)
    F = as_faces(F, V.shape[0])
    import igl  # (here: reading a mesh, which most commands do, needs no libigl)

    with atomic_path(path) as tmp:
        with quiet_native((2,)):
            if path.suffix.lower() == ".ply":  # binary doubles: libigl's ascii PLY keeps 6 digits only
                ok = igl.writePLY(str(tmp), V, F, encoding=igl.FileEncoding.Binary)
            else:
                ok = igl.write_triangle_mesh(str(tmp), V, F)
        if ok is False:
            raise InputError("libigl could not write the mesh", path)
    return path


