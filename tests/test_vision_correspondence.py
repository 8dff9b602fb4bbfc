"""The shipped MediaPipe <-> face model maps (facegeom.vision.correspondence) and the script that makes them.

Thresholds are the numbers ``data/mediapipe_map/make_map.py`` prints (its docstring lists them) with a margin
of about 3x or 0.3-0.5 mm, whichever is larger; a change of method that moves them should update both.
"""
from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from facegeom.errors import InputError
from facegeom.vision import correspondence as corr

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "data" / "mediapipe_map" / "make_map.py"

# (MediaPipe point, iBUG landmark) the map is built to match; measured 0.0-0.1 mm apart on the neutral
EYE_CORNERS = ((33, 36), (133, 39), (362, 42), (263, 45))
MOUTH_CORNERS = ((61, 48), (291, 54))
NOSE_TIP = ((4, 30),)
OTHER_PAIRS = ((2, 33), (168, 27), (0, 51), (17, 57), (152, 8))
PAIR_TOL_CM = 0.05  # measured <= 0.01 cm
MIRROR_TOL_CM = 0.05  # measured max 0.014 cm
INNER51_TOL_CM = 0.12  # measured max 0.08 cm (landmark 35); per region mean <= 0.02 cm
JAW_TOL_CM = 0.4  # measured max 0.24 cm (landmarks 0 and 16, beyond MediaPipe's outline)
SCRIPT_SECONDS = 30  # the script takes ~4 s


def _raw_rows(path: Path) -> np.ndarray:
    lines = [ln for ln in path.read_text(encoding="utf-8").splitlines() if ln and not ln.startswith("#")]
    return np.array([[float(c) for c in ln.split(",")] for ln in lines[1:]])


def _mapped(face_model) -> np.ndarray:
    return corr.mediapipe_map().points(face_model.neutral, face_model.triangles)


def test_the_files_load_with_their_shapes():
    mp = corr.mediapipe_map()
    assert mp.triangle.shape == (468,) and mp.triangle.dtype == np.int64
    assert mp.bary.shape == (468, 3) and mp.bary.dtype == np.float64
    assert mp.distance.shape == (468,)
    lm = corr.landmarks68_map()
    assert lm.corners.shape == (68, 3) and lm.corners.dtype == np.int64
    assert lm.bary.shape == (68, 3) and lm.distance.shape == (68,)
    V, F = corr.canonical_mesh()
    assert V.shape == (468, 3) and F.shape == (898, 3)
    assert corr.mediapipe_map() is mp  # cached
    with pytest.raises(ValueError):
        mp.bary[0, 0] = 1.0  # read-only


@pytest.mark.parametrize("path, cols", [(corr.MEDIAPIPE_FILE, slice(2, 5)), (corr.LANDMARKS68_FILE, slice(4, 7))],
                         ids=["mediapipe", "landmarks68"])
def test_barycentric_coordinates_as_written(path, cols):
    rows = _raw_rows(path)
    b = rows[:, cols]
    assert (b >= -1e-9).all()
    np.testing.assert_allclose(b.sum(axis=1), 1.0, atol=1e-9)
    assert (rows[:, -1] >= 0).all()


def test_every_index_is_valid(face_model):
    mp = corr.mediapipe_map()
    assert mp.triangle.min() >= 0 and mp.triangle.max() < len(face_model.triangles)
    lm = corr.landmarks68_map()
    faces = {tuple(f) for f in corr.canonical_mesh()[1].tolist()}
    assert all(tuple(c) in faces for c in lm.corners.tolist())


def test_the_shipped_map_fits_this_face_model(face_model):
    """The header names the neutral it was made on; a different face model would need a rerun of the script."""
    import hashlib

    N = face_model.neutral.astype("<f4").tobytes() + face_model.triangles.astype("<i4").tobytes()
    assert hashlib.sha256(N).hexdigest() in corr.MEDIAPIPE_FILE.read_text(encoding="utf-8")


def test_the_map_puts_the_points_on_the_neutral_surface(face_model):
    mp = corr.mediapipe_map()
    P = _mapped(face_model)
    assert P.shape == (468, 3) and np.isfinite(P).all()
    assert mp.distance.max() < 0.05  # measured max 0.011 cm before the snap
    batch = np.stack([face_model.neutral, face_model.neutral + 1.0])
    Pb = mp.points(batch, face_model.triangles)
    assert Pb.shape == (2, 468, 3)
    np.testing.assert_allclose(Pb[0], P)
    np.testing.assert_allclose(Pb[1], P + 1.0)
    with pytest.raises(InputError):
        mp.points(face_model.neutral[:100], face_model.triangles)
    with pytest.raises(InputError):
        mp.points(face_model.neutral, face_model.triangles[:10])


@pytest.mark.parametrize("pairs", [EYE_CORNERS, MOUTH_CORNERS, NOSE_TIP, OTHER_PAIRS],
                         ids=["eye corners", "mouth corners", "nose tip", "nose root, subnasale, lip mids, chin"])
def test_well_defined_points_land_on_their_landmarks(face_model, pairs):
    P = _mapped(face_model)
    L = face_model.neutral[face_model.landmarks]
    d = [float(np.linalg.norm(P[a] - L[b])) for a, b in pairs]
    assert max(d) < PAIR_TOL_CM, dict(zip(pairs, np.round(d, 3)))


def test_mirror_points_map_to_mirror_points(face_model):
    V, _ = corr.canonical_mesh()
    d, mirror = cKDTree(V).query(V * [-1.0, 1.0, 1.0])
    assert d.max() < 1e-6 and (mirror[mirror] == np.arange(468)).all()  # the canonical mesh is exactly symmetric
    assert (mirror == np.arange(468)).sum() == 28  # the midline
    P = _mapped(face_model)
    err = np.linalg.norm(P * [-1.0, 1.0, 1.0] - P[mirror], axis=1)
    assert err.max() < MIRROR_TOL_CM, (int(err.argmax()), float(err.max()))


def test_landmarks68_from_the_mapped_points_reproduce_the_landmarks(face_model):
    L = face_model.neutral[face_model.landmarks]
    got = corr.landmarks68_from_mesh_points(_mapped(face_model))
    assert got.shape == (68, 3)
    err = np.linalg.norm(got - L, axis=1)
    assert err[17:].max() < INNER51_TOL_CM, (17 + int(err[17:].argmax()), float(err[17:].max()))
    assert err[:17].max() < JAW_TOL_CM, err[:17].round(3)


def test_landmarks68_from_mesh_points_shapes():
    rng = np.random.default_rng(0)
    P = rng.normal(size=(4, 5, 468, 2))
    out = corr.landmarks68_from_mesh_points(P)
    assert out.shape == (4, 5, 68, 2)
    np.testing.assert_allclose(out[2, 3], corr.landmarks68_from_mesh_points(P[2, 3]))
    iris = np.concatenate([P[0, 0], rng.normal(size=(10, 2))])  # the iris refinement's 478 points
    np.testing.assert_allclose(corr.landmarks68_from_mesh_points(iris), out[0, 0])
    # an affine map of the points maps the landmarks the same way (barycentric combinations)
    A, t = np.array([[2.0, 0.3], [-0.1, 1.5]]), np.array([10.0, -4.0])
    np.testing.assert_allclose(corr.landmarks68_from_mesh_points(P[0, 0] @ A.T + t), out[0, 0] @ A.T + t)
    for bad in (np.zeros((467, 2)), np.zeros((479, 3)), np.zeros(468)):
        with pytest.raises(InputError):
            corr.landmarks68_from_mesh_points(bad)


def test_lid_and_lip_points_follow_their_own_lid_and_lip(face_model):
    """The upper inner lip stays with the upper lip when the jaw opens; the upper lid closes a blink."""
    mp, lm = corr.mediapipe_map(), corr.landmarks68_map()
    names = list(face_model.expression_names)
    N, T = face_model.neutral, face_model.triangles

    def moved(shape):
        D = face_model.expression_deltas[names.index(shape)]
        before, after = mp.points(N, T), mp.points(N + D, T)
        L_after = lm.points(after)
        err = np.linalg.norm(L_after - (N + D)[face_model.landmarks], axis=1)
        return after - before, err

    d, err = moved("jawOpen")
    d = np.linalg.norm(d, axis=1)
    assert d[13] < 0.5 and d[14] > 2.0  # upper / lower inner lip mid-points (measured 0.24 / 4.0 cm)
    assert err[17:].max() < INNER51_TOL_CM  # the 68 follow the open mouth (measured 0.084 cm)
    d, err = moved("eyeBlink_R")
    # the subject's right upper lid comes down, the lower lid stays (it slides 0.27 cm sideways in the face
    # model's blink, as the model's own landmark 40 does); measured dy -0.81 / 0.02 cm
    assert d[159, 1] < -0.5 and abs(d[145, 1]) < 0.1
    assert err[36:42].max() < INNER51_TOL_CM


def _corrupt(tmp_path: Path, src: Path, old: str, new: str) -> Path:
    text = src.read_text(encoding="utf-8")
    assert old in text
    tmp_path.mkdir(parents=True, exist_ok=True)
    out = tmp_path / src.name
    out.write_text(text.replace(old, new, 1), encoding="utf-8")
    return out


def test_a_broken_file_is_a_clear_error(tmp_path):
    src = corr.MEDIAPIPE_FILE
    lines = src.read_text(encoding="utf-8").splitlines()
    row = next(ln for ln in lines if ln.startswith("5,"))
    cells = row.split(",")
    bad_bary = ",".join([*cells[:2], "0.9", *cells[3:]])
    cases = {
        "header row": _corrupt(tmp_path / "a", src, "point,triangle", "point,tri"),
        "do not sum to 1": _corrupt(tmp_path / "b", src, row, bad_bary),
        "data rows": _corrupt(tmp_path / "c", src, row + "\n", ""),
        "not a number": _corrupt(tmp_path / "d", src, row, row.replace(cells[1], "x", 1)),
    }
    for message, path in cases.items():
        with pytest.raises(corr.MapFileError, match=message) as info:
            corr.mediapipe_map(path)
        assert str(path) in str(info.value) and "make_map.py" in str(info.value)
    lm_src = corr.LANDMARKS68_FILE
    row = next(ln for ln in lm_src.read_text(encoding="utf-8").splitlines() if ln.startswith("20,"))
    cells = row.split(",")
    swapped = ",".join([cells[0], "0", "1", "2", *cells[4:]])  # (0, 1, 2) is no triangle of the canonical mesh
    with pytest.raises(corr.MapFileError, match="not a triangle"):
        corr.landmarks68_map(_corrupt(tmp_path / "e", lm_src, row, swapped))
    with pytest.raises(corr.MapFileError, match="file not found|not found"):
        corr.mediapipe_map(tmp_path / "missing.csv")


def test_the_script_reproduces_the_shipped_files(face_model, tmp_path):
    """Rerun ``make_map.py --out`` (about 4 s) and compare: the same points on the neutral, the same landmarks."""
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    start = time.perf_counter()
    r = subprocess.run([sys.executable, str(SCRIPT), "--out", str(tmp_path)], cwd=ROOT, env=env, capture_output=True,
                       text=True, timeout=10 * SCRIPT_SECONDS, check=False)
    seconds = time.perf_counter() - start
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    assert seconds < SCRIPT_SECONDS, f"make_map.py took {seconds:.1f} s"
    assert "inner 51 (17-67)" in r.stdout
    for name in (corr.MEDIAPIPE_FILE.name, corr.LANDMARKS68_FILE.name):
        new, old = (tmp_path / name).read_text(encoding="utf-8"), (corr.DATA / name).read_text(encoding="utf-8")
        assert [ln for ln in new.splitlines() if ln.startswith("#")] == [ln for ln in old.splitlines()
                                                                         if ln.startswith("#")]
    new_mp = corr.mediapipe_map(tmp_path / corr.MEDIAPIPE_FILE.name)
    old_mp = corr.mediapipe_map()
    N, T = face_model.neutral, face_model.triangles
    np.testing.assert_allclose(new_mp.points(N, T), old_mp.points(N, T), atol=1e-7)
    np.testing.assert_allclose(new_mp.distance, old_mp.distance, atol=1e-6)
    new_lm = corr.landmarks68_map(tmp_path / corr.LANDMARKS68_FILE.name)
    P = np.random.default_rng(1).normal(size=(468, 3))
    np.testing.assert_allclose(new_lm.points(P), corr.landmarks68_map().points(P), atol=1e-7)
    np.testing.assert_allclose(new_lm.distance, corr.landmarks68_map().distance, atol=1e-6)
