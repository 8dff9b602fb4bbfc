"""libigl's ARAP and biharmonic deformation behind the Deformer interface."""
from __future__ import annotations

import igl
import numpy as np

from facegeom.baselines._common import apply_displacement_map, fit_inputs, require_handle_per_component
from facegeom.errors import InputError
from facegeom.interfaces import Params, as_positions, check_fitted, check_range, is_integer

ENERGIES = {
    "spokes": igl.ARAP_ENERGY_TYPE_SPOKES,
    "spokes_and_rims": igl.ARAP_ENERGY_TYPE_SPOKES_AND_RIMS,
    "elements": igl.ARAP_ENERGY_TYPE_ELEMENTS,
}


class ARAPDeformer(Params):
    """As-rigid-as-possible deformation (Sorkine & Alexa 2007), libigl's implementation.

    ``fit`` runs ``arap_precomputation`` (the factorization); every ``deform``
    starts from the rest mesh and runs ``iterations`` local/global steps, so
    results do not depend on earlier calls.

    Parameters
    ----------
    iterations : int
        Local/global iterations per ``deform``.
    energy : {"spokes_and_rims", "spokes", "elements"}
        libigl's ARAP energy for triangle meshes.
    """

    def __init__(self, iterations: int = 10, energy: str = "spokes_and_rims"):
        iterations = check_range("iterations", iterations, 1, 1000, "ARAP settles within tens of iterations",
                                 integer=True)
        if not isinstance(energy, str) or energy not in ENERGIES:
            raise InputError(f"energy must be one of {', '.join(ENERGIES)}, got {energy!r}")
        self.iterations, self.energy = int(iterations), energy
        self.data_ = None

    def fit(self, vertices, faces, handles) -> "ARAPDeformer":
        """Run libigl's ``arap_precomputation`` on the rest shape with the markers as fixed vertices.

        ``energy`` and ``iterations`` are set on an ``igl.ARAPData``, which keeps
        the factorization of the global step (3-D deformation).

        Parameters
        ----------
        vertices : (n, 3) float64
            The rest shape.
        faces : (m, 3) int64
            Triangles indexing ``vertices``.
        handles : (k,) int64
            Distinct marker vertex ids.

        Returns
        -------
        self

        Raises
        ------
        InputError
            Bad arrays.
        SolveError
            A mesh component without a marker.
        """
        V, F, H = fit_inputs(vertices, faces, handles)
        require_handle_per_component(F, V.shape[0], H, "arap")
        data = igl.ARAPData()
        data.max_iter = self.iterations
        data.energy = ENERGIES[self.energy]
        igl.arap_precomputation(V, F, 3, H.astype(np.int32), data)
        self.vertices_, self.faces_, self.handles_, self.data_ = V, F, H, data
        return self

    def deform(self, handle_positions) -> np.ndarray:
        """Run ``iterations`` ARAP local/global steps from the rest shape with the markers at ``handle_positions``.

        Every call starts from a copy of the rest vertices, so the result does not
        depend on earlier calls.

        Parameters
        ----------
        handle_positions : (k, 3) float64
            One position per marker, in the order of ``handles``.

        Returns
        -------
        (n, 3) float64
            The deformed vertices (markers at their positions).

        Raises
        ------
        InputError
            A wrong shape, NaN or inf; :class:`~facegeom.interfaces.NotFittedError`
            before :meth:`fit`.
        """
        check_fitted(self, "data_")
        P = as_positions(handle_positions, self.handles_.size)
        return np.asarray(igl.arap_solve(P, self.data_, self.vertices_.copy()))


class BiharmonicDeformer(Params):
    """k-harmonic interpolation of the marker displacements (libigl ``harmonic``).

    ``k = 2`` (biharmonic) is the classic smooth deformation of Botsch & Kobbelt /
    Jacobson et al.; ``k = 1`` harmonic, ``k = 3`` triharmonic. The result is
    linear in the displacements: ``fit`` solves once for unit data and keeps the
    ``(n, k)`` weight map, so ``deform`` is one matrix product.
    """

    def __init__(self, k: int = 2):
        if not is_integer(k) or not 1 <= k <= 3:
            raise InputError(f"k must be 1, 2 or 3, got {k!r}")
        self.k = int(k)
        self.map_ = None

    def fit(self, vertices, faces, handles) -> "BiharmonicDeformer":
        """Solve libigl's ``harmonic`` of order ``self.k`` once, for unit data at the markers.

        Column ``j`` of the solution is the k-harmonic field equal to 1 at marker
        ``j`` and 0 at the others; the solution is stored transposed, as the
        ``(k, n)`` map ``map_`` (``k`` markers).

        Parameters
        ----------
        vertices : (n, 3) float64
            The rest shape.
        faces : (m, 3) int64
            Triangles indexing ``vertices``.
        handles : (k,) int64
            Distinct marker vertex ids.

        Returns
        -------
        self

        Raises
        ------
        InputError
            Bad arrays, or libigl's solve giving NaN or inf (degenerate mesh).
        SolveError
            A mesh component without a marker.
        """
        V, F, H = fit_inputs(vertices, faces, handles)
        require_handle_per_component(F, V.shape[0], H, "biharmonic")
        W = igl.harmonic(V, F, H, np.eye(H.size), self.k)
        if not np.all(np.isfinite(W)):
            raise InputError("biharmonic: libigl's solve failed (degenerate mesh?); clean the mesh first")
        self.map_ = np.ascontiguousarray(np.asarray(W).T)  # (k, n)
        self.vertices_, self.handles_ = V, H
        return self

    def deform(self, handle_positions) -> np.ndarray:
        """Interpolate the marker displacements: ``V + W (handle_positions - V[handles])``, one dense product.

        Parameters
        ----------
        handle_positions : (k, 3) float64
            One position per marker, in the order of ``handles``.

        Returns
        -------
        (n, 3) float64
            The deformed vertices (markers set exactly to their positions).

        Raises
        ------
        InputError
            A wrong shape, NaN or inf; :class:`~facegeom.interfaces.NotFittedError`
            before :meth:`fit`.
        """
        check_fitted(self, "map_")
        P = as_positions(handle_positions, self.handles_.size)
        Y = apply_displacement_map(self.vertices_, self.handles_, self.map_, P)
        Y[self.handles_] = P
        return Y
