"""The reference "markers move, nothing else"."""
from __future__ import annotations

import numpy as np

from facegeom.baselines._common import fit_inputs
from facegeom.interfaces import Params, as_positions, check_fitted


class MarkersOnly(Params):
    """Return the rest mesh with only the marker vertices moved to their positions.

    The floor every deformer must beat: it shows how much of the error is the
    motion between the markers.
    """

    def __init__(self):
        self.vertices_ = None

    def fit(self, vertices, faces, handles) -> "MarkersOnly":
        """Validate and keep the rest shape and the marker ids (nothing to precompute).

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
        """
        self.vertices_, _, self.handles_ = fit_inputs(vertices, faces, handles)
        return self

    def deform(self, handle_positions) -> np.ndarray:
        """Return a copy of the rest shape with only the marker vertices moved to ``handle_positions``.

        Parameters
        ----------
        handle_positions : (k, 3) float64
            One position per marker, in the order of ``handles``.

        Returns
        -------
        (n, 3) float64
            The deformed vertices.

        Raises
        ------
        InputError
            A wrong shape, NaN or inf; :class:`~facegeom.interfaces.NotFittedError`
            before :meth:`fit`.
        """
        check_fitted(self, "vertices_")
        P = as_positions(handle_positions, self.handles_.size)
        Y = self.vertices_.copy()
        Y[self.handles_] = P
        return Y
