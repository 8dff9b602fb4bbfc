"""Mesh geometry on libigl: adjacency, rings, geodesic rings, components, Laplacians.

Conventions (libigl's): ``V`` is ``#V by 3`` float64 vertex positions, ``F`` is
``#F by 3`` int64 triangles. Neighbourhoods are returned as a boolean sparse
``#V by #V`` CSR matrix whose row ``i`` holds the ids of the ``i``-th
neighbourhood (vertex ``i`` included); ``neighbourhood_lists`` turns that into
a list of index arrays.
"""
from __future__ import annotations

import igl
import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph

from facegeom.errors import InputError
from facegeom.interfaces import as_faces, as_vertices

__all__ = [
    "adjacency",
    "k_ring",
    "geodesic_rings",
    "neighbourhood_lists",
    "connected_components",
    "edge_lengths",
    "mean_edge_length",
    "walkable_faces",
    "cotangent_laplacian",
    "mass_matrix",
    "boundary_band",
]


def _n_from(F: np.ndarray, n_vertices: int | None) -> int:
    return int(F.max()) + 1 if n_vertices is None else int(n_vertices)


def adjacency(F, n_vertices: int | None = None) -> sp.csr_matrix:
    """Vertex adjacency of a triangle mesh.

    Parameters
    ----------
    F : (m, 3) int array
        Triangles.
    n_vertices : int, optional
        Number of vertices (isolated trailing vertices are kept); default ``F.max()+1``.

    Returns
    -------
    A : (n, n) scipy.sparse.csr_matrix of bool
        ``A[i, j]`` is True when ``i`` and ``j`` share an edge; zero diagonal.
    """
    n = _n_from(np.asarray(F), n_vertices)
    F = as_faces(F, n)
    A = igl.adjacency_matrix(F).tocsr()
    if A.shape[0] < n:  # igl sizes the matrix by F.max()+1
        A.resize((n, n))
    A = A.astype(bool)
    A.eliminate_zeros()
    return A


def k_ring(F, n_vertices: int | None = None, k: int = 1) -> sp.csr_matrix:
    """All vertices within ``k`` edges of each vertex (the vertex itself included).

    Computed as the sparsity pattern of ``(A + I)^k`` (libigl has no k-ring
    function), all vertices at once.

    Returns
    -------
    R : (n, n) scipy.sparse.csr_matrix of bool
        Row ``i`` = the ``k``-ring of vertex ``i``; sorted column indices.
    """
    if int(k) != k or k < 0:
        raise InputError(f"k must be a non-negative integer, got {k!r}")
    A = adjacency(F, n_vertices)
    n = A.shape[0]
    step = (A + sp.identity(n, dtype=bool, format="csr")).astype(np.int8).tocsr()
    R = step if k else sp.identity(n, dtype=np.int8, format="csr")  # the 1-ring is A + I itself: no product
    for _ in range(int(k) - 1):
        R = (R @ step).tocsr()
        R.data[:] = 1  # keep the pattern only (no overflow)
    R = R.astype(bool)
    R.sort_indices()
    return R


def edge_lengths(V, F) -> np.ndarray:
    """Length of every unique undirected edge, ``(#E,)``."""
    V = as_vertices(V)
    F = as_faces(F, V.shape[0])
    E = igl.edges(F)
    return np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)


def mean_edge_length(V, F) -> float:
    """Mean length of the unique edges of the mesh."""
    return float(edge_lengths(V, F).mean())


def walkable_faces(V, F) -> np.ndarray:
    """The faces of ``F`` with an area: exact (MMP) geodesics loop without bound on a zero-area face.

    A face whose doubled area is at most ``1e-12`` times the squared diagonal of
    the mesh's box (two coincident vertices, or three on a line) carries no
    distance its edges do not, so it is left out; a mesh of coincident
    vertices has none left.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    if F.size == 0:
        return F.reshape(0, 3)
    diag2 = float(((V.max(axis=0) - V.min(axis=0)) ** 2).sum()) if V.size else 0.0
    a = np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    return F[a > 1e-12 * diag2]


def _edge_graph(V: np.ndarray, F: np.ndarray) -> sp.csr_matrix:
    E = igl.edges(F)
    w = np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)
    n = V.shape[0]
    G = sp.coo_matrix((np.r_[w, w], (np.r_[E[:, 0], E[:, 1]], np.r_[E[:, 1], E[:, 0]])), shape=(n, n))
    return G.tocsr()


def geodesic_rings(V, F, radius: float, method: str = "exact", chunk: int = 1024,
                   progress: bool = False) -> sp.csr_matrix:
    """All vertices within geodesic distance ``radius`` of each vertex.

    Parameters
    ----------
    V : (n, 3) float array
    F : (m, 3) int array
    radius : float
        Geodesic radius, in the mesh's units.
    method : {"exact", "graph"}
        ``"exact"``: libigl's exact (MMP) geodesics, computed for each vertex on
        the local patch that can contain its geodesic disk (the vertices whose
        edge-path distance is at most ``2 * radius``; an edge path is never
        shorter than the geodesic, and on a mesh without needle triangles a
        geodesic of length ``r`` is followed by an edge path shorter than
        ``2 r``), so each call is small. About 0.5 ms per vertex.
        ``"graph"``: shortest edge paths (Dijkstra on the edge graph, scipy),
        an upper bound of the geodesic distance, so the rings are a little
        smaller; all vertices at once, much faster.
    chunk : int
        Sources per Dijkstra batch (bounds memory to ``chunk * n`` floats).
    progress : bool
        Show a progress bar (exact method).

    Returns
    -------
    R : (n, n) scipy.sparse.csr_matrix of bool
        Row ``i`` = vertices within ``radius`` of vertex ``i`` (``i`` included).
    """
    V = as_vertices(V)
    F = as_faces(F, V.shape[0])
    if not np.isfinite(radius) or radius <= 0:
        raise InputError(f"radius must be a positive number, got {radius!r}")
    if method not in ("exact", "graph"):
        raise InputError(f"method must be 'exact' or 'graph', got {method!r}")
    n = V.shape[0]
    G = _edge_graph(V, F)
    limit = radius if method == "graph" else 2.0 * radius
    rows, cols = [], []
    for s in range(0, n, chunk):
        src = np.arange(s, min(s + chunk, n))
        D = csgraph.dijkstra(G, directed=False, indices=src, limit=limit)
        r, c = np.nonzero(np.isfinite(D) & (D <= limit))
        rows.append(src[r])
        cols.append(c)
    rows = np.concatenate(rows)
    cols = np.concatenate(cols)
    P = sp.csr_matrix((np.ones(rows.size, bool), (rows, cols)), shape=(n, n))
    P.sort_indices()
    if method == "graph":
        return P
    return _exact_on_patches(V, walkable_faces(V, F), P, radius, progress)


def _exact_on_patches(V, F, P: sp.csr_matrix, radius: float, progress: bool) -> sp.csr_matrix:
    n = V.shape[0]
    # faces incident to each vertex, to cut each local patch without an O(n) mask
    VF = sp.csr_matrix(
        (np.ones(F.size, bool), (F.ravel(), np.repeat(np.arange(F.shape[0]), 3))), shape=(n, F.shape[0])
    )
    remap = np.full(n, -1, np.int64)
    rows, cols = [], []
    it = range(n)
    if progress:
        from tqdm import tqdm

        it = tqdm(it, desc="exact geodesic rings", unit="vertex", mininterval=0.5)
    for i in it:
        idx = P.indices[P.indptr[i]:P.indptr[i + 1]]
        faces = np.unique(VF[idx].indices)
        remap[idx] = np.arange(idx.size)
        Fl = remap[F[faces]]
        Fl = Fl[(Fl >= 0).all(axis=1)]
        d = igl.exact_geodesic(V[idx], Fl, VS=np.array([remap[i]]), VT=np.arange(idx.size))
        remap[idx] = -1
        on_patch = np.zeros(idx.size, bool)
        on_patch[Fl.ravel()] = True  # a vertex on no kept face gets no valid distance
        on_patch[np.searchsorted(idx, i)] = True
        keep = idx[on_patch & (d <= radius)]
        rows.append(np.full(keep.size, i))
        cols.append(keep)
    rows = np.concatenate(rows)
    cols = np.concatenate(cols)
    R = sp.csr_matrix((np.ones(rows.size, bool), (rows, cols)), shape=(n, n))
    R.sort_indices()
    return R


def neighbourhood_lists(R: sp.csr_matrix) -> list[np.ndarray]:
    """Rows of an ``(n, n)`` neighbourhood matrix as a list of ``n`` int64 index arrays."""
    R = sp.csr_matrix(R)
    return [R.indices[R.indptr[i]:R.indptr[i + 1]].astype(np.int64) for i in range(R.shape[0])]


def connected_components(F, n_vertices: int | None = None) -> tuple[int, np.ndarray]:
    """Vertex connected components.

    Returns
    -------
    count : int
    labels : (n,) int64
        Component id of each vertex (an isolated vertex is its own component).
    """
    A = adjacency(F, n_vertices)
    count, labels = csgraph.connected_components(A, directed=False)
    return int(count), labels.astype(np.int64)


def unlabelled_components(graph, labelled) -> tuple[int, int, int]:
    """Components of a sparse ``graph`` (non-zeros = edges) that hold none of ``labelled``.

    Returns ``(count, example, size)``: how many such components, the first
    point of the first one and its size (``(0, -1, 0)`` when every component
    has a label).
    """
    count, comp = csgraph.connected_components(sp.csr_matrix(graph) != 0, directed=False)
    has = np.zeros(count, bool)
    has[comp[np.asarray(labelled, dtype=np.int64)]] = True
    if has.all():
        return 0, -1, 0
    bad = int(np.flatnonzero(~has)[0])
    members = comp == bad
    return int((~has).sum()), int(np.flatnonzero(members)[0]), int(members.sum())


def cotangent_laplacian(V, F) -> sp.csr_matrix:
    """libigl's cotangent Laplacian ``L`` (negative semidefinite, rows sum to 0).

    Parameters
    ----------
    V : (n, 3) float array
    F : (m, 3) int array

    Returns
    -------
    L : (n, n) scipy.sparse.csr_matrix of float64
    """
    V = as_vertices(V)
    F = as_faces(F, V.shape[0])
    return igl.cotmatrix(V, F).tocsr()


def mass_matrix(V, F, kind: str = "voronoi") -> sp.csr_matrix:
    """libigl's lumped mass matrix (diagonal): ``kind`` in {"voronoi", "barycentric"}.

    Parameters
    ----------
    V : (n, 3) float array
    F : (m, 3) int array

    Returns
    -------
    M : (n, n) scipy.sparse.csr_matrix of float64
        Vertex areas (in squared mesh units) on the diagonal.

    Raises
    ------
    InputError
        Unknown ``kind``, or invalid ``V`` / ``F``.
    """
    V = as_vertices(V)
    F = as_faces(F, V.shape[0])
    types = {
        "voronoi": igl.MASSMATRIX_TYPE_VORONOI,
        "barycentric": igl.MASSMATRIX_TYPE_BARYCENTRIC,
    }
    if kind not in types:
        raise InputError(f"kind must be one of {sorted(types)}, got {kind!r}")
    return igl.massmatrix(V, F, types[kind]).tocsr()


def boundary_band(V, F, width: float) -> np.ndarray:
    """Vertices within ``width`` of the mesh's boundary along its edges -> bool ``(#V,)``.

    The boundary edges come from libigl's ``boundary_facets``; the distance is
    the shortest edge path to a boundary vertex (Dijkstra from all of them at
    once, cut at ``width``). A closed mesh has no band (all False); vertices in
    no triangle are not in it.
    """
    V, F = as_vertices(V), as_faces(F, V.shape[0])
    if not (width >= 0 and np.isfinite(width)):
        raise InputError(f"width must be a non-negative number, got {width!r}")
    n = V.shape[0]
    out = igl.boundary_facets(F)
    E = out[0] if isinstance(out, tuple) else out
    if E.size == 0:
        return np.zeros(n, dtype=bool)
    d = csgraph.dijkstra(_edge_graph(V, F), indices=np.unique(E), min_only=True, limit=width)
    return np.isfinite(d)
