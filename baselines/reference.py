"""The reference "markers move, nothing else"."""
from __future__ import annotations

import numpy as np

from baselines._common import fit_inputs
from facegeom.interfaces import Params, as_positions, check_fitted


class MarkersOnly(Params):
    """Return the rest mesh with only the marker vertices moved to their positions.

    The floor every deformer must beat: it shows how much of the error is the
    motion between the markers.
    """

    def __init__(self):
        self.vertices_ = None

    def fit(self, vertices, faces, handles) -> "MarkersOnly":
        self.vertices_, _, self.handles_ = fit_inputs(vertices, faces, handles)
        return self

    def deform(self, handle_positions) -> np.ndarray:
        check_fitted(self, "vertices_")
        P = as_positions(handle_positions, self.handles_.size)
        Y = self.vertices_.copy()
        Y[self.handles_] = P
        return Y
