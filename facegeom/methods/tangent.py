"""The semi-supervised tangent framework (Zhang, Li & Liang, Signal Processing 2017).

One core, used for face driving (data points = mesh vertices, neighbourhoods =
mesh rings) and for expression retargeting (data points = frames,
neighbourhoods = temporal windows).

Algorithm 1 of the paper: for every neighbourhood ``I_i`` (``k_i`` points,
centred block ``X_i - mean``), take the ``d`` leading left singular vectors
``g_1..g_d`` (in ``R^{k_i}``), set ``G_i = [e/sqrt(k_i), g_1, .., g_d]`` and
accumulate ``B(I_i, I_i) += I - G_i G_i^T``. The target ``Y`` minimises
``trace(Y^T B Y) + beta * ||Y_labelled - Y_hat||^2`` (eq. 15), solved from the
linear system of eq. 18; with ``beta=None`` the labels are hard constraints
(eliminated), the limit ``beta -> inf``.

``B`` is assembled for all neighbourhoods at once: neighbourhoods are grouped
by size and each group's local PCAs are one batched ``eigh`` of the ``(D, D)``
covariances (``D`` is small: 3 for vertices) or, when ``D`` exceeds ``k``,
of the ``(k, k)`` Gram matrices. No Python loop runs per point.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from facegeom.errors import InputError, SolveError
from facegeom.interfaces import (
    Params,
    as_faces,
    as_handles,
    as_positions,
    as_vertices,
    check_fitted,
    check_range,
    is_finite_number,
    is_integer,
)
from facegeom.linalg import SPDSolver, factorize_solve_spd, factorize_spd
from facegeom.registration import kabsch

__all__ = [
    "as_neighbourhoods",
    "local_tangent_bases",
    "alignment_matrix",
    "TangentSolver",
    "TangentDeformer",
    "AUTO_LAMBDAS",
    "kabsch",
    "kabsch_many",
    "robust_kabsch",
    "robust_kabsch_many",
]


# --------------------------------------------------------------------------- neighbourhoods


def as_neighbourhoods(neighbourhoods, n: int) -> sp.csr_matrix:
    """Neighbourhoods as a boolean ``(n, n)`` CSR matrix (row ``i`` = the ``i``-th one).

    Accepts such a sparse matrix or a list of ``n`` integer index arrays.
    Duplicated indices within one neighbourhood are merged.
    """
    if sp.issparse(neighbourhoods):
        R = sp.csr_matrix(neighbourhoods)
        if R.shape != (n, n):
            raise InputError(f"neighbourhood matrix must be ({n}, {n}), got {R.shape}")
        R = R.astype(bool)
    else:
        lists = list(neighbourhoods)
        if len(lists) != n:
            raise InputError(f"expected {n} neighbourhoods (one per point), got {len(lists)}")
        lens = np.array([len(x) for x in lists])
        if (lens == 0).any():
            raise InputError(f"neighbourhood {int(np.flatnonzero(lens == 0)[0])} is empty")
        cols = np.concatenate([np.asarray(x).ravel() for x in lists]).astype(np.int64)
        if cols.min() < 0 or cols.max() >= n:
            raise InputError(f"neighbourhood index out of range [0, {n})")
        rows = np.repeat(np.arange(n), lens)
        R = sp.csr_matrix((np.ones(cols.size, bool), (rows, cols)), shape=(n, n))
    R.sum_duplicates()
    R.eliminate_zeros()
    R.sort_indices()
    if (np.diff(R.indptr) == 0).any():
        raise InputError(f"neighbourhood {int(np.flatnonzero(np.diff(R.indptr) == 0)[0])} is empty")
    return R


# --------------------------------------------------------------------------- local PCA, alignment matrix


def local_tangent_bases(P: np.ndarray, d: int, abs_tol: float = 0.0) -> np.ndarray:
    """Batched local PCA: the ``d`` leading left singular vectors of each centred block.

    Parameters
    ----------
    P : (m, k, D) float
        ``m`` neighbourhoods of ``k`` points each.
    d : int
    abs_tol : float
        Directions whose singular value is at most ``abs_tol`` are dropped too
        (in addition to those below ``1e-10`` times the block's largest one).

    Returns
    -------
    U : (m, k, d) float
        Orthonormal columns spanning the ``d`` leading directions of each centred
        block in ``R^k`` (a direction with zero singular value is returned as a
        zero column: the block has lower rank than ``d``).
    """
    _, k, D = P.shape
    Pc = P - P.mean(axis=1, keepdims=True)
    # the covariance path's products are np.matmul (a small GEMM per block), several times faster than the equal
    # einsum contractions over strided views (mesh vertices: 0.25 s less on 68,000 of them); the Gram path (frames
    # as points, D > k) keeps its einsum sums bitwise: its eigenvectors are taken as they come, and the
    # retargeter's weight selection has near-ties that rounding-level changes of B can flip
    if D <= k:
        C = np.matmul(Pc.transpose(0, 2, 1), Pc)  # (m, D, D) covariances
        w, V = np.linalg.eigh(C)  # ascending
        w = w[:, ::-1][:, :d]
        V = np.ascontiguousarray(V[:, :, ::-1][:, :, :d])
        s = np.sqrt(np.clip(w, 0, None))
        scale = np.max(s[:, :1], axis=1, keepdims=True)
        ok = (s > 1e-10 * np.maximum(scale, 1e-300)) & (s > abs_tol)
        U = np.matmul(Pc, V)
        U /= np.where(ok, s, 1.0)[:, None, :]
        U *= ok[:, None, :]
    else:
        Gm = np.einsum("mki,mli->mkl", Pc, Pc)  # (m, k, k) Gram matrices
        w, U = np.linalg.eigh(Gm)
        w = w[:, ::-1][:, :d]
        U = U[:, :, ::-1][:, :, :d]
        scale = np.max(w[:, :1], axis=1, keepdims=True)
        ok = (w > 1e-20 * np.maximum(scale, 1e-300)) & (w > abs_tol**2)
        U = U * ok[:, None, :]
    return U


#: Bytes of neighbourhood points gathered at once by :func:`alignment_matrix` (the local PCA's working set; the
#: result does not depend on it, a group's blocks are the same computed alone).
ALIGNMENT_BLOCK_BYTES = 32 * 2 ** 20


def alignment_matrix(X, neighbourhoods, d: int, weights=None, rank_tol: float = 0.0) -> sp.csr_matrix:
    """The alignment matrix ``B`` of Algorithm 1, as one sparse ``(N, N)`` matrix.

    Parameters
    ----------
    X : (N, D) float
        Data points (mesh vertices, or frames flattened to vectors).
    neighbourhoods : (N, N) sparse bool matrix or list of N index arrays
        The local structure of each point (the point itself included).
    d : int
        Manifold dimension (number of tangent directions). A neighbourhood with
        ``k_i <= d + 1`` points is fitted exactly by its affine map and adds a
        zero block.
    weights : (N,) float, optional
        Non-negative weight of each neighbourhood's block (default 1).
    rank_tol : float
        A local direction counts only if its singular value exceeds ``rank_tol``
        times the data's global spread ``sqrt(mean ||x - mean(x)||^2)``; weaker
        ones (e.g. rounding noise in a window where nothing moves) are dropped,
        so the block pins the window to its affine fit of fewer directions
        instead of leaving a free, arbitrarily large coefficient.

    Returns
    -------
    B : (N, N) scipy.sparse.csr_matrix
        Symmetric positive semidefinite; constants are in its null space, and so
        is every coordinate of ``X`` when ``d >= rank`` of the local blocks.
    """
    X = np.asarray(X, dtype=np.float64)
    if X.ndim != 2 or X.shape[0] == 0:
        raise InputError(f"X must have shape (N, D), got {X.shape}")
    if not np.all(np.isfinite(X)):
        raise InputError("X contains NaN or inf")
    if not is_integer(d) or d < 1:
        raise InputError(f"d must be a positive integer, got {d!r}")
    d = int(d)
    N = X.shape[0]
    R = as_neighbourhoods(neighbourhoods, N)
    if weights is not None:
        weights = np.asarray(weights, dtype=np.float64)
        if weights.shape != (N,) or not np.all(np.isfinite(weights)) or (weights < 0).any():
            raise InputError(f"weights must be ({N},) non-negative finite numbers")
    sizes = np.diff(R.indptr)
    abs_tol = 0.0
    if rank_tol > 0:
        abs_tol = float(rank_tol) * float(np.sqrt(((X - X.mean(axis=0)) ** 2).sum(axis=1).mean()))
    rows, cols, vals = [], [], []
    # 32-bit triplet indices when they fit: the COO -> CSR scatter of millions of them runs ~1.5x faster
    itype = np.int32 if N < 2**31 else np.int64
    for k in np.unique(sizes):
        ids = np.flatnonzero(sizes == k)
        if k <= d + 1:
            continue  # an affine map of d coordinates fits k <= d+1 points exactly
        # neighbourhoods in groups whose gathered points X[idx] stay near ALIGNMENT_BLOCK_BYTES: a long take's
        # frames as points (100,000 windows of 7 frames x 240 coordinates) would otherwise gather 1.3 GB at once
        step = max(1, ALIGNMENT_BLOCK_BYTES // (8 * k * max(X.shape[1], k)))
        for s in range(0, ids.size, step):
            part = ids[s:s + step]
            idx = R.indices[R.indptr[part][:, None] + np.arange(k)].astype(itype, copy=False)  # (m, k)
            U = local_tangent_bases(X[idx], d, abs_tol)
            # I - G G^T with G = [e/sqrt(k), U]
            blk = np.matmul(U, U.transpose(0, 2, 1))
            np.negative(blk, out=blk)
            blk -= 1.0 / k
            blk[:, np.arange(k), np.arange(k)] += 1.0
            if weights is not None:
                blk *= weights[part][:, None, None]
            rows.append(np.repeat(idx, k, axis=1).ravel())
            cols.append(np.tile(idx, (1, k)).ravel())
            vals.append(blk.ravel())
    if not vals:
        return sp.csr_matrix((N, N))
    B = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(N, N))
    B.sum_duplicates()
    return B


# --------------------------------------------------------------------------- solving eq. 18


class TangentSolver:
    """Factorize ``B`` (plus an optional extra SPD energy) once for a label set.

    Parameters
    ----------
    B : (N, N) sparse symmetric PSD matrix
    labelled : (M,) int
        Indices of the labelled points.
    beta : float or None
        Label weight of eq. 9 / 18; ``None`` = hard constraints (labels exact).

    dense_map : {"auto", True, False}
        The solution is linear in the labels, ``Y = W Y_hat``. With ``True``
        the ``(N, M)`` map ``W`` is precomputed in the constructor (``M``
        back-substitutions at once) and ``solve`` is one dense product, the
        fastest per-frame path for a few hundred labels; with ``False``
        ``solve`` back-substitutes every call. ``auto``: the map when it holds
        at most 8 million entries (64 MB). ``solve(Y_hat)`` then costs one
        back-substitution or one dense product.

    Raises
    ------
    SolveError
        A connected part of ``B``'s graph holds no label (its position would be
        free), or the system is singular for another reason.
    """

    def __init__(self, B, labelled, beta: float | None = None, dense_map="auto"):
        B = sp.csr_matrix(B, dtype=np.float64)
        N = B.shape[0]
        labelled = as_handles(labelled, N, "labelled")
        if beta is not None:
            beta = float(beta)
            if not is_finite_number(beta) or beta <= 0:
                raise InputError(f"beta must be a positive number or None (hard constraints), got {beta!r}")
        self.N, self.labelled, self.beta = N, labelled, beta
        self._check_components(B, labelled)
        if beta is None:
            mask = np.ones(N, bool)
            mask[labelled] = False
            self.free = np.flatnonzero(mask)
            Bf = B[self.free]
            A = Bf[:, self.free]
            self._coupling = Bf[:, labelled].tocsr()
            self._labelled_block = B[labelled][:, labelled].toarray()
        else:
            self.free = None
            A = B + sp.csr_matrix((np.full(labelled.size, beta), (labelled, labelled)), shape=(N, N))
        if dense_map == "auto":
            dense_map = N * labelled.size <= 8_000_000
        # the factor is checked on the labels' own right-hand sides (a long take's labels far apart leave the
        # system regular but too ill-conditioned for an arbitrary one); with the dense map those are its columns,
        # solved in the same pass as the check's random one
        M = labelled.size
        if dense_map:
            if beta is None:
                rhs = -self._coupling.toarray()  # (N_free, M)
            else:
                rhs = np.zeros((N, M))
                rhs[labelled, np.arange(M)] = beta
            probe = None  # the right-hand sides themselves
        elif beta is None:
            probe = self._coupling[:, :64].toarray()
        else:
            probe = np.zeros((N, min(M, 64)))
            probe[labelled[:probe.shape[1]], np.arange(probe.shape[1])] = beta
        self.solver: SPDSolver
        try:
            if dense_map:
                self.solver, sol = factorize_solve_spd(A, rhs, probe=probe)
            else:
                self.solver = factorize_spd(A, probe=probe if np.any(probe) else None)
        except SolveError as exc:
            raise SolveError(
                f"the tangent-framework system cannot be solved with these {labelled.size} labels "
                f"(too few labels, or labels in degenerate position): {exc}"
            ) from None
        self.map_ = None
        self._schur = None
        if dense_map:
            # stored transposed, (M, N): (D, M) @ (M, N) runs faster than (N, M) @ (M, D) for small D
            if beta is None:
                self.map_ = np.zeros((M, N))  # a labelled column copies its label exactly
                self.map_[:, self.free] = sol.T
                self.map_[np.arange(M), labelled] = 1.0
                self._schur = self._labelled_block + np.asarray(self._coupling.T @ sol)  # see schur_complement
            else:
                self.map_ = np.ascontiguousarray(sol.T)

    @staticmethod
    def _check_components(B: sp.csr_matrix, labelled: np.ndarray) -> None:
        from facegeom.geometry import unlabelled_components

        count, example, size = unlabelled_components(B, labelled)
        if count:
            raise SolveError(
                f"{count} connected part(s) of the data have no label (e.g. one of {size} points, "
                f"point {example}); every connected component needs labels"
            )

    def schur_complement(self) -> np.ndarray:
        """The energy of the labels alone: ``K = B_LL - B_LF B_FF^-1 B_FL``, ``(M, M)`` symmetric PSD.

        With hard constraints the minimum of ``trace(Y^T B Y)`` for labels ``Y_L``
        is ``trace(Y_L^T K Y_L)``; so soft labels with weight ``beta`` give the
        labelled values ``(I + K / beta)^-1 Y_hat`` and the whole solution is the
        hard map applied to them. Costs ``M`` back-substitutions without the dense map.

        Raises
        ------
        SolveError
            The solver has soft labels (``beta`` is not None).
        """
        if self.beta is not None:
            raise SolveError("the Schur complement is defined for hard constraints (beta=None)")
        K = self._schur  # made in the constructor from the dense map's solve
        if K is None:
            K = self._labelled_block + np.asarray(self._coupling.T @ self.solver.solve(-self._coupling.toarray()))
        return 0.5 * (K + K.T)

    def solve(self, Y_hat) -> np.ndarray:
        """Return ``Y (N, D)`` for labels ``Y_hat (M, D)``."""
        Y_hat = np.asarray(Y_hat, dtype=np.float64)
        if Y_hat.ndim == 1:
            Y_hat = Y_hat[:, None]
        if Y_hat.shape[0] != self.labelled.size:
            raise InputError(f"expected {self.labelled.size} labels, got {Y_hat.shape[0]}")
        if not np.all(np.isfinite(Y_hat)):
            raise InputError("labels contain NaN or inf")
        if self.map_ is not None:  # (M, N) for both forms: one product
            return np.ascontiguousarray((Y_hat.T @ self.map_).T)
        if self.beta is None:
            Y = np.empty((self.N, Y_hat.shape[1]))
            Y[self.labelled] = Y_hat
            Y[self.free] = self.solver.solve(-(self._coupling @ Y_hat))
            return Y
        rhs = np.zeros((self.N, Y_hat.shape[1]))
        rhs[self.labelled] = self.beta * Y_hat
        return self.solver.solve(rhs)

    def solve_rows(self, Z) -> np.ndarray:
        """:meth:`solve` in transposed layout: labels ``Z (D, M)`` -> ``Y^T (D, N)``.

        With the dense map this is one product ``Z @ map`` whose long rows suit
        many right-hand sides (e.g. the coordinates of many frames); no checks
        beyond the shape (callers validate their input).
        """
        Z = np.asarray(Z, dtype=np.float64)
        if Z.ndim != 2 or Z.shape[1] != self.labelled.size:
            raise InputError(f"expected labels of shape (D, {self.labelled.size}), got {Z.shape}")
        if self.map_ is None:
            return np.ascontiguousarray(self.solve(Z.T).T)
        return Z @ self.map_


# --------------------------------------------------------------------------- face driving


#: neighbourhood="geodesic": the largest radius, in mean edge lengths of the mesh (the default is 2.5).
MAX_RADIUS_EDGES = 20


def kabsch_many(P: np.ndarray, Q: np.ndarray, weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`kabsch` of ``P (m,3)`` onto every frame of ``Q (T,m,3)``, weights ``(T,m)``: ``R (T,3,3)``, ``t (T,3)``.
    """
    T, m = Q.shape[:2]
    p0, q0 = P.mean(axis=0), Q.mean(axis=1)  # both centred first: no cancellation far from the origin
    Pc, Qc = P - p0, Q - q0[:, None, :]
    # one small product per frame (np.matmul over the stack), so a frame's result does not depend on the batch
    if weights is None:
        mp, mq = np.zeros((T, 3)), np.zeros((T, 3))
        H = np.matmul(Pc.T, Qc) / m
    else:
        w = weights / weights.sum(axis=1, keepdims=True)  # (T, m)
        mp, mq = np.einsum("tm,mj->tj", w, Pc), np.einsum("tm,tmj->tj", w, Qc)
        # H_t = sum_i w_ti (P_i - mp_t)(Q_ti - mq_t)^T = (w_t P)^T Q_t - mp_t mq_t^T
        H = np.matmul(Pc.T[None] * w[:, None, :], Qc) - mp[:, :, None] * mq[:, None, :]
    mp, mq = mp + p0, mq + q0
    R = _rotations_svd(np.swapaxes(H, 1, 2))  # V diag(1, 1, s) U^T of H = U S V^T
    return R, mq - np.einsum("tij,tj->ti", R, mp)


#: Reweighting rounds of :func:`robust_kabsch` (3: the face error changes by < 0.1 % from 3 to 10 rounds, seed 3000).
ROBUST_ITERATIONS = 3


def robust_kabsch(P: np.ndarray, Q: np.ndarray, iterations: int = ROBUST_ITERATIONS
                  ) -> tuple[np.ndarray, np.ndarray]:
    """A rigid motion ``P -> Q`` that the markers moved by an expression do not drag along (IRLS :func:`kabsch`).

    Starts from the plain fit and reweights ``iterations`` times with Cauchy
    weights ``1 / (1 + (r_i / c)^2)`` of the residuals ``r_i``, ``c`` = their
    median: markers that move with the head (forehead, nose, temples) set the
    motion, those an expression moves count less. A rigid motion of all
    markers is returned exactly (any positive weights fit it).
    """
    R, t = kabsch(P, Q)
    for _ in range(iterations):
        r = np.linalg.norm(P @ R.T + t - Q, axis=1)
        c = np.median(r)
        if not c > 0:
            break
        R, t = kabsch(P, Q, 1.0 / (1.0 + (r / c) ** 2))
    return R, t


# flat indices (row-major in a 3 x 3 block) of the four factors of every cofactor:
# C[i, j] = X[i+1, j+1] X[i+2, j+2] - X[i+1, j+2] X[i+2, j+1] (indices mod 3)
# (all four as one index array, so a step gathers once)
_COF = np.array([3 * ((i + di) % 3) + (j + dj) % 3 for di, dj in ((1, 1), (2, 2), (1, 2), (2, 1))
                 for i in range(3) for j in range(3)])


def _cofactors(X: np.ndarray) -> np.ndarray:
    """Cofactor matrices of the 3 x 3 blocks of ``X (9, T)`` (row-major blocks), same layout."""
    g = X[_COF].reshape(4, 9, X.shape[1])
    return g[0] * g[1] - g[2] * g[3]


#: Scaled Newton steps of :func:`_nearest_rotations` before the frames that have not converged go to the SVD.
POLAR_STEPS = 8


def _rotations_svd(A: np.ndarray) -> np.ndarray:
    """The rotations nearest to the ``(T, 3, 3)`` stack ``A`` by batched SVDs (``V diag(1, 1, s) U^T`` of ``A^T``)."""
    U, _, Vt = np.linalg.svd(np.swapaxes(A, 1, 2))
    V, Ut = np.swapaxes(Vt, 1, 2), np.swapaxes(U, 1, 2)
    s = np.sign(np.linalg.det(V @ Ut))
    s[s == 0] = 1.0
    V = V.copy()
    V[:, :, 2] *= s[:, None]
    return V @ Ut


def _nearest_rotations(A: np.ndarray) -> np.ndarray:
    """The rotation nearest to each 3 x 3 block of ``A (3, 3, T)`` (entry ``[j, a, t]``), same layout.

    For ``det A > 0`` that is the orthogonal polar factor, found by Newton's
    iteration ``X <- (z X + X^-T / z) / 2`` with Frobenius-norm scaling ``z``
    (Higham), every 3 x 3 block at once with the inverse from cofactors, so the
    cost is a few elementwise passes over ``9 T`` numbers per step instead of
    ``T`` LAPACK calls. It converges quadratically; a frame whose last step
    still moved it by more than ``1e-8`` (so its error can exceed rounding),
    and every frame with ``det A <= 0`` (reflections, rank-deficient blocks),
    goes to :func:`_rotations_svd`, the reference it equals up to rounding.
    """
    T = A.shape[2]
    X = A.reshape(9, T)
    C = _cofactors(X)
    det = np.einsum("kt,kt->t", X[:3], C[:3])
    ok = det > 0
    if not ok.all():  # no Newton for these frames: identity stand-ins, then the SVD
        X = np.where(ok, X, np.eye(3).reshape(9, 1))
        C = np.where(ok, C, np.eye(3).reshape(9, 1))
        det = np.where(ok, det, 1.0)
    for step in range(POLAR_STEPS):
        if step:
            C = _cofactors(X)
            det = np.einsum("kt,kt->t", X[:3], C[:3])
        z = np.sqrt(np.sqrt(np.einsum("kt,kt->t", C, C) / np.einsum("kt,kt->t", X, X)) / det)
        Xn = X * (0.5 * z)
        Xn += C * (0.5 / (z * det))
        if step >= 3 or step == POLAR_STEPS - 1:  # (steps 1-3 leave > 1e-5 on blocks of condition ~4)
            d = Xn - X
            moved = np.einsum("kt,kt->t", d, d)
            X = Xn
            if (moved < 1e-16).all():
                break
        else:
            X = Xn
    bad = ~(ok & (moved < 1e-16))
    R = X.reshape(3, 3, T)
    if bad.any():
        R = R.copy()
        R[:, :, bad] = _rotations_svd(A[:, :, bad].transpose(2, 0, 1)).transpose(1, 2, 0)
    return R


def robust_kabsch_many(P: np.ndarray, Q: np.ndarray, iterations: int = ROBUST_ITERATIONS
                       ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`robust_kabsch` of ``P (m,3)`` onto every frame of ``Q (T,m,3)``, batched: ``R (T,3,3)``, ``t (T,3)``.

    The frames are laid out once as a ``(3T, m)`` block (row ``j T + t`` = the
    ``j``-th coordinate of frame ``t``'s centred markers). A reweighting round
    is one ``(3T, 4) x (4, m)`` product for the residuals (rotation and
    translation together), a few passes over the block (squared distances, a
    row sort for the median, Cauchy weights) and one ``(4T, m) x (m, 4)``
    product for all weighted cross-covariances, centroids and weight sums; the
    rotations come from :func:`_nearest_rotations`.
    """
    T, m = Q.shape[:2]
    Qm = np.ascontiguousarray(Q.transpose(2, 0, 1))  # (3, T, m)
    p0, q0 = P.mean(axis=0), Qm.mean(axis=2)  # both centred first: no cancellation far from the origin
    Qm -= q0[:, :, None]
    Qm = Qm.reshape(3 * T, m)  # row j T + t = Q[t, :, j] - q0[t, j]
    P1 = np.empty((m, 4))
    P1[:, :3], P1[:, 3] = P - p0, 1.0
    # plain fit: uniform weights, both centroids zero
    A = (Qm @ P1[:, :3]).reshape(3, T, 3).transpose(0, 2, 1)  # A[j, a, t] = m H_t[a, j]
    R, tc = _nearest_rotations(np.ascontiguousarray(A)), np.zeros((3, T))
    Rb = np.empty((3 * T, 4))
    W = np.empty((4 * T, m))
    lo, hi = (m - 1) // 2, m // 2  # the median is the mean of the sorted values lo and hi
    for _ in range(iterations):
        Rb[:, :3] = R.transpose(0, 2, 1).reshape(3 * T, 3)
        Rb[:, 3] = tc.ravel()
        D = Rb @ P1.T  # (3T, m): R_t p_i + tc_t
        D -= Qm
        D *= D
        w = W[3 * T:]
        np.add(D[:T], D[T:2 * T], out=w)
        w += D[2 * T:]  # (T, m) squared residuals
        s = np.sort(w, axis=1)  # the median of the distances from the squared ones (sqrt is monotonic)
        c = np.sqrt(s[:, hi]) if lo == hi else 0.5 * (np.sqrt(s[:, lo]) + np.sqrt(s[:, hi]))
        if not (c > 0).any():
            break
        w *= np.where(c > 0, 1.0 / np.where(c > 0, c * c, 1.0), 0.0)[:, None]  # Cauchy weights 1 / (1 + r^2 / c^2)
        w += 1.0
        np.divide(1.0, w, out=w)
        np.multiply(Qm.reshape(3, T, m), w, out=W[:3 * T].reshape(3, T, m))
        G = W @ P1  # (4T, 4)
        S = G[3 * T:, 3]
        mp = G[3 * T:, :3].T / S  # (3, T)
        mqr = G[:3 * T, 3].reshape(3, T)
        A = G[:3 * T, :3].reshape(3, T, 3).transpose(0, 2, 1) - mqr[:, None, :] * mp[None, :, :]
        R = _nearest_rotations(np.ascontiguousarray(A))
        tc = mqr / S - np.einsum("jat,at->jt", R, mp)
    t = (q0 + tc - np.einsum("jat,a->jt", R, p0)).T
    return np.ascontiguousarray(R.transpose(2, 0, 1)), t


#: Default weight of the biharmonic prior relative to the tangent alignment energy (see docs/benchmarks/driving.md:
#: tuned on ``bench drive`` seeds 1000-3000, not the reported seed 0).
SMOOTHNESS_DEFAULT = 30.0

#: Candidate label regularisations of ``beta="auto"``, relative to the mean eigenvalue of the labels' energy ``K``:
#: 0 (exact interpolation) and 19 log-spaced values from 1e-3 to 1e3 (a factor ~2.15 apart).
AUTO_LAMBDAS = np.r_[0.0, np.logspace(-3.0, 3.0, 19)]


#: Candidate spectral powers ``p`` of ``select="ml"``: the labels' prior covariance is ``K^-p`` (plus white noise);
#: 1 is the energy's own Gaussian prior, the others let the criterion follow markers whose detail decays more
#: slowly (``p < 1``) or faster (``p > 1``) across the energy's eigen-directions than the energy assumes.
AUTO_POWERS = np.array([0.5, 0.75, 1.0, 1.25, 1.5, 2.0])


class _AutoSmoother:
    """Soft labels whose weight is chosen per frame from the markers alone (``beta="auto"``).

    ``K = U diag(k) U^T`` is the labels' energy (the Schur complement of the
    alignment system). Soft labels with weight ``1 / lam`` give the labelled
    values ``S y`` with ``S = U diag(1 / (1 + lam k)) U^T``, an ``(M, M)``
    linear smoother; in the eigenbasis (``z = U^T y``) every candidate is a
    vector of factors ``1 / (1 + lam k^p)`` (``p = 1``: eq. 18 exactly).

    ``criterion="gcv"``: generalised cross-validation over ``lam`` with
    ``p = 1``, ``M ||(I - S) y||^2 / (M - tr S)^2 = M sum g^2 |z|^2 / (sum g)^2``
    with ``g = k / (1 + lam k)`` (``lam`` cancels, so ``lam = 0``, exact
    interpolation, is its limit). ``criterion="ml"``: restricted maximum
    likelihood of the model ``z_j ~ N(0, a (k_j^-p + lam))`` (a smooth field of
    prior covariance ``K^-p`` plus white marker noise; the energy's null space
    — constants — is left out, as REML does), over ``lam`` and ``p`` in
    :data:`AUTO_POWERS`, the scale ``a`` profiled out:
    ``3 r log(sum |z_j|^2 / v_j / (3 r)) + 3 sum log v_j``, ``v_j = k_j^-p + lam``
    (``r`` directions). The chosen factors are the Wiener filter of that model.
    Both scores are one ``(G, M)`` product per frame for the ``G`` candidates.
    """

    def __init__(self, K: np.ndarray, criterion: str = "gcv", lambdas: np.ndarray = AUTO_LAMBDAS):
        k, U = np.linalg.eigh(K)
        k = np.clip(k, 0.0, None)
        m = k.size
        self.U = np.ascontiguousarray(U)
        self.k = k  # the eigenvalues of K (clipped at 0)
        self.criterion = criterion
        lam = np.asarray(lambdas, dtype=np.float64)
        powers = AUTO_POWERS if criterion == "ml" else np.array([1.0])
        pos = k > 1e-9 * max(k.max(), 1e-300)  # the range of K (its null space holds the constants)
        keep, lin, const, lams, pows = [], [], [], [], []
        for p in powers:
            kk = np.where(pos, np.where(pos, k, 1.0) ** p, 0.0)
            scale = kk.sum() / m
            kk = kk / (scale if scale > 0 else 1.0)  # lam is relative to the mean eigenvalue of K^p
            keep.append(1.0 / (1.0 + lam[:, None] * kk[None, :]))  # (L, M)
            if criterion == "gcv":
                g = kk[None, :] / (1.0 + lam[:, None] * kk[None, :])
                den = g.sum(axis=1) ** 2
                lin.append(np.where(den[:, None] > 0, m * g**2 / np.where(den > 0, den, 1.0)[:, None], 0.0))
                const.append(np.zeros(lam.size))
            else:
                v = 1.0 / np.where(pos, kk, 1.0)[None, :] + lam[:, None]  # (L, M) prior + noise variances
                lin.append(np.where(pos[None, :], 1.0 / v, 0.0))
                const.append(3.0 * np.log(np.where(pos[None, :], v, 1.0)).sum(axis=1))
            lams.append(lam)
            pows.append(np.full(lam.size, p))
        self._keep = np.concatenate(keep)  # (G, M): the factor of each eigen-direction per candidate
        self._lin = np.concatenate(lin)  # (G, M): the score is linear in |z_j|^2 (GCV), or its log (ML)
        self._const = np.concatenate(const)
        self.lambdas, self.powers = np.concatenate(lams), np.concatenate(pows)
        self._n = 3.0 * max(int(pos.sum()), 1)

    def _choose(self, zz: np.ndarray) -> np.ndarray:
        """Candidate index per column of ``zz (M, T)`` (squared eigen-coefficients summed over x, y, z)."""
        S = self._lin @ zz  # (G, T)
        if self.criterion == "ml":
            S = self._n * np.log(np.maximum(S, 1e-300) / self._n) + self._const[:, None]
        g = np.argmin(S, axis=0)
        self.score = S[g, np.arange(S.shape[1])]  # the chosen candidates' scores (GCV: comparable across priors)
        return g

    def coefficients(self, y: np.ndarray) -> tuple[np.ndarray, int]:
        """The smoothed labels in the eigenbasis, ``diag(keep) U^T y`` for ``y (M, D)``, and the chosen candidate."""
        z = self.U.T @ y
        g = int(self._choose(np.einsum("md,md->m", z, z)[:, None])[0])
        return self._keep[g][:, None] * z, g

    def coefficients_many(self, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`coefficients` of every frame of ``Y (T, M, 3)``: ``(T, M, 3)`` and the ``(T,)`` candidates.

        All frames' eigen-coefficients come from one ``(M, M) x (M, 3T)`` product.
        """
        T, m = Y.shape[:2]
        Z = (self.U.T @ np.ascontiguousarray(Y.transpose(1, 0, 2)).reshape(m, 3 * T)).reshape(m, T, 3)
        g = self._choose(np.einsum("mti,mti->mt", Z, Z))
        return Z.transpose(1, 0, 2) * self._keep[g][:, :, None], g

    def smooth(self, y: np.ndarray) -> tuple[np.ndarray, int]:
        """``S y`` for labels ``y (M, D)`` (back in the labels' basis) and the chosen candidate."""
        c, g = self.coefficients(y)
        return self.U @ c, g


@dataclass
class _Config:
    neighbourhood: str
    rings: int
    radius: float | None
    d: int
    beta: float | None
    field: str
    align: str
    smoothness: float


class TangentDeformer(Params):
    """Face driving with the tangent framework (a :class:`~facegeom.interfaces.Deformer`).

    Data points are the mesh vertices, neighbourhoods are mesh rings, labels
    are the marker positions.

    Parameters
    ----------
    neighbourhood : {"kring", "geodesic"}
        ``kring``: all vertices within ``rings`` edges; ``geodesic``: all
        vertices within geodesic distance ``radius`` (libigl exact geodesics)
        joined with the 1-ring, so no neighbourhood is degenerate.
    rings : int
        Ring size for ``kring``.
    radius : float, optional
        Radius for ``geodesic``; default 2.5 x the mean edge length.
    d : int
        Number of tangent directions of the local PCA (the manifold dimension).
    beta : "auto", float or None
        Label weight (eq. 18). ``None`` = hard constraints (markers exact);
        a number = soft labels of that fixed weight; ``"auto"`` (default) =
        soft labels whose weight every ``deform`` chooses from the markers
        alone by generalised cross-validation (GCV) over :data:`AUTO_LAMBDAS`:
        near-exact interpolation for markers the smooth deformation explains,
        more smoothing for noisy ones. The fitted marker values are
        ``S(lam) y`` with ``S`` an ``(M, M)`` smoother from the
        eigendecomposition of the labels' energy (made in ``fit``); the rest of
        the mesh follows through the same precomputed marker-to-vertex map as
        with exact labels, so a deform costs one ``(M, M)`` product more.
    field : {"displacement", "position"}
        ``position`` is the paper: the unknown is the deformed positions ``Y``.
        ``displacement``: the unknown is ``Y - X``; the framework then asks the
        *motion* to be locally an affine map of the tangent coordinates. With
        ``d = 3`` both are identical (the rest shape lies in ``B``'s null
        space); with ``d = 2`` (the surface's own dimension) only the
        displacement form keeps the rest shape, while the position form
        flattens the face.
    align : {"robust", "rigid", "none"}
        ``rigid``: per ``deform``, estimate the best rigid motion of the markers
        (Kabsch, 80 points: microseconds), solve in the rest frame, move the
        result back. Makes the method exactly equivariant to rigid motions of
        all markers, whatever ``d`` and ``field``. ``robust`` (default): the
        same with :func:`robust_kabsch`, so the markers an expression moves
        (jaw, lips) do not tilt the estimated head motion.
    smoothness : float
        Weight (default :data:`SMOOTHNESS_DEFAULT`) of an added biharmonic energy ``L^T M^-1 L`` (libigl cotangent
        Laplacian and Voronoi mass) on the unknown field, relative to ``B``
        after both are scaled to the same trace. ``0`` = the framework alone.
    select : {"gcv", "ml"}
        How ``beta="auto"`` chooses: ``gcv`` (default) = generalised
        cross-validation over the weight; ``ml`` = restricted maximum
        likelihood over the weight and a spectral power of the labels' prior
        (:data:`AUTO_POWERS`). See :class:`_AutoSmoother`. ``ml`` was 1 % better
        than GCV at 0.5 mm noise on the tuning seed 0 of the realistic protocol
        but 1.5-3 % worse on the held-out seeds 1 and 2, so GCV stays the default.
    prior : {"uniform", "amplitude"}
        The prior of the markers' displacements with ``beta="auto"``.
        ``uniform`` (default): the labels' energy alone (every marker's
        displacement equally large a priori; smoothed by ``select``).
        ``amplitude`` (with ``select="gcv"``): the same energy
        with a per-marker amplitude estimated from the markers (the lengths of
        the ``uniform``-smoothed displacements, spread over neighbouring
        markers), so still regions are smoothed more than moving ones; its
        weight by GCV, and a frame keeps the ``uniform`` result where that has
        the lower GCV score
        (:class:`~facegeom.methods.tangent_prior.AmplitudeSmoother`). On the
        realistic protocol 5-8 % better than ``uniform`` at 0.5 mm noise, the
        same on clean markers, but one ``(M, M)`` tridiagonal reduction per
        frame: ~0.8 ms more per deform and ~4x the ``deform_many`` time per
        frame, so it is not the default (see docs/benchmarks/driving.md).

    Notes
    -----
    Defaults (``kring``, 1 ring, ``d=2``, displacement, robust alignment,
    smoothness 30 = :data:`SMOOTHNESS_DEFAULT`, ``beta="auto"``): see docs/benchmarks/driving.md for how they were
    chosen (``facegeom bench drive``, tuning seeds apart from the reported ones); the
    paper's plain configuration is ``d=3, field="position", align="none",
    smoothness=0, beta=None``.

    Attributes
    ----------
    lambda_ : float or (T,) float
        With ``beta="auto"``: the relative regularisation chosen by the last
        ``deform`` (per frame for ``deform_many``); 0 = exact interpolation. With
        ``prior="amplitude"`` it is the amplitude prior's weight (relative to
        the mean eigenvalue of its energy).
    power_ : float or (T,) float
        With ``beta="auto"``: the spectral power chosen with it (1 with ``select="gcv"``).
    """

    def __init__(self, neighbourhood: str = "kring", rings: int = 1, radius: float | None = None, d: int = 2,
                 beta: float | str | None = "auto", field: str = "displacement", align: str = "robust",
                 smoothness: float = SMOOTHNESS_DEFAULT, select: str = "gcv", prior: str = "uniform"):
        if neighbourhood not in ("kring", "geodesic"):
            raise InputError(f"neighbourhood must be 'kring' or 'geodesic', got {neighbourhood!r}")
        rings = check_range("rings", rings, 1, 10, "ten edge rings hold a face's features; the cost grows with "
                            "a ring's area", integer=True)
        if radius is not None and (not is_finite_number(radius) or radius <= 0):
            raise InputError(f"radius must be a positive number, got {radius!r}")
        if not is_integer(d) or not 1 <= d <= 3:
            raise InputError(f"d must be 1, 2 or 3 for mesh vertices, got {d!r}")
        if beta is not None and beta != "auto":
            if isinstance(beta, str):
                raise InputError(f"beta must be 'auto', a positive number or None (hard constraints), got {beta!r}")
            beta = check_range("beta", beta, 1e-6, 1e12, "below it the labels no longer hold the solution and the "
                                   "system is singular; beyond it they are hard constraints: use None")
        if field not in ("displacement", "position"):
            raise InputError(f"field must be 'displacement' or 'position', got {field!r}")
        if align not in ("robust", "rigid", "none"):
            raise InputError(f"align must be 'robust', 'rigid' or 'none', got {align!r}")
        smoothness = check_range("smoothness", smoothness, 0, 1e6, "a weight relative to the framework's term, "
                                 "which vanishes beyond it")
        if select not in ("ml", "gcv"):
            raise InputError(f"select must be 'ml' or 'gcv', got {select!r}")
        if prior not in ("amplitude", "uniform"):
            raise InputError(f"prior must be 'amplitude' or 'uniform', got {prior!r}")
        self.neighbourhood, self.rings, self.radius = neighbourhood, int(rings), radius
        self.d, self.beta, self.field, self.align = int(d), beta, field, align
        self.smoothness = float(smoothness)
        self.select = select
        self.prior = prior
        self.solver_ = None

    def __repr__(self) -> str:
        return "TangentDeformer(" + ", ".join(f"{k}={v!r}" for k, v in self.get_params().items()) + ")"

    # ---------------------------------------------------------------- fit
    def _neighbourhoods(self, V, F):
        from facegeom import geometry

        if self.neighbourhood == "kring":
            return geometry.k_ring(F, V.shape[0], self.rings)
        edge = geometry.mean_edge_length(V, F)
        radius = self.radius if self.radius is not None else 2.5 * edge
        if radius > MAX_RADIUS_EDGES * edge:
            raise InputError(f"radius {radius:g} is {radius / edge:.0f} mean edge lengths of this mesh: at most "
                             f"{MAX_RADIUS_EDGES} (a neighbourhood's cost grows with its area)")
        R = geometry.geodesic_rings(V, F, radius, method="exact")
        return (R + geometry.k_ring(F, V.shape[0], 1)).astype(bool).tocsr()

    def fit(self, vertices, faces, handles) -> "TangentDeformer":
        """Build and factorize the tangent-alignment system on the rest shape.

        Parameters
        ----------
        vertices : (n, 3) float64
            The rest shape.
        faces : (m, 3) int64
            Triangles indexing ``vertices``.
        handles : (k,) int64
            Distinct marker vertex ids (``k >= 3`` unless ``align="none"``).

        Returns
        -------
        self

        Raises
        ------
        InputError
            Bad arrays, too few markers, or vertices of zero area (with ``smoothness > 0``).
        """
        V = as_vertices(vertices)
        F = as_faces(faces, V.shape[0])
        H = as_handles(handles, V.shape[0])
        if H.size < 3 and self.align != "none":
            raise InputError(f"align={self.align!r} needs at least 3 markers, got {H.size}")
        R = self._neighbourhoods(V, F)
        B = alignment_matrix(V, R, self.d)
        if self.smoothness > 0:
            from facegeom import geometry

            L = geometry.cotangent_laplacian(V, F)
            M = geometry.mass_matrix(V, F).diagonal()
            if (M <= 0).any():
                raise InputError("the mesh has vertices with zero area (unreferenced or degenerate); clean it first")
            # L^T M^-1 L as one sparse product (the rows of L scaled in place of a diagonal matrix product)
            W = sp.csr_matrix((L.data * np.repeat(1.0 / M, np.diff(L.indptr)), L.indices, L.indptr), shape=L.shape)
            Q = (L.T @ W).tocsr()
            B = (B + (self.smoothness * B.diagonal().sum() / Q.diagonal().sum()) * Q).tocsr()
        self.vertices_, self.faces_, self.handles_ = V, F, H
        auto = isinstance(self.beta, str)
        self.solver_ = TangentSolver(B, H, None if auto else self.beta)
        self.smoother_ = _AutoSmoother(self.solver_.schur_complement(), self.select) if auto else None
        self.amplitude_ = None
        if auto and self.prior == "amplitude" and self.select == "gcv":  # (``ml`` is a study option: uniform only)
            from facegeom.methods.tangent_prior import AmplitudeSmoother

            Ks = self.smoother_.U @ (self.smoother_.k[:, None] * self.smoother_.U.T)
            self.amplitude_ = AmplitudeSmoother(Ks, V[H], AUTO_LAMBDAS)
        # with soft labels the map takes the smoothed eigen-coefficients directly: U^T map, (M, n)
        self._coef_map = None
        if auto and self.solver_.map_ is not None:
            self._coef_map = np.ascontiguousarray(self.smoother_.U.T @ self.solver_.map_)
        self._map_aug = None
        self.lambda_ = self.power_ = None
        return self

    # ---------------------------------------------------------------- deform
    def deform(self, handle_positions) -> np.ndarray:
        """Drive the rest shape with one frame of marker positions.

        Parameters
        ----------
        handle_positions : (k, 3) float64
            One position per marker, in the order of ``handles``.

        Returns
        -------
        (n, 3) float64
            The deformed vertices (markers exact when ``beta`` is None).
        """
        check_fitted(self, "solver_")
        P = as_positions(handle_positions, self.handles_.size)
        X, H = self.vertices_, self.handles_
        if self.align != "none":
            Rm, t = (robust_kabsch if self.align == "robust" else kabsch)(X[H], P)
            P = (P - t) @ Rm  # the labels in the rest frame: R^T (p - t)
        Z = P - X[H] if self.field == "displacement" else P
        if self.smoother_ is not None:
            c, g = self.smoother_.coefficients(Z)
            self.lambda_, self.power_ = float(self.smoother_.lambdas[g]), float(self.smoother_.powers[g])
            if self.amplitude_ is not None:  # the default smoothing sets the amplitude, the amplitude prior smooths
                f, lam, used = self.amplitude_.smooth(Z, self.smoother_.U @ c, self.smoother_.score[0])
                if used:
                    self.lambda_, c = lam, self.smoother_.U.T @ f
            if self._coef_map is not None:
                Y = np.ascontiguousarray((c.T @ self._coef_map).T)
            else:
                Y = self.solver_.solve(self.smoother_.U @ c)
        else:
            Y = self.solver_.solve(Z)
        if self.field == "displacement":
            Y += X
        if self.align != "none":
            Y = Y @ Rm.T + t
        return Y

    def deform_many(self, handle_positions) -> np.ndarray:
        """:meth:`deform` of every frame at once (the batched method of :class:`~facegeom.interfaces.Deformer`).

        One product with the precomputed marker-to-vertex map for all frames
        (or one multi-right-hand-side solve) instead of one per frame: the map is
        read from memory once per call, not once per frame. Equal to stacking
        :meth:`deform` up to rounding (~1e-15 relative).

        Parameters
        ----------
        handle_positions : (F, k, 3) float64
            Marker positions per frame.

        Returns
        -------
        (F, n, 3) float64
            The deformed vertices per frame (a transposed view of a ``(F, 3, n)`` array).
        """
        lin = self.linear_many(handle_positions)
        if lin is not None:  # the dense map: one product of the frames' (3, k + 4) rows with it
            C, basis = lin
            T, q = C.shape[0], basis.shape[0]
            return (C.reshape(3 * T, q) @ basis).reshape(T, 3, basis.shape[1]).transpose(0, 2, 1)
        return self._deform_many(handle_positions)

    def linear_many(self, handle_positions):
        """The frames of :meth:`deform_many` as coefficients on one fixed basis, or None without a dense map.

        Whatever the alignment and the soft labels' choice do per frame (robust rigid motion, GCV weight,
        amplitude prior: all in marker space), every frame's vertices are ``(C[t] @ basis).T``: the rows of the
        marker-to-vertex map, the rest shape's coordinates and a row of ones, combined by the frame's rotated
        labels, rotation and translation. :meth:`deform_many` is exactly that product.

        Parameters
        ----------
        handle_positions : (T, k, 3) float64
            Marker positions per frame.

        Returns
        -------
        (C, basis) or None
            ``C (T, 3, k + 4)`` float64 (row ``i``: coordinate ``i`` of the frame) and ``basis (k + 4, n)``
            float64 (read it, do not change it); None when the solver keeps no dense map (the frames are then
            solves, not one product).
        """
        check_fitted(self, "solver_")
        P = np.asarray(handle_positions, dtype=np.float64)
        k = self.handles_.size
        if P.ndim != 3 or P.shape[1:] != (k, 3):
            raise InputError(f"handle_positions must have shape (T, {k}, 3), got {P.shape}")
        if not np.all(np.isfinite(P)):
            raise InputError("handle_positions contain NaN or inf")
        if self.solver_.map_ is None:
            return None
        return self._deform_many(P, rows=True)

    def _deform_many(self, handle_positions, rows: bool = False):
        """:meth:`deform_many`; with ``rows`` (dense map only) :meth:`linear_many`'s ``(C, basis)`` instead."""
        check_fitted(self, "solver_")
        P = np.asarray(handle_positions, dtype=np.float64)
        k = self.handles_.size
        if P.ndim != 3 or P.shape[1:] != (k, 3):
            raise InputError(f"handle_positions must have shape (T, {k}, 3), got {P.shape}")
        if not np.all(np.isfinite(P)):
            raise InputError("handle_positions contain NaN or inf")
        T = P.shape[0]
        X, H = self.vertices_, self.handles_
        if self.align != "none":
            Rm, t = (robust_kabsch_many if self.align == "robust" else kabsch_many)(X[H], P)
            P = np.matmul(P - t[:, None, :], Rm)  # R^T (p - t), per frame
        else:
            Rm, t = np.broadcast_to(np.eye(3), (T, 3, 3)), np.zeros((T, 3))
        if self.field == "displacement":
            P = P - X[H]
        M = self.solver_.map_
        if self.smoother_ is not None:
            P0 = P
            P, g = self.smoother_.coefficients_many(P)
            self.lambda_, self.power_ = self.smoother_.lambdas[g], self.smoother_.powers[g]
            if self.amplitude_ is not None:  # as in deform; per-frame work stays in marker space
                F, lam, used = self.amplitude_.smooth_many(P0, np.matmul(self.smoother_.U, P), self.smoother_.score)
                self.lambda_ = np.where(used, lam, self.lambda_)
                P = np.matmul(self.smoother_.U.T, F)
            if self._coef_map is not None:
                M = self._coef_map  # the labels stay eigen-coefficients: no (M, M) product back
            else:
                P = np.matmul(self.smoother_.U, P)
        Zt = P.transpose(0, 2, 1)  # (T, 3, k): rows = the x, y, z label coordinates of each frame
        if M is None:  # no dense map: one multi-right-hand-side solve, then the rigid motion
            Y = self.solver_.solve_rows(Zt.reshape(3 * T, k)).reshape(T, 3, X.shape[0])
            if self.field == "displacement":
                Y += X.T
            Y = np.matmul(Rm, Y) + t[:, :, None]
        else:
            # Y_t^T = R_t Z_t^T map + R_t X^T + t_t 1^T = [R_t Z_t^T | R_t | t_t] @ [map; X^T; 1]: the rotation goes
            # to the small (3, k) labels and the rest position and translation into the same product, so the
            # (3T, n) result is written once instead of being passed over four more times
            if getattr(self, "_map_aug", None) is None:
                rest = X.T if self.field == "displacement" else np.zeros_like(X.T)
                self._map_aug = np.ascontiguousarray(np.vstack([M, rest, np.ones((1, X.shape[0]))]))
            C = np.concatenate([np.matmul(Rm, Zt), Rm, t[:, :, None]], axis=2)  # (T, 3, k + 4)
            if rows:
                return C, self._map_aug
            Y = (C.reshape(3 * T, k + 4) @ self._map_aug).reshape(T, 3, X.shape[0])
        return Y.transpose(0, 2, 1)  # a view: the caller's copy (e.g. into a float32 cache) is the only pass
