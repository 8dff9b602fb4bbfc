"""Reading the mesh that a clean-up step (clean, decimate, crop) starts from."""
from __future__ import annotations

import numpy as np

from facegeom.io import read_polygon_mesh

__all__ = ["read_input_mesh"]


def read_input_mesh(path, polygons: bool = False) -> tuple[np.ndarray, np.ndarray | list[list[int]]]:
    """Read a mesh with :func:`facegeom.io.read_polygon_mesh` (its checks: empty, NaN, truncated, indices).

    Parameters
    ----------
    path : str or Path
        An ``.obj``, ``.ply`` or ``.off`` file.
    polygons : bool
        Keep the polygons of a mesh with faces of more than three corners (as
        ``clean`` triangulates them itself) instead of their fan triangulation;
        for every format.

    Returns
    -------
    V : ndarray, shape (n, 3)
        Vertex positions.
    F : ndarray of int, shape (m, 3), or list of list of int
        Triangles; with ``polygons``, the polygons (vertex indices per face)
        when the mesh has any.
    """
    mesh = read_polygon_mesh(path)
    if polygons and (mesh.sizes > 3).any():
        return mesh.vertices, [p.tolist() for p in mesh.polygons()]
    return mesh.vertices, mesh.triangles()
