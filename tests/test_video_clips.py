"""Synthetic face videos with known truth (facegeom.pipelines.video_clips): specs, props, a rendered clip and its truth.

Rendering needs polyscope's off-screen (EGL) renderer and PyAV; without them those tests skip, saying why.
Everything is rendered at 320 x 240 with one renderer (polyscope has one window per process).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from facegeom.pipelines import video_clips as vc
from facegeom.errors import InputError

SIZE = (320, 240)
FRAMES = 12


@pytest.fixture(scope="module")
def one_take(real_takes):
    """A single take, as on a fresh machine (CI fetches one public take)."""
    return [real_takes[0]]


@pytest.fixture(scope="module")
def renderer(headless):
    """The face renderer; polyscope is started as the viewer tests start it (the ``headless`` fixture skips where
    EGL cannot start), so that a viewer test run after these in the same process finds it set up as it expects."""
    from facegeom.pipelines.render import FaceRenderer

    try:
        return FaceRenderer(*SIZE)
    except InputError as exc:  # pragma: no cover - the headless fixture has skipped already
        pytest.skip(f"headless rendering unavailable here: {exc}")


@pytest.fixture(scope="module")
def spec(face_model, one_take):
    """A tune clip of FRAMES frames, its background made a blue no skin comes near (for the pixel checks)."""
    s = vc.make_specs(1, seed=3, family="tune", frames=FRAMES, size=SIZE, takes=one_take, model=face_model)[0]
    return dataclasses.replace(s, background_colours=((0.15, 0.3, 0.9),))


@pytest.fixture(scope="module")
def clips(tmp_path_factory, face_model, one_take, spec, renderer):
    pytest.importorskip("av")
    out = [tmp_path_factory.mktemp(f"clip{k}") for k in range(2)]
    return [vc.render_clip(spec, d, face_model, takes=one_take, renderer=renderer, progress=False) for d in out]


def frames_of(path):
    from facegeom.io.video import open_video

    with open_video(path) as r:
        return [f.image for f in r]


# ----------------------------------------------------------------------------- geometry, no rendering


def test_sphere_zones_tile_the_sphere_facing_out():
    parts = [vc.sphere_zone(1.2, a, b, r, 48) for a, b, r in ((0, 0.3, 3), (0.3, 0.6, 3), (0.6, math.pi, 24))]
    for V, F in parts:
        assert np.allclose(np.linalg.norm(V, axis=1), 1.2)
        n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
        assert np.all(np.einsum("ij,ij->i", n, V[F].mean(axis=1)) > 0)  # counter-clockwise seen from outside
    area = sum(0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1).sum()
               for V, F in parts)
    assert area == pytest.approx(4 * math.pi * 1.2 ** 2, rel=0.01)
    # neighbouring zones meet at the same ring
    ring = lambda V, z: V[np.isclose(V[:, 2], z)]
    z = 1.2 * math.cos(0.3)
    assert np.allclose(np.sort(ring(parts[0][0], z), axis=0), np.sort(ring(parts[1][0], z), axis=0))
    with pytest.raises(InputError):
        vc.sphere_zone(1.0, 1.0, 0.5, 2)


def test_gaze_convention():
    # yaw positive looks to the subject's left (+x), pitch positive up (+y)
    assert np.allclose(vc.gaze_rotation(math.radians(90), 0) @ [0, 0, 1], [1, 0, 0], atol=1e-12)
    assert np.allclose(vc.gaze_rotation(0, math.radians(90)) @ [0, 0, 1], [0, 1, 0], atol=1e-12)
    y, p = 0.3, -0.2
    assert np.allclose(vc.gaze_rotation(y, p) @ [0, 0, 1],
                       [math.cos(p) * math.sin(y), math.sin(p), math.cos(p) * math.cos(y)])


def test_eye_look_weights_follow_the_gaze(face_model):
    """The eye-look weights set from a gaze give that gaze back through the take reader's relation (signs flipped:
    ARKit's yaw is positive to the subject's right, its pitch positive down)."""
    from facegeom.io.takes import eye_rotations, ict_to_arkit

    g = np.radians([[[15, 8], [11, 8]], [[-18, -10], [-20, -10]], [[0, 0], [0, 0]]])
    W = np.zeros((3, len(face_model.expression_names)))
    for name, w in vc._look_weights(face_model, g).items():
        W[:, face_model.expression_names.index(name)] = w
    arkit, names = ict_to_arkit(W, face_model.expression_names)
    rot = eye_rotations(arkit, names)
    back = -np.stack([rot[:, [3, 4]], rot[:, [0, 1]]], axis=1)
    assert np.allclose(back, g, atol=1e-9)


def test_eyeballs_sit_behind_the_lids(face_model):
    rng = np.random.default_rng(0)
    for identity in (None, face_model.random_identity(rng), face_model.random_identity(rng)):
        N = face_model.identity_neutral(identity)
        C = vc.eye_centres(face_model, identity)
        assert C[0, 0] < 0 < C[1, 0]  # eye 0 is the subject's right (-x)
        for k, sl in enumerate((slice(36, 42), slice(42, 48))):
            lids = N[face_model.landmarks[sl]].mean(axis=0)
            assert np.allclose(C[k, :2], lids[:2])
            assert 1.0 <= lids[2] - C[k, 2] <= 1.6
            # no skin vertex near the eye inside the ball (neutral and closed lids)
            for w in (None, {"eyeBlink_L": 1.0, "eyeBlink_R": 1.0}):
                V = face_model.face(identity, w)
                d = np.linalg.norm(V - C[k], axis=1)
                assert d[np.linalg.norm(N - lids, axis=1) < 3].min() >= vc.EYE_RADIUS + 0.5 * vc.EYE_CLEARANCE
    for part in vc.HOLES:
        assert len(vc.hole_loop(face_model, part)) > 10
    with pytest.raises(InputError, match="unknown part"):
        vc.hole_loop(face_model, "nose")


# ----------------------------------------------------------------------------- specs


def test_specs_are_deterministic_and_round_trip(face_model, one_take):
    a = vc.make_specs(3, seed=5, family="holdout", frames=20, size=SIZE, takes=one_take, model=face_model)
    b = vc.make_specs(5, seed=5, family="holdout", frames=20, size=SIZE, takes=one_take, model=face_model)
    assert a == b[:3]  # a clip depends on (seed, family, index) only
    assert len({s.name for s in b}) == 5 and len({s.seed for s in b}) == 5
    for s in a:
        assert vc.ClipSpec.from_json(s.to_json()) == s
    with pytest.raises(InputError, match="clip spec"):
        vc.ClipSpec.from_json('{"name": "x"}')


def peak_yaw(spec) -> float:
    """The largest head yaw of a clip, degrees."""
    R, _ = vc.head_pose(spec, np.zeros(3))
    return float(np.degrees(np.abs(np.arctan2(R[:, 0, 2], R[:, 2, 2]))).max())


def test_families_differ_by_construction(face_model, real_takes):
    from facegeom.pipelines.render import SKIN_TONES
    from facegeom.io.takes import read_take

    kw = {"frames": 60, "size": (640, 480), "takes": real_takes, "model": face_model}
    tune = vc.make_specs(24, seed=1, family="tune", **kw)
    hold = vc.make_specs(24, seed=1, family="holdout", **kw)
    assert not {s.seed for s in tune} & {s.seed for s in hold}
    lengths = {p.name: read_take(p).n_frames for p in real_takes}
    for s in tune:  # windows in the first half of a take, in the second for the holdout
        assert s.start + s.frames <= lengths[s.take] // 2
    for s in hold:
        assert s.start >= lengths[s.take] - lengths[s.take] // 2
    ft, fh = vc.FAMILIES["tune"], vc.FAMILIES["holdout"]
    assert fh.yaw > ft.yaw and fh.pitch > ft.pitch and fh.roll > ft.roll
    for fam, specs in ((ft, tune), (fh, hold)):
        for s in specs:
            assert 0.4 * fam.yaw - 1e-6 <= peak_yaw(s) <= fam.yaw + 1e-6
            assert any(lo - 1e-9 <= s.fov <= hi + 1e-9 for lo, hi in fam.fov)
            assert s.fraction <= fam.fraction[1] + 1e-9 and s.background == fam.background
            assert s.focal == pytest.approx(s.height / 2 / math.tan(math.radians(s.fov) / 2))
            g = vc.gaze_curves(s)
            assert np.degrees(np.abs(g[..., 0])).max() <= fam.gaze_yaw + 1e-6
            assert np.degrees(np.abs(g[..., 1])).max() <= fam.gaze_pitch + 1e-6
    assert max(s.fov for s in tune) < 65.001 and all(s.fov <= 45 or s.fov >= 65 for s in hold)
    assert min(s.fraction for s in tune) > max(s.fraction for s in hold) - 1e-9
    assert np.mean([peak_yaw(s) for s in hold]) > np.mean([peak_yaw(s) for s in tune])
    bright = lambda s: sum(s.skin)
    assert np.mean([bright(s) for s in hold]) < np.mean([bright(s) for s in tune])
    assert max(bright(s) for s in hold) < sum(SKIN_TONES[1]) and min(bright(s) for s in tune) > sum(SKIN_TONES[3])
    assert {s.background for s in tune} == {"plain"} and {s.background for s in hold} == {"noise"}


def test_spec_errors(face_model, one_take):
    with pytest.raises(InputError, match="unknown clip family"):
        vc.make_specs(1, family="train", takes=one_take, model=face_model)
    with pytest.raises(InputError, match="need a take of at least"):
        vc.make_specs(1, frames=10 ** 6, takes=one_take, model=face_model)
    with pytest.raises(InputError, match="n must be"):
        vc.make_specs(0, takes=one_take, model=face_model)
    s = vc.make_specs(1, frames=5, size=SIZE, takes=one_take, model=face_model)[0]
    with pytest.raises(InputError, match="not among the takes"):
        vc.clip_weights(dataclasses.replace(s, take="nope.csv"), face_model, one_take)


def test_head_and_gaze_from_the_take(face_model, tmp_path):
    """With take_head the take's own head rotation drives the pose (when it has one); with gaze_from_take the gaze
    is the take's eye-look weights read back, and those weights are rendered as they are."""
    from scipy.spatial.transform import Rotation

    from facegeom.io.takes import ARKIT_NAMES, eye_rotations, head_angles, write_livelink_csv

    T = 80
    rng = np.random.default_rng(4)
    W = np.clip(rng.uniform(0, 0.6, (T, 52)), 0, 1)
    rot = np.zeros((T, 9))
    rot[:, 0] = 0.3 * np.sin(np.linspace(0, 3, T))  # head yaw
    rot[:, 1] = 0.1
    path = write_livelink_csv(tmp_path / "moving.csv", W, ARKIT_NAMES, 30.0, rotations=rot)
    kw = {"frames": 20, "size": SIZE, "takes": [path], "model": face_model}
    s = vc.make_specs(1, seed=0, take_head=True, gaze_from_take=True, **kw)[0]
    assert s.head_from_take and s.gaze_from_take
    weights, gaze, head = vc.clip_weights(s, face_model, [path])
    a, b = s.window
    assert np.allclose(head, rot[a:b, :3], atol=1e-6)
    R, _ = vc.head_pose(s, np.zeros(3), head)
    assert np.allclose(head_angles(R), rot[a:b, :3], atol=1e-6)
    assert np.allclose(R, Rotation.from_euler("YXZ", rot[a:b, :3]).as_matrix())
    er = eye_rotations(W[a:b], ARKIT_NAMES)
    assert np.allclose(gaze[:, 0], -er[:, [3, 4]], atol=1e-6) and np.allclose(gaze[:, 1], -er[:, [0, 1]], atol=1e-6)
    j = face_model.expression_names.index("eyeLookIn_L")
    assert np.allclose(weights[:, j], W[a:b, ARKIT_NAMES.index("EyeLookInLeft")], atol=1e-6)
    # without take_head (or a take without head rotation) the head follows the drawn sinusoids
    s2 = vc.make_specs(1, seed=0, **kw)[0]
    assert not s2.head_from_take and not s2.gaze_from_take


def test_landmarks_stay_in_the_frame(face_model, one_take):
    """make_specs moves the camera back (or calms the drift) until every landmark stays inside the frame."""
    for fam in ("tune", "holdout"):
        for s in vc.make_specs(6, seed=2, family=fam, frames=90, size=SIZE, takes=one_take, model=face_model):
            W, gaze, head = vc.clip_weights(s, face_model, one_take)
            centre = vc._face_frame(face_model, np.asarray(s.identity))[0]
            R, t = vc.head_pose(s, centre, head)
            truth = {"weights": W, "identity": np.asarray(s.identity), "rotations": R, "translations": t,
                     "focal": s.focal, "width": s.width, "height": s.height, "gaze": gaze,
                     "eye_centres": vc.eye_centres(face_model, s.identity), "eye_radius": vc.EYE_RADIUS}
            uv = vc.landmark_truth(truth, face_model)
            assert uv.shape == (90, 68, 2)
            assert uv[..., 0].min() > 0 and uv[..., 0].max() < s.width
            assert uv[..., 1].min() > 0 and uv[..., 1].max() < s.height


# ----------------------------------------------------------------------------- rendering


def test_clip_video_and_truth(clips, spec, face_model):
    video = clips[0]
    assert video.name == f"{spec.name}.mp4"
    frames = frames_of(video)
    assert len(frames) == FRAMES and frames[0].shape == (SIZE[1], SIZE[0], 3)
    with np.load(video.with_name(f"{spec.name}.truth.npz")) as z:
        d = {k: z[k] for k in z.files}
    T, B = FRAMES, len(face_model.expression_names)
    assert d["weights"].shape == (T, B) and d["weights"].min() >= 0 and d["weights"].max() <= 1
    assert tuple(d["expression_names"]) == face_model.expression_names
    assert d["identity"].shape == (face_model.n_identities,)
    assert d["rotations"].shape == (T, 3, 3) and d["translations"].shape == (T, 3)
    assert np.allclose(np.einsum("tij,tkj->tik", d["rotations"], d["rotations"]), np.eye(3), atol=1e-9)
    assert d["gaze"].shape == (T, 2, 2) and d["eye_centres"].shape == (2, 3)
    assert float(d["focal"]) == pytest.approx(spec.focal)
    assert (int(d["width"]), int(d["height"])) == SIZE and float(d["fps"]) == pytest.approx(spec.fps)
    assert str(d["take"]) == spec.take and tuple(d["window"]) == spec.window
    assert vc.ClipSpec.from_json(str(d["spec"])) == spec
    # the gaze drawn drives the eye-look weights rendered
    look = vc._look_weights(face_model, d["gaze"])
    for name, w in look.items():
        assert np.allclose(d["weights"][:, face_model.expression_names.index(name)], w)


def test_render_is_deterministic(clips):
    a, b = clips
    with np.load(a.with_suffix(".truth.npz")) as za, np.load(b.with_suffix(".truth.npz")) as zb:
        assert za.files == zb.files
        for k in za.files:
            assert np.array_equal(za[k], zb[k]), k
    fa, fb = frames_of(a)[0], frames_of(b)[0]
    assert np.abs(fa.astype(int) - fb.astype(int)).mean() < 0.5


def test_landmark_truth_lies_on_the_face(clips, spec, face_model):
    video = clips[0]
    uv = vc.landmark_truth(video.with_suffix(".truth.npz"), face_model)
    assert uv.shape == (FRAMES, 68, 2)
    bg = np.asarray(vc.grade(np.full((1, 1, 3), np.round(np.asarray(spec.background_colours[0]) * 255),
                                     dtype=np.uint8), dataclasses.replace(spec, noise=0.0), 0)[0, 0], dtype=float)
    for k, img in enumerate(frames_of(video)):
        for j in (30, 33, 8, 27):  # nose tip, under the nose, chin, nose bridge
            x, y = np.round(uv[k, j]).astype(int)
            assert np.abs(img[y, x].astype(float) - bg).max() > 40, (k, j, img[y, x], bg)
    # a corner is background
    assert np.abs(frames_of(video)[0][2, 2].astype(float) - bg).max() < 15
    pupils = vc.pupil_truth(video.with_suffix(".truth.npz"))
    assert pupils.shape == (FRAMES, 2, 2)
    assert np.all(pupils[:, 0, 0] < pupils[:, 1, 0])  # the subject's right eye is on the image's left


def _frontal(spec):
    """A close frontal look at the spec's face: no light changes or noise, a grey background."""
    return dataclasses.replace(spec, fov=50.0, distance=24.0, gain=1.0, contrast=1.0, gamma=1.0,
                               tint=(1.0, 1.0, 1.0), noise=0.0, background="plain",
                               background_colours=((0.45, 0.5, 0.55),), iris=vc.IRIS_COLOURS["blue"])


def test_iris_follows_the_gaze(spec, face_model, renderer):
    from matplotlib.path import Path as MPath

    scene = vc.ClipScene(_frontal(spec), face_model, renderer)
    cam = scene.camera.with_pose(np.eye(3), np.array([0.0, 0.0, -scene.spec.distance]) - scene.centre)
    lm = cam.project(scene.neutral[face_model.landmarks])
    yy, xx = np.mgrid[0:SIZE[1], 0:SIZE[0]]
    xs = {}
    for yaw in (-20, 0, 20):
        img = scene.render(gaze=np.radians([[yaw, 0], [yaw, 0]])).astype(float)
        lum = img @ [0.299, 0.587, 0.114]
        for k, sl in enumerate((slice(36, 42), slice(42, 48))):
            eye = MPath(lm[sl]).contains_points(np.c_[xx.ravel(), yy.ravel()]).reshape(lum.shape)  # inside the lids
            dark = eye & (lum < 0.6 * np.percentile(lum[eye], 95))  # iris and pupil against the sclera
            assert dark.sum() > 10, (yaw, k)
            xs[yaw, k] = np.nonzero(dark)[1].mean()
    for k in range(2):  # looking to the subject's left moves the iris to the image's right
        assert xs[-20, k] + 1.5 < xs[0, k] < xs[20, k] - 1.5, xs
    # the pupil truth lands on the dark pixels
    truth = {"weights": np.zeros((1, len(face_model.expression_names))), "identity": scene.identity,
             "rotations": cam.R[None], "translations": cam.t[None], "focal": scene.spec.focal,
             "width": SIZE[0], "height": SIZE[1], "gaze": np.radians([[[20, 0], [20, 0]]]),
             "eye_centres": scene.props.centres, "eye_radius": scene.props.radius}
    p = vc.pupil_truth(truth)[0]
    assert abs(p[0, 0] - xs[20, 0]) < 3 and abs(p[1, 0] - xs[20, 1]) < 3


def _caps(V, props):
    """The holes closed by flat fans (both sides): what can be seen through them."""
    out = []
    for loop in props.loops.values():
        B = V[loop]
        n = len(loop)
        j = np.arange(n)
        F = np.c_[j, (j + 1) % n, np.full(n, n)]
        P = np.r_[B, B.mean(axis=0, keepdims=True)]
        out += [(P, F, (0.0, 1.0, 0.0)), (P.copy(), F[:, ::-1].copy(), (0.0, 1.0, 0.0))]
    return out


@pytest.mark.parametrize("yaw,pitch", [(0, 0), (30, -10), (-30, 15)])
def test_open_mouth_is_dark_and_props_stay_inside(spec, face_model, renderer, yaw, pitch):
    """jawOpen 1: the mouth shows the dark pouch, not the background; the eyes and the pouch change no pixel outside
    the holes (nothing pokes through chin, cheeks or lids) and leave no hole to the background."""
    from scipy import ndimage
    from scipy.spatial.transform import Rotation

    scene = vc.ClipScene(_frontal(spec), face_model, renderer)
    w = np.zeros(len(face_model.expression_names))
    w[face_model.expression_names.index("jawOpen")] = 1.0
    V = scene.vertices(w)
    R = Rotation.from_euler("YXZ", np.radians([yaw, pitch, 0])).as_matrix()
    cam = scene.camera.with_pose(R, -R @ scene.centre + [0.0, 0.0, -30.0])
    magenta = (1.0, 0.0, 1.0)
    g = np.radians([[20, 10], [20, 10]])
    plain = renderer.render(V, face_model.triangles, cam, background=magenta)
    props = renderer.render(V, face_model.triangles, cam, background=magenta,
                            extra=scene.props.meshes(V, g, scene.spec.iris, scene.spec.skin))
    holes = renderer.render(V, face_model.triangles, cam, background=magenta, extra=_caps(V, scene.props))
    inside_holes = ndimage.binary_dilation(np.any(plain != holes, axis=2), iterations=1)
    changed = np.any(plain != props, axis=2)
    assert not np.any(changed & ~inside_holes)
    bg = np.all(props == [255, 0, 255], axis=2)
    lab, n = ndimage.label(bg)
    edge = set(np.unique(np.r_[lab[0], lab[-1], lab[:, 0], lab[:, -1]]))
    assert all(k in edge for k in range(1, n + 1))  # no background seen through the face
    if yaw == 0:
        uv = cam.project(V[face_model.landmarks])
        x, y = np.round((uv[62] + uv[66]) / 2).astype(int)  # between the inner lips
        r, gg, b = props[y, x].astype(int)
        assert r > gg and r > b and r + gg + b < 300, props[y, x]
