"""Input validation and defect counts of a mesh (numpy and libigl only)."""
from __future__ import annotations

import numpy as np

from facegeom.errors import InputError
from facegeom.interfaces import as_faces, as_vertices
from facegeom.pipelines.cleanup.topology import edge_face_counts

__all__ = ["mesh_problems"]


def _check_mesh(V, F, path=None) -> tuple[np.ndarray, np.ndarray | list, bool]:
    """Validate V and F (triangles, an (m, k) polygon array or a list of polygons)."""
    V = as_vertices(V, "vertex coordinates", path)
    n = V.shape[0]
    if isinstance(F, np.ndarray) and F.ndim == 2 and F.shape[1] == 3:
        return V, as_faces(F, n, "faces", path), False
    if isinstance(F, np.ndarray) and F.ndim == 2 and F.shape[1] > 3:
        polys = [np.asarray(r, dtype=np.int64) for r in F]
    else:
        try:
            polys = [np.asarray(p, dtype=np.int64).ravel() for p in F]
        except (TypeError, ValueError):
            raise InputError("faces must be triangles (m, 3) or a list of polygons of vertex ids", path) from None
    if not polys:
        raise InputError("faces is empty: the mesh has no face", path)
    for k, p in enumerate(polys):
        if p.size < 3:
            raise InputError(f"face {k} has {p.size} vertices; a polygon needs at least 3", path)
        if p.min() < 0 or p.max() >= n:
            raise InputError(f"face {k} indexes vertex {int(p.max() if p.max() >= n else p.min())}, outside "
                             f"[0, {n})", path)
    if all(p.size == 3 for p in polys):
        return V, np.array(polys, dtype=np.int64), False
    return V, polys, True


def mesh_problems(V, F) -> dict[str, int]:
    """Counts of the defects :func:`clean` repairs (all 0 on a clean mesh); numpy and libigl only.

    Keys: ``duplicate_vertices`` (same position), ``unreferenced_vertices``,
    ``degenerate_faces`` (repeated vertex or zero area), ``duplicate_faces``
    (same vertex set), ``non_manifold_edges``, ``non_manifold_vertices``,
    ``components``.

    Parameters
    ----------
    V : (n, 3) float
        Vertex positions.
    F : (m, 3) int
        Triangles.

    Returns
    -------
    dict of str -> int
    """
    from facegeom.geometry import connected_components

    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    n = V.shape[0]
    out = {"duplicate_vertices": int(n - np.unique(V, axis=0).shape[0]),
           "unreferenced_vertices": int(n - np.unique(F).size)}
    rep = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 0] == F[:, 2])
    area = np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    out["degenerate_faces"] = int((rep | (area == 0)).sum())
    out["duplicate_faces"] = int(F.shape[0] - np.unique(np.sort(F, axis=1), axis=0).shape[0])
    out["non_manifold_edges"] = _non_manifold_edges(F)
    out["non_manifold_vertices"] = _non_manifold_vertices(F[~rep])
    out["components"] = connected_components(F, n)[0] - out["unreferenced_vertices"]
    return out


def _non_manifold_edges(F) -> int:
    """How many edges of the triangles ``F (m, 3)`` have more than two faces."""
    return edge_face_counts(F)[0]


def _non_manifold_vertices(F) -> int:
    """How many used vertices of the triangles ``F (m, 3)`` are not manifold (libigl's test)."""
    import igl

    F = np.asarray(F, dtype=np.int64)
    if F.size == 0:
        return 0
    vm = np.asarray(igl.is_vertex_manifold(F)).astype(bool).ravel()
    used = np.zeros(vm.size, bool)
    used[np.unique(F)] = True
    return int((~vm & used).sum())
