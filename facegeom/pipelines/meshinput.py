"""Reading the mesh that a clean-up step (clean, decimate, crop) starts from."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from facegeom.io import read_mesh
from facegeom.model import read_obj_polygons

__all__ = ["read_input_mesh"]


def read_input_mesh(path, polygons: bool = False) -> tuple[np.ndarray, np.ndarray | list[list[int]]]:
    """Read a mesh with :func:`facegeom.io.read_mesh` (its checks: empty, NaN, truncated, indices).

    Parameters
    ----------
    path : str or Path
        An ``.obj``, ``.ply`` or ``.off`` file.
    polygons : bool
        Keep the polygons of an OBJ with faces of more than three corners (as
        ``clean`` triangulates them itself) instead of their fan triangulation.

    Returns
    -------
    V : ndarray, shape (n, 3)
        Vertex positions.
    F : ndarray of int, shape (m, 3), or list of list of int
        Triangles; with ``polygons``, an OBJ's polygons (vertex indices per face)
        when it has any.
    """
    V, F = read_mesh(path)
    p = Path(path)
    if polygons and p.suffix.lower() == ".obj":
        raw = p.read_bytes()
        n_f = raw.count(b"\nf ") + int(raw.startswith(b"f "))
        if n_f and n_f != F.shape[0]:  # polygons were fan-triangulated on reading: let clean triangulate them
            polys = read_obj_polygons(p)
            if polys and all(min(q) >= 0 and max(q) < V.shape[0] for q in polys):
                return V, polys
    return V, F
