"""Laplacian surface editing (Sorkine, Cohen-Or, Lipman, Alexa, Roessl, Seidel; SGP 2004).

Energy: ``sum_i || L(V')_i - T_i(V') delta_i ||^2`` with ``delta = L V`` the
rest differential coordinates and the markers as hard constraints. In
``mode="similarity"`` (the paper's), ``T_i`` is the linearised similarity
transform of vertex ``i`` (``s I + [h]_x`` plus a translation), chosen to best
map ``i`` and its 1-ring from rest to deformed positions; that best fit is a
linear function of the unknown positions (the paper's closed form), so the
whole energy stays one quadratic form in ``V'`` (its three coordinates
coupled). ``mode="plain"`` keeps ``delta`` as it is (``T_i = I``).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from facegeom.baselines._common import fit_inputs, require_handle_per_component
from facegeom.errors import InputError
from facegeom.geometry import adjacency, cotangent_laplacian
from facegeom.interfaces import Params, as_positions, check_fitted
from facegeom.methods.tangent import TangentSolver


def normalized_laplacian(V, F, weights: str) -> sp.csr_matrix:
    """``L`` with rows scaled to unit diagonal: ``(L V)_i = v_i - weighted mean of its 1-ring``."""
    n = V.shape[0]
    if weights == "cotangent":
        L = -cotangent_laplacian(V, F)  # positive diagonal
    else:
        A = adjacency(F, n).astype(np.float64)
        L = sp.diags(np.asarray(A.sum(axis=1)).ravel()) - A
    diag = L.diagonal()
    if (diag <= 0).any():
        raise InputError(f"laplacian: vertex {int(np.flatnonzero(diag <= 0)[0])} has no valid neighbour "
                         "(unreferenced or degenerate); clean the mesh first")
    return (sp.diags(1.0 / diag) @ L).tocsr()


def similarity_operator(V: np.ndarray, L: sp.csr_matrix) -> sp.csr_matrix:
    """The ``(3n, 3n)`` map ``x -> T(x) delta`` of the paper (x interleaved: x0,y0,z0,x1,...)."""
    n = V.shape[0]
    delta = L @ V
    # neighbourhood of i = i and its 1-ring (the off-diagonal pattern of L)
    P = (L != 0).tocsr()
    P.setdiag(True)
    P.sort_indices()
    sizes = np.diff(P.indptr)
    rows, cols, vals = [], [], []
    for m in np.unique(sizes):
        ids = np.flatnonzero(sizes == m)
        idx = P.indices[P.indptr[ids][:, None] + np.arange(m)]  # (g, m)
        p = V[idx]  # (g, m, 3)
        g = ids.size
        A = np.zeros((g, m, 3, 7))
        x, y, z = p[..., 0], p[..., 1], p[..., 2]
        one = np.ones_like(x)
        # unknowns (s, h1, h2, h3, tx, ty, tz);  T v = s v + h x v + t
        A[:, :, 0, 0], A[:, :, 0, 2], A[:, :, 0, 3], A[:, :, 0, 4] = x, z, -y, one
        A[:, :, 1, 0], A[:, :, 1, 1], A[:, :, 1, 3], A[:, :, 1, 5] = y, -z, x, one
        A[:, :, 2, 0], A[:, :, 2, 1], A[:, :, 2, 2], A[:, :, 2, 6] = z, y, -x, one
        A = A.reshape(g, 3 * m, 7)
        Apinv = np.linalg.pinv(A)  # (g, 7, 3m): the closed-form best fit
        dx, dy, dz = delta[ids, 0], delta[ids, 1], delta[ids, 2]
        Dm = np.zeros((g, 3, 7))  # T delta for the unknowns (s, h); translation does not act on delta
        Dm[:, 0, 0], Dm[:, 0, 2], Dm[:, 0, 3] = dx, dz, -dy
        Dm[:, 1, 0], Dm[:, 1, 1], Dm[:, 1, 3] = dy, -dz, dx
        Dm[:, 2, 0], Dm[:, 2, 1], Dm[:, 2, 2] = dz, dy, -dx
        C = Dm @ Apinv  # (g, 3, 3m)
        r = (3 * ids[:, None] + np.arange(3)[None, :])  # (g, 3)
        c = (3 * idx[:, :, None] + np.arange(3)[None, None, :]).reshape(g, 3 * m)  # (g, 3m)
        rows.append(np.repeat(r[:, :, None], 3 * m, axis=2).ravel())
        cols.append(np.repeat(c[:, None, :], 3, axis=1).ravel())
        vals.append(C.ravel())
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * n, 3 * n))


class LaplacianDeformer(Params):
    """Laplacian surface editing behind the Deformer interface.

    Parameters
    ----------
    mode : {"similarity", "plain"}
        ``similarity``: the paper's implicitly estimated, linearised similarity
        transforms (rotation and isotropic scale of each differential
        coordinate); ``plain``: differential coordinates kept as they are.
    weights : {"cotangent", "uniform"}
        Laplacian weights (libigl's cotangent matrix, or the graph Laplacian),
        each row normalised to a unit diagonal so ``delta_i`` is the offset of
        vertex ``i`` from the weighted mean of its 1-ring (the same scale on
        fine and coarse parts of the mesh).

    Notes
    -----
    ``fit`` builds and factorizes the normal equations once (sparse Cholesky);
    the solution is linear in the marker displacements, so ``deform`` is a
    dense product or one back-substitution.
    """

    def __init__(self, mode: str = "similarity", weights: str = "cotangent"):
        if mode not in ("similarity", "plain"):
            raise InputError(f"mode must be 'similarity' or 'plain', got {mode!r}")
        if weights not in ("cotangent", "uniform"):
            raise InputError(f"weights must be 'cotangent' or 'uniform', got {weights!r}")
        self.mode, self.weights = mode, weights
        self.solver_ = None

    def fit(self, vertices, faces, handles) -> "LaplacianDeformer":
        """Build and factorize the Laplacian-editing system of the rest shape.

        The Laplacian (``weights``) is normalised to a unit diagonal. ``plain``:
        factorizes ``L^T L``, one system shared by the three coordinates, with the
        markers as hard constraints (and a dense marker-to-vertex map when it is
        small enough). ``similarity``: builds the ``(3n, 3n)`` operator
        ``K = L (x) I_3 - T`` (``T`` the linearised similarity fit of every 1-ring,
        coordinates coupled) and factorizes ``K^T K`` with the ``3k`` marker
        coordinates constrained.

        Parameters
        ----------
        vertices : (n, 3) float64
            The rest shape.
        faces : (m, 3) int64
            Triangles indexing ``vertices``.
        handles : (k,) int64
            Distinct marker vertex ids (``k >= 3`` with ``mode="similarity"``).

        Returns
        -------
        self

        Raises
        ------
        InputError
            Bad arrays, too few markers, or a vertex without a valid neighbour.
        SolveError
            A mesh component without a marker, or a singular system.
        """
        V, F, H = fit_inputs(vertices, faces, handles, min_handles=3 if self.mode == "similarity" else 1)
        n = V.shape[0]
        require_handle_per_component(F, n, H, "laplacian")
        L = normalized_laplacian(V, F, self.weights)
        if self.mode == "plain":
            self.solver_ = TangentSolver((L.T @ L).tocsr(), H)
        else:
            K = sp.kron(L, sp.identity(3), format="csr") - similarity_operator(V, L)
            dofs = (3 * H[:, None] + np.arange(3)).ravel()
            # 3n unknowns: a dense map would cost more to build than it saves; back-substitute per frame
            self.solver_ = TangentSolver((K.T @ K).tocsr(), dofs, dense_map=False)
        self.vertices_, self.handles_ = V, H
        return self

    def deform(self, handle_positions) -> np.ndarray:
        """Move the markers to ``handle_positions``; the other vertices follow the Laplacian energy.

        Solves the factorized system for the displacement field whose marker values
        are ``handle_positions - vertices[handles]`` (the energy vanishes on the rest
        shape) and adds it to the rest shape.

        Parameters
        ----------
        handle_positions : (k, 3) float64
            One position per marker, in the order of ``handles``.

        Returns
        -------
        (n, 3) float64
            The deformed vertices (markers exact).

        Raises
        ------
        InputError
            A wrong shape, NaN or inf; :class:`~facegeom.interfaces.NotFittedError`
            before :meth:`fit`.
        """
        check_fitted(self, "solver_")
        P = as_positions(handle_positions, self.handles_.size)
        D = P - self.vertices_[self.handles_]  # the energy vanishes on the rest shape: solve for displacements
        if self.mode == "plain":
            return self.vertices_ + self.solver_.solve(D)
        return self.vertices_ + self.solver_.solve(D.reshape(-1, 1)).reshape(-1, 3)
