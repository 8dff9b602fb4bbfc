import numpy as np
import pytest

from facegeom.errors import InputError
from facegeom.io import read_markers, read_mesh, write_markers, write_mesh


@pytest.mark.parametrize("ext", [".obj", ".ply", ".off"])
def test_mesh_roundtrip(tmp_path, grid, ext):
    V, F = grid
    p = write_mesh(tmp_path / f"m{ext}", V, F)
    V2, F2 = read_mesh(p)
    np.testing.assert_allclose(V2, V, rtol=1e-14, atol=1e-14)  # no precision lost
    np.testing.assert_array_equal(F2, F)
    assert V2.dtype == np.float64 and F2.dtype == np.int64
    assert [q.name for q in tmp_path.iterdir()] == [f"m{ext}"]  # no temporary left behind


def test_quads_are_triangulated(tmp_path):
    (tmp_path / "q.obj").write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\nf 1 2 3 4\nf 2 5 3\n")
    V, F = read_mesh(tmp_path / "q.obj")
    assert F.shape == (3, 3)
    (tmp_path / "q.off").write_text("OFF\n4 1 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n")
    assert read_mesh(tmp_path / "q.off")[1].shape == (2, 3)


BAD = {
    "empty.obj": (b"", "empty file"),
    "garbage.obj": (b"hello world\n", "no vertex"),
    "nan.obj": (b"v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "NaN"),
    "past.obj": (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", "outside"),
    "noface.obj": (b"v 0 0 0\nv 1 0 0\nv 0 1 0\n", "no face"),
    "trunc.ply": (b"ply\nformat binary_little_endian 1.0\nelement vertex 100\nproperty float x\n"
                  b"property float y\nproperty float z\nelement face 10\n"
                  b"property list uchar int vertex_indices\nend_header\n\x00\x00", "truncated"),
    "mesh.stl": (b"solid x\n", "unsupported"),
}


@pytest.mark.parametrize("name", sorted(BAD))
def test_bad_meshes_name_file_and_problem(tmp_path, name):
    content, problem = BAD[name]
    (tmp_path / name).write_bytes(content)
    with pytest.raises(InputError) as e:
        read_mesh(tmp_path / name)
    assert name in str(e.value) and problem in str(e.value)


def test_missing_mesh(tmp_path):
    with pytest.raises(InputError, match="file not found"):
        read_mesh(tmp_path / "none.obj")


def test_failed_write_leaves_old_file(tmp_path, grid):
    V, F = grid
    p = write_mesh(tmp_path / "m.obj", V, F)
    before = p.read_bytes()
    bad = V.copy()
    bad[0, 0] = np.nan
    with pytest.raises(InputError):
        write_mesh(p, bad, F)
    assert p.read_bytes() == before
    with pytest.raises(InputError, match="outside"):
        write_mesh(p, V, F + 1000)
    assert p.read_bytes() == before and len(list(tmp_path.iterdir())) == 1


def test_markers_roundtrip(tmp_path):
    ids = np.array([5, 0, 17])
    pos = np.random.default_rng(0).standard_normal((3, 3))
    p = write_markers(tmp_path / "m.csv", ids, pos)
    assert p.read_text().splitlines()[0] == "vertex_id,x,y,z"
    i2, p2 = read_markers(p, n_vertices=18)
    np.testing.assert_array_equal(i2, ids)
    np.testing.assert_array_equal(p2, pos)  # repr keeps every bit


@pytest.mark.parametrize("text,problem", [
    ("", "empty"),
    ("id,x,y,z\n0,1,2,3\n", "wrong columns"),
    ("vertex_id,x,y\n0,1,2\n", "wrong columns"),
    ("vertex_id,x,y,z\n", "no marker rows"),
    ("vertex_id,x,y,z\n0,1,2\n", "expected 4 values"),
    ("vertex_id,x,y,z\na,1,2,3\n", "not an integer"),
    ("vertex_id,x,y,z\n0,1,nan,3\n", "NaN"),
    ("vertex_id,x,y,z\n0,1,2,3\n0,1,2,3\n", "repeated"),
    ("vertex_id,x,y,z\n99,1,2,3\n", "out of range"),
    ("vertex_id,x,y,z\n-1,1,2,3\n", "negative"),
])
def test_bad_markers(tmp_path, text, problem):
    p = tmp_path / "markers.csv"
    p.write_text(text)
    with pytest.raises(InputError) as e:
        read_markers(p, n_vertices=10)
    assert "markers.csv" in str(e.value) and problem in str(e.value)
