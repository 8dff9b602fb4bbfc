"""BlendshapeRig, targets, camera and landmark sets (facegeom.model.rig)."""
from __future__ import annotations

import numpy as np
import pytest

from facegeom.errors import InputError
from facegeom.io import write_mesh
from facegeom.model import (
    EVAL_LANDMARKS_26,
    FIT_LANDMARKS_23,
    INNER_EYE_CORNERS,
    INNER_LANDMARKS_49,
    MIRROR_68,
    BlendshapeRig,
    LandmarkTarget,
    MeshTarget,
    PinholeCamera,
    PointCloudTarget,
    look_at_camera,
)

# --------------------------------------------------------------------------- a tiny rig

NEUTRAL = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.5], [2, 0, 0.2]], float)
TRIS = np.array([[0, 1, 2], [1, 3, 2], [1, 4, 3]])
NAMES = ("jawOpen", "smile_L", "smile_R", "blink")


def tiny_deltas(seed=0):
    return np.random.default_rng(seed).normal(size=(4, 5, 3))


@pytest.fixture
def rig():
    return BlendshapeRig(NEUTRAL, tiny_deltas(), NAMES, TRIS, landmark_ids=[0, 3])


def test_sizes_and_readonly(rig):
    assert rig.n_vertices == 5 and rig.n_shapes == 4
    assert rig.deltas.dtype == np.float64 and rig.triangles.dtype == np.int64
    with pytest.raises(ValueError):
        rig.neutral[0, 0] = 1.0
    assert "n_shapes=4" in repr(rig)


def test_input_is_copied():
    d = tiny_deltas()
    r = BlendshapeRig(NEUTRAL, d, NAMES, TRIS)
    d[0] += 1
    assert not np.allclose(r.deltas, d)


@pytest.mark.parametrize("kwargs, problem", [
    ({"deltas": tiny_deltas()[:, :4]}, "4 vertices per shape but the neutral has 5"),
    ({"deltas": tiny_deltas()[0]}, "shape (B, n, 3)"),
    ({"deltas": np.zeros((0, 5, 3))}, "at least one blendshape"),
    ({"names": NAMES[:3]}, "3 names for 4 blendshapes"),
    ({"names": ("a", "b", "a", "c")}, "duplicate blendshape name 'a'"),
    ({"names": ("a", "", "b", "c")}, "non-empty string"),
    ({"names": "abcd"}, "not one string"),
    ({"neutral": np.r_[NEUTRAL[:4], [[np.nan, 0, 0]]]}, "NaN"),
    ({"triangles": [[0, 1, 9]]}, "outside [0, 5)"),
    ({"landmark_ids": [0, 0]}, "repeated"),
    ({"landmark_ids": [7]}, "out of range"),
])
def test_validation(kwargs, problem):
    args = dict(neutral=NEUTRAL, deltas=tiny_deltas(), names=NAMES, triangles=TRIS)
    args.update(kwargs)
    with pytest.raises(InputError, match=None) as exc:
        BlendshapeRig(**args)
    assert problem in str(exc.value)


def test_nan_in_deltas_names_the_shape():
    d = tiny_deltas()
    d[2, 3, 1] = np.nan
    with pytest.raises(InputError, match=r"shape 2 'smile_R', vertex 3"):
        BlendshapeRig(NEUTRAL, d, NAMES, TRIS)


def test_shape_index_and_unknown_names(rig):
    assert rig.shape_index("smile_R") == 2
    with pytest.raises(InputError, match=r"unknown blendshape 'smile_r'.*did you mean 'smile_R'"):
        rig.shape_index("smile_r")
    with pytest.raises(InputError, match="the rig has 4 shapes"):
        rig.shape_index("zzzzzzzz")


def test_weights_from_dict(rig):
    w = rig.weights_from_dict({"blink": 0.5, "jawOpen": 1})
    assert np.array_equal(w, [1, 0, 0, 0.5])
    with pytest.raises(InputError, match="unknown blendshape 'nope'"):
        rig.weights_from_dict({"nope": 1.0})
    with pytest.raises(InputError, match="NaN"):
        rig.weights_from_dict({"blink": float("nan")})
    with pytest.raises(InputError, match=r"shape \(4,\)"):
        rig.evaluate(np.ones(3))


def test_evaluate_matches_loop(rig):
    w = np.array([0.3, -0.2, 0.0, 1.5])
    expected = NEUTRAL.copy()
    for b in range(4):
        expected += w[b] * rig.deltas[b]
    assert np.allclose(rig.evaluate(w), expected)
    assert np.allclose(rig.evaluate(dict(zip(NAMES, w))), expected)
    assert np.allclose(rig.evaluate(w, vertex_ids=[4, 1]), expected[[4, 1]])
    assert np.allclose(rig.evaluate(np.zeros(4)), NEUTRAL)


def test_delta_matrix_and_gram(rig):
    D = rig.delta_matrix()
    assert D.shape == (15, 4)
    for b in range(4):
        assert np.array_equal(D[:, b], rig.deltas[b].ravel())
    w = np.array([0.1, 0.2, 0.3, 0.4])
    assert np.allclose(D @ w, (rig.evaluate(w) - NEUTRAL).ravel())
    G = rig.gram()
    assert np.allclose(G, D.T @ D)
    assert np.array_equal(G, G.T)
    assert rig.gram() is G and rig.delta_matrix() is D  # cached


def test_npz_round_trip(rig, tmp_path):
    p = rig.save_npz(tmp_path / "rig.npz")
    r2 = BlendshapeRig.from_npz(p)
    for k in ("neutral", "deltas", "triangles", "landmark_ids"):
        assert np.array_equal(getattr(r2, k), getattr(rig, k))
    assert r2.names == rig.names
    # without landmark ids, and a path without the .npz suffix (written atomically as is)
    r3 = BlendshapeRig(NEUTRAL, tiny_deltas(), NAMES, TRIS)
    r3.save_npz(tmp_path / "rig.bin", compressed=True)
    assert BlendshapeRig.from_npz(tmp_path / "rig.bin").landmark_ids is None
    assert sorted(x.name for x in tmp_path.iterdir()) == ["rig.bin", "rig.npz"]


def test_npz_errors(tmp_path):
    p = tmp_path / "bad.npz"
    np.savez(p, neutral=NEUTRAL, deltas=tiny_deltas(), names=np.array(NAMES), triangles=TRIS)
    with pytest.raises(InputError, match=r"bad\.npz: not a rig file: missing key\(s\) landmark_ids"):
        BlendshapeRig.from_npz(p)
    with pytest.raises(InputError, match="file not found"):
        BlendshapeRig.from_npz(tmp_path / "none.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(InputError, match="junk.npz"):
        BlendshapeRig.from_npz(tmp_path / "junk.npz")
    np.savez(tmp_path / "dup.npz", neutral=NEUTRAL, deltas=tiny_deltas(), names=np.array(["a"] * 4),
             triangles=TRIS, landmark_ids=np.zeros(0, int))
    with pytest.raises(InputError, match=r"dup\.npz: duplicate blendshape name"):
        BlendshapeRig.from_npz(tmp_path / "dup.npz")


def test_obj_folder_round_trip(rig, tmp_path):
    rig.write_obj_folder(tmp_path)
    r2 = BlendshapeRig.from_obj_folder(tmp_path)
    assert r2.names == tuple(sorted(NAMES))  # sorted by file name
    order = [rig.shape_index(n) for n in r2.names]
    assert np.allclose(r2.deltas, rig.deltas[order], atol=1e-12)
    assert np.allclose(r2.neutral, NEUTRAL)
    assert np.array_equal(r2.triangles, TRIS)


def test_obj_folder_by_hand_and_errors(tmp_path):
    write_mesh(tmp_path / "base.obj", NEUTRAL, TRIS)
    write_mesh(tmp_path / "b_up.obj", NEUTRAL + [0, 1, 0], TRIS)
    write_mesh(tmp_path / "a_left.obj", NEUTRAL + [-2, 0, 0], TRIS)
    (tmp_path / "notes.txt").write_text("ignored")
    r = BlendshapeRig.from_obj_folder(tmp_path, neutral_name="base")
    assert r.names == ("a_left", "b_up")
    assert np.allclose(r.deltas[0], [-2, 0, 0]) and np.allclose(r.deltas[1], [0, 1, 0])
    with pytest.raises(InputError, match="no neutral mesh 'neutral.obj'"):
        BlendshapeRig.from_obj_folder(tmp_path, neutral_name="neutral")
    V, F = NEUTRAL[:4], TRIS[:2]
    write_mesh(tmp_path / "c_small.obj", V, F)
    with pytest.raises(InputError, match=r"c_small\.obj: has 4 vertices but the neutral 'base.obj' has 5"):
        BlendshapeRig.from_obj_folder(tmp_path, neutral_name="base")
    empty = tmp_path / "empty"
    empty.mkdir()
    write_mesh(empty / "neutral.obj", NEUTRAL, TRIS)
    with pytest.raises(InputError, match="no blendshape OBJ"):
        BlendshapeRig.from_obj_folder(empty)
    with pytest.raises(InputError, match="not a folder"):
        BlendshapeRig.from_obj_folder(tmp_path / "nope")


# --------------------------------------------------------------------------- camera


def test_projection_of_known_points():
    cam = PinholeCamera(100.0, 320, 240)  # identity pose: camera at the origin looking down -z
    P = np.array([[0, 0, -10], [1, 0, -10], [0, 1, -10], [-2, -1, -5]], float)
    uv = cam.project(P)
    assert np.allclose(uv, [[320, 240], [330, 240], [320, 230], [280, 260]])


def test_projection_with_pose_and_center():
    R = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]], float)  # 90 degrees about z
    cam = PinholeCamera(50.0, 0, 0, R, [0, 0, -4])
    assert np.allclose(cam.center, R.T @ [0, 0, 4])
    x = np.array([[1.0, 0, 0]])  # -> camera (0, 1, -4): above the centre
    assert np.allclose(cam.project(x), [[0, -50 / 4]])


def test_behind_camera_and_camera_validation():
    cam = PinholeCamera(100.0, 0, 0)
    with pytest.raises(InputError, match="landmark 1 is behind the camera"):
        cam.project([[0, 0, -1], [0, 0, 1]], what="landmark")
    with pytest.raises(InputError, match="behind the camera"):
        cam.project([[0, 0, 0.0]])
    with pytest.raises(InputError, match="point 1 is NaN"):
        cam.project([[0, 0, -1], [0, np.nan, -1]])
    with pytest.raises(InputError, match="focal must be > 0"):
        PinholeCamera(0, 0, 0)
    with pytest.raises(InputError, match="rotation matrix"):
        PinholeCamera(1, 0, 0, R=2 * np.eye(3))
    with pytest.raises(InputError, match="rotation matrix"):
        PinholeCamera(1, 0, 0, R=np.diag([1.0, 1, -1]))
    with pytest.raises(InputError, match=r"t must have shape \(3,\)"):
        PinholeCamera(1, 0, 0, t=[0, 0])
    with pytest.raises(InputError, match="cx must be finite"):
        PinholeCamera(1, np.nan, 0)


def test_jacobian_matches_finite_differences():
    cam = look_at_camera(NEUTRAL, yaw=20, pitch=-10)
    X = NEUTRAL + 0.1
    J = cam.jacobian(X)
    h = 1e-6
    for k in range(3):
        dX = np.zeros(3)
        dX[k] = h
        num = (cam.project(X + dX) - cam.project(X - dX)) / (2 * h)
        assert np.allclose(J[:, :, k], num, rtol=1e-5, atol=1e-4)


def test_look_at_camera_frames_the_mesh():
    cam = look_at_camera(NEUTRAL, focal=500, image_size=(640, 480))
    assert np.allclose(cam.R, np.eye(3))
    uv = cam.project(NEUTRAL)
    assert np.all((uv >= 0) & (uv <= [640, 480]))
    # +x goes right, +y goes up (smaller v)
    assert uv[1, 0] > uv[0, 0] and uv[2, 1] < uv[0, 1]
    far = look_at_camera(NEUTRAL, focal=500, distance=100)
    assert np.isclose(np.linalg.norm(far.center - [1, 0.5, 0.25]), 100)
    side = look_at_camera(NEUTRAL, yaw=90, distance=10)
    assert np.allclose(side.center, [1 + 10, 0.5, 0.25])  # orbits to +x, still looks at the centre
    assert np.allclose(side.to_camera([[1, 0.5, 0.25]]), [[0, 0, -10]])


# --------------------------------------------------------------------------- targets


def test_mesh_target():
    t = MeshTarget(NEUTRAL, weights=np.ones(5))
    assert t.n_vertices == 5
    with pytest.raises(InputError, match="NaN"):
        MeshTarget(np.r_[NEUTRAL[:4], [[0, np.inf, 0]]])
    with pytest.raises(InputError, match="weights must be >= 0"):
        MeshTarget(NEUTRAL, weights=[1, 1, -1, 1, 1])
    with pytest.raises(InputError, match="all zero"):
        MeshTarget(NEUTRAL, weights=np.zeros(5))
    with pytest.raises(InputError, match=r"shape \(5,\)"):
        MeshTarget(NEUTRAL, weights=np.ones(4))
    rig = BlendshapeRig(NEUTRAL[:3], tiny_deltas()[:, :3], NAMES, TRIS[:1])
    with pytest.raises(InputError, match="5 vertices, the rig 3"):
        MeshTarget(NEUTRAL).check(rig)


def test_landmark_target(rig):
    cam = look_at_camera(NEUTRAL)
    t = LandmarkTarget.from_mesh(NEUTRAL, [0, 3, 4], cam)
    assert t.n_landmarks == 3
    assert np.allclose(t.project(NEUTRAL), t.points2d)
    t.check(rig)
    sub = t.subset([2, 0])
    assert np.array_equal(sub.vertex_ids, [4, 0])
    assert np.array_equal(t.rows_of([4, 0]), [2, 0])
    with pytest.raises(InputError, match="vertex 1 is not among"):
        t.rows_of([1])
    with pytest.raises(InputError, match="landmark 1 is NaN"):
        LandmarkTarget([[0, 0], [np.nan, 1]], [0, 1], cam)
    with pytest.raises(InputError, match="vertex id 1 is repeated"):
        LandmarkTarget([[0, 0], [1, 1]], [1, 1], cam)
    with pytest.raises(InputError, match="2 landmark points for 3 vertex ids"):
        LandmarkTarget([[0, 0], [1, 1]], [1, 2, 3], cam)
    with pytest.raises(InputError, match="PinholeCamera"):
        LandmarkTarget([[0, 0]], [1], camera=None)
    with pytest.raises(InputError, match="out of range"):
        LandmarkTarget([[0, 0]], [99], cam).check(rig)
    behind = PinholeCamera(100, 0, 0, t=[0, 0, 5])  # the mesh at z ~ 0 is at camera z ~ +5
    with pytest.raises(InputError, match="landmark 0 is behind the camera"):
        t.__class__.from_mesh(NEUTRAL, [0], behind)


def test_point_cloud_target():
    t = PointCloudTarget(NEUTRAL, normals=np.tile([0, 0, 2.0], (5, 1)))
    assert np.allclose(t.normals, [0, 0, 1]) and t.n_points == 5
    with pytest.raises(InputError, match="empty"):
        PointCloudTarget(np.zeros((0, 3)))
    with pytest.raises(InputError, match="point 2 is NaN"):
        PointCloudTarget(np.r_[NEUTRAL[:2], [[np.nan, 0, 0]]])
    with pytest.raises(InputError, match="normal 0 is zero"):
        PointCloudTarget(NEUTRAL, normals=np.zeros((5, 3)))
    with pytest.raises(InputError, match=r"shape \(N, 3\)"):
        PointCloudTarget(np.zeros((4, 2)))


# --------------------------------------------------------------------------- landmark sets


def test_landmark_sets_partition_the_49():
    assert len(INNER_LANDMARKS_49) == 49 and 60 not in INNER_LANDMARKS_49 and 64 not in INNER_LANDMARKS_49
    assert INNER_LANDMARKS_49 == tuple(i for i in range(17, 68) if i not in (60, 64))
    assert len(FIT_LANDMARKS_23) == 23 and len(EVAL_LANDMARKS_26) == 26
    assert sorted(FIT_LANDMARKS_23 + EVAL_LANDMARKS_26) == list(INNER_LANDMARKS_49)
    assert set(INNER_EYE_CORNERS) <= set(FIT_LANDMARKS_23)


def test_landmark_sets_are_mirror_symmetric_and_cover_every_region():
    assert all(MIRROR_68[MIRROR_68[i]] == i for i in range(68))
    for s in (FIT_LANDMARKS_23, EVAL_LANDMARKS_26):
        assert {MIRROR_68[i] for i in s} == set(s)
        for lo, hi in [(17, 27), (27, 36), (36, 48), (48, 60), (60, 68)]:  # brows, nose, eyes, lips
            assert any(lo <= i < hi for i in s)


# --------------------------------------------------------------------------- the real ICT rig


@pytest.fixture(scope="module")
def ict_rig(face_model):
    return BlendshapeRig.from_face_model(face_model)


def test_ict_rig_matches_the_face_model(face_model, ict_rig):
    assert ict_rig.n_shapes == 53 and ict_rig.n_vertices == face_model.n_vertices
    assert ict_rig.landmark_ids.shape == (68,)
    expr = {"jawOpen": 0.7, "mouthSmile_L": 0.4, "eyeBlink_R": 1.0}
    assert np.allclose(ict_rig.evaluate(expr), face_model.face(expression=expr), atol=1e-5)
    ident = face_model.random_identity(3)
    r2 = BlendshapeRig.from_face_model(face_model, identity=ident)
    assert np.allclose(r2.neutral, face_model.identity_neutral(ident))
    G = ict_rig.gram()
    assert G.shape == (53, 53)
    assert np.allclose(np.diag(G), np.sum(ict_rig.deltas.reshape(53, -1) ** 2, axis=1))
    assert np.linalg.eigvalsh(G).min() > -1e-6 * np.abs(G).max()


def test_ict_front_camera_sees_the_landmarks_like_a_photo(ict_rig):
    V = ict_rig.neutral
    cam = look_at_camera(V)
    ids = ict_rig.landmark_vertices(range(68))
    uv = LandmarkTarget.from_mesh(V, ids, cam).points2d
    assert np.all((uv > 0) & (uv < [640, 480]))
    assert uv[36, 0] < uv[45, 0]  # the subject's right eye on the image's left
    assert uv[19, 1] < uv[37, 1] < uv[30, 1] < uv[51, 1] < uv[8, 1]  # brow above eye above nose above mouth above chin
    lm_sets = ict_rig.landmark_vertices(FIT_LANDMARKS_23), ict_rig.landmark_vertices(EVAL_LANDMARKS_26)
    assert not set(lm_sets[0]) & set(lm_sets[1])


def test_ict_npz_round_trip(ict_rig, tmp_path):
    r2 = BlendshapeRig.from_npz(ict_rig.save_npz(tmp_path / "ict.npz"))
    assert r2.names == ict_rig.names and np.array_equal(r2.deltas, ict_rig.deltas)
