"""The blendshape-fitting baselines of the SEM paper (baselines.fitters): L1Reg, L2Reg, PCAExp, PCADel."""
import time

import numpy as np
import pytest

from facegeom.baselines.fitters import L1RegFitter, L2RegFitter, PCADelFitter, PCAExpFitter
from facegeom.errors import InputError
from facegeom.interfaces import FitResult, Fitter
from facegeom.metrics import landmark_normalized_error
from facegeom.model import (
    INNER_EYE_CORNERS,
    INNER_LANDMARKS_49,
    BlendshapeRig,
    LandmarkTarget,
    MeshTarget,
    PinholeCamera,
    PointCloudTarget,
    look_at_camera,
)

from .conftest import grid_mesh

TINY_REG = dict(l1=lambda: L1RegFitter(w_l1=1e-9), l2=lambda: L2RegFitter(w_l2=1e-9))
ALL = [L1RegFitter, L2RegFitter, PCAExpFitter, PCADelFitter]


def tiny_rig(B=5, seed=0):
    """A 4x3-vertex bumped grid with B random smooth-ish delta-blendshapes (no landmark ids)."""
    V, F = grid_mesh(4, 3, bump=0.3)
    rng = np.random.default_rng(seed)
    deltas = rng.normal(scale=0.2, size=(B, V.shape[0], 3))
    return BlendshapeRig(V, deltas, [f"s{i}" for i in range(B)], F)


@pytest.fixture(scope="module")
def ict(face_model):
    return BlendshapeRig.from_face_model(face_model, face_model.random_identity(np.random.default_rng(7)))


def sparse_weights(B, rng, k=4):
    w = np.zeros(B)
    w[rng.choice(B, k, replace=False)] = rng.uniform(0.3, 0.9, k)
    return w


# --------------------------------------------------------------------------- API


@pytest.mark.parametrize("cls", ALL)
def test_defaults_protocol_and_result(cls):
    f = cls()
    assert isinstance(f, Fitter)
    rig = tiny_rig()
    res = f.fit(rig, MeshTarget(rig.evaluate(np.full(5, 0.3))))
    assert isinstance(res, FitResult)
    assert res.weights.shape == (5,) and res.vertices.shape == (12, 3)
    for key in ("energy", "data_energy", "scale", "iterations", "time_s", "converged", "method"):
        assert key in res.info


# --------------------------------------------------------------------------- exact recovery


@pytest.mark.parametrize("make", list(TINY_REG.values()), ids=list(TINY_REG))
def test_exact_recovery_tiny_rig(make):
    rig = tiny_rig()
    w = np.array([0.0, 0.7, 0.0, 0.25, 0.0])
    res = make().fit(rig, MeshTarget(rig.evaluate(w)))
    np.testing.assert_allclose(res.weights, w, atol=1e-6)
    np.testing.assert_allclose(res.vertices, rig.evaluate(w), atol=1e-6)


@pytest.mark.parametrize("make", list(TINY_REG.values()), ids=list(TINY_REG))
def test_exact_recovery_ict(ict, make):
    w = sparse_weights(ict.n_shapes, np.random.default_rng(1), k=5)
    res = make().fit(ict, MeshTarget(ict.evaluate(w)))
    np.testing.assert_allclose(res.weights, w, atol=1e-4)
    assert np.abs(res.vertices - ict.evaluate(w)).max() < 1e-4  # cm


@pytest.mark.parametrize("cls", [PCAExpFitter, PCADelFitter])
@pytest.mark.parametrize("which", ["tiny", "ict"])
def test_pca_reconstructs_faces_in_span(cls, which, request):
    rig = tiny_rig() if which == "tiny" else request.getfixturevalue("ict")
    f = cls(n_components=rig.n_shapes, w_prior=0.0)
    model = f._model(rig)
    c = np.random.default_rng(2).normal(size=model.P) * np.sqrt(model.variances)
    target = model.vertices(c)  # a face of the PCA span (mean / neutral + U c)
    res = f.fit(rig, MeshTarget(target))
    np.testing.assert_allclose(res.vertices, target, atol=1e-8)
    # the reported blendshape weights reproduce the PCA face
    np.testing.assert_allclose(rig.evaluate(res.weights), res.vertices, atol=1e-8)
    # a face of the rig is in the full PCA span too, and its weights are recovered
    w = sparse_weights(rig.n_shapes, np.random.default_rng(3), k=3)
    res = f.fit(rig, MeshTarget(rig.evaluate(w)))
    np.testing.assert_allclose(res.weights, w, atol=1e-6)


def test_pca_truncation_and_prior_shrink(ict):
    w = sparse_weights(ict.n_shapes, np.random.default_rng(4), k=4)
    T = MeshTarget(ict.evaluate(w))
    errs = [np.abs(PCADelFitter(n_components=k, w_prior=0.0).fit(ict, T).vertices - T.vertices).mean()
            for k in (5, 20, 53)]
    assert errs[0] > errs[1] > errs[2] and errs[2] < 1e-8
    # a strong prior pulls PCADel to the neutral, PCAExp to the mean shape
    res = PCADelFitter(w_prior=1e6).fit(ict, T)
    assert np.abs(res.vertices - ict.neutral).max() < 1e-3
    res = PCAExpFitter(w_prior=1e6).fit(ict, T)
    np.testing.assert_allclose(res.weights, 1.0 / (ict.n_shapes + 1), atol=1e-4)
    assert 0.0 < PCAExpFitter(n_components=0.9).fit(ict, T).info["energy"]


# --------------------------------------------------------------------------- L1 / L2 behaviour


def test_weights_in_unit_box(ict):
    rng = np.random.default_rng(5)
    w = sparse_weights(ict.n_shapes, rng, k=6) * 1.8 - 0.2  # outside the box on purpose
    V = ict.evaluate(w) + rng.normal(scale=0.05, size=(ict.n_vertices, 3))
    cam = look_at_camera(ict.neutral)
    ids = ict.landmark_vertices(INNER_LANDMARKS_49)
    targets = [MeshTarget(V), LandmarkTarget.from_mesh(V, ids, cam), PointCloudTarget(V[::3])]
    for f in (L1RegFitter(icp_iterations=5), L2RegFitter(icp_iterations=5), L1RegFitter(w_l1=0.0, icp_iterations=5)):
        for t in targets:
            res = f.fit(ict, t)
            assert res.weights.min() >= 0.0 and res.weights.max() <= 1.0
        W = f.fit_many(ict, V[None])[0].weights
        assert W.min() >= 0.0 and W.max() <= 1.0


def test_l1_sparser_than_l2_at_equal_data_fit(ict):
    rng = np.random.default_rng(6)
    w = sparse_weights(ict.n_shapes, rng, k=5)
    T = MeshTarget(ict.evaluate(w) + rng.normal(scale=0.05, size=(ict.n_vertices, 3)))
    l1 = L1RegFitter(w_l1=1e-2).fit(ict, T)
    # the L2 weight whose data energy is closest to L1's
    cands = [L2RegFitter(w_l2=10.0 ** e).fit(ict, T) for e in np.arange(-5, 0.01, 0.25)]
    l2 = min(cands, key=lambda r: abs(np.log(r.info["data_energy"] / l1.info["data_energy"])))
    assert abs(np.log(l2.info["data_energy"] / l1.info["data_energy"])) < 0.2
    nnz = lambda r: int((r.weights > 1e-3).sum())  # noqa: E731
    assert nnz(l1) < nnz(l2)


@pytest.mark.parametrize("cls", ALL)
def test_fit_many_matches_fit(ict, cls):
    rng = np.random.default_rng(8)
    Vs = np.stack([ict.evaluate(sparse_weights(ict.n_shapes, rng)) + rng.normal(scale=0.05, size=(ict.n_vertices, 3))
                   for _ in range(4)])
    f = cls(icp_iterations=3)
    res = f.fit_many(ict, Vs)
    W = np.stack([r.weights for r in res])
    for V, r in zip(Vs, res):
        one = f.fit(ict, MeshTarget(V))
        np.testing.assert_allclose(one.weights, r.weights, atol=2e-5)
        np.testing.assert_allclose(one.vertices, r.vertices, atol=1e-3)
        assert r.info["method"] == one.info["method"] and r.info["time_s"] >= 0
    # a mixed list: a weighted mesh and a point cloud go through fit()
    mixed = [MeshTarget(Vs[0]), MeshTarget(Vs[1], weights=np.ones(ict.n_vertices)), PointCloudTarget(Vs[2][::5])]
    W2 = np.stack([r.weights for r in f.fit_many(ict, mixed)])
    np.testing.assert_allclose(W2[:2], W[:2], atol=2e-5)


# --------------------------------------------------------------------------- landmarks


@pytest.mark.parametrize("cls", ALL)
def test_landmarks_known_and_unknown_pose(ict, cls):
    """Noise-free landmarks of a rig face: the fit must get within 1% of the inter-ocular distance.

    The truth is reachable (the landmarks come from a rig face), so the only
    error left is the regularisation bias of the default weights and the pose
    estimate; 1% of the inter-ocular distance (~0.5 px here) is below the
    landmark detectors' noise the paper deals with, and at least 5x below the
    neutral face's error.
    """
    rng = np.random.default_rng(9)
    w = sparse_weights(ict.n_shapes, rng, k=4)
    V = ict.evaluate(w)
    cam = look_at_camera(V, yaw=15)
    ids = ict.landmark_vertices(INNER_LANDMARKS_49)
    eyes = ict.landmark_vertices(INNER_EYE_CORNERS)
    posed = LandmarkTarget.from_mesh(V, ids, cam)
    unposed = LandmarkTarget(posed.points2d, ids, PinholeCamera(cam.focal, cam.cx, cam.cy))
    ne0 = landmark_normalized_error(ict.neutral, posed, eyes)
    f = cls()
    for target in (posed, unposed):
        res = f.fit(ict, target)
        fitted_cam = res.info["camera"]
        assert fitted_cam.posed
        fitted_target = LandmarkTarget(target.points2d, ids, fitted_cam)
        ne = landmark_normalized_error(res.vertices, fitted_target, eyes)
        assert ne < 0.01 and ne < ne0 / 5, (ne, ne0)
    # with the known pose the camera is the target's own
    assert f.fit(ict, posed).info["camera"] is cam


def test_landmarks_tiny_rig_without_landmark_ids():
    rig = tiny_rig()
    w = np.array([0.5, 0.0, 0.3, 0.0, 0.0])
    V = rig.evaluate(w)
    cam = look_at_camera(V)
    target = LandmarkTarget.from_mesh(V, np.arange(12), cam)
    res = L1RegFitter(w_l1=1e-9).fit(rig, target)
    np.testing.assert_allclose(res.weights, w, atol=1e-4)


# --------------------------------------------------------------------------- point clouds


def _sample_surface(V, F, count, rng):
    """``count`` points uniformly on the triangles (area-weighted) plus the vertices."""
    A = np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    t = rng.choice(len(F), count, p=A / A.sum())
    u, v = rng.random(count), rng.random(count)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    P = V[F[t, 0]] + u[:, None] * (V[F[t, 1]] - V[F[t, 0]]) + v[:, None] * (V[F[t, 2]] - V[F[t, 0]])
    return np.r_[V, P]


@pytest.mark.parametrize("cls", ALL)
def test_point_cloud_fit(ict, cls):
    rng = np.random.default_rng(10)
    w = sparse_weights(ict.n_shapes, rng, k=4)
    V = ict.evaluate(w)
    P = _sample_surface(V, ict.triangles, 30_000 - ict.n_vertices, rng)[rng.permutation(30_000)]
    target = PointCloudTarget(P)
    res = cls().fit(ict, target)
    err0 = np.linalg.norm(ict.neutral - V, axis=1).mean()
    err = np.linalg.norm(res.vertices - V, axis=1).mean()
    if cls in (L1RegFitter, L2RegFitter):
        assert err < 0.02 and err < err0 / 10, (err, err0)  # 0.2 mm mean vertex error
    else:  # unbounded PCA coefficients: point-to-point ICP stops in a worse local minimum (~1.3 mm)
        assert err < err0 / 2, (err, err0)
    assert res.info["icp_iterations"] >= 1
    if cls is L1RegFitter:  # region: only the narrow face area is matched
        res_r = cls(region=np.arange(6706)).fit(ict, target)
        assert np.linalg.norm(res_r.vertices - V, axis=1)[:6706].mean() < 0.02


# --------------------------------------------------------------------------- errors


@pytest.mark.parametrize("cls", ALL)
def test_bad_targets(cls):
    rig = tiny_rig()
    f = cls()
    with pytest.raises(InputError):
        f.fit(rig, rig.neutral)  # an array, not a target
    with pytest.raises(InputError):
        f.fit(rig, MeshTarget(np.zeros((11, 3))))
    with pytest.raises(InputError):
        f.fit(rig, LandmarkTarget(np.zeros((2, 2)), [0, 12], look_at_camera(rig.neutral)))
    with pytest.raises(InputError):
        f.fit("rig", MeshTarget(rig.neutral))
    with pytest.raises(InputError):
        f.fit_many(rig, np.zeros((2, 11, 3)))
    bad = np.stack([rig.neutral, rig.neutral])
    bad[1, 3, 0] = np.nan
    with pytest.raises(InputError, match="target mesh 1"):
        f.fit_many(rig, bad)
    with pytest.raises(InputError):
        cls(region=[0, 99]).fit(rig, PointCloudTarget(rig.neutral))


@pytest.mark.parametrize("make", [
    lambda: L1RegFitter(w_l1=-1.0), lambda: L1RegFitter(w_l2=np.nan), lambda: L2RegFitter(w_l2="a"),
    lambda: L1RegFitter(icp_iterations=0), lambda: L2RegFitter(max_iter=1.5), lambda: L1RegFitter(region=[]),
    lambda: PCAExpFitter(n_components=0), lambda: PCAExpFitter(n_components=1.5), lambda: PCADelFitter(w_prior=-1),
    lambda: PCADelFitter(n_components=True), lambda: PCAExpFitter(n_components="all"),
    lambda: L1RegFitter(region=np.zeros(3, bool)),
])
def test_bad_parameters(make):
    with pytest.raises(InputError):
        make()


# --------------------------------------------------------------------------- speed (reported, loosely checked)


def test_speed_report(ict, capsys):
    rng = np.random.default_rng(11)
    T = 1000
    W = np.array([sparse_weights(ict.n_shapes, rng, k=int(rng.integers(2, 7))) for _ in range(T)])
    Vs = (W @ ict.delta_matrix().T).reshape(T, -1, 3) + ict.neutral
    Vs += rng.normal(scale=0.05, size=Vs.shape)
    lines = []
    for f in (L1RegFitter(), L2RegFitter(), PCAExpFitter(), PCADelFitter()):
        f.fit_many(ict, Vs[:8])  # build the model
        t = time.perf_counter()
        f.fit_many(ict, Vs)
        many = T / (time.perf_counter() - t)
        t = time.perf_counter()
        for V in Vs[:10]:
            f.fit(ict, MeshTarget(V))
        single = 10 / (time.perf_counter() - t)
        cam = look_at_camera(ict.neutral, yaw=15)
        ids = ict.landmark_vertices(INNER_LANDMARKS_49)
        lms = [LandmarkTarget.from_mesh(V, ids, cam) for V in Vs[:5]]
        t = time.perf_counter()
        for lt in lms:
            f.fit(ict, lt)
        lm = 5 / (time.perf_counter() - t)
        lines.append(f"{type(f).__name__}: mesh fit_many {many:.0f}/s, mesh fit {single:.0f}/s, "
                     f"landmarks (49, known pose) {lm:.0f}/s")
        assert many > 200
    P = _sample_surface(Vs[0], ict.triangles, 30_000 - ict.n_vertices, rng)
    t = time.perf_counter()
    L1RegFitter().fit(ict, PointCloudTarget(P))
    lines.append(f"L1RegFitter: 30,000-point cloud {time.perf_counter() - t:.3f} s")
    with capsys.disabled():
        print("\n" + "\n".join(lines))
