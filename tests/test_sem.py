"""Selective Expression Manipulation: the greedy core, the three target kinds, options and bad input."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from facegeom import registry
from facegeom.errors import InputError
from facegeom.methods.sem import SEMFitter, sem_gram, sem_vectors
from facegeom.model import (
    FIT_LANDMARKS_23,
    BlendshapeRig,
    LandmarkTarget,
    MeshTarget,
    PinholeCamera,
    PointCloudTarget,
    look_at_camera,
)


def tiny_rig(B=5, n=30, seed=0, orthogonal=False):
    rng = np.random.default_rng(seed)
    neutral = rng.normal(size=(n, 3))
    D = rng.normal(size=(B, n * 3))
    if orthogonal:
        D = np.linalg.qr(D.T)[0].T * rng.uniform(0.5, 2.0, (B, 1))
    tris = np.array([[0, 1, 2], [2, 3, 4]])
    return BlendshapeRig(neutral, D.reshape(B, n, 3), [f"s{i}" for i in range(B)], tris)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_orthogonal_shapes_are_recovered_exactly(seed):
    """With mutually orthogonal deltas, greedy ERSim coefficients are the exact projection."""
    rng = np.random.default_rng(seed)
    rig = tiny_rig(6, 20, seed % 3, orthogonal=True)
    w = np.where(rng.random(6) < 0.5, rng.uniform(0.1, 1.0, 6), 0.0)
    r = SEMFitter().fit(rig, MeshTarget(rig.evaluate(w)))
    np.testing.assert_allclose(r.weights, w, atol=1e-9)


def test_single_shape_on_the_real_rig(face_model):
    rig = BlendshapeRig.from_face_model(face_model, face_model.random_identity(3))
    j = rig.shape_index("jawOpen")
    w = np.zeros(rig.n_shapes)
    w[j] = 0.7
    r = SEMFitter().fit(rig, MeshTarget(rig.evaluate(w)))
    assert r.info["order"][0] == j and r.info["selected"] == ["jawOpen"]
    np.testing.assert_allclose(r.weights, w, atol=1e-9)


def test_batched_equals_single(face_model):
    rig = BlendshapeRig.from_face_model(face_model)
    rng = np.random.default_rng(1)
    W = np.where(rng.random((6, rig.n_shapes)) < 0.1, rng.random((6, rig.n_shapes)), 0)
    T = rig.neutral[None] + np.tensordot(W, rig.deltas, 1)
    f = SEMFitter()
    E = np.stack([r.weights for r in f.fit_many(rig, T)])
    for k in range(6):
        np.testing.assert_allclose(E[k], f.fit(rig, MeshTarget(T[k])).weights, atol=1e-10)


def test_exclusion_drops_a_cancelling_candidate():
    """b cancels the motion of a; without exclusion greedy would later pick it."""
    a = np.array([1.0, 0.0, 0.0])
    b = np.array([-0.9, 1.0, 0.0])  # moves against a, and sideways
    c = np.array([0.0, 0.5, 1.0])
    M = np.stack([a, b, c])
    target = 1.0 * a + 0.05 * np.array([0, 1, 0]) + 0.6 * c
    e_ex, order = sem_vectors(M, target, exclusion=True)
    e_no, _ = sem_vectors(M, target, exclusion=False)
    assert e_ex[1] == 0.0 and e_no[1] > 0.0
    assert order[0] == 0


def test_gram_core_matches_explicit_vectors():
    rng = np.random.default_rng(2)
    M = rng.normal(size=(7, 40))
    d = rng.normal(size=40)
    e1, o1 = sem_gram(M @ d, M @ M.T, d @ d)
    e2, o2 = sem_vectors(M, d)
    np.testing.assert_array_equal(e1, e2)
    assert np.all(e1 >= 0)


def test_clamp_and_refit(face_model):
    rig = BlendshapeRig.from_face_model(face_model, face_model.random_identity(4))
    rng = np.random.default_rng(5)
    w = np.zeros(rig.n_shapes)
    w[rng.choice(rig.n_shapes, 4, replace=False)] = rng.uniform(0.3, 0.9, 4)
    T = MeshTarget(rig.evaluate(w))
    plain = SEMFitter().fit(rig, T)
    refit = SEMFitter(refit=True, clamp=True).fit(rig, T)
    assert refit.weights.max() <= 1.0 and refit.weights.min() >= 0.0
    sq = lambda r: ((r.vertices - T.vertices) ** 2).sum()  # noqa: E731
    assert sq(refit) <= sq(plain) * (1 + 1e-9)  # least squares on the selected support: never worse
    assert set(np.flatnonzero(refit.weights)) <= set(np.flatnonzero(plain.weights))


@pytest.fixture(scope="module")
def landmark_case(face_model):
    rig = BlendshapeRig.from_face_model(face_model, face_model.random_identity(7))
    w = np.zeros(rig.n_shapes)
    w[rig.shape_index("jawOpen")] = 0.6
    V = rig.evaluate(w)
    ids = face_model.landmarks[list(FIT_LANDMARKS_23)]
    cam = look_at_camera(V, yaw=15, pitch=5)
    return rig, w, V, ids, cam


def test_landmarks_known_pose(landmark_case):
    rig, w, V, ids, cam = landmark_case
    r = SEMFitter().fit(rig, LandmarkTarget(cam.project(V[ids]), ids, cam))
    j = rig.shape_index("jawOpen")
    assert r.info["order"][0] == j
    assert abs(r.weights[j] - 0.6) < 0.05
    before = np.abs(cam.project(rig.neutral[ids]) - cam.project(V[ids])).mean()
    after = np.abs(cam.project(r.vertices[ids]) - cam.project(V[ids])).mean()
    assert after < 0.1 * before


def test_landmarks_unknown_pose(landmark_case):
    rig, w, V, ids, cam = landmark_case
    unposed = PinholeCamera(cam.focal, cam.cx, cam.cy)
    r = SEMFitter().fit(rig, LandmarkTarget(cam.project(V[ids]), ids, unposed))
    assert r.info["pose_estimated"]
    est = r.info["camera"]
    angle = np.degrees(np.arccos(np.clip((np.trace(est.R @ cam.R.T) - 1) / 2, -1, 1)))
    assert angle < 3.0  # the pose is found to within a few degrees despite the open jaw
    px = np.linalg.norm(est.project(r.vertices[ids]) - cam.project(V[ids]), axis=1).mean()
    assert px < 1.0  # and the landmarks are matched to a pixel


def test_landmarks_batched_equals_single(face_model, landmark_case):
    """fit_many on landmarks (vectorised over targets, mixed known / unknown poses) gives fit()'s result per target."""
    rig, _, _, ids, _ = landmark_case
    rng = np.random.default_rng(5)
    targets = []
    for k in range(6):
        w = np.where(rng.random(rig.n_shapes) < 0.08, rng.uniform(0.3, 1.0, rig.n_shapes), 0.0)
        V = rig.evaluate(w)
        cam = look_at_camera(V, yaw=rng.uniform(-20, 20), pitch=rng.uniform(-10, 10))
        uv = cam.project(V[ids]) + rng.normal(size=(ids.size, 2))
        targets.append(LandmarkTarget(uv, ids, cam if k % 2 else PinholeCamera(cam.focal, cam.cx, cam.cy)))
    for fitter in (SEMFitter(), SEMFitter(clamp=True, stop="ric")):
        res = fitter.fit_many(rig, targets, chunk=2)
        for k, tg in enumerate(targets):
            r = fitter.fit(rig, tg)
            np.testing.assert_allclose(res[k].weights, r.weights, atol=1e-6)
            np.testing.assert_allclose(res[k].info["camera"].t, r.info["camera"].t, atol=1e-6)
            np.testing.assert_allclose(res[k].vertices, r.vertices, atol=1e-6)
    # a mixed list: the mesh goes through the mesh path, the landmarks through theirs
    mixed = SEMFitter().fit_many(rig, [targets[0], MeshTarget(rig.neutral)])
    np.testing.assert_allclose(mixed[0].weights, SEMFitter().fit(rig, targets[0]).weights, atol=1e-6)
    assert not mixed[1].weights.any() and "time_s" in mixed[1].info


def test_zero_coefficient_candidate_is_not_excluded_by_rounding(landmark_case):
    """A candidate with e_i = 0 leaves eq. 22's index unchanged, so it must stay a candidate whatever the rounding.

    Two copies of jawOpen's delta: after the first is selected at the true weight, the copy's coefficient is 0;
    with an exact-tie comparison it could be dropped or kept depending on the last bit of the projection.
    The selection must be identical when the rig's shapes are permuted (different rounding paths).
    """
    rig, _, V, ids, cam = landmark_case
    r1 = SEMFitter().fit(rig, LandmarkTarget(cam.project(V[ids]), ids, cam))
    perm = np.random.default_rng(0).permutation(rig.n_shapes)
    rig_p = BlendshapeRig(rig.neutral, rig.deltas[perm], [rig.names[i] for i in perm], rig.triangles,
                          rig.landmark_ids)
    r2 = SEMFitter().fit(rig_p, LandmarkTarget(cam.project(V[ids]), ids, cam))
    np.testing.assert_allclose(r2.weights, r1.weights[perm], atol=1e-9)


def test_point_cloud_single_shape(face_model):
    rig = BlendshapeRig.from_face_model(face_model)
    w = np.zeros(rig.n_shapes)
    w[rig.shape_index("jawOpen")] = 0.6
    V = rig.evaluate(w)
    rng = np.random.default_rng(0)
    P = V[:6706][rng.choice(6706, 5000, replace=False)] + rng.normal(size=(5000, 3)) * 0.01
    r = SEMFitter(region=np.arange(6706)).fit(rig, PointCloudTarget(P))
    assert r.info["order"][0] == rig.shape_index("jawOpen")
    assert abs(r.weights[rig.shape_index("jawOpen")] - 0.6) < 0.1


def test_registry_and_bad_input(face_model):
    assert "sem" in registry.available("fitters")
    f = registry.create("fitters", "sem")
    rig = tiny_rig()
    with pytest.raises(InputError, match="MeshTarget, LandmarkTarget or PointCloudTarget"):
        f.fit(rig, np.zeros((30, 3)))
    with pytest.raises(InputError, match="31 vertices, the rig 30"):
        f.fit(rig, MeshTarget(np.zeros((31, 3))))
    with pytest.raises(InputError, match="region"):
        SEMFitter(region=[0, 99]).fit(rig, PointCloudTarget(np.zeros((4, 3))))
    with pytest.raises(InputError, match="exclusion"):
        SEMFitter(exclusion="yes")
    with pytest.raises(InputError, match=r"shape \(K, 30, 3\)"):
        f.fit_many(rig, np.zeros((2, 29, 3)))
