"""Input checks shared by the baseline deformers."""
from __future__ import annotations

from facegeom.errors import SolveError
from facegeom.geometry import adjacency, unlabelled_components
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


def apply_displacement_map(V, H, map_, P):
    """``V + W (P - V[H])`` for a precomputed ``(k, n)`` map ``W^T``: one dense product per frame."""
    D = P - V[H]
    return V + (D.T @ map_).T


def require_handle_per_component(F, n: int, H, method: str) -> None:
    """A mesh component without a handle leaves its position free: a clear error."""
    count, example, size = unlabelled_components(adjacency(F, n), H)
    if count:
        raise SolveError(
            f"{method}: {count} mesh component(s) have no marker (e.g. the one holding vertex "
            f"{example}, {size} vertices); "
            "put a marker on every component or remove it (clean the mesh with largest_component=True)"
        )
