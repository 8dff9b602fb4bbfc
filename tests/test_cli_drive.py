"""End-to-end: `facegeom drive` and `facegeom bench drive` on the real ICT face."""
import csv
import subprocess
import sys

import numpy as np
import pytest

from facegeom.io import read_mesh, write_markers, write_mesh
from facegeom.model import layouts as markers


def run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "facegeom", *args], capture_output=True, text=True, timeout=300,
                          cwd=cwd)


@pytest.fixture(scope="module")
def drive_inputs(tmp_path_factory, face_model):
    d = tmp_path_factory.mktemp("drive")
    m = face_model
    X = m.identity_neutral(m.random_identity(1))
    T = m.face(m.random_identity(1), {"jawOpen": 0.7, "mouthSmile_L": 0.5})
    H = markers.ict80(m)
    write_mesh(d / "face.obj", X, m.triangles)
    write_markers(d / "markers.csv", H, T[H])
    return d, X, T, H


def test_drive_one_method(drive_inputs):
    d, X, T, H = drive_inputs
    r = run("drive", str(d / "face.obj"), str(d / "markers.csv"), "-o", str(d / "out.ply"))
    assert r.returncode == 0, r.stderr
    Y, F = read_mesh(d / "out.ply")
    np.testing.assert_allclose(Y[H], T[H], atol=1e-5)
    err = np.linalg.norm(Y - T, axis=1)[:6706].mean()
    still = np.linalg.norm(X - T, axis=1)[:6706].mean()
    assert err < 0.35 * still  # the face follows the markers, not only the markers move


def test_drive_all_methods(drive_inputs):
    d, X, T, H = drive_inputs
    r = run("drive", str(d / "face.obj"), str(d / "markers.csv"), "-m", "all", "-o", str(d / "all"))
    assert r.returncode == 0, r.stderr
    names = sorted(p.stem for p in (d / "all").iterdir())
    assert {"tangent", "rbf", "laplacian", "arap", "biharmonic", "markers-only"} <= set(names)
    assert all(p.suffix == ".obj" for p in (d / "all").iterdir())


def test_drive_with_params_and_bad_params(drive_inputs):
    d, X, T, H = drive_inputs
    r = run("drive", str(d / "face.obj"), str(d / "markers.csv"), "-o", str(d / "p.obj"), "-p", "d=3",
            "-p", "field=position", "-p", "align=none", "-p", "smoothness=0")
    assert r.returncode == 0, r.stderr
    r = run("drive", str(d / "face.obj"), str(d / "markers.csv"), "-o", str(d / "q.obj"), "-p", "d=9")
    assert r.returncode == 2 and "d must be" in r.stderr and not (d / "q.obj").exists()
    r = run("drive", str(d / "face.obj"), str(d / "markers.csv"), "-o", str(d / "q.obj"), "-m", "nope")
    assert r.returncode == 2 and "no deformer named 'nope'" in r.stderr


@pytest.mark.parametrize("content,problem", [
    ("vertex_id,x,y,z\n999999,0,0,0\n", "out of range"),
    ("vertex_id,x,y,z\n5,0,0,0\n5,1,1,1\n", "repeated"),
    ("vertex_id,x,y,z\n5,0,nan,0\n", "NaN"),
    ("id,a,b,c\n5,0,0,0\n", "wrong columns"),
])
def test_drive_bad_markers(drive_inputs, tmp_path, content, problem):
    d, *_ = drive_inputs
    (tmp_path / "m.csv").write_text(content)
    r = run("drive", str(d / "face.obj"), str(tmp_path / "m.csv"), "-o", str(tmp_path / "o.obj"))
    assert r.returncode == 2, r.stderr
    assert "m.csv" in r.stderr and problem in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "o.obj").exists()


def test_drive_bad_mesh(tmp_path, drive_inputs):
    d, *_ = drive_inputs
    (tmp_path / "bad.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n")
    r = run("drive", str(tmp_path / "bad.obj"), str(d / "markers.csv"), "-o", str(tmp_path / "o.obj"))
    assert r.returncode == 2 and "bad.obj" in r.stderr and "Traceback" not in r.stderr
    r = run("drive", str(tmp_path / "missing.obj"), str(d / "markers.csv"), "-o", str(tmp_path / "o.obj"))
    assert r.returncode == 2 and "missing.obj" in r.stderr


def test_drive_component_without_marker(tmp_path, face_model):
    m = face_model
    V = np.r_[m.neutral, m.neutral + [40, 0, 0]]
    F = np.r_[m.triangles, m.triangles + m.n_vertices]
    write_mesh(tmp_path / "two.obj", V, F)
    write_markers(tmp_path / "m.csv", m.landmarks, V[m.landmarks])
    r = run("drive", str(tmp_path / "two.obj"), str(tmp_path / "m.csv"), "-o", str(tmp_path / "o.obj"))
    assert r.returncode == 2 and "no label" in r.stderr and "Traceback" not in r.stderr


def test_bench_drive_small(tmp_path, face_model):
    out = tmp_path / "bench"
    r = run("bench", "drive", "--cases", "2", "--realistic-cases", "2", "--noise", "0,0.5",
            "--methods", "markers-only;biharmonic;tangent", "--out", str(out), "--quiet")
    assert r.returncode == 0, r.stderr
    assert "| method" in r.stdout and "tangent" in r.stdout
    # the realistic protocol comes first: 2 cases x 2 noise levels x 3 methods, and tangent's ratio to the best baseline
    assert r.stdout.index("realistic protocol") < r.stdout.index("paper protocol")
    assert "tangent / best baseline" in r.stdout and "noise 0.5 mm" in r.stdout
    real = list(csv.DictReader(open(out / "drive-realistic.csv")))
    assert len(real) == 12 and {x["noise_mm"] for x in real} == {"0.0", "0.5"}
    assert all(40 <= int(x["markers"]) <= 120 for x in real)
    rows = list(csv.DictReader(open(out / "drive.csv")))
    assert len(rows) == 6
    by = {(r["case"], r["method"]): float(r["mean_mm"]) for r in rows}
    for case in ("0", "1"):  # both deformers beat moving the markers only
        assert by[(case, "tangent")] < by[(case, "markers-only")]
        assert by[(case, "biharmonic")] < by[(case, "markers-only")]
    assert (out / "drive.png").stat().st_size > 10_000


def test_bench_bad_method_spec():
    r = run("bench", "drive", "--cases", "1", "--realistic-cases", "0", "--methods", "tangent:rings")
    assert r.returncode == 2 and "key=value" in r.stderr


def test_bench_drive_bad_noise():
    r = run("bench", "drive", "--cases", "1", "--noise", "0,x")
    assert r.returncode == 2 and "--noise" in r.stderr


def test_bench_retarget_small_on_real_takes(tmp_path, face_model):
    """End to end: 3 sequences (2 real-take windows if the takes exist, 1 synthetic), 2 label counts."""
    from facegeom.model import takes_places

    args = ["bench", "retarget", "--sequences", "3", "--frames", "40", "--labels", "4,10", "--quiet",
            "--methods", "copy;rbf;tangent", "--out", str(tmp_path / "rt")]
    if not any(found for _, _, found in takes_places()):
        args.append("--synthetic-only")
    r = run(*args)
    assert r.returncode == 0, r.stderr
    rows = list(csv.DictReader(open(tmp_path / "rt" / "retarget.csv")))
    assert len(rows) == 3 * 2 * 3
    err = {(x["method"], x["labels"]): [] for x in rows}
    for x in rows:
        err[(x["method"], x["labels"])].append(float(x["mean_mm"]))
    # the copy reference is far off; the tangent framework is far better with 10 labels
    assert sum(err[("tangent", "10")]) < 0.5 * sum(err[("copy", "10")])
    assert (tmp_path / "rt" / "retarget.png").stat().st_size > 1000
    # the realistic protocol first: 5/10/20 uneven labels, clean and with 0.2 mm noise on capture and labels
    real = list(csv.DictReader(open(tmp_path / "rt" / "retarget-realistic.csv")))
    assert len(real) == 3 * 3 * 2 * 3 and {x["noise_mm"] for x in real} == {"0.0", "0.2"}
    assert r.stdout.index("realistic protocol") < r.stdout.index("| Frob.") and "tangent / best baseline" in r.stdout


def test_bench_retarget_bad_takes_folder(tmp_path, face_model):
    r = run("bench", "retarget", "--takes", str(tmp_path), "--sequences", "1")
    assert r.returncode == 2
    assert "no .csv take" in r.stderr and str(tmp_path) in r.stderr and "Traceback" not in r.stderr


def test_animate_end_to_end(tmp_path, face_model, real_takes):
    """Real take -> actor markers -> retargeted -> character mesh per frame (npz + OBJ)."""
    out = tmp_path / "anim.npz"
    r = run("animate", "--start", "300", "--frames", "30", "--labels", "6", "-o", str(out),
            "--obj-dir", str(tmp_path / "objs"))
    assert r.returncode == 0, r.stderr
    z = np.load(out)
    assert z["vertices"].shape == (30, face_model.n_vertices, 3)
    assert len(list((tmp_path / "objs").glob("*.obj"))) == 30
    # the driven character is close to its true faces: errors well under a millimetre
    assert z["frame_error_mm"].mean() < 1.0
    r = run("animate", "--start", "100000", "-o", str(tmp_path / "x.npz"))
    assert r.returncode == 2 and "past its end" in r.stderr
