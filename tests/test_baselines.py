"""Baseline deformers on small synthetic meshes."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from facegeom.baselines.laplacian import LaplacianDeformer
from facegeom.baselines.libigl_deformers import ARAPDeformer, BiharmonicDeformer
from facegeom.baselines.rbf import RBFDeformer
from facegeom.baselines.reference import MarkersOnly
from facegeom.errors import InputError, SolveError
from facegeom.interfaces import NotFittedError

from .conftest import grid_mesh, two_grids

ALL = [RBFDeformer, LaplacianDeformer, ARAPDeformer, BiharmonicDeformer, MarkersOnly,
       lambda: LaplacianDeformer(mode="plain"), lambda: LaplacianDeformer(weights="uniform"),
       lambda: RBFDeformer(kernel="gaussian")]
IDS = ["rbf", "laplacian", "arap", "biharmonic", "markers-only", "laplacian-plain", "laplacian-uniform",
       "rbf-gaussian"]


def mesh():
    V, F = grid_mesh(9, 9, bump=0.3)
    return V, F, np.array([0, 8, 40, 72, 80, 20, 60, 31])


@pytest.mark.parametrize("make", ALL, ids=IDS)
def test_rest_positions_give_rest_mesh(make):
    V, F, h = mesh()
    Y = make().fit(V, F, h).deform(V[h])
    # libigl's ARAP iterations drift by ~1e-5 from an exact rest state; the linear methods are exact
    np.testing.assert_allclose(Y, V, atol=1e-4 if isinstance(make(), ARAPDeformer) else 1e-9)


@pytest.mark.parametrize("make", ALL, ids=IDS)
def test_markers_reach_targets_and_deterministic(make):
    V, F, h = mesh()
    P = V[h] + np.random.default_rng(0).normal(scale=0.05, size=(len(h), 3))
    a = make().fit(V, F, h).deform(P)
    b = make().fit(V, F, h).deform(P)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(a[h], P, atol=1e-9)
    assert np.isfinite(a).all()


@pytest.mark.parametrize("make", ALL, ids=IDS)
def test_not_fitted_and_nan(make):
    V, F, h = mesh()
    d = make()
    with pytest.raises(NotFittedError):
        d.deform(V[h])
    d.fit(V, F, h)
    bad = V[h].copy()
    bad[2, 1] = np.inf
    with pytest.raises(InputError, match="NaN or inf"):
        d.deform(bad)


@pytest.mark.parametrize("make", [LaplacianDeformer, ARAPDeformer, BiharmonicDeformer],
                         ids=["laplacian", "arap", "biharmonic"])
def test_component_without_marker(make):
    V, F = two_grids()
    with pytest.raises(SolveError, match="no marker"):
        make().fit(V, F, [0, 4, 20, 24])


def test_bad_parameters():
    for make in (lambda: RBFDeformer(kernel="nope"), lambda: RBFDeformer(smoothing=-1),
                 lambda: RBFDeformer(degree=1.5), lambda: LaplacianDeformer(mode="x"),
                 lambda: LaplacianDeformer(weights="x"), lambda: ARAPDeformer(iterations=0),
                 lambda: ARAPDeformer(energy="x"), lambda: BiharmonicDeformer(k=7)):
        with pytest.raises(InputError):
            make()


@settings(max_examples=25, deadline=None)
@given(rotvec=st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3),
       shift=st.lists(st.floats(-5.0, 5.0), min_size=3, max_size=3))
def test_rbf_reproduces_rigid_motion(rotvec, shift):
    V, F, h = mesh()
    R = Rotation.from_rotvec(rotvec).as_matrix()
    moved = V @ R.T + shift
    np.testing.assert_allclose(RBFDeformer().fit(V, F, h).deform(moved[h]), moved, atol=1e-8)


def test_arap_and_laplacian_nearly_rigid():
    """ARAP converges to a rigid motion (slowly, from the rest pose); linearised Laplacian editing
    only approximately (its linearised rotations also scale)."""
    V, F, h = mesh()
    R = Rotation.from_rotvec([0.0, 0.0, 0.5]).as_matrix()
    moved = V @ R.T + [1, 2, 3]
    err_arap = np.abs(ARAPDeformer(iterations=100).fit(V, F, h).deform(moved[h]) - moved).max()
    err_lap = np.abs(LaplacianDeformer().fit(V, F, h).deform(moved[h]) - moved).max()
    err_plain = np.abs(LaplacianDeformer(mode="plain").fit(V, F, h).deform(moved[h]) - moved).max()
    assert err_arap < 1e-3
    assert err_lap < err_plain  # the similarity transforms do rotate the differential coordinates


def test_biharmonic_reproduces_affine_interior_on_plane():
    V, F = grid_mesh(9, 9)
    boundary = np.array([i for i in range(81) if i % 9 in (0, 8) or i // 9 in (0, 8)])
    ring2 = np.array([i for i in range(81) if i % 9 in (1, 7) or i // 9 in (1, 7)])
    h = np.union1d(boundary, ring2)
    A = np.array([[1.1, 0.2, 0.0], [0.0, 0.9, 0.0], [0.3, 0.1, 1.0]])
    moved = V @ A.T
    np.testing.assert_allclose(BiharmonicDeformer().fit(V, F, h).deform(moved[h]), moved, atol=1e-8)
