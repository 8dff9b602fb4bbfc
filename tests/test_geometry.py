import time

import numpy as np
import pytest
import scipy.sparse as sp

from facegeom import geometry as g
from facegeom.errors import InputError

from .conftest import grid_mesh


def _bfs_ring(F, n, i, k):
    nbrs = [set() for _ in range(n)]
    for a, b, c in F:
        nbrs[a] |= {b, c}; nbrs[b] |= {a, c}; nbrs[c] |= {a, b}
    ring, frontier = {i}, {i}
    for _ in range(k):
        frontier = set().union(*(nbrs[v] for v in frontier)) - ring
        ring |= frontier
    return ring


def test_adjacency_symmetric_and_matches_faces(grid):
    V, F = grid
    A = g.adjacency(F, len(V))
    assert (A != A.T).nnz == 0 and A.diagonal().sum() == 0
    # interior vertex of the grid triangulation has 6 neighbours
    assert A[9].nnz == 6
    assert g.adjacency(F, len(V) + 2).shape == (len(V) + 2, len(V) + 2)


@pytest.mark.parametrize("k", [0, 1, 2, 3])
def test_k_ring_matches_bfs(grid, k):
    V, F = grid
    R = g.k_ring(F, len(V), k)
    for i in (0, 9, 27, 63):
        assert set(R[i].indices) == _bfs_ring(F, len(V), i, k)


def test_k_ring_bad_k(grid):
    with pytest.raises(InputError):
        g.k_ring(grid[1], 64, -1)


def test_face_two_rings_fast(face_mesh):
    V, F = face_mesh
    g.k_ring(F, len(V), 2)  # warm-up
    t = time.perf_counter()
    R = g.k_ring(F, len(V), 2)
    elapsed = time.perf_counter() - t
    assert R.shape == (9409, 9409) and R[0, 0]
    assert elapsed < 0.5, f"2-rings of the face took {elapsed:.3f} s"


def test_geodesic_rings_on_plane():
    V, F = grid_mesh(15, 15)  # flat: geodesic distance == Euclidean distance
    h = 1 / 14
    r = 2.3 * h  # includes (2,1) steps at 2.236 h, whose edge paths are 2.414 h long
    exact = g.geodesic_rings(V, F, r, method="exact")
    graph = g.geodesic_rings(V, F, r, method="graph")
    D = np.linalg.norm(V[:, None] - V[None], axis=2)
    truth = sp.csr_matrix(D <= r + 1e-9)
    assert (exact != truth).nnz == 0
    # edge paths are never shorter than geodesics: graph rings are subsets
    assert (graph.astype(int) - exact.astype(int)).max() <= 0
    assert graph.sum() < exact.sum()


def test_geodesic_rings_respect_gaps():
    """Two sheets 1e-3 apart are near in space but not on the surface."""
    V1, F1 = grid_mesh(6, 6)
    V2 = V1 + [0, 0, 1e-3]
    V = np.r_[V1, V2]
    F = np.r_[F1, F1 + len(V1)]
    R = g.geodesic_rings(V, F, 0.5, method="exact")
    assert not R[:36, 36:].nnz and not R[36:, :36].nnz


def test_geodesic_rings_bad_input(grid):
    V, F = grid
    with pytest.raises(InputError, match="radius"):
        g.geodesic_rings(V, F, -1.0)
    with pytest.raises(InputError, match="method"):
        g.geodesic_rings(V, F, 0.1, method="heat")


def test_connected_components():
    V1, F1 = grid_mesh(4, 4)
    F = np.r_[F1, F1 + 16]
    n, labels = g.connected_components(F, 33)
    assert n == 3  # two grids and an isolated vertex
    assert len(set(labels[:16])) == 1 and labels[0] != labels[16] and labels[32] not in labels[:32]


def test_laplacian_and_mass(grid):
    V, F = grid_mesh(8, 8, bump=0.3)
    L = g.cotangent_laplacian(V, F)
    M = g.mass_matrix(V, F)
    assert abs(L - L.T).max() < 1e-12
    np.testing.assert_allclose(L @ np.ones(len(V)), 0, atol=1e-10)
    # negative semidefinite
    assert np.linalg.eigvalsh(L.toarray()).max() < 1e-10
    # mass sums to the surface area
    area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1).sum()
    assert M.sum() == pytest.approx(area)
    # linear functions are in the kernel of the cotangent Laplacian at interior vertices (flat grid)
    Vf, Ff = grid_mesh(6, 6)
    Lf = g.cotangent_laplacian(Vf, Ff)
    interior = [i for i in range(36) if 0 < i % 6 < 5 and 0 < i // 6 < 5]
    np.testing.assert_allclose((Lf @ Vf[:, 0])[interior], 0, atol=1e-10)
    with pytest.raises(InputError):
        g.mass_matrix(V, F, kind="nope")


def test_boundary_band_on_a_grid():
    """On a flat grid the edge-path distance to the border is the distance to the nearest side (axis steps)."""
    V, F = grid_mesh(11, 11)  # spacing 0.1
    for width, rows in ((0.0, 0), (0.1, 1), (0.25, 2)):
        band = g.boundary_band(V, F, width)
        d = np.minimum.reduce([V[:, 0], 1 - V[:, 0], V[:, 1], 1 - V[:, 1]])
        assert np.array_equal(band, d <= 0.1 * rows + 1e-9)


def test_boundary_band_closed_mesh_and_bad_width():
    """A closed surface (a tetrahedron) has no border; a negative or NaN width is a clear error."""
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    assert not g.boundary_band(V, F, 10.0).any()
    for bad in (-1.0, float("nan")):
        with pytest.raises(InputError, match="width"):
            g.boundary_band(V, F, bad)
