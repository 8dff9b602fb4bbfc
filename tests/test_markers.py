import numpy as np
import pytest

from facegeom.constants import FACE_AREA
from facegeom.errors import InputError
from facegeom.model import KINDS, NAMED, named_expression, random_sparse_expression
from facegeom.model import layouts as markers

from .conftest import grid_mesh


def test_farthest_points_spread():
    V, F = grid_mesh(11, 11)
    out = markers.farthest_points(V, F, np.array([0]), 3)
    # from a corner, the farthest point is the opposite corner, then the other two corners
    assert out[0] == 120 and set(out[1:]) == {10, 110}


def test_ict80_layout(face_model):
    L = markers.ict80(face_model)
    assert L.shape == (80,) and len(np.unique(L)) == 80
    np.testing.assert_array_equal(L[:68], face_model.landmarks)
    assert (L[68:] < FACE_AREA).all()
    np.testing.assert_array_equal(L, markers.ict80(face_model))  # deterministic
    # the extra 12 are spread: no two closer than 2 cm
    P = face_model.neutral[L[68:]]
    d = np.linalg.norm(P[:, None] - P[None], axis=2) + np.eye(12) * 1e9
    assert d.min() > 2.0


def test_layouts(face_model):
    r = markers.layout(face_model, "random60", seed=3)
    assert r.shape == (60,) and len(np.unique(r)) == 60
    assert not np.array_equal(r, markers.layout(face_model, "random60", seed=4))
    assert markers.layout(face_model, "landmarks68").shape == (68,)
    for bad in ("nope", "randomx", "random2"):
        with pytest.raises(InputError):
            markers.layout(face_model, bad)


def test_expressions_use_real_shape_names(face_model):
    for name in NAMED:
        for shape in named_expression(name):
            face_model.expression_index(shape)  # raises if unknown
    rng = np.random.default_rng(0)
    for _ in range(20):
        e = random_sparse_expression(face_model.expression_names, rng)
        assert 2 <= len(e) <= 6 and all(0.3 <= w <= 1 for w in e.values())
        assert not any(k.startswith("eyeLook") for k in e)
    assert "random-sparse" in KINDS
