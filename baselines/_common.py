"""Input checks shared by the baseline deformers."""
from __future__ import annotations

import numpy as np
from scipy.sparse import csgraph

from facegeom.errors import SolveError
from facegeom.geometry import adjacency
from facegeom.interfaces import as_faces, as_handles, as_vertices


def fit_inputs(vertices, faces, handles, min_handles: int = 1):
    """Validate the rest mesh and handles; returns (V, F, H) as float64/int64."""
    V = as_vertices(vertices)
    F = as_faces(faces, V.shape[0])
    H = as_handles(handles, V.shape[0])
    if H.size < min_handles:
        from facegeom.errors import InputError

        raise InputError(f"this method needs at least {min_handles} markers, got {H.size}")
    return V, F, H


def require_handle_per_component(F, n: int, H, method: str) -> None:
    """A mesh component without a handle leaves its position free: a clear error."""
    count, comp = csgraph.connected_components(adjacency(F, n), directed=False)
    has = np.zeros(count, bool)
    has[comp[H]] = True
    if not has.all():
        bad = int(np.flatnonzero(~has)[0])
        raise SolveError(
            f"{method}: {int((~has).sum())} mesh component(s) have no marker (e.g. the one holding vertex "
            f"{int(np.flatnonzero(comp == bad)[0])}, {int((comp == bad).sum())} vertices); "
            "put a marker on every component or remove it (facegeom clean --largest)"
        )
