"""The faster TangentDeformer.fit equals the reference computation it replaced (within rounding).

Each faster path is pinned against the straightforward form it replaced: the batched local PCA's matmul
products (einsum before), the 1-ring without a product, the biharmonic energy as one sparse product, the
factorization's check solved with the dense map's columns (``factorize_solve_spd``), the map written in its
transposed layout and the Schur complement taken from the same solve.
"""
import numpy as np
import pytest
import scipy.sparse as sp

from facegeom import geometry
from facegeom.errors import SolveError
from facegeom.linalg import factorize_solve_spd, factorize_spd
from facegeom.methods.tangent import TangentDeformer, TangentSolver, alignment_matrix, local_tangent_bases

from .conftest import grid_mesh


def einsum_bases(P, d, abs_tol=0.0):
    """local_tangent_bases as it was written with einsum (the reference)."""
    _, k, D = P.shape
    Pc = P - P.mean(axis=1, keepdims=True)
    if D <= k:
        w, V = np.linalg.eigh(np.einsum("mki,mkj->mij", Pc, Pc))
        w, V = w[:, ::-1][:, :d], V[:, :, ::-1][:, :, :d]
        s = np.sqrt(np.clip(w, 0, None))
        ok = (s > 1e-10 * np.maximum(s[:, :1], 1e-300)) & (s > abs_tol)
        return np.einsum("mki,mij->mkj", Pc, V) / np.where(ok, s, 1.0)[:, None, :] * ok[:, None, :]
    w, U = np.linalg.eigh(np.einsum("mki,mli->mkl", Pc, Pc))
    w, U = w[:, ::-1][:, :d], U[:, :, ::-1][:, :, :d]
    ok = (w > 1e-20 * np.maximum(w[:, :1], 1e-300)) & (w > abs_tol**2)
    return U * ok[:, None, :]


def reference_alignment(X, R, d):
    """alignment_matrix with the einsum bases and 64-bit COO triplets."""
    N = X.shape[0]
    sizes = np.diff(R.indptr)
    rows, cols, vals = [], [], []
    for k in np.unique(sizes):
        if k <= d + 1:
            continue
        ids = np.flatnonzero(sizes == k)
        idx = R.indices[R.indptr[ids][:, None] + np.arange(k)].astype(np.int64)
        U = einsum_bases(X[idx], d)
        blk = np.eye(k) - 1.0 / k - np.einsum("mkd,mld->mkl", U, U)
        rows.append(np.repeat(idx, k, axis=1).ravel())
        cols.append(np.tile(idx, (1, k)).ravel())
        vals.append(blk.ravel())
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(N, N))


def reference_k_ring(F, n, k):
    A = geometry.adjacency(F, n)
    step = (A + sp.identity(n, dtype=bool, format="csr")).astype(np.int8).tocsr()
    R = sp.identity(n, dtype=np.int8, format="csr")
    for _ in range(k):
        R = (R @ step).tocsr()
        R.data[:] = 1
    return R.astype(bool)


def reference_system(V, F, H, smoothness=30.0):
    """The fit's system as it was assembled: einsum local PCA, L^T diag(1/M) L, the same scaling."""
    B = reference_alignment(V, reference_k_ring(F, len(V), 1).tocsr(), 2)
    L = geometry.cotangent_laplacian(V, F)
    M = geometry.mass_matrix(V, F).diagonal()
    Q = (L.T @ sp.diags(1.0 / M) @ L).tocsr()
    return (B + (smoothness * B.diagonal().sum() / Q.diagonal().sum()) * Q).tocsr()


@pytest.mark.parametrize("D, d", [(3, 1), (3, 2), (3, 3), (12, 2), (12, 3)])
def test_bases_match_einsum(D, d):
    rng = np.random.default_rng(D + d)
    P = rng.standard_normal((50, 7, D))
    if D <= 7:  # rank-deficient blocks: their zero columns too (the Gram path's null space is rounding noise)
        P[:5, :, 2:] = 0.0
    got, ref = local_tangent_bases(P, d), einsum_bases(P, d)
    # columns are defined up to sign; the projector U U^T is what enters B
    np.testing.assert_allclose(got @ got.transpose(0, 2, 1), ref @ ref.transpose(0, 2, 1), atol=1e-12)


@pytest.mark.parametrize("k", [0, 1, 2, 3])
def test_k_ring_matches_products(k):
    V, F = grid_mesh(9, 7, bump=0.3)
    got, ref = geometry.k_ring(F, len(V), k), reference_k_ring(F, len(V), k)
    assert (got != ref).nnz == 0 and got.dtype == bool and got.has_sorted_indices


def test_alignment_matches_reference_on_face(face_model):
    V, F = face_model.neutral, face_model.triangles
    R = geometry.k_ring(F, len(V), 1)
    got, ref = alignment_matrix(V, R, 2), reference_alignment(V, R, 2)
    assert abs(got - ref).max() < 1e-12 * abs(ref).max()


def test_factorize_solve_matches_factorize():
    V, F = grid_mesh(12, 10, bump=0.3)
    A = (sp.identity(len(V)) * 1e-3 - geometry.cotangent_laplacian(V, F)).tocsr()
    b = np.random.default_rng(0).standard_normal((len(V), 5))
    s, x = factorize_solve_spd(A, b)
    np.testing.assert_allclose(x, factorize_spd(A).solve(b), rtol=0, atol=1e-12 * np.abs(x).max())
    np.testing.assert_allclose(s.solve(b), x, rtol=0, atol=1e-12 * np.abs(x).max())
    np.testing.assert_allclose(A @ x, b, atol=1e-9)
    _, x1 = factorize_solve_spd(A, b[:, 0])
    assert x1.shape == (len(V),)
    np.testing.assert_allclose(x1, x[:, 0], atol=1e-12 * np.abs(x).max())
    # a singular matrix is refused, also when the right-hand side is zero (it is then no probe)
    Ls = -geometry.cotangent_laplacian(V, F)
    for rhs in (b, np.zeros_like(b)):
        with pytest.raises(SolveError):
            factorize_solve_spd(Ls, rhs)


@pytest.mark.parametrize("beta", [None, 0.5])
def test_solver_dense_map_matches_solves(beta):
    V, F = grid_mesh(14, 12, bump=0.4)
    H = np.arange(0, len(V), 9)
    B = reference_system(V, F, H)
    dense = TangentSolver(B, H, beta, dense_map=True)
    plain = TangentSolver(B, H, beta, dense_map=False)
    Z = np.random.default_rng(1).standard_normal((H.size, 3))
    a, b = dense.solve(Z), plain.solve(Z)
    assert np.abs(a - b).max() < 1e-10 * np.abs(b).max()
    if beta is None:
        K, K0 = dense.schur_complement(), plain.schur_complement()
        assert np.abs(K - K0).max() < 1e-10 * np.abs(K0).max()
        np.testing.assert_allclose(dense.map_[:, H], np.eye(H.size), atol=0)


def test_deformer_matches_reference_system():
    V, F = grid_mesh(16, 15, bump=0.5)
    H = np.arange(3, len(V), 11)
    td = TangentDeformer(beta=None, align="none").fit(V, F, H)
    ref = TangentSolver(reference_system(V, F, H), H, None, dense_map=False)
    P = V[H] + np.random.default_rng(2).normal(0, 0.02, (H.size, 3))
    Y = td.deform(P)
    assert np.abs(Y - (V + ref.solve(P - V[H]))).max() < 1e-10
    assert np.abs(Y[H] - P).max() < 1e-12
