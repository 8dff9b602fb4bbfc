"""Files of faces found in pixels: the 68 landmarks as an iBUG ``.pts``, all face-mesh points as a CSV.

``.pts`` is what landmark tools read and write (300-W, menpo, dlib's tools):
``version: 1``, ``n_points: 68``, ``{``, one ``x y`` line per point in
1-based pixels (the top-left pixel's centre is ``(1, 1)``), ``}``;
:func:`facegeom.io.read_pts` reads it back to 0-based pixels.

The mesh-points CSV has a header ``face,point,x,y,z`` and one row per point
of every face: ``face`` counts from 0 (largest first), ``point`` is the
face-mesh model's index (0-467; 468-472 the subject's right iris, centre
first, 473-477 the left, when the irises were found), ``x, y`` 0-based image
pixels, ``z`` the model's relative depth in pixels (smaller is nearer the
camera).
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from facegeom.errors import InputError

__all__ = ["write_pts", "write_mesh_points", "MESH_POINTS_HEADER"]

MESH_POINTS_HEADER = "face,point,x,y,z"


def write_pts(path: str | os.PathLike, points: np.ndarray) -> Path:
    """Write ``(N, 2)`` 0-based pixel positions as a ``.pts`` annotation (1-based, 3 decimals).

    Raises
    ------
    InputError
        Not ``(N, 2)`` finite values.
    """
    P = np.asarray(points, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 2 or P.shape[0] < 1 or not np.isfinite(P).all():
        raise InputError(f"landmarks must be (N, 2) finite pixel positions, not {P.shape}", path)
    lines = ["version: 1", f"n_points: {P.shape[0]}", "{"]
    lines += [f"{x + 1:.3f} {y + 1:.3f}" for x, y in P]
    lines.append("}")
    path = Path(path)
    path.write_text("\n".join(lines) + "\n")
    return path


def write_mesh_points(path: str | os.PathLike, faces: list[np.ndarray]) -> Path:
    """Write each face's ``(P, 3)`` points (x, y in 0-based pixels, z relative depth) as the mesh-points CSV."""
    rows = [MESH_POINTS_HEADER]
    for f, P in enumerate(faces):
        P = np.asarray(P, dtype=np.float64)
        if P.ndim != 2 or P.shape[1] != 3 or not np.isfinite(P).all():
            raise InputError(f"face {f}: points must be (P, 3) finite values, not {P.shape}", path)
        rows += [f"{f},{i},{x:.3f},{y:.3f},{z:.3f}" for i, (x, y, z) in enumerate(P)]
    path = Path(path)
    path.write_text("\n".join(rows) + "\n")
    return path
