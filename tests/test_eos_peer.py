"""The eos peer fitter (facegeom.baselines.eos_peer): eos's camera + NNLS blendshape fit on our rig's landmarks."""
import sys
import time

import numpy as np
import pytest

eos = pytest.importorskip("eos")

from facegeom.baselines.eos_peer import EosFitter  # noqa: E402
from facegeom.errors import InputError  # noqa: E402
from facegeom.model import FIT_LANDMARKS_23, BlendshapeRig, LandmarkTarget, MeshTarget, PointCloudTarget, look_at_camera


def synthetic(face_model, seed, n_active=None, focal=1000.0):
    """A random identity with 2-3 active expressions (weights 0.3-0.9) seen at yaw 10 on the 23 fit landmarks."""
    rng = np.random.default_rng(seed)
    rig = BlendshapeRig.from_face_model(face_model, face_model.random_identity(rng))
    k = int(rng.integers(2, 4)) if n_active is None else n_active
    w = np.zeros(rig.n_shapes)
    active = rng.choice(rig.n_shapes, k, replace=False)
    w[active] = rng.uniform(0.3, 0.9, k)
    V = rig.evaluate(w)
    ids = np.asarray(face_model.landmarks)[list(FIT_LANDMARKS_23)]
    cam = look_at_camera(V, yaw=10, focal=focal)
    return rig, w, active, V, LandmarkTarget.from_mesh(V, ids, cam)


def rms(a, b):
    return float(np.sqrt(((a - b) ** 2).sum(axis=1).mean()))


def affine_rms(A, points3d, points2d):
    return rms(np.c_[points3d, np.ones(len(points3d))] @ A[:2].T, points2d)


def test_result_and_info(face_model):
    rig, _, _, _, target = synthetic(face_model, 0)
    r = EosFitter().fit(rig, target)
    assert r.weights.shape == (rig.n_shapes,) and r.weights.dtype == np.float64
    assert np.all(np.isfinite(r.weights)) and (r.weights >= 0).all()  # eos's NNLS: >= 0, no upper bound
    np.testing.assert_allclose(r.vertices, rig.evaluate(r.weights))
    info = r.info
    assert info["iterations"] == 5 and info["time_s"] > 0
    assert info["affine_camera"].shape == (3, 4) and info["rotation"].shape == (3, 3)
    np.testing.assert_allclose(info["rotation"] @ info["rotation"].T, np.eye(3), atol=1e-5)
    assert info["scale"] > 0 and info["yaw_pitch_roll"].shape == (3,)
    assert info["selected"] == [rig.names[i] for i in np.flatnonzero(r.weights > 0)]
    # the reported affine error is that of the fitted face under the reported camera
    ids = target.vertex_ids
    assert info["rms_px_affine"] == pytest.approx(
        affine_rms(info["affine_camera"], r.vertices[ids], target.points2d), rel=1e-4, abs=1e-4)


def test_reduces_the_landmark_error_under_eos_camera(face_model):
    """eos fits its own (affine) model well: the landmark error drops by a clear factor."""
    for seed in range(6):
        rig, _, _, _, target = synthetic(face_model, seed)
        ids = target.vertex_ids
        r = EosFitter().fit(rig, target)
        first = EosFitter(iterations=0).fit(rig, target)  # no camera / expression alternation
        # the neutral under eos's camera estimated on the neutral (the first step of the fit)
        pts = [p.astype(np.float32) for p in target.points2d]
        _, _, A0 = EosFitter()._camera(pts, rig.neutral[ids], 640, 480)
        before = affine_rms(A0, rig.neutral[ids], target.points2d)
        assert r.info["rms_px_affine"] < 0.35 * before, (seed, r.info["rms_px_affine"], before)
        assert r.info["rms_px_affine"] <= first.info["rms_px_affine"] + 1e-3  # the alternation helps


def test_perspective_error_drops_for_most_targets(face_model):
    """Under the true (perspective) camera the gain is modest, and some targets get worse (ratio up to ~2):
    eos's affine camera cannot explain the perspective landmarks and its unregularised NNLS absorbs the
    difference into spurious shapes.  Only "most targets improve" holds (median ratio ~0.8 here)."""
    ratios = []
    for seed in range(10):
        rig, _, _, V, target = synthetic(face_model, seed)
        r = EosFitter().fit(rig, target)
        ratios.append(rms(target.project(r.vertices), target.points2d)
                      / rms(target.project(rig.neutral), target.points2d))
    assert np.median(ratios) < 1.0, ratios


def test_eos_recovers_the_shape_given_the_true_camera(face_model):
    """Our blendshapes reach eos in the right order: with the exact (linearised) camera,
    eos.fitting.fit_expressions alone recovers a single jawOpen."""
    rig = BlendshapeRig.from_face_model(face_model, face_model.random_identity(0))
    w = rig.weights_from_dict({"jawOpen": 0.8})
    V = rig.evaluate(w)
    ids = np.asarray(face_model.landmarks)[list(FIT_LANDMARKS_23)]
    cam = look_at_camera(V, yaw=10, focal=50000.0)  # nearly orthographic
    target = LandmarkTarget.from_mesh(V, ids, cam)
    c = V[ids].mean(axis=0)
    J = cam.jacobian(c[None])[0]
    A = np.zeros((3, 4), np.float32)
    A[:2, :3], A[:2, 3], A[2, 3] = J, cam.project(c[None])[0] - J @ c, 1.0
    shapes, face, vids, _ = EosFitter()._model(rig, ids)
    coeffs = np.asarray(eos.fitting.fit_expressions(shapes, face, A, [p.astype(np.float32) for p in target.points2d],
                                                    vids))
    assert int(np.argmax(coeffs)) == rig.shape_index("jawOpen")
    assert coeffs[rig.shape_index("jawOpen")] == pytest.approx(0.8, abs=0.05)


@pytest.mark.xfail(strict=True, reason="eos estimates its camera on the neutral face (an expression biases it) and "
                                       "fits 53 shapes to 46 numbers by unregularised NNLS: the largest active "
                                       "shape is rarely the largest weight")
def test_largest_active_shape_is_ranked_first(face_model):
    hits = 0
    for seed in range(10):
        rig, w, active, _, target = synthetic(face_model, seed)
        r = EosFitter().fit(rig, target)
        hits += int(np.argmax(r.weights)) == int(active[np.argmax(w[active])])
    assert hits >= 5


def test_same_as_eos_fit_shape_and_pose(face_model):
    """Our loop is eos's own fit_shape_and_pose with the identity frozen (a 1-mode PCA with a ~0 variance)."""
    rig, _, _, _, target = synthetic(face_model, 3)
    ids = target.vertex_ids
    L = len(ids)
    basis = np.zeros((3 * L, 1), np.float32)
    basis[0, 0] = 1.0
    shape = eos.morphablemodel.PcaModel(rig.neutral[ids].ravel().astype(np.float32), basis,
                                        np.array([1e-10], np.float32), [[0, 1, 2]])
    blendshapes = [eos.morphablemodel.Blendshape(n, d[ids].ravel().astype(np.float32))
                   for n, d in zip(rig.names, rig.deltas)]
    model = eos.morphablemodel.MorphableModel(shape, blendshapes, eos.morphablemodel.PcaModel())
    landmarks = [eos.core.Landmark(str(i), p.astype(np.float32)) for i, p in enumerate(target.points2d)]
    _, _, _, theirs = eos.fitting.fit_shape_and_pose(model, landmarks, eos.core.LandmarkMapper(), 640, 480,
                                                     num_iterations=5)
    ours = EosFitter(iterations=5).fit(rig, target).weights
    np.testing.assert_allclose(ours, theirs, atol=1e-2 * max(1.0, float(np.max(ours))))


def test_compact_equals_full_model(face_model):
    rig, _, _, _, target = synthetic(face_model, 1)
    a = EosFitter(compact=True).fit(rig, target).weights
    b = EosFitter(compact=False).fit(rig, target).weights
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-5)


def test_only_landmark_targets(face_model):
    rig = BlendshapeRig.from_face_model(face_model)
    for target in (MeshTarget(rig.neutral), PointCloudTarget(rig.neutral[:100])):
        with pytest.raises(InputError, match="eos fits 2-D landmarks only"):
            EosFitter().fit(rig, target)
    with pytest.raises(InputError, match="at least 4 landmarks"):
        EosFitter().fit(rig, LandmarkTarget.from_mesh(rig.neutral, [0, 1, 2], look_at_camera(rig.neutral)))
    with pytest.raises(InputError):
        EosFitter().fit("not a rig", MeshTarget(rig.neutral))


def test_bad_parameters():
    for bad in (-1, 1.5, True):
        with pytest.raises(InputError, match="iterations"):
            EosFitter(iterations=bad)
    with pytest.raises(InputError, match="compact"):
        EosFitter(compact="yes")


def test_missing_eos_is_an_input_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "eos", None)  # makes `import eos` raise ImportError
    with pytest.raises(InputError, match=r"eos is not installed: pip install 'facegeom\[eos\]' \(eos-py\)"):
        EosFitter()


def test_speed(face_model):
    rig, _, _, _, target = synthetic(face_model, 2)
    f = EosFitter()
    f.fit(rig, target)  # builds the eos blendshapes once
    n = 20
    t0 = time.perf_counter()
    for _ in range(n):
        f.fit(rig, target)
    rate = n / (time.perf_counter() - t0)
    print(f"eos peer: {rate:.1f} fits/s")
    assert rate > 2.0


# ----------------------------------------------------------------------------- scored as eos returns it
def _spy(monkeypatch, name):
    """Wrap ``eos.fitting.<name>``: the list of what each call returned."""
    returned = []
    real = getattr(eos.fitting, name)

    def spy(*args, **kwargs):
        out = real(*args, **kwargs)
        returned.append(out)
        return out

    monkeypatch.setattr(eos.fitting, name, spy)
    return returned


def test_expression_peer_weights_are_what_eos_returned(face_model, monkeypatch):
    """EosFitter's weights are the coefficients of eos's last fit_expressions call, unchanged."""
    rig, _, _, _, target = synthetic(face_model, 4)
    returned = _spy(monkeypatch, "fit_expressions")
    r = EosFitter().fit(rig, target)
    assert len(returned) == 6  # iterations + 1
    np.testing.assert_array_equal(r.weights, np.asarray(returned[-1], dtype=np.float64))
    np.testing.assert_allclose(r.vertices, rig.evaluate(r.weights))


def test_identity_peer_passes_eos_result_through_unchanged(face_model, monkeypatch):
    """The identity peer's fit is eos's fit_shape_and_pose as eos returns it: its weights are not clipped to [0, 1]
    (eos's blendshape solve has no upper bound; a weight above 1 stays), so a comparison scores eos's own face."""
    from facegeom.baselines.eos_identity import EosIdentityFitter

    rng = np.random.default_rng(11)
    a = face_model.random_identity(rng)
    w = np.zeros(face_model.n_expressions)
    w[[face_model.expression_index("jawOpen"), face_model.expression_index("mouthSmile_L")]] = [0.6, 0.4]
    V = face_model.face(a, w)
    ids = np.asarray(face_model.landmarks)
    target = LandmarkTarget.from_mesh(V, ids, look_at_camera(V, yaw=10))
    returned = _spy(monkeypatch, "fit_shape_and_pose")
    fit = EosIdentityFitter().fit(face_model, target)
    (mesh, _, alpha, coeffs), = returned
    np.testing.assert_array_equal(fit.weights[0], np.asarray(coeffs, dtype=np.float64))
    np.testing.assert_array_equal(fit.info["shape_coefficients"], np.asarray(alpha, dtype=np.float64))
    assert fit.weights.max() > 1.0 and fit.weights.min() >= 0.0  # eos's result, outside [0, 1]
    # the face scored is eos's: at the landmarks it is eos's mesh, and it has eos's error under eos's camera
    np.testing.assert_allclose(fit.vertices(0)[ids], np.asarray(mesh.vertices, dtype=np.float64), atol=1e-3)
    assert affine_rms(fit.info["affine_camera"], fit.vertices(0)[ids], target.points2d) == pytest.approx(
        fit.info["rms"][0], rel=1e-3, abs=1e-3)
