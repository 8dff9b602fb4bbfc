"""Selective Expression Manipulation: the greedy core, the three target kinds, options and bad input."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from facegeom import registry
from facegeom.errors import InputError
from facegeom.methods.sem import SEMFitter, SEMLSFitter, sem_gram, sem_orthogonal_gram, sem_vectors
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


# --------------------------------------------------------------------------- sem-ls: least-squares coefficients


def dense_case(face_model, seed, noise_cm=0.0):
    """A random identity's rig and a dense expression (every shape active, like a real take frame)."""
    rng = np.random.default_rng(seed)
    rig = BlendshapeRig.from_face_model(face_model, face_model.random_identity(rng))
    w = rng.uniform(0.02, 0.6, rig.n_shapes) * (rng.random(rig.n_shapes) < 0.8)
    V = rig.evaluate(w)
    return rig, w, V, V + rng.normal(size=V.shape) * noise_cm


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_orthogonal_path_recovers_a_dense_expression_exactly(face_model, seed):
    """Noise-free dense target: the least-squares path reaches the truth (the paper's greedy cannot)."""
    rig, w, V, _ = dense_case(face_model, seed)
    r = SEMLSFitter().fit(rig, MeshTarget(V))
    np.testing.assert_allclose(r.weights, w, atol=1e-6)
    greedy = SEMFitter(clamp=True).fit(rig, MeshTarget(V))
    assert np.abs(greedy.weights - w).max() > 1e-3  # the published greedy stops short on dense targets


def test_orthogonal_path_stays_sparse_on_a_sparse_noisy_target(face_model):
    """GCV cuts the path: a 3-shape expression under 0.5 mm noise is fitted with few shapes, the true ones first."""
    rng = np.random.default_rng(4)
    rig = BlendshapeRig.from_face_model(face_model, face_model.random_identity(rng))
    names = ["jawOpen", "mouthSmile_L", "eyeBlink_R"]
    w = rig.weights_from_dict(dict(zip(names, (0.6, 0.5, 0.8))))
    T = rig.evaluate(w) + rng.normal(size=(rig.n_vertices, 3)) * 0.05
    r = SEMLSFitter().fit(rig, MeshTarget(T))
    assert set(rig.names[i] for i in r.info["order"][:3]) == set(names)
    assert (r.weights > 1e-3).sum() <= 12
    for n, v in zip(names, (0.6, 0.5, 0.8)):
        assert abs(r.weights[rig.shape_index(n)] - v) < 0.01


def test_orthogonal_gram_batch_bounds_and_degenerate_shapes(face_model):
    rig, w, V, T = dense_case(face_model, 1, noise_cm=0.05)
    D, G = rig.delta_matrix(), rig.gram()
    targets = np.stack([T, rig.evaluate(np.clip(w * 2.5, 0, 1.6)), rig.neutral])
    d = (targets - rig.neutral).reshape(3, -1)
    E, orders = sem_orthogonal_gram(d @ D, G, (d * d).sum(1), d.shape[1], upper=1.0)
    for k in range(3):  # the batch equals one target at a time
        e1, o1 = sem_orthogonal_gram(d[k] @ D, G, d[k] @ d[k], d.shape[1], upper=1.0)
        np.testing.assert_allclose(E[k], e1, atol=1e-10)
        np.testing.assert_array_equal(orders[k], o1)
    assert E.min() >= 0 and E.max() <= 1 + 1e-12  # the bounds hold where least squares would leave them
    assert not E[2].any() and (orders[2] == -1).all()  # the neutral: nothing selected
    # a duplicated shape adds nothing once its twin is selected: no crash, the fit is unchanged
    D2 = np.c_[D, D[:, 0]]
    e2, _ = sem_orthogonal_gram(d[0] @ D2, D2.T @ D2, d[0] @ d[0], d.shape[1], upper=1.0)
    np.testing.assert_allclose(rig.delta_matrix() @ E[0], D2 @ e2, atol=1e-6)


def test_sem_ls_fit_many_equals_fit_and_landmarks_take_the_posterior_mode(face_model, landmark_case):
    rig, w, V, T = dense_case(face_model, 2, noise_cm=0.05)
    f = SEMLSFitter()
    many = f.fit_many(rig, np.stack([T, V]))
    np.testing.assert_allclose(many[0].weights, f.fit(rig, MeshTarget(T)).weights, atol=1e-9)
    np.testing.assert_allclose(many[1].weights, f.fit(rig, MeshTarget(V)).weights, atol=1e-9)
    # landmarks: "auto" is the posterior mode ("map"), not the greedy with the noise-aware stop (sem+)
    lrig, _, LV, ids, cam = landmark_case
    tg = LandmarkTarget(cam.project(LV[ids]), ids, cam)
    auto = f.fit(lrig, tg).weights
    np.testing.assert_allclose(auto, SEMFitter(clamp=True, coefficients="map").fit(lrig, tg).weights, atol=1e-12)
    greedy = SEMLSFitter(coefficients="greedy").fit(lrig, tg).weights
    np.testing.assert_allclose(greedy, SEMFitter(clamp=True, stop="ric").fit(lrig, tg).weights, atol=1e-12)
    assert np.abs(auto - greedy).max() > 1e-6
    lsq = SEMLSFitter(coefficients="lsq").fit(lrig, tg)  # least squares on the projected motions also runs
    assert lsq.weights.min() >= 0 and lsq.weights.max() <= 1 + 1e-12


def test_sem_ls_on_a_point_cloud_and_registry(face_model):
    assert registry.available("fitters")["sem-ls"].endswith("SEMLSFitter")
    rig = BlendshapeRig.from_face_model(face_model)
    w = np.zeros(rig.n_shapes)
    w[rig.shape_index("jawOpen")] = 0.6
    rng = np.random.default_rng(0)
    P = rig.evaluate(w)[:6706][rng.choice(6706, 5000, replace=False)] + rng.normal(size=(5000, 3)) * 0.01
    r = registry.create("fitters", "sem-ls", region=np.arange(6706)).fit(rig, PointCloudTarget(P))
    paper = SEMFitter(region=np.arange(6706)).fit(rig, PointCloudTarget(P))
    V = rig.evaluate(w)[:6706]
    err = [np.linalg.norm(x.vertices[:6706] - V, axis=1).mean() for x in (r, paper)]
    assert abs(r.weights[rig.shape_index("jawOpen")] - 0.6) < 0.05 and (r.weights > 0.05).sum() <= 4
    assert err[0] <= 1.1 * err[1] and err[0] < 0.02  # as good as the paper's fit (0.2 mm on 0.1 mm noise)
    with pytest.raises(InputError, match="coefficients must be 'greedy'"):
        SEMLSFitter(coefficients="banana")
