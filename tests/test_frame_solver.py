"""Per-frame pose and weights (FrameSolver), the identity and focal length from frames, gaze, calibration."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from facegeom.errors import InputError
from facegeom.methods.frame_solver import FrameSolver
from facegeom.methods.video_identity import fit_identity_frames
from facegeom.model.camera import PinholeCamera


@pytest.fixture(scope="module")
def setup(face_model):
    from facegeom.pipelines.track import point_vertices

    keep, tri, bary = point_vertices(face_model)
    ids = tri[np.arange(len(tri)), np.argmax(bary, axis=1)]  # the nearest corner: plain vertex ids for most tests
    return face_model, keep, ids


def _pose(rng, yaw=25.0):
    R = Rotation.from_euler("YXZ", [rng.uniform(-yaw, yaw), rng.uniform(-10, 10), rng.uniform(-8, 8)],
                            degrees=True).as_matrix()
    return R, np.array([rng.uniform(-4, 4), rng.uniform(-3, 3), -55.0 + rng.uniform(-5, 5)])


def test_point_vertices_drop_the_outline_and_lie_on_the_face(setup):
    model, keep, ids = setup
    assert keep.size == 468 - 36 and ids.size == keep.size
    assert ids.min() >= 0 and ids.max() < model.n_vertices


def test_points_inside_triangles_are_the_blend_of_their_corners(face_model):
    """With barycentric points the solver sees exactly the mapped points (not the nearest vertices, ~1 mm off)."""
    from facegeom.pipelines.track import point_vertices
    from facegeom.vision.correspondence import mediapipe_map

    keep, tri, bary = point_vertices(face_model)
    cam = PinholeCamera(650.0, 319.5, 239.5)
    fs = FrameSolver(face_model.neutral, face_model.expression_deltas, tri, cam, bary=bary)
    w = np.zeros(face_model.n_expressions)
    w[face_model.expression_index("jawOpen")] = 0.6
    R, t = Rotation.from_euler("Y", 20, degrees=True).as_matrix(), np.array([0.0, 0.0, -50.0])
    V = face_model.face(None, w)
    want = cam.with_pose(R, t).project(mediapipe_map().points(V, face_model.triangles)[keep])
    assert np.abs(fs.project(R, t, w) - want).max() < 1e-9
    with pytest.raises(InputError, match="bary"):
        FrameSolver(face_model.neutral, face_model.expression_deltas, tri[:, 0], cam, bary=bary)


def test_noise_free_points_give_back_pose_and_weights(setup):
    """From a cold start (PnP on the neutral), exact points and a tiny assumed noise (the prior then weighs
    nothing): the pose to 0.05 degrees, the weights to 0.02."""
    model, _, ids = setup
    rng = np.random.default_rng(0)
    cam = PinholeCamera(700.0, 319.5, 239.5)
    fs = FrameSolver(model.neutral, model.expression_deltas, ids, cam, noise_px=0.01, iterations=20)
    for _ in range(5):
        w = np.zeros(model.n_expressions)
        act = rng.choice(model.n_expressions, 4, replace=False)
        w[act] = rng.uniform(0.3, 0.9, 4)
        R, t = _pose(rng)
        r = fs.solve(fs.project(R, t, w))
        angle = np.degrees(np.linalg.norm(Rotation.from_matrix(r.R @ R.T).as_rotvec()))
        assert angle < 0.05, angle
        assert np.abs(r.w - w).max() < 0.05 and np.abs(r.w - w).mean() < 0.02
        assert r.rms < 0.2


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), noise=st.floats(0.0, 20.0))
def test_weights_stay_in_their_bounds(setup, seed, noise):
    model, _, ids = setup
    rng = np.random.default_rng(seed)
    fs = FrameSolver(model.neutral, model.expression_deltas, ids, PinholeCamera(600.0, 320, 240), noise_px=1.0)
    w = rng.uniform(0, 1, model.n_expressions) * (rng.uniform(size=model.n_expressions) < 0.2)
    R, t = _pose(rng, 40)
    uv = fs.project(R, t, w) + rng.normal(0, noise, (ids.size, 2))
    r = fs.solve(uv)
    assert np.isfinite(r.w).all() and (r.w >= 0).all() and (r.w <= 1).all()
    assert np.isfinite(r.R).all() and np.allclose(r.R @ r.R.T, np.eye(3), atol=1e-9)


def test_point_weights_are_inverse_variance_and_zero_drops_a_point(setup):
    """A point with weight 0 pulls nothing, however far off it is; the fixed weights and a frame's own multiply;
    the residual reported stays plain pixels."""
    model, _, ids = setup
    rng = np.random.default_rng(3)
    cam = PinholeCamera(650.0, 319.5, 239.5)
    w = np.zeros(model.n_expressions)
    w[rng.choice(model.n_expressions, 3, replace=False)] = 0.5
    R, t = _pose(rng)
    K = ids.size
    base = FrameSolver(model.neutral, model.expression_deltas, ids, cam, noise_px=0.5)
    uv = base.project(R, t, w)
    bad = uv.copy()
    bad[:20] += 80.0  # twenty points far off
    pw = np.ones(K)
    pw[:20] = 0.0
    fixed = FrameSolver(model.neutral, model.expression_deltas, ids, cam, noise_px=0.5, point_weights=pw)
    r_fixed = fixed.solve(bad, R, t, w)
    r_frame = base.solve(bad, R, t, w, point_weights=pw)
    assert np.degrees(np.linalg.norm(Rotation.from_matrix(r_fixed.R @ R.T).as_rotvec())) < 0.05
    np.testing.assert_allclose(r_fixed.w, r_frame.w, atol=1e-9)
    assert r_fixed.rms > 10.0  # plain pixels over every point: the twenty far ones show
    r_plain = base.solve(bad, R, t, w)
    assert np.abs(r_plain.w - w).max() > np.abs(r_fixed.w - w).max() + 0.05  # unweighted, they pull
    with pytest.raises(InputError, match="point_weights"):
        FrameSolver(model.neutral, model.expression_deltas, ids, cam, point_weights=-pw)


def test_the_shipped_point_noise_is_measured_and_sharp_features_are_surest(face_model):
    from facegeom.pipelines.track import point_vertices, point_weights
    from facegeom.vision.correspondence import point_noise

    sd = point_noise()
    assert sd.shape == (468,) and (sd > 0.005).all() and (sd < 0.3).all()
    # the eye corners and the nose (sharp features) are placed surer than the forehead, the chin and the lower
    # cheeks along the jaw (smooth skin)
    sharp = sd[[33, 133, 362, 263, 1, 4]].mean()
    smooth = sd[[10, 151, 152, 175, 288, 58]].mean()
    assert sharp < 0.6 * smooth, (sharp, smooth)
    keep, _, _ = point_vertices(face_model)
    w = point_weights(keep)
    assert w.shape == keep.shape and w.mean() == pytest.approx(1.0)


def test_frame_solver_refuses_bad_arguments(setup):
    model, _, ids = setup
    cam = PinholeCamera(600.0, 320, 240)
    with pytest.raises(InputError, match="noise_px"):
        FrameSolver(model.neutral, model.expression_deltas, ids, cam, noise_px=0)
    with pytest.raises(InputError, match="vertex_ids"):
        FrameSolver(model.neutral, model.expression_deltas, [1, 2], cam)
    fs = FrameSolver(model.neutral, model.expression_deltas, ids, cam)
    with pytest.raises(InputError, match="finite"):
        fs.solve(np.full((ids.size, 2), np.nan))


def test_identity_from_frames_beats_the_generic_face(setup):
    """Twelve turning frames of a random person (1.5 px noise): the fitted neutral is nearer the person's than
    the generic neutral is (measured: 0.64-1.8 mm against 2.8-4.0 mm on seeds 0-2); a given focal is kept."""
    model, _, ids = setup
    for seed in range(3):
        rng = np.random.default_rng(seed)
        a = model.random_identity(rng, 1.0)
        cam = PinholeCamera(650.0, 319.5, 239.5)
        frames = []
        for _ in range(12):
            w = np.zeros(model.n_expressions)
            act = rng.choice(model.n_expressions, 3, replace=False)
            w[act] = rng.uniform(0, 0.4, 3)
            R, t = _pose(rng, 30)
            X = model.face(a, w)[ids]
            frames.append(cam.with_pose(R, t).project(X) + rng.normal(0, 1.5, (ids.size, 2)))
        r = fit_identity_frames(np.array(frames), ids, 640, 480, model.neutral, model.expression_deltas,
                                model.identity_modes, focal=650.0, noise_px=1.5, rounds=12)
        assert r.focal == 650.0
        person = model.identity_neutral(a)
        fitted = np.linalg.norm(r.neutral - person, axis=1).mean()
        generic = np.linalg.norm(model.neutral - person, axis=1).mean()
        assert fitted < 0.7 * generic, (fitted, generic)
        assert r.rms < 1.5 * np.sqrt(2) * 1.3


def test_gaze_from_an_iris_on_the_eyeball():
    """An iris centre placed on the eyeball at a known yaw / pitch is read back (both eyes, head turned)."""
    from facegeom.pipelines.track import EYEBALL_RADIUS, gaze_angles

    centres = np.array([[-3.2, 3.5, 8.0], [3.2, 3.5, 8.0]])
    cam = PinholeCamera(800.0, 319.5, 239.5)
    R = Rotation.from_euler("YXZ", [15, -5, 3], degrees=True).as_matrix()
    t = np.array([1.0, -2.0, -50.0])
    for yaw, pitch in ((0.0, 0.0), (0.3, 0.1), (-0.25, -0.2)):
        d = np.array([np.sin(yaw) * np.cos(pitch), np.sin(pitch), np.cos(yaw) * np.cos(pitch)])
        iris = np.array([cam.with_pose(R, t).project((c + EYEBALL_RADIUS * d)[None])[0] for c in centres])
        g = gaze_angles(iris, R, t, centres, cam)
        assert np.allclose(g, [[yaw, pitch], [yaw, pitch]], atol=1e-6), g


def test_calibration_takes_the_rest_off_and_keeps_full_expressions():
    from facegeom.pipelines.track import calibrate

    T = 300
    W = np.zeros((T, 3))
    W[:, 0] = 0.2  # never relaxes: a rest value
    W[100:150, 0] = 1.0
    W[:, 1] = np.r_[np.zeros(200), np.linspace(0, 1, 100)]  # an expression that starts at 0
    W[:, 2] = 0.8  # held all take: at most CALIBRATION_MAX comes off
    out, rest = calibrate(W, 30.0)
    assert np.allclose(rest, [0.2, 0.0, 0.5])
    assert np.allclose(out[:, 1], W[:, 1]) and out[120, 0] == 1.0 and out[0, 0] == 0.0
    assert np.allclose(out[:, 2], 0.6)
    short, none = calibrate(W[:30], 30.0)  # one second: left alone
    assert np.array_equal(short, W[:30]) and not none.any()


def test_identity_frames_are_calm_and_spread():
    from facegeom.pipelines.track import choose_identity_frames

    rng = np.random.default_rng(0)
    T = 200
    P = np.tile(rng.normal(0, 1, (1, 468, 2)), (T, 1, 1)) * 5 + 300
    P[:, 263, 0] = P[:, 33, 0] + 60
    P[:, 263, 1] = P[:, 33, 1]
    P[:, 4, 0] += np.linspace(-15, 15, T)  # the nose tip sweeps: the head turns
    P[50:100, 14, 1] += 30  # the mouth opens in frames 50-99
    found = np.ones(T, bool)
    found[:10] = False
    k = choose_identity_frames(P, found, 12)
    assert k.size == 12 and np.unique(k).size == 12 and found[k].all()
    assert not ((k >= 50) & (k < 100)).any()
    assert k.min() < 40 and k.max() > 160
