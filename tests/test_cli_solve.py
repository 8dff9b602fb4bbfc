"""End to end: `facegeom solve` on the real ICT rig (FACEGEOM_DATA) with npz and CSV captures, and bad input."""
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from facegeom.io.markerseq import write_marker_sequence
from facegeom.model import BlendshapeRig
from facegeom.model.layouts import ict80
from facegeom.pipelines.solve import marker_vertices


GENERIC = ("--identity", "off")
"""These captures are made from the generic face itself: solved on it as it is (no actor's identity to fit), the
solve is exact."""

def run(*args):
    return subprocess.run([sys.executable, "-m", "facegeom", *args], capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def capture(tmp_path_factory, face_model):
    d = tmp_path_factory.mktemp("solve")
    rig = BlendshapeRig.from_face_model(face_model)
    ids = ict80(face_model)
    rng = np.random.default_rng(0)
    T = 30
    W = np.zeros((T, rig.n_shapes))
    W[:, rig.shape_index("jawOpen")] = 0.5 + 0.4 * np.sin(np.linspace(0, 3, T))
    W[:, rig.shape_index("mouthSmile_L")] = np.linspace(0, 0.8, T)
    F = rig.neutral[ids][None] + np.einsum("tb,bpi->tpi", W, rig.deltas[:, ids])
    R = Rotation.from_rotvec(rng.normal(0, 0.2, (T, 3))).as_matrix()
    t = rng.normal(0, 3, (T, 3))
    X = np.einsum("tij,tpj->tpi", R, F) + t[:, None]
    X[5, 3] = np.nan  # a lost marker
    write_marker_sequence(d / "cap.npz", X, names=[f"v{i}" for i in ids])
    names = [f"M{j:02d}" for j in range(ids.size)]
    write_marker_sequence(d / "cap.csv", X, names=names)
    (d / "map.csv").write_text("marker,vertex\n" + "".join(f"{n},{i}\n" for n, i in zip(names, ids)))
    return d, rig, ids, W, R, t


def test_solve_npz_capture(capture):
    d, rig, ids, W, R, t = capture
    r = run("solve", str(d / "cap.npz"), "-o", str(d / "curves.npz"), "--smooth", "off", *GENERIC)
    assert r.returncode == 0, r.stderr
    assert "30 frames x 80 markers" in r.stdout and "1 lost markers" in r.stdout
    z = np.load(d / "curves.npz")
    assert list(z["names"]) == list(rig.names)
    assert z["weights"].shape == (30, rig.n_shapes) and np.abs(z["weights"] - W).max() < 1e-4
    assert np.abs(z["rotations"] - R).max() < 1e-5 and np.abs(z["translations"] - t).max() < 1e-4
    assert z["poses"].shape == (30, 4, 4) and float(z["fps"]) > 0
    assert z["lost"].sum() == 1 and str(z["fitter"]) == "sem-ls"


def test_solve_csv_capture_with_map_and_layout(capture):
    d, rig, ids, W, R, t = capture
    r = run("solve", str(d / "cap.csv"), *GENERIC, "--markers", str(d / "map.csv"), "-o", str(d / "c1.npz"),
            "--fitter", "l2reg", "--smooth", "auto")
    assert r.returncode == 0, r.stderr
    z = np.load(d / "c1.npz")
    assert np.abs(z["weights"] - W).mean() < 0.02 and z["smoothing"].shape == (rig.n_shapes,)
    r = run("solve", str(d / "cap.csv"), "--markers", "ict80", "-o", str(d / "c2.npz"), "--smooth", "off", *GENERIC)
    assert r.returncode == 0, r.stderr
    assert np.abs(np.load(d / "c2.npz")["weights"] - W).max() < 1e-4


def test_marker_vertices_forms(face_model):
    rig = BlendshapeRig.from_face_model(face_model)
    assert marker_vertices(["v10", "11", "V12"], rig).tolist() == [10, 11, 12]
    lay = ict80(face_model)
    names = [str(j) for j in range(80)][::-1]
    assert marker_vertices(names, rig, "ict80").tolist() == lay[::-1].tolist()


@pytest.mark.parametrize("args, message", [
    (["missing.npz"], "file not found"),
    (["{d}/cap.csv"], "is not a vertex id"),
    (["{d}/cap.npz", "--smooth", "lots"], "--smooth"),
    (["{d}/cap.npz", "--markers", "ict81"], "unknown marker layout"),
    (["{d}/cap.npz", "--markers", "random60"], "60 markers, the capture 80"),
    (["{d}/cap.npz", "--fitter", "nope"], "no fitter named"),
    (["{d}/map.csv", "--markers", "{d}/map.csv"], ""),
])
def test_bad_input_is_one_line(capture, args, message):
    d = capture[0]
    out = d / "bad.npz"
    r = run("solve", *[a.format(d=d) for a in args], "-o", str(out))
    assert r.returncode != 0 and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert message in r.stderr and not out.exists()


def test_bad_output_suffix_and_too_few_markers(capture, tmp_path):
    d = capture[0]
    r = run("solve", str(d / "cap.npz"), "-o", str(tmp_path / "curves.txt"))
    assert r.returncode == 2 and "unsupported curves format" in r.stderr
    X = np.load(d / "cap.npz")["markers"]
    X[7, 2:] = np.nan
    names = [str(n) for n in np.load(d / "cap.npz")["marker_names"]]
    write_marker_sequence(tmp_path / "gappy.npz", X, names=names)
    r = run("solve", str(tmp_path / "gappy.npz"), "-o", str(tmp_path / "c.npz"))
    assert r.returncode == 2 and "frame 7" in r.stderr and "gappy.npz" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and not (tmp_path / "c.npz").exists()


def test_animate_with_a_rig_writes_curves(tmp_path, real_takes):
    out = tmp_path / "anim.npz"
    r = run("animate", "--rig", "ict", "--frames", "40", "--labels", "5", "-o", str(out))
    assert r.returncode == 0, r.stderr
    z = np.load(out)
    assert z["weights"].shape == (40, 53) and z["rotations"].shape == (40, 3, 3)
    assert "weight error vs the take" in r.stdout
    r = run("animate", "--rig", "ict", "--frames", "40", "--obj-dir", str(tmp_path / "objs"), "-o", str(out))
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1


def test_solve_c3d_in_millimetres_to_glb_and_livelink(capture):
    """A C3D in mm (converted to the rig's cm), out as a .glb rig animation and a Live Link take."""
    from facegeom.io.c3d import write_c3d
    from facegeom.io.gltf import read_glb_animation
    from facegeom.io.takes import ict_weights, read_take

    d, rig, ids, W, R, t = capture
    X = np.einsum("tij,tpj->tpi", R, rig.neutral[ids][None] + np.einsum("tb,bpi->tpi", W, rig.deltas[:, ids]))
    X = X + t[:, None]
    write_c3d(d / "cap.c3d", X * 10.0, [f"v{i}" for i in ids], fps=60.0, unit="mm")
    r = run("solve", str(d / "cap.c3d"), "-o", str(d / "anim.glb"), "--smooth", "off", *GENERIC)
    assert r.returncode == 0, r.stderr
    g = read_glb_animation(d / "anim.glb")
    assert list(g.names) == list(rig.names) and g.fps == pytest.approx(60.0)
    assert np.abs(g.weights - W).max() < 1e-3  # float32 in the file; the capture is in mm, the rig in cm
    assert np.abs(g.neutral - rig.neutral * 0.01).max() < 1e-6  # glTF metres
    r = run("solve", str(d / "cap.c3d"), "-o", str(d / "take.csv"), "--smooth", "off", *GENERIC)
    assert r.returncode == 0, r.stderr
    take = read_take(d / "take.csv")
    back = ict_weights(take, rig.names, clip=False)
    assert np.abs(back - W).max() < 1e-3
