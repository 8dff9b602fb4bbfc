"""The validating mesh / point-cloud readers of facegeom.io.formats: every feature, every refusal.

Each hostile input of issue 16 (files that crashed libigl or pymeshlab, hung,
allocated tens of GB or read silently wrong) is built here as bytes and must
raise a one-line InputError naming the file.
"""
from __future__ import annotations

import struct

import numpy as np
import pytest

from facegeom.errors import InputError
from facegeom.io import read_mesh, read_point_cloud, read_polygon_mesh, write_mesh
from facegeom.pipelines.meshinput import read_input_mesh

QUAD = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0]], dtype=float)


def put(tmp_path, name, content):
    p = tmp_path / name
    p.write_bytes(content if isinstance(content, bytes) else content.encode())
    return p


def fails(tmp_path, name, content, *needles):
    p = put(tmp_path, name, content)
    with pytest.raises(InputError) as e:
        read_mesh(p)
    msg = str(e.value)
    assert name in msg and "\n" not in msg, msg
    for n in needles:
        assert n in msg, msg
    return msg


def ply_header(fmt, elements):
    lines = ["ply", f"format {fmt} 1.0", "comment made by a test", "obj_info x"]
    for name, count, props in elements:
        lines.append(f"element {name} {count}")
        lines += [f"property {p}" for p in props]
    return ("\n".join(lines) + "\nend_header\n").encode()


# --------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("ext", [".obj", ".ply", ".off"])
def test_round_trip_with_write_mesh(tmp_path, face_mesh, ext):
    V, F = face_mesh
    V2, F2 = read_mesh(write_mesh(tmp_path / f"f{ext}", V, F))
    np.testing.assert_array_equal(F2, F)
    np.testing.assert_allclose(V2, V, rtol=1e-14, atol=1e-14)
    assert V2.dtype == np.float64 and F2.dtype == np.int64 and V2.flags.c_contiguous and F2.flags.c_contiguous


# --------------------------------------------------------------------------- OBJ


def test_obj_corner_forms_negative_indices_and_ignored_records(tmp_path):
    text = ("# comment\nmtllib a.mtl\no thing\ng group\ns 1\nusemtl m\n"
            "v 0 0 0\nv 1 0 0 1.0\nv 1 1 0 0.5 0.5 0.5\nvt 0 0\nvn 0 0 1\nvp 0.5\n"
            "f 1/1 2/1/1 3//1\n  v 0 1 0\nf -1 -4 -2 # a comment\nl 1 2\np 1\n")
    mesh = read_polygon_mesh(put(tmp_path, "a.obj", text))
    assert mesh.vertices.shape == (4, 3)
    np.testing.assert_array_equal(mesh.triangles(), [[0, 1, 2], [3, 0, 2]])


def test_obj_line_continuation_keeps_line_numbers(tmp_path):
    p = put(tmp_path, "c.obj", "v 0 0 \\\n 0\nv 1 0 0\nv 0 1 0\nf 1 2 \\\r\n 3\nf 1 2 7\n")
    with pytest.raises(InputError, match="line 7: vertex index 7 is outside 1..3"):
        read_mesh(p)
    V, F = read_mesh(put(tmp_path, "d.obj", "v 0 0 \\\n 0\nv 1 0 0\nv 0 1 0\nf 1 2 \\\n 3\n"))
    assert V.shape == (3, 3) and F.tolist() == [[0, 1, 2]]


def test_obj_polygons_are_fans_and_kept_on_request(tmp_path):
    text = "".join(f"v {x} {y} {z}\n" for x, y, z in QUAD) + "f 1 2 3 4\nf 2 5 3\nf 1 2 3 4 5\n"
    p = put(tmp_path, "q.obj", text)
    V, F = read_mesh(p)
    assert F.tolist() == [[0, 1, 2], [0, 2, 3], [1, 4, 2], [0, 1, 2], [0, 2, 3], [0, 3, 4]]
    mesh = read_polygon_mesh(p)
    assert [q.tolist() for q in mesh.polygons()] == [[0, 1, 2, 3], [1, 4, 2], [0, 1, 2, 3, 4]]
    assert mesh.offsets.tolist() == [0, 4, 7, 12]


def test_obj_crlf_cr_and_non_utf8(tmp_path):
    text = b"# \xff\xfe caf\xe9\r\nv 0 0 0\r\nv 1 0 0\r\nv 0 1 0\r\nf 1 2 3\r\n"
    assert read_mesh(put(tmp_path, "a.obj", text))[1].tolist() == [[0, 1, 2]]
    assert read_mesh(put(tmp_path, "b.obj", text.replace(b"\r\n", b"\r")))[1].tolist() == [[0, 1, 2]]


@pytest.mark.parametrize("text,needles", [
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", ("line 4", "at least 3", "got 2")),
    ("v 0 0 0\nf 1\n", ("line 2", "at least 3", "got 1")),  # was a MemoryError in libigl
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2\nf 1 2 3\n", ("line 5", "got 2")),  # was silently dropped
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", ("line 4", "vertex index 0")),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", ("line 4", "vertex index 4 is outside 1..3")),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -4\n", ("line 4", "relative vertex index -4")),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 3", ("")),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 3.5\n", ("line 5", "'3.5' is not an integer")),
    ("v 0 0 0\nv 1 0\nv 0 1 0\nf 1 2 3\n", ("line 2", "three coordinates")),
    ("v 0 0 0\nv 1 0 x\nv 0 1 0\nf 1 2 3\n", ("line 2", "'x' is not a number")),
    ("v 0 0 0\nv 1 0 0\nv 0 inf 0\nf 1 2 3\n", ("vertex 3 (line 3)", "NaN or inf")),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3 99999999999999999999999\n", ("line 4", "not an integer")),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 /3\n", ("line 4", "'/3'")),
])
def test_obj_refusals_name_the_line(tmp_path, text, needles):
    if not needles:  # the last line without a newline is fine
        assert read_mesh(put(tmp_path, "ok.obj", text))[1].shape == (2, 3)
        return
    fails(tmp_path, "bad.obj", text, *needles)


def test_obj_cut_inside_a_face_line(tmp_path, face_mesh):
    V, F = face_mesh
    raw = write_mesh(tmp_path / "f.obj", V, F).read_bytes()
    cut = raw[:raw.rindex(b"\nf ") + 4]  # "f 12" -> a face of one corner
    fails(tmp_path, "cut.obj", cut, "at least 3")


# --------------------------------------------------------------------------- PLY


def test_ply_encodings_any_element_order_extra_properties_and_lists(tmp_path):
    V = QUAD[:4]
    faces = [[0, 1, 2, 3], [0, 2, 1]]
    elements = [
        ("material", 1, ["uchar r", "list uchar float coeffs"]),
        ("face", 2, ["uchar flags", "list uchar uint vertex_indices", "list uchar float texcoord", "float q"]),
        ("vertex", 4, ["double nx", "float x", "short id", "float y", "float z", "uchar red"]),
        ("edge", 1, ["int vertex1", "int vertex2"]),
    ]
    ascii_body = ("7 2 0.5 0.25\n"
                  "1 4 0 1 2 3 8 0 0 1 0 1 1 0 1 0.5\n1 3 0 2 1 6 0 0 1 1 0 1 0.5\n"
                  + "".join(f"0 {x} 3 {y} {z} 255\n" for x, y, z in V) + "0 1\n")
    p = put(tmp_path, "a.ply", ply_header("ascii", elements) + ascii_body.encode())
    got = read_polygon_mesh(p)
    np.testing.assert_array_equal(got.vertices, V)
    assert [q.tolist() for q in got.polygons()] == faces
    for order, fmt in (("<", "binary_little_endian"), (">", "binary_big_endian")):
        body = struct.pack(order + "BB2f", 7, 2, 0.5, 0.25)
        body += struct.pack(order + "BB4IB8ff", 1, 4, 0, 1, 2, 3, 8, 0, 0, 1, 0, 1, 1, 0, 1, 0.5)
        body += struct.pack(order + "BB3IB6ff", 1, 3, 0, 2, 1, 6, 0, 0, 1, 1, 0, 1, 0.5)
        body += b"".join(struct.pack(order + "dfhffB", 0, x, 3, y, z, 255) for x, y, z in V)
        body += struct.pack(order + "ii", 0, 1)
        got = read_polygon_mesh(put(tmp_path, f"{fmt}.ply", ply_header(fmt, elements) + body))
        np.testing.assert_array_equal(got.vertices, V)
        assert [q.tolist() for q in got.polygons()] == faces, fmt


def test_ply_blender_style_uniform_faces_and_vertex_index_name(tmp_path):
    V = QUAD[:4]
    elements = [("vertex", 4, ["float x", "float y", "float z", "float s", "float t"]),
                ("face", 2, ["list uchar int vertex_index", "list uchar float texcoord"])]
    body = b"".join(struct.pack("<5f", x, y, z, 0, 0) for x, y, z in V)
    body += b"".join(struct.pack("<B3iB6f", 3, *f, 6, *range(6)) for f in ([0, 1, 2], [0, 2, 3]))
    F = read_mesh(put(tmp_path, "b.ply", ply_header("binary_little_endian", elements) + body))[1]
    assert F.tolist() == [[0, 1, 2], [0, 2, 3]]


def test_ply_mixed_polygons_are_walked(tmp_path):
    elements = [("vertex", 5, ["float x", "float y", "float z"]), ("face", 3, ["list uchar int vertex_indices"])]
    polys = [[0, 1, 2, 3], [1, 4, 2], [0, 1, 2, 3, 4]]
    body = b"".join(struct.pack("<3f", *v) for v in QUAD)
    body += b"".join(struct.pack(f"<B{len(q)}i", len(q), *q) for q in polys)
    p = put(tmp_path, "m.ply", ply_header("binary_little_endian", elements) + body)
    assert [q.tolist() for q in read_polygon_mesh(p).polygons()] == polys
    assert read_mesh(p)[1].shape == (6, 3)
    for cut in (1, 5, 9):
        fails(tmp_path, f"m{cut}.ply", p.read_bytes()[:-cut], "truncated in the face section")


def grid_ply(fmt="binary_little_endian"):
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], dtype=np.float32)
    F = np.array([[0, 1, 2], [1, 3, 2]])
    elements = [("vertex", 4, ["float x", "float y", "float z"]), ("face", 2, ["list uchar int vertex_indices"])]
    if fmt == "ascii":
        body = "".join(f"{x} {y} {z}\n" for x, y, z in V) + "".join(f"3 {a} {b} {c}\n" for a, b, c in F)
        return ply_header(fmt, elements) + body.encode()
    body = V.astype("<f4").tobytes() + b"".join(struct.pack("<B3i", 3, *f) for f in F)
    return ply_header(fmt, elements) + body


@pytest.mark.parametrize("content,needles", [
    (b"ply\n", ("end_header",)),
    (b"ply\nformat ascii 1.0\nend_header\n", ("no vertex element",)),
    (b"plyformat\n", ("not a PLY",)),
    (b"ply\nformat binary 1.0\nelement vertex 1\nend_header\n", ("line 2", "format")),
    (b"ply\nformat ascii 1.0\nelement vertex -1\nproperty float x\nend_header\n", ("non-negative",)),
    (b"ply\nformat ascii 1.0\nelement x -1\nend_header\n", ("non-negative",)),  # hung
    (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty quad x\nend_header\n0\n", ("types among",)),
    (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty list float int x\nend_header\n", ("integer type",)),
    (b"ply\nformat ascii 1.0\nproperty float x\nend_header\n", ("before any element",)),
    (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float y\nproperty float z\nend_header\n0 0\n", ("'x'",)),
    (b"ply\nformat binary_little_endian 1.0\nelement vertex 1000000000000\nproperty float x\n"
     b"property float y\nproperty float z\nend_header\n", ("truncated in the vertex section",)),
    (b"ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
     b"property float z\nelement face 1\nproperty list uint int vertex_indices\nend_header\n\xff\xff\xff\xff",
     ("truncated in the face section",)),
    (b"ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
     b"property float z\nelement face 1\nproperty list char int vertex_indices\nend_header\n\xff",
     ("negative list length",)),
    (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
     b"element face 1\nproperty list uchar float vertex_indices\nend_header\n", ("list of integers",)),
    (b"ply\nformat ascii 1.0\nfoo bar\nend_header\n", ("unknown keyword",)),
])
def test_ply_header_refusals(tmp_path, content, needles):
    fails(tmp_path, "h.ply", content, *needles)


def test_ply_truncation_is_never_zeros(tmp_path):
    raw = grid_ply()
    for cut in range(1, len(raw) - raw.index(b"end_header") - 11):
        msg = fails(tmp_path, f"t{cut}.ply", raw[:-cut], "truncated")
        assert "face section" in msg or "vertex section" in msg
    fails(tmp_path, "short.ply", raw[:100], "truncated")  # a PLY cut at 100 bytes


def test_ply_five_bytes_cut_and_trailing_data(tmp_path):
    raw = grid_ply()
    fails(tmp_path, "cut5.ply", raw[:-5], "truncated in the face section")
    assert read_mesh(put(tmp_path, "pad.ply", raw + b"\n\x00 "))[1].shape == (2, 3)  # blanks tolerated
    fails(tmp_path, "extra.ply", raw + b"\x01\x02", "bytes after the last element")
    fails(tmp_path, "extra_a.ply", grid_ply("ascii") + b"3 0 1 2\n", "values after the last element")


def test_ply_ascii_fewer_faces_than_header_nan_and_bad_faces(tmp_path):
    raw = grid_ply("ascii")
    assert read_mesh(put(tmp_path, "ok.ply", raw))[1].tolist() == [[0, 1, 2], [1, 3, 2]]
    fails(tmp_path, "few.ply", raw[:raw.rindex(b"3 1 3 2")], "truncated in the face section")
    fails(tmp_path, "nan.ply", raw.replace(b"1.0 1.0 0.0", b"1.0 nan 0.0"), "vertex 3 (0-based)", "NaN")
    fails(tmp_path, "two.ply", raw.replace(b"3 1 3 2\n", b"2 1 3 2\n"), "face 1 (0-based) has 2 vertices")
    fails(tmp_path, "idx.ply", raw.replace(b"3 1 3 2", b"3 1 9 2"), "face 1 (0-based)", "9 is outside 0..3")
    fails(tmp_path, "neg.ply", raw.replace(b"3 1 3 2", b"3 1 -1 2"), "-1 is outside")
    binary = grid_ply()
    bad = binary[:-4] + struct.pack("<i", 4)
    fails(tmp_path, "idx_b.ply", bad, "face 1 (0-based): vertex index 4 is outside 0..3")
    two = ply_header("binary_little_endian", [("vertex", 3, ["float x", "float y", "float z"]),
                                              ("face", 1, ["list uchar int vertex_indices"])])
    fails(tmp_path, "f2.ply", two + bytes(36) + struct.pack("<B2i", 2, 0, 1), "face 0 (0-based) has 2 vertices")


def test_ply_real_face_truncated_in_its_face_section(tmp_path, face_mesh):
    V, F = face_mesh
    raw = write_mesh(tmp_path / "f.ply", V, F).read_bytes()
    fails(tmp_path, "cut.ply", raw[:len(raw) * 2 // 3], "truncated in the face section")


# --------------------------------------------------------------------------- OFF


@pytest.mark.parametrize("head", ["OFF\n4 2 0\n", "OFF 4 2 0\n", "  # a comment\n\n  OFF\n# counts\n 4 2 0\n",
                                  "COFF\n4 2 0\n", "NOFF\n4 2 5\n", "STOFF\n4 2 0\n", "OFF\n4 2\n"])
def test_off_variants(tmp_path, head):
    extra = {"COFF": " 255 0 0 255", "NOFF": " 0 0 1", "STOFF": " 0.5 0.5"}.get(head.split()[0], "")
    body = "".join(f"{x} {y} {z}{extra}\n" for x, y, z in QUAD[:4]) + "\n# faces\n4 0 1 2 3 255 0 0\n3 0 2 1\n"
    mesh = read_polygon_mesh(put(tmp_path, "v.off", head + body))
    np.testing.assert_array_equal(mesh.vertices, QUAD[:4])
    assert [q.tolist() for q in mesh.polygons()] == [[0, 1, 2, 3], [0, 2, 1]]


@pytest.mark.parametrize("content,needles", [
    (b"OFF", ("no vertex and face counts",)),
    (b"OFF\n", ("no vertex and face counts",)),
    (b"OFF\n1000000000 8 0", ("truncated", "1000000000 vertices")),  # grew to 24 GB in libigl
    (b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n", ("truncated",)),
    (b"OFF\n3 1 0\n0 0 0\n1 0\n0 1 0\n3 0 1 2\n", ("line 4", "three coordinates")),
    (b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n2 0 1\n", ("line 6", "at least 3")),
    (b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n4 0 1 2\n", ("line 6", "announces 4")),
    (b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n", ("line 6", "3 is outside 0..2")),
    (b"OFF\n3 1 0\n0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n", ("vertex 1 (0-based; line 4)", "NaN")),
    (b"OFF\n-3 1 0\n", ("line 2", "non-negative")),
    (b"4OFF\n3 1 0\n", ("3-D",)),
    (b"PLY\n3 1 0\n", ("not an OFF file",)),
    (b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n99999999999999999999 0 1 2\n", ("line 6",)),
    (b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n9223372036854775807 0 1 2\n", ("line 6",)),
])
def test_off_refusals(tmp_path, content, needles):
    fails(tmp_path, "bad.off", content, *needles)


# --------------------------------------------------------------------------- polygons mode, point clouds


def test_read_input_mesh_keeps_polygons_of_every_format(tmp_path):
    polys = [[0, 1, 2, 3], [1, 4, 2]]
    obj = "".join(f"v {x} {y} {z}\n" for x, y, z in QUAD) + "f 1 2 3 4\nf 2 5 3\n"
    off = "OFF\n5 2 0\n" + "".join(f"{x} {y} {z}\n" for x, y, z in QUAD) + "4 0 1 2 3\n3 1 4 2\n"
    elements = [("vertex", 5, ["float x", "float y", "float z"]), ("face", 2, ["list uchar int vertex_indices"])]
    ply = ply_header("binary_little_endian", elements) + QUAD.astype("<f4").tobytes() + \
        struct.pack("<B4iB3i", 4, 0, 1, 2, 3, 3, 1, 4, 2)
    for name, content in (("q.obj", obj), ("q.off", off), ("q.ply", ply)):
        p = put(tmp_path, name, content)
        V, F = read_input_mesh(p, polygons=True)
        assert F == polys, name
        assert read_input_mesh(p)[1].tolist() == [[0, 1, 2], [0, 2, 3], [1, 4, 2]]
    tri = put(tmp_path, "t.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    assert isinstance(read_input_mesh(tri, polygons=True)[1], np.ndarray)


def test_point_clouds_from_every_format(tmp_path):
    P = np.random.default_rng(1).normal(size=(20, 3))
    rows = [[float(a) for a in p] for p in P]
    xyz = "# x y z nx\n" + "".join(f"{a!r} {b!r} {c!r} 0 0 1\n" for a, b, c in rows) + "\n"
    np.testing.assert_array_equal(read_point_cloud(put(tmp_path, "p.xyz", xyz)), P)
    obj = "".join(f"v {a!r} {b!r} {c!r}\n" for a, b, c in rows) + "f 1 2\n"  # faces are ignored
    np.testing.assert_array_equal(read_point_cloud(put(tmp_path, "p.obj", obj)), P)
    off = f"OFF\n{len(P)} 0 0\n" + "".join(f"{a!r} {b!r} {c!r}\n" for a, b, c in rows)
    np.testing.assert_array_equal(read_point_cloud(put(tmp_path, "p.off", off)), P)
    ply = ply_header("binary_big_endian", [("vertex", 20, ["double x", "double y", "double z"])]) + \
        P.astype(">f8").tobytes()
    np.testing.assert_array_equal(read_point_cloud(put(tmp_path, "p.ply", ply)), P)
    np.save(tmp_path / "p.npy", P)
    np.testing.assert_array_equal(read_point_cloud(tmp_path / "p.npy"), P)


@pytest.mark.parametrize("name,content,needle", [
    ("c.ply", b"ply\nformat binary_little_endian 1.0\nend_header\n", "no vertex element"),  # 28-byte segfault
    ("c.xyz", b"1 2 3\n4 5\n", "line 2"),
    ("n.xyz", b"1 2 3\n4 5 nan\n", "point 1 (0-based; line 2)"),
    ("c.off", b"OFF\n1000000000 0 0\n", "truncated"),
    ("z.ply", b"ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\n"
              b"end_header\n", "no point"),
])
def test_bad_point_clouds(tmp_path, name, content, needle):
    with pytest.raises(InputError) as e:
        read_point_cloud(put(tmp_path, name, content))
    assert name in str(e.value) and needle in str(e.value)


def test_npy_header_larger_than_the_file(tmp_path):
    np.save(tmp_path / "a.npy", np.zeros((2, 3)))
    raw = (tmp_path / "a.npy").read_bytes().replace(b"(2, 3)", b"(9999999999999, 3)")
    with pytest.raises(InputError, match="cannot read as .npy"):
        read_point_cloud(put(tmp_path, "h.npy", raw))
    np.save(tmp_path / "o.npy", np.array([object()]), allow_pickle=True)
    with pytest.raises(InputError, match="cannot read as .npy"):
        read_point_cloud(tmp_path / "o.npy")


def test_ply_ascii_rows_with_more_values_than_the_header(tmp_path):
    """MeshLab (VCG) ascii PLYs can put extra values on a face row: one row per line keeps the rows apart."""
    head = ("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 2\nproperty list uchar int vertex_indices\nproperty list uchar float texcoord\n"
            "property uchar red\nend_header\n")
    verts = "0 0 0\n1 0 0\n1 1 0\n0 1 0\n"
    faces = "3 0 1 2 6 0 0 1 0 1 1 9 1 1 1\n3 0 2 3 6 0 0 1 1 0 1 9 1 1 1\n"  # 4 values past `red`
    p = tmp_path / "vcg.ply"
    p.write_text(head + verts + faces)
    V, F = read_mesh(p)
    assert V.shape == (4, 3) and F.tolist() == [[0, 1, 2], [0, 2, 3]]
    p.write_text(head + verts + "3 0 1 2 6 0 0 1 0 1 1\n3 0 2 3 6 0 0 1 1 0 1 9\n")  # a row short of `red`
    with pytest.raises(InputError, match="face row 0"):
        read_mesh(p)


def test_off_counts_glued_to_the_keyword_and_faces_wrapped_over_lines(tmp_path):
    """Two OFF variants met in public test models: ``OFF8 6 12`` headers, and one face index per line."""
    verts = "0 0 0\n1 0 0\n1 1 0\n0 1 0\n"
    p = tmp_path / "glued.off"
    p.write_text("\t   OFF4 2 0 # a comment\n" + verts + "3 0 1 2\n3 0 2 3\n")
    assert read_mesh(p)[1].tolist() == [[0, 1, 2], [0, 2, 3]]
    p = tmp_path / "wrapped.off"
    p.write_text("OFF\n4 1 0\n" + verts + "4 0\n1 \n2\n\n3\n")
    assert [q.tolist() for q in read_polygon_mesh(p).polygons()] == [[0, 1, 2, 3]]
    p.write_text("OFF\n4 2 0\n" + verts + "4 0\n1 \n2\n\n3\n")  # the stream holds one face, not two
    with pytest.raises(InputError, match="line 7"):
        read_mesh(p)
