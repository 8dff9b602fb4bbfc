"""The tangent-framework core and TangentDeformer on small synthetic meshes."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from facegeom import geometry
from facegeom.errors import InputError, SolveError
from facegeom.interfaces import NotFittedError
from facegeom.methods.tangent import TangentDeformer, TangentSolver, alignment_matrix, kabsch, kabsch_many

from .conftest import grid_mesh, two_grids


def loop_reference(X, neighbourhoods, d):
    """Algorithm 1 written literally, one neighbourhood at a time."""
    N = X.shape[0]
    B = np.zeros((N, N))
    for I in neighbourhoods:
        I = np.asarray(I)
        k = len(I)
        Xi = X[I] - X[I].mean(axis=0)
        U, s, _ = np.linalg.svd(Xi, full_matrices=False)
        G = np.c_[np.ones(k) / np.sqrt(k), U[:, :d]]
        if k <= d + 1:
            continue
        B[np.ix_(I, I)] += np.eye(k) - G @ G.T
    return B


def random_neighbourhoods(N, rng, kmin=4, kmax=9):
    out = []
    for i in range(N):
        k = rng.integers(kmin, kmax + 1)
        others = rng.choice(np.delete(np.arange(N), i), size=k - 1, replace=False)
        out.append(np.r_[i, others])
    return out


@pytest.mark.parametrize("d", [1, 2, 3])
@pytest.mark.parametrize("D", [3, 12])
def test_batched_matches_loop(d, D):
    rng = np.random.default_rng(d * 10 + D)
    X = rng.standard_normal((30, D))
    nb = random_neighbourhoods(30, rng, kmin=d + 2, kmax=9 if D == 3 else 14)
    B = alignment_matrix(X, nb, d).toarray()
    np.testing.assert_allclose(B, loop_reference(X, nb, d), atol=1e-10)


def test_B_symmetric_psd_and_null_space():
    V, F = grid_mesh(7, 7, bump=0.4)
    R = geometry.k_ring(F, len(V), 2)
    B = alignment_matrix(V, R, 3)
    Bd = B.toarray()
    np.testing.assert_allclose(Bd, Bd.T, atol=1e-12)
    assert np.linalg.eigvalsh(Bd).min() > -1e-10
    np.testing.assert_allclose(B @ np.ones(len(V)), 0, atol=1e-10)
    np.testing.assert_allclose(B @ V, 0, atol=1e-10)  # d = 3 keeps every affine function of X
    # d = 2 on a curved patch does not keep the height coordinate
    assert np.abs(alignment_matrix(V, R, 2) @ V[:, 2]).max() > 1e-3


def test_neighbourhood_matrix_equals_lists():
    V, F = grid_mesh(6, 6, bump=0.2)
    R = geometry.k_ring(F, len(V), 1)
    lists = geometry.neighbourhood_lists(R)
    assert abs(alignment_matrix(V, R, 2) - alignment_matrix(V, lists, 2)).max() < 1e-12


def test_bad_core_input():
    X = np.zeros((4, 3))
    with pytest.raises(InputError, match="d must be"):
        alignment_matrix(X, [[0, 1]] * 4, 0)
    with pytest.raises(InputError, match="expected 4 neighbourhoods"):
        alignment_matrix(X, [[0, 1]], 1)
    with pytest.raises(InputError, match="out of range"):
        alignment_matrix(X, [[0, 9]] * 4, 1)
    with pytest.raises(InputError, match="empty"):
        alignment_matrix(X, [[0], [], [1], [2]], 1)
    with pytest.raises(InputError, match="NaN"):
        alignment_matrix(np.full((4, 3), np.nan), [[0, 1]] * 4, 1)


def test_hard_and_soft_constraints():
    V, F = grid_mesh(8, 8, bump=0.3)
    B = alignment_matrix(V, geometry.k_ring(F, len(V), 2), 3)
    lab = np.array([0, 7, 56, 63, 27])
    target = V[lab] + np.random.default_rng(1).normal(scale=0.1, size=(5, 3))
    hard = TangentSolver(B, lab).solve(target)
    np.testing.assert_allclose(hard[lab], target, atol=1e-12)
    soft = TangentSolver(B, lab, beta=1e8, dense_map=False).solve(target)
    np.testing.assert_allclose(soft, hard, atol=1e-5)
    loose = TangentSolver(B, lab, beta=1e-2).solve(target)
    assert np.abs(loose[lab] - target).max() > 1e-3  # a weak weight does not pin the labels
    # the dense map and the back-substitution agree
    np.testing.assert_allclose(TangentSolver(B, lab, dense_map=False).solve(target), hard, atol=1e-10)
    with pytest.raises(InputError, match="beta"):
        TangentSolver(B, lab, beta=-1.0)
    with pytest.raises(InputError, match="expected 5 labels"):
        TangentSolver(B, lab).solve(target[:3])


def test_component_without_label_is_a_clear_error():
    V, F = two_grids()
    with pytest.raises(SolveError, match="no label"):
        TangentDeformer().fit(V, F, [0, 4, 20, 24])


def test_too_few_labels_is_a_clear_error():
    V, F = grid_mesh(5, 5, bump=0.2)
    with pytest.raises(SolveError, match="cannot be solved"):
        TangentDeformer(d=3, field="position", align="none", smoothness=0).fit(V, F, [12])


CONFIGS = [
    {},  # the defaults
    {"d": 3, "field": "position", "align": "none", "smoothness": 0.0, "beta": None},  # the paper's plain configuration
    {"rings": 2, "d": 3, "smoothness": 0.0},
    {"beta": 1e6},
]


@pytest.mark.parametrize("params", CONFIGS)
def test_rest_positions_give_rest_mesh(params):
    V, F = grid_mesh(9, 9, bump=0.3)
    h = np.array([0, 8, 40, 72, 80, 20, 60])
    Y = TangentDeformer(**params).fit(V, F, h).deform(V[h])
    np.testing.assert_allclose(Y, V, atol=1e-6 if "beta" in params else 1e-9)


def _mesh_and_handles():
    V, F = grid_mesh(9, 9, bump=0.3)
    return V, F, np.array([0, 8, 40, 72, 80, 20, 60, 31])


@settings(max_examples=25, deadline=None)
@given(rotvec=st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3),
       shift=st.lists(st.floats(-5.0, 5.0), min_size=3, max_size=3),
       config=st.sampled_from([0, 1, 2]))
def test_rigid_motion_of_markers_moves_mesh_rigidly(rotvec, shift, config):
    V, F, h = _mesh_and_handles()
    R = Rotation.from_rotvec(rotvec).as_matrix()
    moved = V @ R.T + shift
    d = TangentDeformer(**CONFIGS[config]).fit(V, F, h)
    np.testing.assert_allclose(d.deform(moved[h]), moved, atol=1e-8)


def test_paper_configuration_reproduces_affine_motion():
    V, F, h = _mesh_and_handles()
    A = np.array([[1.2, 0.1, 0.0], [0.0, 0.9, 0.3], [0.1, 0.0, 1.1]])
    moved = V @ A.T + [0.5, -1, 2]
    d = TangentDeformer(d=3, field="position", align="none", smoothness=0.0, beta=None).fit(V, F, h)
    np.testing.assert_allclose(d.deform(moved[h]), moved, atol=1e-8)


def test_deterministic_and_markers_exact():
    V, F, h = _mesh_and_handles()
    P = V[h] + np.random.default_rng(0).normal(scale=0.05, size=(len(h), 3))
    a = TangentDeformer(beta=None).fit(V, F, h).deform(P)
    b = TangentDeformer(beta=None).fit(V, F, h).deform(P)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(a[h], P, atol=1e-12)
    c = TangentDeformer().fit(V, F, h)  # the self-tuned default: deterministic too
    np.testing.assert_array_equal(c.deform(P), c.deform(P))


def test_geodesic_neighbourhoods():
    V, F, h = _mesh_and_handles()
    P = V[h] + np.random.default_rng(0).normal(scale=0.05, size=(len(h), 3))
    Y = TangentDeformer(neighbourhood="geodesic", beta=None).fit(V, F, h).deform(P)
    np.testing.assert_allclose(Y[h], P, atol=1e-12)
    assert np.isfinite(Y).all()


def test_deformer_bad_input():
    V, F, h = _mesh_and_handles()
    for bad in ({"d": 0}, {"d": 4}, {"rings": 0}, {"beta": 0.0}, {"field": "x"}, {"align": "x"},
                {"smoothness": -1.0}, {"neighbourhood": "x"}, {"radius": -1.0}):
        with pytest.raises(InputError):
            TangentDeformer(**bad)
    d = TangentDeformer()
    with pytest.raises(NotFittedError):
        d.deform(V[h])
    with pytest.raises(InputError, match="out of range"):
        d.fit(V, F, [0, 1, 999])
    with pytest.raises(InputError, match="repeated"):
        d.fit(V, F, [0, 1, 1])
    d.fit(V, F, h)
    bad = V[h].copy()
    bad[0, 0] = np.nan
    with pytest.raises(InputError, match="NaN"):
        d.deform(bad)
    with pytest.raises(InputError, match="shape"):
        d.deform(V[h][:3])


def test_kabsch_recovers_rotation():
    rng = np.random.default_rng(0)
    P = rng.standard_normal((10, 3))
    R = Rotation.from_rotvec([0.3, -1.0, 2.0]).as_matrix()
    R2, t = kabsch(P, P @ R.T + [1, 2, 3])
    np.testing.assert_allclose(R2, R, atol=1e-12)
    np.testing.assert_allclose(t, [1, 2, 3], atol=1e-12)


@pytest.mark.parametrize("params", CONFIGS + [{"dense_map": False}, {"select": "ml"},
                                              {"select": "ml", "dense_map": False}])
def test_deform_many_equals_deform_frame_by_frame(params):
    from facegeom.pipelines.animate import drive_frames

    V, F, h = _mesh_and_handles()
    rng = np.random.default_rng(1)
    R = Rotation.from_rotvec(rng.normal(size=(7, 3))).as_matrix()
    P = np.einsum("tij,mj->tmi", R, V[h]) + rng.normal(size=(7, 1, 3)) + rng.normal(scale=0.05, size=(7, len(h), 3))
    dense = params.pop("dense_map", True) if "dense_map" in params else True
    d = TangentDeformer(**params).fit(V, F, h)
    if not dense:
        d.solver_.map_ = None  # the factor's multi-right-hand-side solve instead of the dense map
        d._coef_map = d._map_aug = None  # (and no map of the smoother's eigen-coefficients)
    one = np.stack([d.deform(p) for p in P])
    np.testing.assert_allclose(d.deform_many(P), one, rtol=0, atol=1e-12)
    Y, _ = drive_frames(d, P, block=3)  # blocks of 3, 3, 1 frames
    np.testing.assert_allclose(Y, one, rtol=0, atol=1e-12)
    with pytest.raises(InputError, match="shape"):
        d.deform_many(P[:, :3])
    bad = P.copy()
    bad[2, 1, 0] = np.inf
    with pytest.raises(InputError, match="NaN or inf"):
        d.deform_many(bad)


def test_kabsch_many_equals_kabsch_per_frame():
    rng = np.random.default_rng(2)
    P = rng.standard_normal((12, 3))
    Q = np.stack([P @ Rotation.from_rotvec(r).as_matrix().T + t + rng.normal(scale=0.1, size=(12, 3))
                  for r, t in zip(rng.normal(size=(5, 3)), rng.normal(size=(5, 3)))])
    Q = np.concatenate([Q, -Q[:1]])  # a reflected frame: still a rotation, det +1
    R, t = kabsch_many(P, Q)
    for k in range(Q.shape[0]):
        R1, t1 = kabsch(P, Q[k])
        np.testing.assert_allclose(R[k], R1, atol=1e-12)
        np.testing.assert_allclose(t[k], t1, atol=1e-12)
        assert np.linalg.det(R[k]) == pytest.approx(1.0)
