"""Property tests of every file reader: mutated, truncated or random bytes either read as valid
arrays or raise InputError, nothing else (no other exception, no native crash, bounded memory).

Each reader runs in-process on bytes derived from a valid seed: cut at a random
offset, bytes flipped, inserted or deleted, a number replaced by a huge or
negative count, chunks of another format spliced in. ``FACEGEOM_FUZZ_EXAMPLES``
sets the examples per reader (default 100, derandomized so CI is stable; set
it for a long, random run). Inputs found to break a reader are kept in
:data:`CORPUS` as literal bytes.
"""
from __future__ import annotations

import io
import os
import re
import struct
import tracemalloc

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from facegeom.errors import InputError
from facegeom.io import (
    read_landmarks,
    read_marker_sequence,
    read_markers,
    read_mesh,
    read_point_cloud,
    read_polygon_mesh,
    read_pts,
)

EXAMPLES = int(os.environ.get("FACEGEOM_FUZZ_EXAMPLES", "100"))
FUZZ = settings(max_examples=EXAMPLES, deadline=None, derandomize="FACEGEOM_FUZZ_EXAMPLES" not in os.environ,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow], database=None)

SQUARE = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0.5, 1]])


def _ply(fmt: str) -> bytes:
    head = (f"ply\nformat {fmt} 1.0\ncomment seed\nelement vertex 5\nproperty float x\nproperty float y\n"
            "property float z\nproperty uchar red\nelement face 3\nproperty list uchar int vertex_indices\n"
            "property list uchar float texcoord\nelement edge 1\nproperty int a\nproperty int b\nend_header\n")
    faces = [[0, 1, 2, 3], [0, 1, 4], [1, 2, 4]]
    if fmt == "ascii":
        body = "".join(f"{x} {y} {z} 255\n" for x, y, z in SQUARE)
        body += "".join(f"{len(f)} {' '.join(map(str, f))} 2 0.5 0.5\n" for f in faces) + "0 1\n"
        return (head + body).encode()
    o = "<" if fmt.endswith("little_endian") else ">"
    body = b"".join(struct.pack(o + "3fB", x, y, z, 255) for x, y, z in SQUARE)
    body += b"".join(struct.pack(o + f"B{len(f)}iB2f", len(f), *f, 2, 0.5, 0.5) for f in faces)
    return head.encode() + body + struct.pack(o + "2i", 0, 1)


SEEDS = {
    "obj": (b"# seed\nmtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0 1 0 0\nv 0 1 0\nv 0.5 0.5 1\nvt 0 0\nvn 0 0 1\n"
            b"g g\ns off\nf 1/1/1 2/1/1 3/1/1 4/1/1\nf 1//1 2//1 -1//1\nf 2 3 \\\n 5\nl 1 2\n"),
    "ply_ascii": _ply("ascii"),
    "ply_binary": _ply("binary_little_endian"),
    "ply_big": _ply("binary_big_endian"),
    "off": b"# seed\nCOFF\n5 3 0\n0 0 0 255 0 0\n1 0 0 255 0 0\n1 1 0 0 0 255\n0 1 0 0 0 255\n0.5 0.5 1 1 1 1\n"
           b"4 0 1 2 3\n3 0 1 4 255 0 0\n3 1 2 4\n",
    "xyz": b"# x y z\n0 0 0\n1 0 0 0 0 1\n1 1 0\n\n0 1 0\n0.5 0.5 1\n",
    "landmarks": b"vertex_id,u,v\n0,10.5,20\n3,11,21.25\n7,0,0\n",
    "markers": b"vertex_id,x,y,z\n5,0.1,0.2,0.3\n0,1,2,3\n17,-1,-2,-3\n",
    "sequence": b"frame,marker,x,y,z\n0,m0,0,0,0\n0,m1,1,0,0\n1,m0,0,0.1,0\n1,m1,1,0.1,0\n",
    "pts": b"version: 1\nn_points:  3\n{\n357.417253 308.455774\n356.005 320.18\n1 1\n}\n",
}
SUFFIX = {"obj": ".obj", "ply_ascii": ".ply", "ply_binary": ".ply", "ply_big": ".ply", "off": ".off",
          "xyz": ".xyz", "landmarks": ".csv", "markers": ".csv", "sequence": ".csv", "npz": ".npz",
          "pts": ".pts"}


def _npz_seed() -> bytes:
    buf = io.BytesIO()
    np.savez(buf, positions=np.arange(12, dtype=float).reshape(2, 2, 3), frames=np.array([0, 1]),
             names=np.array(["m0", "m1"]))
    return buf.getvalue()


SEEDS["npz"] = _npz_seed()

NUMBER = re.compile(rb"\d+")
HUGE = [b"0", b"-1", b"4294967295", b"1000000000", b"99999999999999999999", b"nan", b"1e308", b"-2147483648"]


@st.composite
def mutated(draw, kind: str) -> bytes:
    """A seed changed by 1-4 random edits, or random bytes, or another format's seed."""
    data = SEEDS[kind]
    if draw(st.integers(0, 9)) == 0:
        return draw(st.binary(max_size=300))
    if draw(st.integers(0, 9)) == 0:
        data = SEEDS[draw(st.sampled_from(sorted(SEEDS)))]
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["cut", "flip", "insert", "delete", "number", "splice", "repeat"]))
        at = draw(st.integers(0, len(data)))
        if op == "cut":
            data = data[:at]
        elif op == "flip" and data:
            at = min(at, len(data) - 1)
            data = data[:at] + bytes([data[at] ^ draw(st.integers(1, 255))]) + data[at + 1:]
        elif op == "insert":
            data = data[:at] + draw(st.binary(min_size=1, max_size=8)) + data[at:]
        elif op == "delete":
            data = data[:at] + data[at + draw(st.integers(1, 16)):]
        elif op == "number":
            numbers = list(NUMBER.finditer(data))
            if numbers:
                m = numbers[draw(st.integers(0, len(numbers) - 1))]
                data = data[:m.start()] + draw(st.sampled_from(HUGE)) + data[m.end():]
        elif op == "splice":
            other = SEEDS[draw(st.sampled_from(sorted(SEEDS)))]
            data = data[:at] + other[:draw(st.integers(0, len(other)))]
        elif op == "repeat":
            data = data[:at] + data[at:at + draw(st.integers(1, 64))] * draw(st.integers(2, 20)) + data[at:]
    return data


def check_mesh(path):
    try:
        V, F = read_mesh(path)
    except InputError:
        return
    assert V.dtype == np.float64 and V.ndim == 2 and V.shape[1] == 3 and V.shape[0] >= 1
    assert np.isfinite(V).all()
    assert F.dtype == np.int64 and F.ndim == 2 and F.shape[1] == 3 and F.shape[0] >= 1
    assert F.min() >= 0 and F.max() < V.shape[0]
    mesh = read_polygon_mesh(path)
    assert (mesh.sizes >= 3).all() and mesh.offsets[-1] == mesh.corners.size
    assert np.array_equal(mesh.triangles(), F)


def check_cloud(path):
    try:
        P = read_point_cloud(path)
    except InputError:
        return
    assert P.dtype == np.float64 and P.ndim == 2 and P.shape[1] == 3 and P.shape[0] >= 1 and np.isfinite(P).all()


def check_landmarks(path):
    try:
        ids, uv = read_landmarks(path)
    except InputError:
        return
    assert ids.dtype == np.int64 and ids.ndim == 1 and (ids >= 0).all() and np.unique(ids).size == ids.size
    assert uv.shape == (ids.size, 2) and np.isfinite(uv).all()


def check_pts(path):
    try:
        P = read_pts(path)
    except InputError:
        return
    assert P.dtype == np.float64 and P.ndim == 2 and P.shape[1] == 2 and P.shape[0] >= 1 and np.isfinite(P).all()


def check_markers(path):
    try:
        ids, pos = read_markers(path, n_vertices=20)
    except InputError:
        return
    assert ids.ndim == 1 and (ids >= 0).all() and (ids < 20).all() and np.unique(ids).size == ids.size
    assert pos.shape == (ids.size, 3) and np.isfinite(pos).all()


def check_sequence(path):
    try:
        seq = read_marker_sequence(path)
    except InputError:
        return
    P = np.asarray(seq.positions)
    assert P.dtype == np.float64 and P.ndim == 3 and P.shape[2] == 3
    assert np.asarray(seq.frames).shape == (P.shape[0],)


CHECKS = {"obj": (check_mesh, check_cloud), "ply_ascii": (check_mesh, check_cloud),
          "ply_binary": (check_mesh, check_cloud), "ply_big": (check_mesh, check_cloud),
          "off": (check_mesh, check_cloud), "xyz": (check_cloud,), "landmarks": (check_landmarks,),
          "markers": (check_markers,), "sequence": (check_sequence,), "npz": (check_sequence,),
          "pts": (check_pts,)}
BOUNDED = {"obj", "ply_ascii", "ply_binary", "ply_big", "off", "xyz"}  # our readers: memory O(file size)


def run_readers(kind: str, data: bytes, path) -> None:
    path.write_bytes(data)
    measure = kind in BOUNDED
    if measure:
        tracemalloc.start()
    try:
        for check in CHECKS[kind]:
            check(path)
        if measure:
            peak = tracemalloc.get_traced_memory()[1]
            assert peak < 100 * len(data) + (1 << 20), f"{peak} bytes for a {len(data)}-byte file"
    finally:
        if measure:
            tracemalloc.stop()


@pytest.mark.parametrize("kind", sorted(SEEDS))
def test_seeds_are_valid(tmp_path, kind):
    path = tmp_path / f"seed{SUFFIX[kind]}"
    path.write_bytes(SEEDS[kind])
    for check in CHECKS[kind]:
        check(path)
    if kind in BOUNDED:
        assert read_point_cloud(path).shape[0] == 5
    if kind in BOUNDED - {"xyz"}:
        assert read_polygon_mesh(path).n_faces == 3


@pytest.mark.parametrize("kind", sorted(SEEDS))
def test_mutated_files_read_or_raise_input_error(tmp_path, kind):
    @FUZZ
    @given(data=mutated(kind))
    def run(data):
        run_readers(kind, data, tmp_path / f"f{SUFFIX[kind]}")

    run()


# Inputs that crashed, hung or misread (issue 16 and what the fuzzing found), as literal bytes.
CORPUS = [
    ("obj", b"v 0 0 0\nf 1\n"),
    ("obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n"),
    ("obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 3\nf 3"),
    ("obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf -9 1 2\n"),
    ("obj", b"v \\\n\\\n\\"),
    ("ply_ascii", b"ply\n"),
    ("ply_ascii", b"ply\nformat ascii 1.0\nelement x -1\nend_header\n"),
    ("ply_ascii", b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                  b"element face 2\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 nan 0\n"
                  b"3 0 1 2\n"),
    ("ply_binary", b"ply\nformat binary_little_endian 1.0\nend_header\n"),
    ("ply_binary", b"ply\nformat binary_little_endian 1.0\nelement vertex 4294967295\nproperty double x\n"
                   b"property double y\nproperty double z\nend_header\n"),
    ("ply_binary", b"ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
                   b"property float z\nelement face 99999999\nproperty list uint uint vertex_indices\nend_header\n"
                   b"\xff\xff\xff\xff"),
    ("ply_binary", b"ply\nformat binary_little_endian 1.0\nelement e 99999999999999999999\nend_header\n"),
    ("off", b"OFF"),
    ("off", b"OFF\n1000000000 8 0"),
    ("off", b"  # c\n  OFF # c\n 3 1 0\n0 0 0\n1 0 0\n0 1 0\n 3 0 1 2\n"),
    ("off", b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n9223372036854775807 0 1 2\n"),
    ("xyz", b"1 2 3\n\xff\xfe\n"),
    ("landmarks", b"vertex_id,u,v\n99999999999999999999,10.5,20\n3,11,21.25\n7,0,0\n"),  # OverflowError
    ("markers", b"vertex_id,x,y,z\n99999999999999999999,0.1,0.2,0.3\n"),  # OverflowError
    ("sequence", b"frame,marker,x,y,z\n99999999999999999999,m0,0,0,0\n"),
]


@pytest.mark.parametrize("kind,data", CORPUS)
def test_regression_corpus(tmp_path, kind, data):
    run_readers(kind, data, tmp_path / f"c{SUFFIX[kind]}")


# ----------------------------------------------------------------------------- C3D
# ezc3d (C++) crashes, loops or allocates without bound on some malformed files; read_c3d parses in a
# child process, so a crash there is an InputError here and cannot take pytest down with it. Each
# example starts one process (~0.3 s), hence fewer examples than the text readers.
C3D_EXAMPLES = max(10, EXAMPLES // 4)
C3D_HEADER_COUNTS = (0, 2, 4, 6, 8, 16, 18)  # byte offsets of the header's u16 counts and block numbers


def _c3d_seed() -> bytes:
    pytest.importorskip("ezc3d")
    import tempfile

    from facegeom.io.c3d import write_c3d

    P = np.arange(120, dtype=float).reshape(10, 4, 3) + 1.0
    P[2, 1] = np.nan  # one gap
    with tempfile.TemporaryDirectory() as d:
        return write_c3d(os.path.join(d, "seed.c3d"), P, list("abcd"), 90.0, "cm").read_bytes()


@st.composite
def mutated_c3d(draw, seed: bytes) -> bytes:
    """A valid C3D cut short, with bytes flipped, a header count made huge, or a parameter byte replaced."""
    data = bytearray(seed)
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(["cut", "flip", "count", "param"]))
        if op == "cut":
            data = data[:draw(st.integers(0, len(data)))]
        elif op == "flip" and data:
            at = draw(st.integers(0, len(data) - 1))
            data[at] ^= draw(st.integers(1, 255))
        elif op == "count" and len(data) >= 20:
            at = draw(st.sampled_from(C3D_HEADER_COUNTS))
            data[at:at + 2] = struct.pack("<H", draw(st.sampled_from([0, 1, 255, 32767, 65535])))
        elif op == "param" and len(data) > 600:
            at = draw(st.integers(512, min(len(data), 1024) - 1))
            data[at] = draw(st.sampled_from([0, 1, 0x7F, 0x80, 0xFF]))
    return bytes(data)


def _check_c3d(path) -> None:
    from facegeom.io.c3d import read_c3d

    try:
        seq = read_c3d(path)
    except InputError as exc:
        assert "\n" not in str(exc) and str(path) in str(exc)
        return
    P = seq.positions
    assert P.dtype == np.float64 and P.ndim == 3 and P.shape[2] == 3 and P.shape[0] >= 1 and P.shape[1] >= 1
    assert not np.isinf(P).any() and len(seq.names) == P.shape[1] and len(set(seq.names)) == P.shape[1]
    assert np.array_equal(seq.frames, np.arange(P.shape[0])) and seq.fps > 0
    assert seq.unit in (None, "mm", "cm", "m")


@pytest.fixture
def quick_c3d_timeout(monkeypatch):
    from facegeom.io import c3d

    monkeypatch.setattr(c3d, "_TIMEOUT_S", 3.0)  # the seed reads in ~0.3 s; a hang ends in 3 s, not 10


def test_c3d_seed_is_valid(tmp_path):
    path = tmp_path / "seed.c3d"
    path.write_bytes(_c3d_seed())
    from facegeom.io.c3d import read_c3d

    seq = read_c3d(path)
    assert seq.names == tuple("abcd") and seq.unit == "cm" and seq.missing().sum() == 1


def test_mutated_c3d_reads_or_raises_input_error(tmp_path, quick_c3d_timeout):
    seed = _c3d_seed()

    @settings(FUZZ, max_examples=C3D_EXAMPLES)
    @given(data=mutated_c3d(seed))
    def run(data):
        path = tmp_path / "f.c3d"
        path.write_bytes(data)
        _check_c3d(path)

    run()


def test_c3d_regression_corpus(tmp_path, quick_c3d_timeout):
    """Files that crashed or hung ezc3d in earlier fuzzing, rebuilt from the seed by the edits found."""
    seed = _c3d_seed()
    hang = bytearray(seed)
    hang[670] = 0x7A  # a parameter's next-entry offset: ezc3d loops for about a minute
    huge = bytearray(seed)
    huge[2:4] = b"\xff\x7f"  # 32767 points in the header
    for k, data in enumerate([bytes(hang), bytes(huge), seed[:512], seed[:600]]):
        path = tmp_path / f"c{k}.c3d"
        path.write_bytes(data)
        _check_c3d(path)


# ----------------------------------------------------------------------------- glTF binary (.glb)


def _glb_seed() -> bytes:
    pytest.importorskip("pygltflib")
    import tempfile

    from facegeom.io.gltf import write_rig_glb

    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=float)
    F = np.array([[0, 1, 2], [0, 2, 3]])
    D = np.stack([np.full((4, 3), 0.1), np.eye(4, 3)])
    W = np.array([[0.0, 1.0], [0.5, 0.5], [1.0, 0.0]])
    with tempfile.TemporaryDirectory() as d:
        return write_rig_glb(os.path.join(d, "seed.glb"), V, F, D, ["a", "b"], W, 30.0).read_bytes()


@st.composite
def mutated_glb(draw, seed: bytes) -> bytes:
    """A valid .glb cut short, with bytes flipped, a JSON number made huge, or a chunk length changed."""
    data = bytearray(seed)
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(["cut", "flip", "number", "length"]))
        if op == "cut":
            data = data[:draw(st.integers(0, len(data)))]
        elif op == "flip" and data:
            at = draw(st.integers(0, len(data) - 1))
            data[at] ^= draw(st.integers(1, 255))
        elif op == "number":
            numbers = list(NUMBER.finditer(bytes(data[:200 + len(data) // 2])))
            if numbers:
                m = numbers[draw(st.integers(0, len(numbers) - 1))]
                data[m.start():m.end()] = draw(st.sampled_from(HUGE))
        elif op == "length" and len(data) >= 16:
            at = draw(st.sampled_from([8, 12]))
            data[at:at + 4] = struct.pack("<I", draw(st.sampled_from([0, 1, 7, 2 ** 31, 2 ** 32 - 1])))
    return bytes(data)


def _check_glb(path) -> None:
    from facegeom.io.gltf import read_glb_animation

    try:
        g = read_glb_animation(path)
    except InputError as exc:
        assert "\n" not in str(exc) and str(path) in str(exc)
        return
    n, K = g.neutral.shape[0], g.deltas.shape[0]
    assert g.neutral.shape == (n, 3) and g.deltas.shape == (K, n, 3) and len(g.names) == K
    assert g.faces.ndim == 2 and g.faces.shape[1] == 3 and (g.faces.size == 0 or g.faces.max() < n)
    assert g.weights.shape == (g.times.size, K) and np.isfinite(g.weights).all()


def test_glb_seed_is_valid(tmp_path):
    from facegeom.io.gltf import read_glb_animation

    path = tmp_path / "seed.glb"
    path.write_bytes(_glb_seed())
    g = read_glb_animation(path)
    assert g.names == ("a", "b") and g.weights.shape == (3, 2)


def test_mutated_glb_reads_or_raises_input_error(tmp_path):
    seed = _glb_seed()

    @FUZZ
    @given(data=mutated_glb(seed))
    def run(data):
        path = tmp_path / "f.glb"
        path.write_bytes(data)
        _check_glb(path)

    run()
