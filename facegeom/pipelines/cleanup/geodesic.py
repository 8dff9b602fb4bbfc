"""Geodesic distance from source vertices (libigl exact or heat geodesics, or edge paths)."""
from __future__ import annotations

import numpy as np

from facegeom.errors import InputError
from facegeom.interfaces import as_faces, as_vertices

__all__ = ["geodesic_distance"]


def geodesic_distance(V, F, sources, *, limit: float | None = None, method: str = "exact") -> np.ndarray:
    """Geodesic distance from the nearest of ``sources`` to every vertex (libigl).

    ``exact``: libigl's exact (MMP) geodesics; with ``limit`` it runs on the
    patch of vertices within edge-path distance ``2 * limit`` (the bound used
    by :func:`facegeom.geometry.geodesic_rings`), others get ``inf``.
    ``heat``: libigl's heat method (fast, about 1 % error).
    ``graph``: shortest edge paths (an upper bound).

    Parameters
    ----------
    V : (n, 3) float
        Vertex positions.
    F : (m, 3) int
        Triangles.
    sources : (k,) int
        Source vertex ids (duplicates ignored).
    limit : float, optional
        Distances beyond about ``limit`` may be ``inf`` (``exact`` and ``graph``).
    method : {'exact', 'heat', 'graph'}

    Returns
    -------
    d : (n,) float
        Distance of each vertex to the nearest source (0 on the sources,
        ``inf`` where unreached).
    """
    import igl
    from scipy.sparse import csgraph

    from facegeom.geometry import _edge_graph, walkable_faces

    V = as_vertices(V)
    F = as_faces(F, V.shape[0])
    src = np.unique(np.asarray(sources, dtype=np.int64))
    n = V.shape[0]
    if src.size == 0:
        raise InputError("at least one source vertex is needed")
    if src.min() < 0 or src.max() >= n:
        raise InputError(f"source vertex {int(src.max() if src.max() >= n else src.min())} is out of range: "
                         f"the mesh has {n} vertices")
    if method == "heat":
        Fw = walkable_faces(V, F)
        if Fw.shape[0] < F.shape[0]:
            raise InputError(f"{F.shape[0] - Fw.shape[0]} of {F.shape[0]} faces have no area (coincident vertices): "
                             f"the heat method needs a clean mesh; run `facegeom clean` first or use exact "
                             f"geodesics")
        data = igl.HeatGeodesicsData()
        try:
            igl.heat_geodesics_precompute(V, F, data)
        except RuntimeError:
            raise InputError("the heat method failed on this mesh (disconnected or non-manifold pieces, a "
                             "triangle soup?): use exact or graph geodesics") from None
        d = np.asarray(igl.heat_geodesics_solve(data, src), dtype=np.float64)
        if not np.isfinite(d).all():
            raise InputError("the heat method gave no distance on this mesh: use exact or graph geodesics")
        return np.maximum(d - d[src].min(), 0.0)
    G = _edge_graph(V, F)
    if method == "graph":
        return csgraph.dijkstra(G, directed=False, indices=src, min_only=True, limit=np.inf if limit is None else limit)
    if method != "exact":
        raise InputError(f"geodesic method must be 'exact', 'heat' or 'graph', got {method!r}")
    bound = np.inf if limit is None else 2.0 * float(limit)
    de = csgraph.dijkstra(G, directed=False, indices=src, min_only=True, limit=bound)
    patch = np.flatnonzero(np.isfinite(de))
    remap = np.full(n, -1, dtype=np.int64)
    remap[patch] = np.arange(patch.size)
    Fl = remap[walkable_faces(V, F)]  # zero-area faces would keep MMP's window propagation going without bound
    Fl = Fl[(Fl >= 0).all(axis=1)]
    out = np.full(n, np.inf)
    if Fl.size == 0:
        out[src] = 0.0
        return out
    d = np.asarray(igl.exact_geodesic(V[patch], Fl, VS=remap[src], VT=np.arange(patch.size)), dtype=np.float64)
    on = np.zeros(patch.size, bool)
    on[Fl.ravel()] = True
    d[~on] = np.inf
    out[patch] = d
    out[src] = 0.0
    return out
