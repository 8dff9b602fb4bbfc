"""Marker layouts on the ICT face: which vertices carry markers (vertex-id arrays).

:func:`layout` picks one by name:

``ict80`` (the default layout of the face-driving experiments): the 68
Multi-PIE landmarks plus 12 points spread over the rest of the narrow face area
(vertices ``[0, FACE_AREA)``, :data:`facegeom.constants.FACE_AREA` = 6706) by
farthest-point sampling in edge-path (geodesic-like)
distance on the generic neutral face, starting from the landmarks. The 12 land
where the landmarks leave gaps: forehead, temples, cheeks, under the chin.
Fully determined by the mesh, so every run and every identity uses the same
vertex ids.

``landmarks68``: the 68 landmark vertices alone.

``random<k>`` layouts (held-out marker layouts, e.g. ``random60``): ``k``
points by farthest-point sampling from a seeded random start vertex on the
narrow face area.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from facegeom.constants import FACE_AREA
from facegeom.errors import InputError

if TYPE_CHECKING:
    import scipy.sparse as sp

__all__ = ["farthest_points", "ict80", "random_layout", "layout"]



def _edge_graph(V: np.ndarray, F: np.ndarray, keep: np.ndarray) -> sp.csr_matrix:
    import scipy.sparse as sp  # here, not at the top: only the farthest-point layouts need the graph

    E = np.r_[F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]
    E = E[keep[E[:, 0]] & keep[E[:, 1]]]
    w = np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)
    n = V.shape[0]
    G = sp.coo_matrix((w, (E[:, 0], E[:, 1])), shape=(n, n)).tocsr()
    return G.maximum(G.T)


def farthest_points(V, F, start: np.ndarray, count: int, region: np.ndarray | None = None) -> np.ndarray:
    """Add ``count`` vertices, each the farthest (edge-path distance) from all chosen so far.

    Parameters
    ----------
    V, F : mesh
    start : (s,) int
        Vertices already chosen (at least one).
    count : int
        How many to add.
    region : (n,) bool, optional
        Only vertices where True may be chosen and paths stay inside it.

    Returns
    -------
    (count,) int64 new vertex ids, in the order chosen.
    """
    V = np.asarray(V, float)
    F = np.asarray(F, np.int64)
    n = V.shape[0]
    region = np.ones(n, bool) if region is None else np.asarray(region, bool)
    from scipy.sparse import csgraph

    G = _edge_graph(V, F, region)
    chosen = list(np.asarray(start, np.int64))
    if not chosen:
        raise InputError("farthest_points needs at least one start vertex")
    dist = csgraph.dijkstra(G, directed=False, indices=chosen, min_only=True)
    out = []
    for _ in range(int(count)):
        d = np.where(region & np.isfinite(dist), dist, -1.0)
        j = int(np.argmax(d))
        if d[j] <= 0:
            raise InputError("no vertex left to choose in the region")
        out.append(j)
        dist = np.minimum(dist, csgraph.dijkstra(G, directed=False, indices=j))
    return np.array(out, dtype=np.int64)


def _narrow(n: int) -> np.ndarray:
    region = np.zeros(n, bool)
    region[: min(FACE_AREA, n)] = True
    return region


def ict80(model) -> np.ndarray:
    """The 80-marker layout: 68 landmarks + 12 farthest points on the narrow face area.

    Returns
    -------
    (80,) int64
        Vertex ids: ``model.landmarks`` first, then the 12 added points.
    """
    extra = farthest_points(model.neutral, model.triangles, model.landmarks, 12, _narrow(model.n_vertices))
    return np.r_[model.landmarks, extra].astype(np.int64)


def random_layout(model, count: int = 80, seed: int = 0) -> np.ndarray:
    """``count`` well-spread markers from a seeded random start (a held-out layout).

    Returns
    -------
    (count,) int64
        Vertex ids in the narrow face area: the random start, then farthest points.
    """
    rng = np.random.default_rng(seed)
    region = _narrow(model.n_vertices)
    start = np.array([rng.integers(0, min(FACE_AREA, model.n_vertices))])
    return np.r_[start, farthest_points(model.neutral, model.triangles, start, count - 1, region)]


def layout(model, name: str = "ict80", seed: int = 0) -> np.ndarray:
    """A layout by name: ``ict80``, ``landmarks68`` or ``random<k>`` (e.g. ``random60``).

    ``seed`` is used by the ``random<k>`` layouts only (``random`` alone is ``random80``).

    Returns
    -------
    (k,) int64
        Marker vertex ids.

    Raises
    ------
    InputError
        Unknown name, or ``k`` not an integer in [4, 2000].
    """
    if name == "ict80":
        return ict80(model)
    if name == "landmarks68":
        return model.landmarks.copy()
    if name.startswith("random"):
        try:
            k = int(name[len("random"):] or 80)
        except ValueError:
            raise InputError(f"bad layout {name!r}: use random<k>, e.g. random60") from None
        if not 4 <= k <= 2000:
            raise InputError(f"bad layout {name!r}: k must be in [4, 2000]")
        return random_layout(model, k, seed)
    raise InputError(f"unknown marker layout {name!r}; use ict80, landmarks68 or random<k>")
