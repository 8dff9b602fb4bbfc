"""Large valid inputs in bounded memory: the streamed capture CSV, the OBJ reader in parts, crop's geodesics on
the region only, and driving a large mesh through a decimated proxy (markers kept exactly)."""
from __future__ import annotations

import subprocess
import sys
import tracemalloc

import numpy as np
import pytest

from facegeom import registry
from facegeom.errors import InputError
from facegeom.io import read_marker_sequence, read_mesh, write_markers, write_mesh
from facegeom.io.formats import obj as obj_format
from facegeom.pipelines.cleanup.cropping import _within_geodesic
from facegeom.pipelines.cleanup.geodesic import geodesic_distance
from facegeom.pipelines.proxy import ProxyDeformer, proxy_policy


def run(*args):
    return subprocess.run([sys.executable, "-m", "facegeom", *args], capture_output=True, text=True, timeout=600)


# --------------------------------------------------------------------------- capture CSV, streamed


def _capture_csv(path, T: int, p: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    P = rng.normal(size=(T, p, 3))
    with open(path, "w") as f:
        f.write("frame,marker,x,y,z\n")
        for t in range(T):
            f.write("".join(f"{t},m{j},{float(P[t, j, 0])!r},{float(P[t, j, 1])!r},{float(P[t, j, 2])!r}\n"
                            for j in range(p)))
    return P


def test_capture_csv_reads_in_memory_near_its_numbers(tmp_path):
    path = tmp_path / "cap.csv"
    P = _capture_csv(path, 800, 40)
    size = path.stat().st_size
    tracemalloc.start()
    try:
        seq = read_marker_sequence(path)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    np.testing.assert_array_equal(seq.positions, P)
    assert seq.names == tuple(f"m{j}" for j in range(40))
    # the numbers themselves take 0.4x the text; rows held as Python lists took about 18x
    assert peak < 3.0 * size, (peak, size)


@pytest.mark.parametrize("rows,message", [
    (["0,a,1,2,3", "0,b,1,2,3", "1,a,1,2,3", "1,a,4,5,6"], "line 5: marker 'a' appears twice in frame 1"),
    (["0,a,1,2,3", "0,b,1,2,3", "1,b,1,2,3"], "frame 1 has 1 markers but the file has 2 (marker 'a' is absent"),
    (["0,a,1,2,3", "0,b,1,inf,3"], "line 3: a coordinate is infinite"),
    (["0,a,1,2,3", "x,b,1,2,3"], "line 3: frame 'x' is not an integer"),
])
def test_capture_csv_errors_name_the_line(tmp_path, rows, message):
    path = tmp_path / "bad.csv"
    path.write_text("\n".join(["frame,marker,x,y,z", *rows]) + "\n")
    with pytest.raises(InputError, match=message.replace("(", r"\(").replace(")", r"\)")) as e:
        read_marker_sequence(path)
    assert str(path) in str(e.value)


def test_capture_csv_bad_text_part_way_names_its_line(tmp_path):
    path = tmp_path / "bad.csv"
    path.write_bytes(b"frame,marker,x,y,z\n0,a,1,2,3\n" * 1 + b"0,b,1,2,\xff\xfe\n")
    with pytest.raises(InputError, match="cannot read as text"):
        read_marker_sequence(path)


# --------------------------------------------------------------------------- OBJ in parts


OBJ_VARIANTS = {
    "plain": b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n",
    "relative and slashes": b"v 0 0 0\nv 1 0 0\nv 1 1 0\nf -3/1 -2/2 -1/3\nv 0 1 0\nf 1//1 3//1 -1//1\n",
    "comments, indent, quads": b"# head\n  v 0 0 0 # a\nv 1 0 0\n\tv 1 1 0\nv 0 1 0 1.0\nvn 0 0 1\nf 1 2 3 4 # q\n",
    "continued": b"v 0 0 \\\n 0\nv 1 0 0\nv 1 1 0\nf 1 \\\n 2 3\n",
}


@pytest.mark.parametrize("name", sorted(OBJ_VARIANTS))
def test_obj_read_in_parts_equals_the_whole(tmp_path, monkeypatch, name):
    path = tmp_path / "m.obj"
    path.write_bytes(OBJ_VARIANTS[name] * 3)
    whole = obj_format.read_obj(path, path.read_bytes())
    for size in (1, 7, 20):
        monkeypatch.setattr(obj_format, "CHUNK_BYTES", size)
        parts = obj_format.read_obj(path, path.read_bytes())
        np.testing.assert_array_equal(parts.vertices, whole.vertices)
        np.testing.assert_array_equal(parts.corners, whole.corners)
        np.testing.assert_array_equal(parts.offsets, whole.offsets)


@pytest.mark.parametrize("body,message", [
    (b"v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 3\n" * 4 + b"v 1 x 0\n", "line 17: 'x' is not a number"),
    (b"v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 3\n" * 4 + b"f 1 2 99\n", "line 17: vertex index 99 is outside 1..12"),
    (b"v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 3\n" * 4 + b"f -13 1 2\n", "line 17: relative vertex index -13"),
    (b"v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 3\n" * 4 + b"v nan 0 0\n", r"vertex 13 \(line 17\)"),
])
def test_obj_in_parts_errors_keep_the_file_line(tmp_path, monkeypatch, body, message):
    monkeypatch.setattr(obj_format, "CHUNK_BYTES", 10)
    path = tmp_path / "bad.obj"
    path.write_bytes(body)
    with pytest.raises(InputError, match=message):
        obj_format.read_obj(path, path.read_bytes())


# --------------------------------------------------------------------------- crop: geodesics on the region


@pytest.mark.parametrize("method", ["exact", "graph"])
def test_crop_region_geodesics_equal_the_whole_mesh(face_model, method):
    V, F = face_model.neutral, face_model.triangles
    src = face_model.landmarks[[30, 8]]
    for r in (1.5, 4.0):
        whole = geodesic_distance(V, F, src, limit=r, method=method) <= r
        np.testing.assert_array_equal(_within_geodesic(V, F, src, r, method), whole)


def test_crop_region_heat_agrees_with_exact(face_model):
    V, F = face_model.neutral, face_model.triangles
    src = face_model.landmarks[[30]]
    exact = _within_geodesic(V, F, src, 4.0, "exact")
    heat = _within_geodesic(V, F, src, 4.0, "heat")
    assert (exact != heat).sum() < 0.03 * exact.sum()


# --------------------------------------------------------------------------- drive through a proxy


def _expression(face_model):
    m = face_model
    X = m.neutral
    T = m.face(None, {"jawOpen": 0.6, "mouthSmile_L": 0.8, "browInnerUp_L": 0.7})
    H = np.unique(m.landmarks)
    return X, T, H


def test_proxy_keeps_markers_exactly_and_follows_the_expression(face_model):
    X, T, H = _expression(face_model)
    F = face_model.triangles
    direct = registry.create("deformers", "tangent").fit(X, F, H).deform(T[H])
    prox = ProxyDeformer(registry.create("deformers", "tangent"), vertices=3000, above=5000).fit(X, F, H)
    assert prox.used_proxy and prox.proxy_vertices <= 3000
    Y = prox.deform(T[H])
    np.testing.assert_allclose(Y[H], T[H], atol=1e-9)
    np.testing.assert_allclose(np.asarray(prox.lift_.sum(axis=1)).ravel(), 1.0)
    err = lambda Z: np.sqrt(((Z - T) ** 2).sum(1).mean())  # noqa: E731
    still = err(X)
    assert err(Y) < 0.5 * still  # the whole face follows, not only the markers
    assert err(Y) < 1.25 * err(direct)  # about as close to the performed expression as solving every vertex
    many = prox.deform_many(np.stack([T[H], X[H]]))
    np.testing.assert_allclose(many[0], Y, atol=1e-9)
    np.testing.assert_allclose(many[1], X, atol=1e-6)


def test_small_meshes_are_driven_directly(face_model):
    X, T, H = _expression(face_model)
    F = face_model.triangles
    direct = registry.create("deformers", "rbf").fit(X, F, H).deform(T[H])
    prox = ProxyDeformer(registry.create("deformers", "rbf")).fit(X, F, H)
    assert not prox.used_proxy
    np.testing.assert_array_equal(prox.deform(T[H]), direct)


@pytest.mark.parametrize("value,expected", [("auto", 100_000), ("off", None), ("20000", 20000), (" OFF ", None)])
def test_proxy_policy(value, expected):
    assert proxy_policy(value) == expected


@pytest.mark.parametrize("value", ["some", "10", "1e12", ""])
def test_proxy_policy_refuses(value):
    with pytest.raises(InputError, match="proxy"):
        proxy_policy(value)


def test_drive_cli_through_a_proxy(tmp_path, face_model):
    X, T, H = _expression(face_model)
    write_mesh(tmp_path / "face.obj", X, face_model.triangles)
    write_markers(tmp_path / "m.csv", H, T[H])
    r = run("drive", str(tmp_path / "face.obj"), str(tmp_path / "m.csv"), "-o", str(tmp_path / "out.obj"),
            "--proxy", "3000")
    assert r.returncode == 0, r.stderr
    assert "driving a proxy of about 3,000" in r.stderr
    Y, F = read_mesh(tmp_path / "out.obj")
    assert Y.shape == X.shape and F.shape == face_model.triangles.shape
    np.testing.assert_allclose(Y[H], T[H], atol=1e-5)
    bad = run("drive", str(tmp_path / "face.obj"), str(tmp_path / "m.csv"), "-o", str(tmp_path / "o2.obj"),
              "--proxy", "lots")
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1, bad.stderr
    assert not (tmp_path / "o2.obj").exists()
