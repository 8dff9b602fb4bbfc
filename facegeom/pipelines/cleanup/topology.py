"""Numpy topology helpers of ``clean``: split non-manifold edges and vertices, orient per piece."""
from __future__ import annotations

import numpy as np

__all__ = ["edge_face_counts", "misoriented_edges", "split_corners", "orient_pieces"]


def _half_edges(F: np.ndarray):
    """Half-edges ``(3m, 2)`` (face k's edges at rows k, m + k, 2m + k), their undirected id and count."""
    m = F.shape[0]
    H = np.r_[F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]
    key = np.sort(H, axis=1)
    n = int(F.max()) + 1 if m else 1
    _, inv, cnt = np.unique(key[:, 0] * n + key[:, 1], return_inverse=True, return_counts=True)
    return H, inv.ravel(), cnt


def edge_face_counts(F) -> tuple[int, int]:
    """How many edges have more than two faces, and how many edges there are.

    Parameters
    ----------
    F : (m, 3) int
        Triangles.

    Returns
    -------
    non_manifold : int
    edges : int
    """
    F = np.asarray(F, dtype=np.int64)
    if F.size == 0:
        return 0, 0
    _, _, cnt = _half_edges(F)
    return int((cnt > 2).sum()), int(cnt.size)


def misoriented_edges(F) -> int:
    """How many edges with two faces are run the same way by both (the faces disagree in orientation there).

    Parameters
    ----------
    F : (m, 3) int
        Triangles.

    Returns
    -------
    int
    """
    F = np.asarray(F, dtype=np.int64)
    if F.size == 0:
        return 0
    H, a, b = _manifold_pairs(F)
    return int((H[a, 0] == H[b, 0]).sum())


def _manifold_pairs(F: np.ndarray):
    """Pairs of half-edge rows on the edges with exactly two faces (rows ``a``, ``b``) and the half-edges."""
    H, inv, cnt = _half_edges(F)
    sel = np.flatnonzero(cnt[inv] == 2)
    sel = sel[np.argsort(inv[sel], kind="stable")]
    return H, sel[0::2], sel[1::2]


def split_corners(F, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Give each fan of faces around a vertex its own copy of the vertex.

    Two corners of a vertex stay on the same vertex when their faces share an
    edge at it that has exactly two faces. Every other contact (an edge with
    three or more faces, a bowtie) is cut: no face is removed.

    Parameters
    ----------
    F : (m, 3) int
        Triangles on ``n`` vertices.
    n : int
        Vertex count.

    Returns
    -------
    F2 : (m, 3) int64
        The faces on the new vertices (the first copy of vertex ``v`` keeps id
        ``v``; further copies get ids ``n, n + 1, ...``).
    src : (n2,) int64
        The vertex each new vertex is a copy of.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    F = np.asarray(F, dtype=np.int64)
    m = F.shape[0]
    H, a, b = _manifold_pairs(F)
    opp = (H[a, 0] == H[b, 1]).astype(np.int64)  # the two faces run the edge in opposite directions
    fa, fb = a % m, b % m
    ca, cb = a // m, b // m  # corner (0, 1, 2) of the half-edge's start in its face
    # half-edge (p, q) of face fa runs from corner ca to corner ca + 1; the corner of p in fb is cb (same
    # direction) or cb + 1 (opposite)
    u = np.r_[fa * 3 + ca, fa * 3 + (ca + 1) % 3]
    v = np.r_[fb * 3 + (cb + opp) % 3, fb * 3 + (cb + 1 - opp) % 3]
    g = coo_matrix((np.ones(u.size), (u, v)), shape=(3 * m, 3 * m))
    _, lab = connected_components(g, directed=False)
    vert = F.ravel()
    # one new vertex per (vertex, corner group); the group with the lowest corner keeps the id
    order = np.lexsort((np.arange(3 * m), lab))
    first = np.ones(order.size, bool)
    first[1:] = lab[order][1:] != lab[order][:-1]
    groups = order[first]  # lowest corner of each group
    gv = vert[groups]
    rank = np.lexsort((groups, gv))
    gv_sorted = gv[rank]
    is_first = np.ones(rank.size, bool)
    is_first[1:] = gv_sorted[1:] != gv_sorted[:-1]
    new_id = np.empty(rank.size, dtype=np.int64)
    new_id[rank[is_first]] = gv_sorted[is_first]
    extra = rank[~is_first]
    new_id[extra] = n + np.arange(extra.size)
    group_of_label = np.full(int(lab.max()) + 1 if lab.size else 0, -1, dtype=np.int64)
    group_of_label[lab[groups]] = np.arange(groups.size)
    F2 = new_id[group_of_label[lab]].reshape(m, 3)
    src = np.r_[np.arange(n), gv[extra]].astype(np.int64)
    return F2, src


def orient_pieces(F, flipped_from_input=None) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """Orient each piece (faces joined by edges with two faces) coherently, on its own.

    A piece that cannot be oriented (a Möbius strip) is left as it is and does
    not stop the others. Each orientable piece keeps the orientation most of
    its faces had in the input.

    Parameters
    ----------
    F : (m, 3) int
        Triangles, edge-manifold.
    flipped_from_input : (m,) int or bool, optional
        Per face: 1 if it is reversed from the input, 0 if not, -1 if unknown
        (not counted in the vote). Default: every face as in the input.

    Returns
    -------
    flip : (m,) bool
        Faces to reverse.
    non_orientable : list of (int, int)
        Per non-orientable piece: its lowest face index and its face count.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    F = np.asarray(F, dtype=np.int64)
    m = F.shape[0]
    if m == 0:
        return np.zeros(0, bool), []
    ref = np.zeros(m, np.int64) if flipped_from_input is None else np.asarray(flipped_from_input, np.int64)
    H, a, b = _manifold_pairs(F)
    fa, fb = a % m, b % m
    par = (H[a, 0] == H[b, 0]).astype(np.int64)  # same direction: the two faces need opposite flips
    # double cover: node f + s * m is face f with flip s; an edge of parity p joins (f, s) and (g, s ^ p)
    u = np.r_[fa, fa + m]
    v = np.r_[fb + par * m, fb + (1 - par) * m]
    g = coo_matrix((np.ones(u.size), (u, v)), shape=(2 * m, 2 * m))
    _, lab = connected_components(g, directed=False)
    l0, l1 = lab[:m], lab[m:]
    _, piece = connected_components(coo_matrix((np.ones(fa.size), (fa, fb)), shape=(m, m)), directed=False)
    bad_piece = np.zeros(int(piece.max()) + 1, bool)
    bad_piece[piece[l0 == l1]] = True
    # in an orientable piece, pick the cover component holding the piece's lowest face unflipped
    lowest = np.full(bad_piece.size, m, dtype=np.int64)
    np.minimum.at(lowest, piece, np.arange(m))
    base = l0[lowest[piece]]
    flip = l1 == base  # face f flipped lies in the chosen component
    good = ~bad_piece[piece]
    flip &= good
    # majority: toggle a piece when most of its known faces would end up reversed from the input
    known = ref >= 0
    rev = (ref.astype(bool) ^ flip) & known
    n_rev = np.bincount(piece[rev], minlength=bad_piece.size)
    n_same = np.bincount(piece[known & ~rev], minlength=bad_piece.size)
    toggle = (n_rev > n_same) & ~bad_piece
    flip ^= toggle[piece]
    sizes = np.bincount(piece, minlength=bad_piece.size)
    bad = [(int(lowest[p]), int(sizes[p])) for p in np.flatnonzero(bad_piece)]
    return flip, sorted(bad)
