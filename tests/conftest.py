"""Shared fixtures: the real face data (the data lookup: $FACEGEOM_DATA, ../shared, the user cache) and small
synthetic meshes. `make test` fetches the data first when none is found (`facegeom data fetch --if-missing`)."""
from __future__ import annotations

import numpy as np
import pytest

from facegeom.errors import DataNotFoundError


@pytest.fixture(scope="session")
def face_model():
    from facegeom.model import load_face_model

    try:
        return load_face_model()
    except DataNotFoundError as exc:  # pragma: no cover - CI always has the data; `make test` fetches it
        pytest.skip(f"real face data not available (run `facegeom data fetch`): {exc}")


@pytest.fixture(scope="session")
def face_mesh(face_model):
    return face_model.neutral.copy(), face_model.triangles.copy()


def two_grids():
    """Two disjoint bumped 5x5 grids (vertices 0-24 and 25-49): a mesh with two components."""
    V1, F1 = grid_mesh(5, 5, bump=0.2)
    return np.r_[V1, V1 + [3, 0, 0]], np.r_[F1, F1 + 25]


def grid_mesh(nx: int = 8, ny: int = 8, bump: float = 0.0):
    """A triangulated (nx x ny)-vertex grid on [0,1]^2, optionally bumped in z."""
    x, y = np.meshgrid(np.linspace(0, 1, nx), np.linspace(0, 1, ny), indexing="xy")
    z = bump * np.sin(np.pi * x) * np.sin(np.pi * y)
    V = np.c_[x.ravel(), y.ravel(), z.ravel()]
    idx = np.arange(nx * ny).reshape(ny, nx)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, d = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    F = np.r_[np.c_[a, b, d], np.c_[a, d, c]]
    return V.astype(np.float64), F.astype(np.int64)


@pytest.fixture
def grid():
    return grid_mesh()
